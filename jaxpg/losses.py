"""Policy-gradient losses: the built-in ones and the helpers to write your own.

A loss is a function `loss(params, apply_fn, batch, hyper) -> (loss, metrics)` of one run
(`LossFn`):

- `params`: the policy's parameters; for a loss with a `critic` (a flax module mapping
  observations `[..., K]` to values `[...]`), `{"policy": ..., "critic": ...}`, each stepped by
  its own optimizer.
- `apply_fn(policy_params, obs [..., K]) -> dist`: the policy's action distribution
  (`jaxpg.distributions`): on CartPole the logit of P(push left) `[...]`, elsewhere a
  `Categorical` or a `Gaussian`. `log_prob(dist, action)` and `entropy(dist)` (here) take any.
- `batch`: a `Batch` of the iteration's episodes, `[T, E]` (time, episodes).
- `hyper`: the run's `Hyperparams` (learning rate, discount, entropy coefficient), scalars.
- `loss` is a scalar to minimise; `metrics` a dict of scalars, kept per iteration
  (`Metrics.extra`).

The trainer adds `-entropy_coef * masked_mean(entropy(dist), alive)` to any loss. A loss takes
no gradient through `jnp.max` of the network's outputs (see `jaxpg.runwise`: shift a softmax by a
`jax.lax.stop_gradient` maximum, or use `jax.nn.log_softmax`). It evaluates
the loss for many runs at once (`jaxpg.runwise`), with its sums in a fixed order.
"""

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxpg import returns, sums
from jaxpg.distributions import entropy as entropy  # re-exported: a loss writer's helpers
from jaxpg.distributions import log_prob as log_prob
from jaxpg.types import Array, ArrayLike, Params

if TYPE_CHECKING:
    from jaxpg.train_config import Hyperparams


class Batch(NamedTuple):
    """One iteration's episodes of one run, `[T, E]` leading axes.

    Steps after an episode ended have `alive` False and zero reward.

    Attributes:
      obs: float `[T, E, K]`, the observation each action was chosen from.
      action: `[T, E]`: int32 for discrete actions (on CartPole 0 pushed left, 1 right), float
        for a continuous one (as sampled, before the environment clipped it).
      reward: float `[T, E]`.
      alive: bool `[T, E]`: the step belongs to its episode.
      returns: float `[T, E]`, discounted returns-to-go, not normalised; 0 where not alive.
      log_prob: float `[T, E]`, log pi(a_t | s_t) of the policy that played the episodes (the
        parameters before this iteration's updates), held fixed.
      values: float `[T, E]`, the loss's critic's values of the observations before this
        iteration's updates, held fixed; 0 for a loss without a critic.
    """

    obs: Array
    action: Array
    reward: Array
    alive: Array
    returns: Array
    log_prob: Array | None = None
    values: Array | None = None


# `apply_fn(policy_params, obs [..., K]) -> dist`, the policy's action distribution.
ApplyFn = Callable[[Params, Array], Any]
# `loss(params, apply_fn, batch, hyper) -> (scalar loss, {name: scalar metric})`.
LossFn = Callable[[Params, ApplyFn, Batch, "Hyperparams"], tuple[Array, dict[str, Array]]]


def masked_mean(values: ArrayLike, alive: Array) -> Array:
    """The mean of `values` over the alive steps of every episode, summed in a fixed order.

    Args:
      values: `[T, E, ...]`; booleans and integers count as floats (0 and 1 for booleans).
      alive: bool `[T, E]`, with trailing axes of size 1 where `values` has more (`[T, E, 1]`
        for `[T, E, K]`): the steps to average over.

    Returns:
      float `[...]`, the mean over the first two axes; 0 where no step is alive.
    """
    values = jnp.asarray(values)
    if not jnp.issubdtype(values.dtype, jnp.floating):
        values = values.astype(jnp.result_type(float))
    return sums.invariant_mean(values, (0, 1), alive)


def reinforce(params: Params, apply_fn: ApplyFn, batch: Batch,
              hyper: "Hyperparams") -> tuple[Array, dict[str, Array]]:
    """The book's loss: -mean over alive steps of A_t log pi(a_t | s_t).

    A_t are the discounted returns normalised over every alive step of the batch,
    (G_t - mean G) / std G.

    Args:
      params: the policy's parameters.
      apply_fn: the policy's distribution, `apply_fn(params, obs)`.
      batch: one run's episodes `[T, E]`.
      hyper: the run's `Hyperparams` (unused).

    Returns:
      (scalar loss, no metrics `{}`).
    """
    del hyper
    advantages = returns.normalize_masked(batch.returns, batch.alive)
    return -masked_mean(advantages * log_prob(apply_fn(params, batch.obs), batch.action),
                        batch.alive), {}


