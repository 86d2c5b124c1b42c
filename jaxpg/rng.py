"""`jax.random`'s threefry numbers, bit for bit, as plain elementwise arithmetic.

On CPU, JAX lowers its threefry hash as a loop of five rounds over the whole array, which XLA can
neither vectorise well nor fuse with the arithmetic that consumes the numbers; drawing them costs
more than simulating CartPole. The same hash unrolled into `jnp` operations fuses into its
consumers and runs several times faster. Every function here returns exactly what its `jax.random`
namesake returns for the same key (with `jax_threefry_partitionable`, JAX's default).

Keys are raw `uint32[2]` keys (`jax.random.PRNGKey`) or typed threefry keys (`jax.random.key`).
`bits` and `uniform` also take R keys `[R, 2]` at once and return `[*shape, R]`: run r's numbers
on the last axis, exactly those of its key alone.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def _threefry2x32(key, hi, lo):
    """Threefry-2x32 with 20 rounds of the counters (hi, lo) under `key` `[2]`; two uint32 arrays.

    The rounds are written in `lax` operations, which JAX traces faster than their `jnp` forms.
    """
    ks = (key[0], key[1], key[0] ^ key[1] ^ np.uint32(0x1BD11BDA))
    x0, x1 = hi + ks[0], lo + ks[1]
    ks = [jnp.broadcast_to(k, x0.shape) for k in ks]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x0 = lax.add(x0, x1)
            x1 = lax.bitwise_xor(x0, _rotate_left(x1, r))
        x0 = lax.add(x0, ks[(i + 1) % 3])
        x1 = lax.add(lax.add(x1, ks[(i + 2) % 3]), np.uint32(i + 1))
    return x0, x1


def _rotate_left(x, r):
    """The bits of uint32 `x` rotated left by `r`."""
    return lax.bitwise_or(lax.shift_left(x, np.uint32(r)),
                          lax.shift_right_logical(x, np.uint32(32 - r)))


def _key_words(key):
    """The two words of a key `[2]`, or of R keys `[R, 2]` (each word then `[R]`)."""
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    return jnp.moveaxis(key, -1, 0)


def _repeats(shape, repeat):
    """(axis, indices along it) that repeat a draw of `shape` as `repeat=(axis, size)` asks, or
    None when nothing is repeated; a ValueError for an axis outside `shape` or a size below its
    length."""
    if repeat is None:
        return None
    axis, size = repeat
    if not -len(shape) <= axis < len(shape) or size < shape[axis]:
        raise ValueError(f"repeat: expected (axis, size) with an axis of shape {shape} and a size "
                         f"of at least that axis's length, got {repeat}")
    axis %= len(shape)
    return None if size == shape[axis] else (axis, np.arange(size) % shape[axis])


def _counters(shape, runs, repeat=None):
    """(hi, lo) halves of the uint64 counters of a draw of `shape`, as `jax.random` counts them:
    an iota reshaped to `shape`; with `repeat`, a constant of those counters repeated, so that the
    hash runs once over the repeated draws."""
    if math.prod(shape) >= 2**32:
        raise ValueError(f"shape: at most 2**32 - 1 numbers per draw, got {shape}")
    repeats = _repeats(shape, repeat)
    if repeats is None:
        lo = lax.iota(jnp.uint32, math.prod(shape)).reshape(shape)
    else:
        lo = np.arange(math.prod(shape), dtype=np.uint32).reshape(shape)
        lo = jnp.asarray(np.take(lo, repeats[1], axis=repeats[0]))
    lo = lo.reshape(*lo.shape, *(1 for _ in runs))
    return jnp.zeros_like(lo), lo


@functools.partial(jax.jit, static_argnames=("shape", "repeat"))
def bits(key, shape, repeat=None):
    """Random uint32 of `shape`, equal to `jax.random.bits(key, shape)`; `[*shape, R]` for R keys.

    `repeat` as for `uniform`.
    """
    words = _key_words(key)
    x0, x1 = _threefry2x32(words, *_counters(tuple(shape), words.shape[1:], repeat))
    return x0 ^ x1


@functools.partial(jax.jit, static_argnames=("shape", "dtype", "repeat"))
def uniform(key, shape, minval=0.0, maxval=1.0, dtype=None, repeat=None):
    """Uniform floats in [minval, maxval), equal to `jax.random.uniform`; fast in float32.

    With R keys `[R, 2]`, `[*shape, R]`; `minval` and `maxval` broadcast against that. With
    `repeat=(axis, size)` (a size of at least the axis's length), the draw's `axis` is repeated
    to `size` entries, entry j being entry j % shape[axis], and drawn so: the copies cost no more
    than the numbers they copy.
    """
    dtype = jax.dtypes.canonicalize_dtype(dtype or float)
    if dtype != jnp.float32:
        if key.ndim > 1:
            draws = jax.vmap(lambda k: jax.random.uniform(k, shape, dtype, minval, maxval))(key)
            draws = jnp.moveaxis(draws, 0, -1)
        else:
            draws = jax.random.uniform(key, shape, dtype, minval, maxval)
        repeats = _repeats(shape, repeat)
        return draws if repeats is None else jnp.take(draws, repeats[1], axis=repeats[0])
    mantissa = bits(key, shape, repeat) >> np.uint32(32 - 23)
    floats = lax.bitcast_convert_type(mantissa | np.uint32(0x3F800000), jnp.float32) - 1.0
    minval = jnp.asarray(minval, jnp.float32)
    maxval = jnp.asarray(maxval, jnp.float32)
    return jnp.maximum(minval, floats * (maxval - minval) + minval)


@functools.partial(jax.jit, static_argnames="num")
def split(key, num=2):
    """`num` new keys `[num, 2]`, equal to `jax.random.split(key, num)`; `[num, R, 2]` for R keys."""
    words = _key_words(key)
    x0, x1 = _threefry2x32(words, *_counters((num,), words.shape[1:]))
    # Kept whole: otherwise XLA recomputes the hash inside every draw that uses one of the keys.
    return lax.optimization_barrier(jnp.stack([x0, x1], axis=-1))
