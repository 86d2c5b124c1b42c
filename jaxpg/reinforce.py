"""REINFORCE on CartPole: the book's training loop as one compiled program.

One iteration plays `episodes` episodes of at most `max_steps` steps with the current policy,
discounts and normalises the rewards, and takes one optimizer step on the REINFORCE loss. The whole
run (every iteration) is a single `lax.scan`, with `vmap` over runs inside it, so that many seeds
and hyperparameter settings train at once in one program.
"""

import dataclasses
import functools
import inspect
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from jaxpg import cartpole, policies, progress, returns, rollout, sums


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Settings of a training run: the book's by default.

    `learning_rate` and `discount` are hyperparameters that a sweep vmaps over; every other field
    fixes the program's shapes or structure.
    """

    # Fix the program.
    iterations: int = 150
    episodes: int = 10  # per update
    max_steps: int = 200  # per episode
    hidden: tuple[int, ...] = (5,)
    activation: str = "elu"
    optimizer: str = "adam"  # any optax optimizer taking a `learning_rate`
    env: str | cartpole.CartPoleParams = "CartPole-v1"
    solved_return: float = 195.0  # the mean return that counts as solved
    # Vmappable.
    learning_rate: float = 0.01
    discount: float = 0.95

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(self.hidden))
        for name in ("iterations", "episodes", "max_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}: must be a positive integer, got {value!r}")
        policies.check_network(self.hidden, self.activation)
        check_optimizer(self.optimizer)
        check_hyperparams(self.learning_rate, self.discount)
        self.env_params  # validates

    @property
    def env_params(self):
        if isinstance(self.env, cartpole.CartPoleParams):
            cartpole.check_params(self.env)
            return self.env
        return cartpole.make_params(self.env)

    @property
    def network(self):
        return policies.PolicyNetwork(hidden=self.hidden, activation=self.activation)

    @property
    def hyperparams(self):
        return Hyperparams(self.learning_rate, self.discount)


class Hyperparams(NamedTuple):
    """The settings a sweep vmaps over: scalars, or `[R]` arrays for R runs."""

    learning_rate: jax.Array
    discount: jax.Array


def check_hyperparams(learning_rate, discount):
    """Raises a ValueError unless every learning rate is positive and every discount in (0, 1]."""
    for lr in jnp.atleast_1d(jnp.asarray(learning_rate)).tolist():
        if not lr > 0:
            raise ValueError(f"learning_rate: must be positive, got {lr}")
    for d in jnp.atleast_1d(jnp.asarray(discount)).tolist():
        if not 0 < d <= 1:
            raise ValueError(f"discount: must be in (0, 1], got {d}")


def _optimizer_factories():
    """optax's optimizers: the functions whose first parameter is `learning_rate`."""
    factories = {}
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


def check_optimizer(name):
    if name not in OPTIMIZERS:
        raise ValueError(
            f"optimizer: unknown {name!r}; allowed: optax optimizers such as adam, sgd, rmsprop "
            f"({len(OPTIMIZERS)} in all: {', '.join(sorted(OPTIMIZERS))})"
        )


RUNS_AXIS = "runs"  # the vmapped axis of runs: rollouts skip ended chunks once all runs agree


class TrainState(NamedTuple):
    """The carry of one run from iteration to iteration."""

    policy_params: dict
    opt_state: optax.OptState
    key: jax.Array


class Metrics(NamedTuple):
    """Per-iteration statistics of a run: `[I]`, or `[R, I]` for R runs."""

    mean_return: jax.Array
    min_return: jax.Array
    max_return: jax.Array
    mean_length: jax.Array
    loss: jax.Array
    grad_norm: jax.Array


class TrainResult(NamedTuple):
    """The trained policy and its per-iteration metrics (leading axis `[R]` for several runs)."""

    policy_params: dict
    metrics: Metrics


def reinforce_loss(policy_params, network, transitions, advantages):
    """Mean over the alive steps of -advantage * log pi(a|s).

    Its gradient is the book's: the gradient of the binary cross-entropy between P(left) and the
    action taken, weighted by the normalised return and averaged over every step of every episode.
    """
    logits = network.apply(policy_params, transitions.obs)
    log_probs = policies.log_prob(logits, transitions.action)
    return -sums.pairwise_mean(advantages * log_probs, (0, 1), transitions.alive)