def reward_to_go(params: Params, apply_fn: ApplyFn, batch: Batch,
                 hyper: "Hyperparams") -> tuple[Array, dict[str, Array]]:
    """REINFORCE on the discounted returns-to-go themselves, without normalisation.

    The loss is -mean over alive steps of G_t log pi(a_t | s_t). Arguments and result are those
    of `reinforce`.
    """
    del hyper
    return -masked_mean(batch.returns * log_prob(apply_fn(params, batch.obs), batch.action),
                        batch.alive), {}


class ValueNetwork(nn.Module):
    """Dense(hidden) -> elu -> ... -> a weighted sum: a state's value `[...]` from obs `[..., K]`.

    By default `hidden=()`: a linear function of the observation, the baseline's default critic.
    The output's weights start as flax's `Dense` kernels do (LeCun normal), its bias at 0.

    Attributes:
      hidden: the sizes of the hidden layers; `()` is linear.
    """

    # Linear by default: as good a baseline as a hidden layer, at a fraction of its cost
    # (docs/performance.md).
    hidden: tuple[int, ...] = ()

    @nn.compact
    def __call__(self, obs: Array) -> Array:
        """The value of each observation: float obs `[..., K]` -> values `[...]`."""
        features = obs
        for size in self.hidden:
            features = nn.elu(nn.Dense(size)(features))
        # A weighted sum, not Dense(1): a linear critic then trains a run alone bit for bit as in
        # a sweep (docs/performance.md).
        weights = self.param("weights", nn.initializers.lecun_normal(in_axis=-1, out_axis=()),
                             (features.shape[-1],))
        bias = self.param("bias", nn.initializers.zeros, ())
        return (features * weights).sum(-1) + bias


class Baseline:
    """REINFORCE with a learned state-value baseline V(s), as its own network and optimizer step.

    Policy loss: -mean over alive steps of A_t log pi(a_t | s_t), with the advantages
    A_t = G_t - V(s_t) normalised over every alive step of the batch, as the book normalises the
    returns, and V held fixed (`stop_gradient`); value loss: mean over alive steps of
    (G_t - V(s_t))^2 / 2. The sum of the two is the loss; each network's gradient comes from its
    own part. Metrics: `value_loss`.

    Two `Baseline`s are equal, and hash alike, when their critics are (and their settings, for
    a subclass's).

    Args:
      critic: the value network, a flax module mapping obs `[..., K]` to values `[...]`.
    """

    # A flax module is an immutable dataclass: one default instance is safe to share.
    def __init__(self, critic: nn.Module = ValueNetwork()) -> None:
        self.critic = critic

    def __call__(self, params: Params, apply_fn: ApplyFn, batch: Batch,
                 hyper: "Hyperparams") -> tuple[Array, dict[str, Array]]:
        """The loss of one run, as any `LossFn`.

        Args:
          params: `{"policy": ..., "critic": ...}`, the two networks' parameters.
          apply_fn: the policy's distribution, `apply_fn(params["policy"], obs)`.
          batch: one run's episodes `[T, E]`.
          hyper: the run's `Hyperparams` (unused).

        Returns:
          (scalar loss, `{"value_loss": scalar}`).
        """
        del hyper
        # Without mutable collections, `apply` returns the module's output alone.
        values = cast(Array, self.critic.apply(params["critic"], batch.obs))
        advantages = jax.lax.stop_gradient(
            returns.normalize_masked(batch.returns - values, batch.alive))
        policy_loss = -masked_mean(
            advantages * log_prob(apply_fn(params["policy"], batch.obs), batch.action), batch.alive)
        value_loss = 0.5 * masked_mean(jnp.square(batch.returns - values), batch.alive)
        return policy_loss + value_loss, {"value_loss": value_loss}

    def __repr__(self) -> str:
        return f"Baseline(critic={self.critic!r})"

    def _key(self) -> tuple[Any, ...]:
        """What tells this loss apart from another of its class."""
        return (self.critic,)

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other._key() == self._key()

    def __hash__(self) -> int:
        return hash((type(self).__name__, self._key()))


