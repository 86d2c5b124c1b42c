"""Policy-gradient losses: the built-in ones and the helpers to write your own.

A loss is a function `loss(params, apply_fn, batch, hyper) -> (loss, metrics)` of one run:

- `params`: the policy's parameters; for a loss with a `critic` (a flax module mapping
  observations `[..., 4]` to values `[...]`), `{"policy": ..., "critic": ...}`, each stepped by
  its own optimizer.
- `apply_fn(policy_params, obs [..., 4]) -> logits [...]`: the logit of P(push left).
- `batch`: a `Batch` of the iteration's episodes, `[T, E]` (time, episodes).
- `hyper`: the run's `Hyperparams` (learning rate, discount, entropy coefficient), scalars.
- `loss` is a scalar to minimise; `metrics` a dict of scalars, kept per iteration
  (`Metrics.extra`).

The trainer adds `-entropy_coef * masked_mean(entropy(logits), alive)` to any loss. It evaluates
the loss for many runs at once (`jaxpg.runwise`), with its sums in a fixed order.
"""

from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxpg import returns, sums


class Batch(NamedTuple):
    """One iteration's episodes of one run, `[T, E]` leading axes; steps after an episode ended
    have `alive` False and zero reward."""

    obs: jax.Array  # [T, E, 4] the observation each action was chosen from
    action: jax.Array  # [T, E] int32: 0 pushed left, 1 right
    reward: jax.Array  # [T, E]
    alive: jax.Array  # [T, E] bool: the step belongs to its episode
    returns: jax.Array  # [T, E] discounted returns-to-go, not normalised; 0 where not alive


def log_prob(logits, action):
    """log pi(action | obs) from the logit of P(left) `[...]`: `log sigmoid(logit)` for action 0."""
    return jax.nn.log_sigmoid(jnp.where(action == 0, logits, -logits))


def entropy(logits):
    """The entropy of the policy's action distribution `[...]`, in nats, from the logit of P(left).

    H = -p log p - (1 - p) log(1 - p) with p = sigmoid(logit), computed as the equal
    softplus(logit) - logit * sigmoid(logit): one logarithm and two exponentials per step.
    """
    return jax.nn.softplus(logits) - logits * jax.nn.sigmoid(logits)


def masked_mean(values, alive):
    """The mean of `values` `[T, E, ...]` over the alive steps of every episode (0 if none);
    booleans count as 0 and 1."""
    values = jnp.asarray(values)
    if not jnp.issubdtype(values.dtype, jnp.floating):
        values = values.astype(jnp.result_type(float))
    return sums.invariant_mean(values, (0, 1), alive)


def reinforce(params, apply_fn, batch, hyper):
    """The book's loss: -mean over alive steps of A_t log pi(a_t | s_t), with A_t the discounted
    returns normalised over every alive step of the batch, (G_t - mean G) / std G."""
    del hyper
    advantages = returns.normalize_masked(batch.returns, batch.alive)
    return -masked_mean(advantages * log_prob(apply_fn(params, batch.obs), batch.action),
                        batch.alive), {}


def reward_to_go(params, apply_fn, batch, hyper):
    """REINFORCE on the discounted returns-to-go themselves: -mean over alive steps of
    G_t log pi(a_t | s_t), without normalisation."""
    del hyper
    return -masked_mean(batch.returns * log_prob(apply_fn(params, batch.obs), batch.action),
                        batch.alive), {}


class ValueNetwork(nn.Module):
    """Dense(hidden) -> elu -> ... -> Dense(1): a state's value `[...]` from obs `[..., 4]`.

    By default `hidden=()`: a linear function of the observation, the baseline's default critic.
    """

    # Linear: as good a baseline as Dense(8) over 64 and 512 seeds, at a fraction of its cost
    # (docs/performance.md).
    hidden: tuple[int, ...] = ()

    @nn.compact
    def __call__(self, obs):
        features = obs
        for size in self.hidden:
            features = nn.elu(nn.Dense(size)(features))
        return nn.Dense(1)(features)[..., 0]


class Baseline:
    """REINFORCE with a learned state-value baseline V(s), as its own network and optimizer step.

    Policy loss: -mean over alive steps of A_t log pi(a_t | s_t), with the advantages
    A_t = G_t - V(s_t) normalised over every alive step of the batch, as the book normalises the
    returns, and V held fixed (`stop_gradient`); value loss: mean over alive steps of
    (G_t - V(s_t))^2 / 2. The sum of the two is the loss; each network's gradient comes from its
    own part. Metrics: `value_loss`.

    Args:
      critic: the value network, a flax module mapping obs `[..., 4]` to values `[...]`.
    """

    def __init__(self, critic=ValueNetwork()):
        self.critic = critic

    def __call__(self, params, apply_fn, batch, hyper):
        del hyper
        values = self.critic.apply(params["critic"], batch.obs)
        advantages = jax.lax.stop_gradient(
            returns.normalize_masked(batch.returns - values, batch.alive))
        policy_loss = -masked_mean(
            advantages * log_prob(apply_fn(params["policy"], batch.obs), batch.action), batch.alive)
        value_loss = 0.5 * masked_mean(jnp.square(batch.returns - values), batch.alive)
        return policy_loss + value_loss, {"value_loss": value_loss}

    def __repr__(self):
        return f"Baseline(critic={self.critic!r})"

    def __eq__(self, other):
        return isinstance(other, Baseline) and other.critic == self.critic

    def __hash__(self):
        return hash(("Baseline", self.critic))


BUILT_IN = {"reinforce": reinforce, "reward-to-go": reward_to_go, "baseline": Baseline()}


def resolve(loss):
    """The loss function that `TrainConfig.loss` names: a built-in's name, or the function itself."""
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


def critic(loss):
    """The critic module of a loss (see `Baseline`), or None."""
    return getattr(resolve(loss), "critic", None)
