"""Sums whose rounding is the same however many training runs are vmapped together.

XLA's CPU reductions pick their order of additions from the whole array's shape, so one run's sum
rounds differently alone than beside 63 others. Elementwise arithmetic does not: a pairwise sum
written as repeated halving (`x[0::2] + x[1::2]`) adds the same numbers in the same order for every
run, whatever the batch, so seed i of a sweep trains exactly as seed i alone.
"""

import jax.numpy as jnp


def pairwise_sum(x, axes):
    """Sums `x` over `axes` by repeated halving; the result has the remaining axes in order."""
    axes = tuple(a % x.ndim for a in (axes if isinstance(axes, tuple) else (axes,)))
    kept = [a for a in range(x.ndim) if a not in axes]
    x = jnp.transpose(x, axes + tuple(kept))
    x = x.reshape(-1, *x.shape[len(axes):])
    while x.shape[0] > 1:
        if x.shape[0] % 2:
            x = jnp.concatenate([x, jnp.zeros_like(x[:1])])
        x = x[0::2] + x[1::2]
    return x[0]


def pairwise_mean(x, axes, where):
    """The mean of `x` over `axes` counting only the entries where `where` is True (0 if none)."""
    count = pairwise_sum(where.astype(x.dtype), axes)
    return pairwise_sum(jnp.where(where, x, 0.0), axes) / jnp.maximum(count, 1)
