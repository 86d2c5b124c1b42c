"""Sums whose rounding is the same however many training runs are computed together.

XLA's CPU reductions choose their order of additions from the whole array's shape, so a run's sum
rounds differently alone than beside 63 other runs. These sums fix the order by elementwise
arithmetic: the first half of the numbers is added to the second half, and again, until one is
left. Elementwise operations round the same for every run, whatever the batch, so seed i of a
sweep trains exactly as seed i alone.
"""

import jax.numpy as jnp


def invariant_sum(x, axes):
    """Sums `x` over `axes` by halving; the result has the remaining axes in order.

    The halves are contiguous, so XLA fuses the producer of `x` into the first halving.
    """
    axes = tuple(a % x.ndim for a in (axes if isinstance(axes, tuple) else (axes,)))
    kept = [a for a in range(x.ndim) if a not in axes]
    x = jnp.transpose(x, axes + tuple(kept))
    x = x.reshape(-1, *x.shape[len(axes):])
    size = 1 << max(0, (x.shape[0] - 1).bit_length())
    x = jnp.pad(x, [(0, size - x.shape[0])] + [(0, 0)] * (x.ndim - 1))
    while x.shape[0] > 1:
        half = x.shape[0] // 2
        x = x[:half] + x[half:]
    return x[0]


def invariant_mean(x, axes, where):
    """The mean of `x` over `axes` counting only the entries where `where` is True (0 if none)."""
    count = invariant_sum(where.astype(x.dtype), axes)
    return invariant_sum(jnp.where(where, x, 0.0), axes) / jnp.maximum(count, 1)
