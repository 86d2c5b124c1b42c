"""The settings of a training run: `TrainConfig`, and the hyperparameters a sweep varies."""

import dataclasses
import functools
import inspect
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence, Set
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import numpy as np
import optax

from jaxpg import envs, losses, policies
from jaxpg.envs import cartpole
from jaxpg.types import ArrayLike
from jaxpg.validation import (
    check_int,
    check_number,
    check_representable,
    in_float64,
    is_int,
    shown,
)

# An optimizer of the user's: `learning_rate -> optax.GradientTransformation`.
OptimizerFactory = Callable[[ArrayLike], optax.GradientTransformation]
# Domain randomisation as `TrainConfig` keeps it: sorted `(field, (low, high))` pairs.
Ranges = tuple[tuple[str, tuple[float, float]], ...]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Settings of a training run: the book's by default.

    `learning_rate`, `discount` and `entropy_coef` are hyperparameters that a sweep varies within
    one compiled program; every other field fixes the program's shapes or structure.

    Attributes:
      iterations: optimizer steps, each on `episodes` fresh episodes of at most `max_steps` steps.
      episodes: episodes played per optimizer step.
      max_steps: the most steps of an episode, at most the environment's time limit
        (`max_steps` of its params); None (the default) is the book's 200 on CartPole (its time
        limit where shorter), that time limit elsewhere, kept as that number
        (`dataclasses.replace` of `env` keeps it too).
      hidden: the hidden layer sizes of the default policy network (`policies.PolicyNetwork`),
        used where `policy` is None; `()` is a linear policy.
      activation: the default network's activation, a name of `policies.ACTIVATIONS`.
      policy: optional flax module mapping observations `[..., K]` to its action distribution
        (`jaxpg.distributions.from_output`): on CartPole the logit of P(push left), `[...]` or
        `[..., 1]`, or the two logits of a categorical policy `[..., 2]`; on an environment of
        n discrete actions their logits `[..., n]`; on a continuous one (mean, log standard
        deviation) `[..., 2]`. The default network gives each environment its kind.
      loss: "reinforce" (the book's), "reward-to-go", "baseline", "ppo", or a function
        `loss(params, apply_fn, batch, hyper) -> (loss, metrics)` (`jaxpg.losses`).
      optimizer: an optax optimizer's name (one taking a `learning_rate`), or a function
        `learning_rate -> optax.GradientTransformation`.
      env: the environment: a name of `jaxpg.envs.MODULES` ("CartPole-v1", "Acrobot-v1", ...) or
        an environment's params (`cartpole.CartPoleParams`, `envs.acrobot.AcrobotParams`, ...).
      randomize: domain randomisation, `{field: (low, high)}` of physical fields (`physics`):
        every episode draws each named field uniformly in [low, high) inside the program. Kept
        as `Ranges`, sorted `(field, (low, high))` pairs of floats.
      solved_return: the mean return that counts as solved; None (the default) is the
        environment's (`envs.solved_return`: the book's 195 on CartPole, Gymnasium's threshold
        elsewhere), kept as that number.
      epochs: how many times each iteration's episodes are gone through, one optimizer step per
        minibatch each time (PPO's epochs); 1 by default, the book's one step.
      minibatches: how many minibatches of whole episodes each epoch splits the episodes into,
        shuffled anew every epoch; `episodes` must be a multiple of it. Several updates on
        minibatches of one episode can train a seed in its last bits otherwise alone than in a
        sweep on a CPU without AVX-512 (README).
      learning_rate: the optimizer's learning rate, positive.
      discount: the discount rate of the returns, in (0, 1].
      entropy_coef: the weight of the entropy bonus `-entropy_coef * mean entropy` added to any
        loss, at least 0.

    Raises:
      ValueError: on construction, naming the first field that is not allowed.
    """

    # Fix the program.
    iterations: int = 150
    episodes: int = 10  # per update
    # Per episode; None stands for the environment's, which the field holds once constructed.
    max_steps: int = None  # type: ignore[assignment]
    hidden: tuple[int, ...] = (5,)
    activation: str = "elu"
    policy: nn.Module | None = None
    loss: str | losses.LossFn = "reinforce"
    optimizer: str | OptimizerFactory = "adam"
    env: Any = "CartPole-v1"  # a name, or an environment's params
    randomize: Any = ()  # a dict {field: (low, high)}, kept as `Ranges`
    solved_return: float = None  # type: ignore[assignment]  # as max_steps: the environment's
    epochs: int = 1
    minibatches: int = 1
    # Varied by sweeps within one program.
    learning_rate: float = 0.01
    discount: float = 0.95
    entropy_coef: float = 0.0

    def __post_init__(self) -> None:
        """Converts `hidden` and `randomize` to their kept forms and checks every field."""
        # A sequence of sizes (a dict or a set is no order of layers).
        if isinstance(self.hidden, Iterable) and not isinstance(self.hidden, str | Mapping | Set):
            object.__setattr__(self, "hidden", tuple(self.hidden))
        if self.max_steps is None:
            object.__setattr__(self, "max_steps", envs.max_steps(self.env_params))
        for name in ("iterations", "episodes", "max_steps", "epochs", "minibatches"):
            object.__setattr__(self, name, check_int(name, getattr(self, name)))
        if self.episodes % self.minibatches:
            raise ValueError(f"minibatches: must divide episodes ({self.episodes}), got "
                             f"{self.minibatches}")
        policies.check_network(self.hidden, self.activation)
        if self.policy is not None and not isinstance(self.policy, nn.Module):
            raise ValueError(f"policy: expected None or a flax.linen.Module, got "
                             f"{type(self.policy).__name__}")
        losses.resolve(self.loss)
        check_optimizer(self.optimizer)
        check_hyperparams(self.learning_rate, self.discount, self.entropy_coef)
        env_params = self.env_params  # raises for an unknown name or unphysical values
        envs.check_episode_steps(self.max_steps, env_params)
        if self.solved_return is None:
            object.__setattr__(self, "solved_return", envs.solved_return(env_params))
        check_number("solved_return", self.solved_return)
        if getattr(env_params, "torque_noise_max", 0):
            raise ValueError("torque_noise_max: training plays Acrobot without torque noise, got "
                             f"{env_params.torque_noise_max}")
        object.__setattr__(self, "randomize", check_ranges(self.randomize, env_params))

    @property
    def env_params(self) -> Any:
        """The environment's params: a preset's, or `env` checked (`envs.resolve`)."""
        return envs.resolve(self.env)

    @property
    def env_name(self) -> str:
        """The environment's name: `env`'s, or its module's for params (CartPole-v1's for
        CartPole's)."""
        return self.env if isinstance(self.env, str) else self.env_module.NAME

    @property
    def env_module(self) -> Any:
        """The environment's module: one of `jaxpg.envs` (CartPole's: `jaxpg.envs.cartpole`)."""
        return envs.module_of(self.env_params)

    @property
    def num_actions(self) -> int | None:
        """The environment's number of discrete actions; None for a continuous action."""
        return getattr(self.env_module, "NUM_ACTIONS", None)

    @property
    def physics(self) -> tuple[str, ...]:
        """The environment's fields that a grid or `randomize` may vary (`envs.physics`)."""
        return envs.physics(self.env_module)

    @property
    def network(self) -> nn.Module:
        """The policy module: `policy`, or the default network of `hidden` and `activation` for
        the environment's actions (one logit on CartPole, n logits, or a `GaussianNetwork`)."""
        if self.policy is not None:
            return self.policy
        if self.num_actions is None:
            return policies.GaussianNetwork(hidden=self.hidden, activation=self.activation)
        return policies.PolicyNetwork(hidden=self.hidden, activation=self.activation,
                                      outputs=1 if self.num_actions == 2 else self.num_actions)

    @property
    def hyperparams(self) -> "Hyperparams":
        """The config's `Hyperparams`, scalars, with its physics."""
        return Hyperparams(self.learning_rate, self.discount, self.entropy_coef, self.env_params)

    @property
    def built_in(self) -> bool:
        """Whether the policy, loss and optimizer are jaxpg's or optax's, named, and the
        environment jaxpg's.

        Then nothing of the user's code decides the training program, which may be kept on disk.
        """
        return self.policy is None and isinstance(self.loss, str) and isinstance(
            self.optimizer, str) and envs.is_built_in(self.env_module)

    @property
    def hand_gradient(self) -> bool:
        """Whether training takes the fast path, whose gradient `jaxpg.hand_gradient` computes.

        That is the default network on CartPole with the book's loss, no entropy bonus and an
        optimizer of `ELEMENTWISE_OPTIMIZERS`.
        """
        return (self.policy is None and self.loss == "reinforce" and self.entropy_coef == 0
                and self.optimizer in ELEMENTWISE_OPTIMIZERS and self.updates == 1
                and self.env_module is cartpole)

    @property
    def updates(self) -> int:
        """Optimizer steps per iteration: `epochs * minibatches`."""
        return self.epochs * self.minibatches


class Hyperparams(NamedTuple):
    """The settings a sweep varies within one program: scalars, or `[R]` arrays for R runs.

    Attributes:
      learning_rate: float32, the optimizer's learning rate.
      discount: float32, the discount rate of the returns.
      entropy_coef: float32, the weight of the entropy bonus.
      env: each run's physics, leaves as the other fields: every physics, a preset's too, is an
        input of the training program, so that one program serves every value and a value trains
        alike whether it is the config's or a grid's.
    """

    learning_rate: ArrayLike
    discount: ArrayLike
    entropy_coef: ArrayLike
    env: Any  # the environment's params

    def per_run(self, runs: int = 1) -> "Hyperparams":
        """These settings, scalars, repeated for `runs` runs.

        Args:
          runs: how many runs.

        Returns:
          `Hyperparams` with numpy `[runs]` leaves in the dtypes training takes them: the
          optimizer's in float32, the physics in JAX's default float, `max_steps` in int32.
        """
        return stack([self] * runs)


def check_ranges(randomize: Any, env_params: Any) -> Ranges:
    """`randomize` as sorted `(field, (low, high))` pairs of floats, checked.

    Each bound is checked as the physics it stands for (the environment's `check_params`), in
    JAX's default float, and so is the width `high - low` that a draw scales by.

    Args:
      randomize: a dict `{field: (low, high)}`, or a list or tuple of `(field, (low, high))` pairs.
      env_params: the physics whose fields the ranges replace, to check each bound's physics.

    Returns:
      The ranges as `Ranges`, sorted by field.

    Raises:
      ValueError: naming `randomize` where it is neither, or names a field twice; naming the field
        for an unknown one, a range that is not two numbers (not bools or strings), whose low is
        above its high, or bounds that are not finite, not physical or overflow JAX's default
        float, as their width may.
    """
    pairs = list(randomize.items()) if isinstance(randomize, Mapping) else randomize
    if not (isinstance(pairs, list | tuple)
            and all(isinstance(pair, list | tuple) and len(pair) == 2 for pair in pairs)):
        raise ValueError(f"randomize: expected a dict {{field: (low, high)}} or (field, (low, "
                         f"high)) pairs, got {shown(randomize)}")
    floats = jax.dtypes.canonicalize_dtype(float)
    module = envs.module_of(env_params)
    physics = envs.physics(module)
    ranges: dict[str, tuple[float, float]] = {}
    for name, bounds in pairs:
        if name not in physics:
            raise ValueError(f"randomize: unknown field {name!r}; allowed: {', '.join(physics)}")
        if name in ranges:
            raise ValueError(f"randomize: {name} is given two ranges; give each field one")
        if not _is_pair(bounds):
            raise ValueError(f"{name}: expected a range (low, high), got {shown(bounds)}")
        # Each a number as given, finite (first: NaN is neither above nor below).
        low, high = (check_number(name, bound) for bound in bounds)
        if not low <= high:
            raise ValueError(f"{name}: the range's low is above its high: ({low}, {high})")
        for bound in (low, high):
            module.check_params(env_params.replace(**{name: bound}))
        check_representable(f"{name} (high - low)", in_float64(np.subtract, high, low), floats)
        ranges[name] = (low, high)
    return tuple(sorted(ranges.items()))


def _is_pair(bounds: Any) -> bool:
    """Whether `bounds` holds two single values: a list or tuple of two that are no sequences
    (numpy could not make an array of `((0.4,), 0.6)`), or a numpy or JAX array of shape (2,)."""
    if isinstance(bounds, list | tuple):
        return len(bounds) == 2 and all(
            not isinstance(bound, list | tuple) and np.ndim(bound) == 0 for bound in bounds)
    return isinstance(bounds, np.ndarray | jax.Array) and bounds.shape == (2,)


# Optimizers that update each parameter from its own history alone: the fast path steps a run's
# parameters as the one vector it keeps them in. `tests/test_iteration.py` checks every name here
# against the per-array update.
ELEMENTWISE_OPTIMIZERS = frozenset({
    "adabelief", "adadelta", "adagrad", "adam", "adamax", "adamaxw", "adamw", "adan", "amsgrad",
    "lion", "optimistic_adam_v2", "optimistic_gradient_descent", "radam", "rmsprop", "rprop", "sgd",
    "sign_sgd", "signum", "yogi",
})

# Hyperparameters that a sweep may vary, and the physical fields of `CartPoleParams`.
HYPERPARAMETERS = ("learning_rate", "discount", "entropy_coef")
PHYSICS = envs.physics(cartpole)


def stack(settings: Sequence[Hyperparams]) -> Hyperparams:
    """`Hyperparams` of R runs from R scalar ones.

    Args:
      settings: R scalar `Hyperparams`, all with the same static physics.

    Returns:
      `Hyperparams` with numpy `[R]` leaves: float32 hyperparameters; physics in JAX's default
      float, integer fields in int32.
    """
    floats = jax.dtypes.canonicalize_dtype(float)

    def column(*values: Any) -> np.ndarray:
        """One field's values of every run as a numpy `[R]` array."""
        if is_int(values[0]):
            return np.asarray(values, np.int32)
        return np.asarray(values, floats)

    env = jax.tree.map(column, *[setting.env for setting in settings])
    return Hyperparams(**{name: np.asarray([getattr(s, name) for s in settings], np.float32)
                          for name in HYPERPARAMETERS}, env=env)


def check_hyperparams(learning_rate: Any, discount: Any, entropy_coef: Any = 0.0) -> None:
    """Checks the hyperparameters of one run.

    Each is checked as the float32 that training takes it as (`stack`), by
    `check_representable`: it must not overflow there, and `learning_rate` and `discount`, which
    0 is not allowed for, must be normal float32s, not round to 0 or to a subnormal number.

    Args:
      learning_rate: must be positive.
      discount: must be in (0, 1].
      entropy_coef: must be at least 0.

    Raises:
      ValueError: naming the first that is not one finite number (`check_number`) in its range,
        or not one as float32.
    """
    checks = (("learning_rate", learning_rate, lambda v: v > 0, "positive"),
              ("discount", discount, lambda v: 0 < v <= 1, "in (0, 1]"),
              ("entropy_coef", entropy_coef, lambda v: v >= 0, "at least 0"))
    for name, value, ok, allowed in checks:
        number = check_number(name, value)
        if not ok(number):
            raise ValueError(f"{name}: must be {allowed}, got {number}")
        check_representable(name, number, np.float32, positive=not ok(0.0))


def _optimizer_factories() -> dict[str, Callable[..., optax.GradientTransformation]]:
    """optax's optimizers: the functions whose first parameter is `learning_rate`."""
    factories: dict[str, Callable[..., optax.GradientTransformation]] = {}
    for name in dir(optax):
        fn = getattr(optax, name)
        if name.startswith("_") or not inspect.isfunction(fn):
            continue
        try:
            params = list(inspect.signature(fn).parameters)
        except (TypeError, ValueError):
            continue
        if params[:1] == ["learning_rate"]:
            factories[name] = fn
    return factories


OPTIMIZERS = _optimizer_factories()


def steps_on_gradients(optimizer: optax.GradientTransformation) -> bool:
    """Whether `optimizer` updates from the gradient, its state and the parameters alone.

    Those are what training passes it; optax's `lbfgs`, for one, also asks for the loss's value
    and function. The update is traced on one float by `jax.eval_shape`, which compiles nothing.

    Args:
      optimizer: an optax optimizer.

    Returns:
      True where its `update(grads, state, params)` traces.
    """
    leaf = jax.ShapeDtypeStruct((1,), np.float32)
    try:
        jax.eval_shape(
            lambda params: optimizer.update(params, optimizer.init(params), params), leaf)
    except TypeError:
        return False
    return True


@functools.cache
def _trains(name: str) -> bool:
    """Whether the optimizer `OPTIMIZERS[name]` of a learning rate alone `steps_on_gradients`."""
    try:
        with warnings.catch_warnings():  # of the optimizer's defaults, for whoever trains with it
            warnings.simplefilter("ignore")
            return steps_on_gradients(OPTIMIZERS[name](learning_rate=0.01))
    except TypeError:  # its factory needs more than a learning rate
        return False


def check_optimizer(name: Any) -> None:
    """Checks `TrainConfig.optimizer`: a name of `OPTIMIZERS` that training can step, or a function.

    A function's optimizer is checked by `iteration.check_config`, before anything compiles.

    Args:
      name: an optax optimizer's name, or a function `learning_rate -> GradientTransformation`.

    Raises:
      ValueError: for an optimizer already made, or a name that optax lacks or whose optimizer
        does not `steps_on_gradients`, listing the names allowed.
    """
    if callable(name):
        return
    if hasattr(name, "init") and hasattr(name, "update"):  # an optax optimizer, made
        raise ValueError("optimizer: expected a name or a function learning_rate -> optimizer "
                         "(such as lambda lr: optax.adam(lr)), got an optimizer already made, "
                         "whose learning rate a sweep could not set")
    known = isinstance(name, str) and name in OPTIMIZERS  # (a list is no key: unhashable)
    if not known or not _trains(name):
        allowed = sorted(filter(_trains, OPTIMIZERS))
        raise ValueError(
            f"optimizer: {'cannot train with' if known else 'unknown'} "
            f"{shown(name)}; allowed: optax optimizers that update from the gradient alone, such "
            f"as adam, sgd, rmsprop ({len(allowed)} in all: {', '.join(allowed)})"
        )


def make_optimizer(config: TrainConfig, learning_rate: ArrayLike) -> optax.GradientTransformation:
    """The optax optimizer of `config` at `learning_rate`.

    Args:
      config: the `TrainConfig`, whose `optimizer` names or makes it.
      learning_rate: a scalar, traced inside the training program.

    Returns:
      The `optax.GradientTransformation`.
    """
    if callable(config.optimizer):
        return config.optimizer(learning_rate)
    return OPTIMIZERS[config.optimizer](learning_rate=learning_rate)
