"""Discounted returns: the book's list interface and the masked, batched `[T, E]` versions."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg import sums


def discount_masked(rewards, alive, discount_rate):
    """Discounted returns of `[T, E, ...]` rewards; 0 on the steps that are not alive.

    G_t = r_t + discount_rate * G_{t+1}, with a reverse scan over time: a loop step is one fused
    kernel and its store, few enough for XLA to run them one after another rather than schedule
    them as a graph (faster than unrolling, whose longer loop bodies it schedules).
    """
    rewards = jnp.where(alive, rewards, 0.0)

    def accumulate(future, reward):
        ret = reward + discount_rate * future
        return ret, ret

    _, returns = jax.lax.scan(accumulate, jnp.zeros_like(rewards[0]), rewards, reverse=True)
    return jnp.where(alive, returns, 0.0)


def normalize_masked(values, alive):
    """`(values - mean) / std` over the alive entries of `[T, E, ...]` (population std); 0 elsewhere.

    Mean and std are over time and episodes, apart for each index of any trailing (run) axes.
    When the std is 0 (every alive value equal) the values are only centred, so nothing divides by 0.
    """
    axes = (0, 1)
    mean = sums.invariant_mean(values, axes, alive)
    centred = jnp.where(alive, values - mean, 0.0)
    std = jnp.sqrt(sums.invariant_mean(jnp.square(centred), axes, alive))
    return centred / jnp.where(std > 0, std, 1.0)


def discount_and_normalize_masked(rewards, alive, discount_rate):
    """Discounted returns of `[T, E]` rewards, normalised over all alive steps of all episodes."""
    return normalize_masked(discount_masked(rewards, alive, discount_rate), alive)


def _check_discount_rate(discount_rate):
    """Raises a ValueError unless `discount_rate` is one number in [0, 1] (or traced)."""
    if isinstance(discount_rate, jax.core.Tracer):
        return
    rate = np.asarray(discount_rate)
    if not (rate.ndim == 0 and rate.dtype.kind in "iuf" and 0 <= rate <= 1):
        raise ValueError(f"discount_rate: must be a number in [0, 1], got {discount_rate!r}")


def _pad(all_rewards):
    """Episodes of different lengths as `[T, E]` rewards and alive mask; a ValueError for no
    episode or an empty one."""
    lengths = [len(r) for r in all_rewards]
    if not lengths or 0 in lengths:
        raise ValueError("rewards: every episode needs at least one reward, got an empty one"
                         if lengths else "all_rewards: expected at least one episode, got none")
    rewards = np.zeros((max(lengths), len(all_rewards)))
    for e, episode in enumerate(all_rewards):
        rewards[: len(episode), e] = episode
    alive = np.arange(rewards.shape[0])[:, None] < np.asarray(lengths)[None, :]
    return jnp.asarray(rewards, dtype=float), jnp.asarray(alive), lengths


def discount_rewards(rewards, discount_rate):
    """The book's `discount_rewards`: `discount_rewards([10, 0, -50], 0.8)` is `[-22, -40, -50]`."""
    _check_discount_rate(discount_rate)
    padded, alive, _ = _pad([rewards])
    return discount_masked(padded, alive, discount_rate)[:, 0]


def discount_and_normalize_rewards(all_rewards, discount_rate):
    """The book's `discount_and_normalize_rewards`: a list of episodes in, a list of arrays out.

    The mean and std are taken over the discounted returns of every step of every episode.
    """
    _check_discount_rate(discount_rate)
    padded, alive, lengths = _pad(all_rewards)
    normalized = discount_and_normalize_masked(padded, alive, discount_rate)
    return [normalized[:n, e] for e, n in enumerate(lengths)]
