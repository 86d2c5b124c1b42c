"""Action distributions: a policy's output as actions, log-probabilities and entropies.

CartPole's policies give the logit of P(push left) `[...]`, the book's form, kept as a plain
array. Policies of other environments give a `Categorical` over n actions (n logits `[..., n]`)
or a `Gaussian` over one continuous action (a mean and a log standard deviation `[..., 2]`).
Each samples from one uniform u in [0, 1) per action, by inverting its distribution function, so
that a rollout draws one number per step whatever the environment. Sums over the n actions are
written out one addition after another, so that a run rounds alike alone and beside others.
"""

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from jaxpg.types import Action, Array

_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


@struct.dataclass
class Categorical:
    """A distribution over actions 0..n-1 from their logits `[..., n]`."""

    logits: Array

    def log_softmax(self) -> Array:
        """log pi(a) for every action `[..., n]`."""
        # The shift changes nothing but the rounding, so no gradient flows through it: the
        # maximum's own gradient compares values that a compiled program may round otherwise.
        shifted = self.logits - jax.lax.stop_gradient(jnp.max(self.logits, axis=-1, keepdims=True))
        return shifted - jnp.log(_total(jnp.exp(shifted)))[..., None]

    def log_prob(self, action: Array) -> Array:
        """log pi(action) `[...]` of int actions `[...]`."""
        each = self.log_softmax()
        chosen = each[..., 0]
        for i in range(1, each.shape[-1]):
            chosen = jnp.where(action == i, each[..., i], chosen)
        return chosen

    def entropy(self) -> Array:
        """-sum_a pi(a) log pi(a) `[...]`, in nats."""
        each = self.log_softmax()
        return -_total(jnp.exp(each) * each)

    def sample(self, u: Array) -> Action:
        """The action whose cumulative probability first exceeds u `[...]`: int32 `[...]`."""
        probs = jnp.exp(self.log_softmax())
        cumulative = probs[..., 0]
        action = (u >= cumulative).astype(jnp.int32)
        for i in range(1, probs.shape[-1] - 1):
            cumulative = cumulative + probs[..., i]
            action = action + (u >= cumulative).astype(jnp.int32)
        return action

    def mode(self) -> Action:
        """The likeliest action (the first of equals): int32 `[...]`."""
        best, action = self.logits[..., 0], jnp.zeros(self.logits.shape[:-1], jnp.int32)
        for i in range(1, self.logits.shape[-1]):
            better = self.logits[..., i] > best
            best = jnp.where(better, self.logits[..., i], best)
            action = jnp.where(better, i, action)
        return action


@struct.dataclass
class Gaussian:
    """A normal distribution of one continuous action: its mean and log standard deviation
    `[...]`. The environment clips an action to its bounds, as Gymnasium's does; the
    distribution is of the unclipped action."""

    mean: Array
    log_std: Array

    def log_prob(self, action: Array) -> Array:
        """log density of float actions `[...]`."""
        z = (action - self.mean) * jnp.exp(-self.log_std)
        return -0.5 * jnp.square(z) - self.log_std - _HALF_LOG_2PI

    def entropy(self) -> Array:
        """The differential entropy `[...]`, in nats."""
        return jnp.broadcast_to(self.log_std + 0.5 + _HALF_LOG_2PI, jnp.shape(self.mean))

    def sample(self, u: Array) -> Action:
        """mean + std * Phi^-1(u), u moved half a step of its grid inward: float `[...]`."""
        # u is a multiple of eps in [0, 1): 2u - 1 + eps lies strictly inside (-1, 1).
        eps = jnp.finfo(u.dtype).eps
        normal = math.sqrt(2) * jax.lax.erf_inv(2 * u - 1 + eps)
        return self.mean + jnp.exp(self.log_std) * normal

    def mode(self) -> Action:
        """The mean `[...]`."""
        return self.mean


def _total(x: Array) -> Array:
    """The sum over the last axis, one addition after another."""
    total = x[..., 0]
    for i in range(1, x.shape[-1]):
        total = total + x[..., i]
    return total


def log_prob(dist: Any, action: Array,
             log_sigmoid: Callable[[Array], Array] = jax.nn.log_sigmoid) -> Array:
    """log pi(action | obs) `[...]` of a policy's distribution.

    Args:
      dist: CartPole's logit of P(push left) `[...]` (then `log sigmoid(logit)` for action 0), a
        `Categorical` or a `Gaussian`.
      action: the actions `[...]`: int (0 pushes CartPole left), or float for a `Gaussian`.
      log_sigmoid: the function CartPole's logit takes: `jax.nn`'s, or `fastmath`'s for the
        hand-derived gradient.

    Returns:
      float `[...]`, the log-probability (density) of each action.
    """
    if isinstance(dist, Categorical | Gaussian):
        return dist.log_prob(action)
    return log_sigmoid(jnp.where(action == 0, dist, -dist))


def entropy(dist: Any) -> Array:
    """The entropy `[...]` of a policy's distribution, in nats.

    For CartPole's logit, p = sigmoid(logit): H = -p log p - (1 - p) log(1 - p), computed as the
    equal softplus(logit) - logit * sigmoid(logit), one logarithm and two exponentials a step.

    Args:
      dist: as for `log_prob`.
    """
    if isinstance(dist, Categorical | Gaussian):
        return dist.entropy()
    return jax.nn.softplus(dist) - dist * jax.nn.sigmoid(dist)


def sample(dist: Any, u: Array) -> Action:
    """Actions `[...]` drawn from uniforms u in [0, 1) `[...]`.

    CartPole's: pushes left with probability sigmoid(logit), action 1 (right) when u > P(left),
    as the book does; int32.
    """
    if isinstance(dist, Categorical | Gaussian):
        return dist.sample(u)
    return (u > jax.nn.sigmoid(dist)).astype(jnp.int32)


def mode(dist: Any) -> Action:
    """The likeliest actions `[...]` (CartPole's: right where P(left) < 1/2, as u = 1/2 would)."""
    if isinstance(dist, Categorical | Gaussian):
        return dist.mode()
    return sample(dist, jnp.full_like(dist, 0.5))


def from_output(out: Array, obs_shape: tuple[int, ...], num_actions: int | None) -> Any:
    """A policy module's output for observations `[..., K]` as its action distribution.

    Args:
      out: the module's output.
      obs_shape: the observations' shape `[..., K]`.
      num_actions: the environment's number of discrete actions; None for one continuous action.

    Returns:
      For two actions (CartPole), the logit of P(action 0) `[...]`, from an output `[...]` or
      `[..., 1]`, or from two logits `[..., 2]` as their difference; for more, a `Categorical` of
      logits `[..., n]`; for a continuous action, a `Gaussian` of (mean, log standard deviation)
      `[..., 2]`.

    Raises:
      ValueError: naming `policy` for an output of any other shape.
    """
    batch = obs_shape[:-1]
    if num_actions == 2:
        if out.shape == batch:
            return out
        if out.shape == (*batch, 1):
            return out[..., 0]
        if out.shape == (*batch, 2):
            return out[..., 0] - out[..., 1]
        allowed = f"logits shaped {batch}, {(*batch, 1)} or {(*batch, 2)}"
    elif out.shape == (*batch, num_actions or 2):
        return Categorical(out) if num_actions else Gaussian(out[..., 0], out[..., 1])
    else:
        allowed = (f"logits shaped {(*batch, num_actions)}" if num_actions else
                   f"(mean, log standard deviation) shaped {(*batch, 2)}")
    raise ValueError(f"policy: for observations {obs_shape} the module must return {allowed}, "
                     f"got {out.shape}")
