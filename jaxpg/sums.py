"""Sums whose rounding is the same however many training runs are computed together.

XLA's CPU reductions choose their order of additions from the whole array's shape, so a run's sum
rounds differently alone than beside 63 other runs. These sums fix the order by elementwise
arithmetic: the first half of the numbers is added to the second half, and again, until one is
left. Elementwise operations round the same for every run, whatever the batch, so seed i of a
sweep trains exactly as seed i alone.
"""

import math

import jax
import jax.numpy as jnp

from jaxpg.types import ArrayLike


def invariant_sum(x: ArrayLike, axes: int | tuple[int, ...]) -> jax.Array:
    """Sums `x` over `axes` by halving; the result has the remaining axes in order.

    The halves are contiguous, so XLA fuses the producer of `x` into the first halving. The axes
    summed are padded with zeros to a power of two, then halved until one entry is left.

    Args:
      x: an array of any shape.
      axes: an axis, or a tuple of axes, negative ones counted from the end.

    Returns:
      The sums, of `x`'s dtype, shaped as `x` without `axes`.
    """
    # `lax` operations rather than `jnp`: JAX traces them faster (docs/performance.md).
    x = jnp.asarray(x)
    axes = tuple(a % x.ndim for a in (axes if isinstance(axes, tuple) else (axes,)))
    kept = [a for a in range(x.ndim) if a not in axes]
    x = jax.lax.transpose(x, axes + tuple(kept))
    x = jax.lax.reshape(x, (math.prod(x.shape[:len(axes)]), *x.shape[len(axes):]))
    size = 1 << max(0, (x.shape[0] - 1).bit_length())
    padding = [(0, size - x.shape[0], 0)] + [(0, 0, 0)] * (x.ndim - 1)
    x = jax.lax.pad(x, jnp.zeros((), x.dtype), padding)
    while x.shape[0] > 1:
        half = x.shape[0] // 2
        x = jax.lax.add(jax.lax.slice_in_dim(x, 0, half), jax.lax.slice_in_dim(x, half, 2 * half))
    return jax.lax.reshape(x, x.shape[1:])


def invariant_mean(x: jax.Array, axes: int | tuple[int, ...], where: jax.Array) -> jax.Array:
    """The mean of `x` over `axes` counting only the entries where `where` is True (0 if none).

    Args:
      x: a float array.
      axes: as for `invariant_sum`.
      where: bool, shaped as `x`.

    Returns:
      The means, shaped as `x` without `axes`, summed in `invariant_sum`'s order.
    """
    count = invariant_sum(where.astype(x.dtype), axes)
    return invariant_sum(jnp.where(where, x, 0.0), axes) / jnp.maximum(count, 1)