class PPO(Baseline):
    """Proximal policy optimisation's clipped surrogate, with generalised advantage estimates
    from a learned state-value critic (Schulman et al., 2017).

    Advantages A_t are GAE(lambda) over the critic's values from before the iteration's updates
    (`Batch.values`, `returns.gae_masked`), normalised over the alive steps of the batch (a
    minibatch, with `TrainConfig.minibatches`). With the probability ratio
    rho_t = pi(a_t | s_t) / pi_old(a_t | s_t) (`Batch.log_prob`), the policy loss is
    -mean min(rho_t A_t, clip(rho_t, 1 - clip, 1 + clip) A_t); the value loss is
    value_coef * mean (V(s_t) - (A_t + V_old(s_t)))^2 / 2, unnormalised A_t. Means are over the
    alive steps. It acts through several updates per batch: `TrainConfig(epochs=...,
    minibatches=...)`. Metrics: `value_loss`, `clip_fraction` (the share of steps whose ratio
    was clipped) and `approx_kl` (mean of (rho_t - 1) - log rho_t).

    Args:
      critic: the value network, a flax module mapping obs `[..., K]` to values `[...]`.
      clip: epsilon, how far the ratio may move from 1, positive.
      gae_lambda: lambda of the advantage estimates, in [0, 1].
      value_coef: the weight of the value loss, at least 0.
    """

    # A flax module is an immutable dataclass: one default instance is safe to share.
    def __init__(self, critic: nn.Module = ValueNetwork(), clip: float = 0.2,
                 gae_lambda: float = 0.95, value_coef: float = 0.5) -> None:
        super().__init__(critic)
        for name, value, ok, allowed in (("clip", clip, clip > 0, "positive"),
                                         ("gae_lambda", gae_lambda, 0 <= gae_lambda <= 1,
                                          "in [0, 1]"),
                                         ("value_coef", value_coef, value_coef >= 0,
                                          "at least 0")):
            if not ok:
                raise ValueError(f"{name}: must be {allowed}, got {value}")
        self.clip, self.gae_lambda, self.value_coef = clip, gae_lambda, value_coef

    def __call__(self, params: Params, apply_fn: ApplyFn, batch: Batch,
                 hyper: "Hyperparams") -> tuple[Array, dict[str, Array]]:
        """The loss of one run, as any `LossFn`; `batch` holds `log_prob` and `values`."""
        old_values = cast(Array, batch.values)
        advantages = returns.gae_masked(batch.reward, old_values, batch.alive,
                                        cast(Array, hyper.discount), self.gae_lambda)
        log_ratio = log_prob(apply_fn(params["policy"], batch.obs), batch.action) - cast(
            Array, batch.log_prob)
        ratio = jnp.exp(log_ratio)
        normalised = returns.normalize_masked(advantages, batch.alive)
        surrogate = jnp.minimum(ratio * normalised,
                                jnp.clip(ratio, 1 - self.clip, 1 + self.clip) * normalised)
        values = cast(Array, self.critic.apply(params["critic"], batch.obs))
        value_loss = 0.5 * masked_mean(jnp.square(values - (advantages + old_values)),
                                       batch.alive)
        metrics = {"value_loss": value_loss,
                   "clip_fraction": masked_mean(jnp.abs(ratio - 1) > self.clip, batch.alive),
                   "approx_kl": masked_mean((ratio - 1) - log_ratio, batch.alive)}
        return -masked_mean(surrogate, batch.alive) + self.value_coef * value_loss, metrics

    def __repr__(self) -> str:
        return (f"PPO(critic={self.critic!r}, clip={self.clip}, gae_lambda={self.gae_lambda}, "
                f"value_coef={self.value_coef})")

    def _key(self) -> tuple[Any, ...]:
        """What tells this loss apart from another PPO."""
        return (self.critic, self.clip, self.gae_lambda, self.value_coef)


BUILT_IN: dict[str, LossFn] = {
    "reinforce": reinforce, "reward-to-go": reward_to_go, "baseline": Baseline(), "ppo": PPO()}


def resolve(loss: Any) -> LossFn:
    """The loss function that `TrainConfig.loss` names.

    Args:
      loss: a built-in's name (`BUILT_IN`), or a function (`LossFn`).

    Returns:
      The built-in loss of that name, or `loss` itself.

    Raises:
      ValueError: for an unknown name, or a value that is neither a name nor callable.
    """
    if isinstance(loss, str):
        if loss not in BUILT_IN:
            raise ValueError(
                f"loss: unknown {loss!r}; allowed: {', '.join(BUILT_IN)}, or a function "
                f"loss(params, apply_fn, batch, hyper) -> (loss, metrics)")
        return BUILT_IN[loss]
    if not callable(loss):
        raise ValueError(f"loss: expected a built-in's name ({', '.join(BUILT_IN)}) or a "
                         f"function, got {type(loss).__name__}")
    return loss


def critic(loss: Any) -> nn.Module | None:
    """The critic module of a loss (see `Baseline`), or None for a loss without one.

    Args:
      loss: as `resolve` takes it.
    """
    return getattr(resolve(loss), "critic", None)
