"""Discounted returns: the book's list interface and the masked, batched `[T, E]` versions."""

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg import sums
from jaxpg.validation import shown

# One episode's rewards, as the book's interface takes them: a list or a 1-d array.
Rewards = Sequence[float] | np.ndarray | jax.Array


def discount_masked(rewards: jax.Array, alive: jax.Array, discount_rate: float | jax.Array
                    ) -> jax.Array:
    """Discounted returns of `[T, E, ...]` rewards; 0 on the steps that are not alive.

    G_t = r_t + discount_rate * G_{t+1}, with a reverse scan over time.

    Args:
      rewards: float `[T, E, ...]` rewards.
      alive: bool `[T, E, ...]` (or broadcasting against `rewards`): the steps of each episode.
      discount_rate: a number in [0, 1], or a traced scalar.

    Returns:
      The returns G `[T, E, ...]`, in the rewards' dtype.
    """
    rewards = jnp.where(alive, rewards, 0.0)

    # A scan rather than an unrolled loop: one fused kernel per step (docs/performance.md).
    def accumulate(future: jax.Array, reward: jax.Array) -> tuple[jax.Array, jax.Array]:
        """G_t from G_{t+1} and r_t, as the carry and the output."""
        ret = reward + discount_rate * future
        return ret, ret

    _, returns = jax.lax.scan(accumulate, jnp.zeros_like(rewards[0]), rewards, reverse=True)
    return jnp.where(alive, returns, 0.0)


def gae_masked(rewards: jax.Array, values: jax.Array, alive: jax.Array,
               discount_rate: float | jax.Array, gae_lambda: float | jax.Array) -> jax.Array:
    """Generalised advantage estimates of `[T, E, ...]` steps; 0 on the steps that are not alive.

    A_t = delta_t + discount_rate * gae_lambda * A_{t+1}, with
    delta_t = r_t + discount_rate * V(s_{t+1}) - V(s_t), by a reverse scan over time. The value
    after an episode's last alive step is 0, whether it ended by termination or at the horizon.

    Args:
      rewards: float `[T, E, ...]` rewards.
      values: float `[T, E, ...]`, the critic's value of each step's observation.
      alive: bool `[T, E, ...]`: the steps of each episode.
      discount_rate: a number in [0, 1], or a traced scalar.
      gae_lambda: a number in [0, 1], or a traced scalar.

    Returns:
      The advantages `[T, E, ...]`, in the rewards' dtype.
    """
    values = jnp.where(alive, values, 0.0)
    next_values = jnp.concatenate([values[1:], jnp.zeros_like(values[:1])])
    deltas = jnp.where(alive, rewards + discount_rate * next_values - values, 0.0)

    def accumulate(future: jax.Array, delta: jax.Array) -> tuple[jax.Array, jax.Array]:
        """A_t from A_{t+1} and delta_t, as the carry and the output."""
        advantage = delta + discount_rate * gae_lambda * future
        return advantage, advantage

    _, advantages = jax.lax.scan(accumulate, jnp.zeros_like(deltas[0]), deltas, reverse=True)
    return jnp.where(alive, advantages, 0.0)


def normalize_masked(values: jax.Array, alive: jax.Array) -> jax.Array:
    """`(values - mean) / std` over the alive entries of `[T, E, ...]`; 0 elsewhere.

    Mean and population std are over time and episodes, apart for each index of any trailing (run)
    axes, and summed in a fixed order (`sums.invariant_mean`). When the std is 0 (every alive
    value equal) the values are only centred, so nothing divides by 0.

    Args:
      values: float `[T, E, ...]`.
      alive: bool `[T, E, ...]`.

    Returns:
      The normalised values `[T, E, ...]`.
    """
    axes = (0, 1)
    mean = sums.invariant_mean(values, axes, alive)
    centred = jnp.where(alive, values - mean, 0.0)
    std = jnp.sqrt(sums.invariant_mean(jnp.square(centred), axes, alive))
    return centred / jnp.where(std > 0, std, 1.0)


def discount_and_normalize_masked(rewards: jax.Array, alive: jax.Array,
                                  discount_rate: float | jax.Array) -> jax.Array:
    """Discounted returns of `[T, E, ...]` rewards, normalised over all alive steps of all episodes.

    Args:
      rewards: float `[T, E, ...]`.
      alive: bool `[T, E, ...]`.
      discount_rate: as for `discount_masked`.

    Returns:
      `normalize_masked(discount_masked(rewards, alive, discount_rate), alive)`, `[T, E, ...]`.
    """
    return normalize_masked(discount_masked(rewards, alive, discount_rate), alive)


def _check_discount_rate(discount_rate: float | jax.Array) -> None:
    """Raises a ValueError unless `discount_rate` is one number in [0, 1] (or traced)."""
    if isinstance(discount_rate, jax.core.Tracer):
        return
    rate = np.asarray(discount_rate)
    if not (rate.ndim == 0 and rate.dtype.kind in "iuf" and 0 <= rate <= 1):
        raise ValueError(f"discount_rate: must be a number in [0, 1], got {shown(discount_rate)}")


def _pad(all_rewards: Sequence[Rewards]) -> tuple[jax.Array, jax.Array, list[int]]:
    """Episodes of different lengths as `[T, E]` rewards, alive mask and the E lengths; a
    ValueError for no episode or an empty one."""
    lengths = [len(r) for r in all_rewards]
    if not lengths or 0 in lengths:
        raise ValueError("rewards: every episode needs at least one reward, got an empty one"
                         if lengths else "all_rewards: expected at least one episode, got none")
    rewards = np.zeros((max(lengths), len(all_rewards)))
    for e, episode in enumerate(all_rewards):
        rewards[: len(episode), e] = episode
    alive = np.arange(rewards.shape[0])[:, None] < np.asarray(lengths)[None, :]
    return jnp.asarray(rewards, dtype=float), jnp.asarray(alive), lengths


def discount_rewards(rewards: Rewards, discount_rate: float) -> jax.Array:
    """The book's `discount_rewards`: `discount_rewards([10, 0, -50], 0.8)` is `[-22, -40, -50]`.

    Args:
      rewards: one episode's `[T]` rewards, at least one.
      discount_rate: a number in [0, 1].

    Returns:
      The discounted returns `[T]`, in the default float dtype.

    Raises:
      ValueError: for a discount rate outside [0, 1] or no reward.
    """
    _check_discount_rate(discount_rate)
    padded, alive, _ = _pad([rewards])
    return discount_masked(padded, alive, discount_rate)[:, 0]


def discount_and_normalize_rewards(all_rewards: Sequence[Rewards], discount_rate: float
                                   ) -> list[jax.Array]:
    """The book's `discount_and_normalize_rewards`: a list of episodes in, a list of arrays out.

    The mean and std are taken over the discounted returns of every step of every episode.

    Args:
      all_rewards: E episodes' rewards, each `[T_e]` with T_e >= 1.
      discount_rate: a number in [0, 1].

    Returns:
      E arrays, `[T_e]` each: the normalised discounted returns.

    Raises:
      ValueError: for a discount rate outside [0, 1], no episode or an empty one.
    """
    _check_discount_rate(discount_rate)
    padded, alive, lengths = _pad(all_rewards)
    normalized = discount_and_normalize_masked(padded, alive, discount_rate)
    return [normalized[:n, e] for e, n in enumerate(lengths)]