def global_norm(tree):
    """The L2 norm of every leaf together, summed pairwise so that it is batch-invariant."""
    squares = [sums.pairwise_sum(jnp.square(leaf).ravel(), 0) for leaf in jax.tree.leaves(tree)]
    return jnp.sqrt(sum(squares))


def make_optimizer(config, learning_rate):
    return OPTIMIZERS[config.optimizer](learning_rate=learning_rate)


def init_run(config, key, hyperparams):
    """The initial `TrainState` of one run."""
    key, key_init = jax.random.split(key)
    policy_params = policies.init_network(key_init, config.network)
    opt_state = make_optimizer(config, hyperparams.learning_rate).init(policy_params)
    return TrainState(policy_params, opt_state, key)


def iterate(config, train_state, hyperparams):
    """One REINFORCE iteration of one run: play, discount, normalise, step the optimizer."""
    network = config.network
    key, key_rollout = jax.random.split(train_state.key)

    # Play the episodes with the current policy.
    policy = policies.network_policy(network, train_state.policy_params)
    episodes = rollout.rollout(
        key_rollout, policy, config.env_params, config.episodes, config.max_steps,
        axis_name=RUNS_AXIS,
    )
    transitions = episodes.transitions

    # Discounted returns, normalised over every step of every episode.
    advantages = returns.discount_and_normalize_masked(
        transitions.reward, transitions.alive, hyperparams.discount
    )

    # One optimizer step on the REINFORCE loss.
    loss, grads = jax.value_and_grad(reinforce_loss)(
        train_state.policy_params, network, transitions, advantages
    )
    optimizer = make_optimizer(config, hyperparams.learning_rate)
    updates, opt_state = optimizer.update(grads, train_state.opt_state, train_state.policy_params)
    policy_params = optax.apply_updates(train_state.policy_params, updates)

    metrics = Metrics(
        mean_return=episodes.returns.mean(),
        min_return=episodes.returns.min(),
        max_return=episodes.returns.max(),
        mean_length=episodes.lengths.mean(),
        loss=loss,
        grad_norm=global_norm(grads),
    )
    return TrainState(policy_params, opt_state, key), metrics


@functools.lru_cache(maxsize=32)
def compiled_program(config, show_progress):
    """The jitted training of R runs at once: `(keys [R], Hyperparams [R]) -> TrainResult [R]`.

    The scan over iterations is outermost and the vmap over runs inside it, so the progress
    callback fires once per iteration with the mean return of every run.
    """

    def program(keys, hyperparams):
        train_states = jax.vmap(functools.partial(init_run, config))(keys, hyperparams)

        def one_iteration(train_states, iteration):
            train_states, metrics = jax.vmap(
                functools.partial(iterate, config), axis_name=RUNS_AXIS
            )(train_states, hyperparams)
            if show_progress:
                progress.report(iteration, metrics.mean_return)
            return train_states, metrics

        train_states, metrics = jax.lax.scan(
            one_iteration, train_states, jnp.arange(config.iterations)
        )
        # Metrics come out of the scan as [I, R]; runs first reads better.
        return TrainResult(train_states.policy_params, jax.tree.map(jnp.transpose, metrics))

    return jax.jit(program)


def run_keys(seeds):
    """One PRNG key per seed: `[R, 2]`."""
    return jax.vmap(jax.random.PRNGKey)(jnp.asarray(seeds, dtype=jnp.uint32))


def train(config=TrainConfig(), seed=0, show_progress=True):
    """Trains one policy with REINFORCE.

    Returns:
      `TrainResult`: the final `policy_params` and `Metrics` with `[iterations]` leaves.
    """
    if not isinstance(config, TrainConfig):
        raise ValueError(f"config: expected a TrainConfig, got {type(config).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        raise ValueError(f"seed: must be an integer in [0, 2**32), got {seed!r}")
    hyperparams = jax.tree.map(lambda v: jnp.asarray([v], jnp.float32), config.hyperparams)
    with progress.bar(config.iterations, enabled=show_progress):
        result = compiled_program(config, show_progress)(run_keys([seed]), hyperparams)
        jax.block_until_ready(result)
    return jax.tree.map(lambda leaf: leaf[0], result)
