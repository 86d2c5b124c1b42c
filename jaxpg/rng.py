"""`jax.random`'s threefry numbers, bit for bit, as plain elementwise arithmetic.

On CPU, JAX lowers its threefry hash as a loop of five rounds over the whole array, which XLA can
neither vectorise well nor fuse with the arithmetic that consumes the numbers. Here the hash is
unrolled into elementwise operations, which fuse into their consumers (docs/performance.md).
Every function here returns exactly what its `jax.random` namesake returns for the same key (with
`jax_threefry_partitionable`, JAX's default).

Keys are raw `uint32[2]` keys (`jax.random.PRNGKey`) or typed threefry keys (`jax.random.key`).
`bits` and `uniform` also take R keys `[R, 2]` at once and return `[*shape, R]`: run r's numbers
on the last axis, exactly those of its key alone.
"""

import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.typing import DTypeLike

from jaxpg.types import ArrayLike, PRNGKey

# `repeat=(axis, size)`: a draw's `axis` repeated to `size` entries (`uniform`).
Repeat = tuple[int, int]

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def _threefry2x32(key: jax.Array, hi: jax.Array, lo: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Threefry-2x32 with 20 rounds of the uint32 counters (hi, lo) under the key's words `[2]`
    (`[2, R]` for R keys, against counters `[..., R]`); two uint32 arrays shaped as the counters."""
    # `lax` operations rather than `jnp`: JAX traces them faster (docs/performance.md).
    ks: Sequence[jax.Array] = (key[0], key[1], key[0] ^ key[1] ^ np.uint32(0x1BD11BDA))
    x0, x1 = hi + ks[0], lo + ks[1]
    ks = [jnp.broadcast_to(k, x0.shape) for k in ks]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x0 = lax.add(x0, x1)
            x1 = lax.bitwise_xor(x0, _rotate_left(x1, r))
        x0 = lax.add(x0, ks[(i + 1) % 3])
        x1 = lax.add(lax.add(x1, ks[(i + 2) % 3]), np.uint32(i + 1))
    return x0, x1


def _rotate_left(x: jax.Array, r: int) -> jax.Array:
    """The bits of uint32 `x` rotated left by `r`."""
    return lax.bitwise_or(lax.shift_left(x, np.uint32(r)),
                          lax.shift_right_logical(x, np.uint32(32 - r)))


def _key_words(key: PRNGKey) -> jax.Array:
    """The two words of a key `[2]`, or of R keys `[R, 2]` (each word then `[R]`)."""
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    return jnp.moveaxis(key, -1, 0)


def _repeats(shape: Sequence[int], repeat: Repeat | None) -> tuple[int, np.ndarray] | None:
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


def _counters(shape: tuple[int, ...], runs: tuple[int, ...], repeat: Repeat | None = None
              ) -> tuple[jax.Array, jax.Array]:
    """(hi, lo) halves of the uint64 counters of a draw of `shape`, as `jax.random` counts them:
    an iota reshaped to `shape`; with `repeat`, a constant of those counters repeated, so that the
    hash runs once over the repeated draws."""
    if math.prod(shape) >= 2**32:
        raise ValueError(f"shape: at most 2**32 - 1 numbers per draw, got {shape}")
    repeats = _repeats(shape, repeat)
    if repeats is None:
        lo = lax.iota(jnp.uint32, math.prod(shape)).reshape(shape)
    else:
        counters = np.arange(math.prod(shape), dtype=np.uint32).reshape(shape)
        lo = jnp.asarray(np.take(counters, repeats[1], axis=repeats[0]))
    lo = lo.reshape(*lo.shape, *(1 for _ in runs))
    return jnp.zeros_like(lo), lo


@functools.partial(jax.jit, static_argnames=("shape", "repeat"))
def bits(key: PRNGKey, shape: Sequence[int], repeat: Repeat | None = None) -> jax.Array:
    """Random uint32 of `shape`, equal to `jax.random.bits(key, shape)`; `[*shape, R]` for R keys.

    Args:
      key: a key `[2]` (raw or typed), or R keys `[R, 2]`.
      shape: the shape of the draw, fewer than 2**32 numbers; static.
      repeat: optional `(axis, size)`, as for `uniform`; static.

    Returns:
      uint32 `shape`, or `[*shape, R]` for R keys.

    Raises:
      ValueError: for a draw of 2**32 numbers or more, or a `repeat` that does not fit `shape`.
    """
    words = _key_words(key)
    x0, x1 = _threefry2x32(words, *_counters(tuple(shape), words.shape[1:], repeat))
    return x0 ^ x1


@functools.partial(jax.jit, static_argnames=("shape", "dtype", "repeat"))
def uniform(key: PRNGKey, shape: Sequence[int], minval: ArrayLike = 0.0, maxval: ArrayLike = 1.0,
            dtype: DTypeLike | None = None, repeat: Repeat | None = None) -> jax.Array:
    """Uniform floats in [minval, maxval), equal to `jax.random.uniform`.

    In float32 the numbers are computed here, elementwise; other dtypes draw with `jax.random`.

    Args:
      key: a key `[2]` (raw or typed), or R keys `[R, 2]`.
      shape: the shape of the draw; static.
      minval: the lower bound, broadcast against the result.
      maxval: the upper bound, broadcast against the result.
      dtype: a float dtype; the default float dtype by default. Static.
      repeat: optional `(axis, size)` (a size of at least the axis's length): the draw's `axis`
        is repeated to `size` entries, entry j being entry j % shape[axis], and drawn so that the
        copies cost no more than the numbers they copy. Static.

    Returns:
      Floats of `dtype`, `shape` (its `axis` of length `size` with `repeat`), or `[*shape, R]`
      for R keys.
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
def split(key: PRNGKey, num: int = 2) -> jax.Array:
    """`num` new raw keys `[num, 2]`, equal to `jax.random.split(key, num)`'s key data.

    Args:
      key: a key `[2]` (raw or typed), or R keys `[R, 2]`.
      num: the number of keys; static.

    Returns:
      uint32 `[num, 2]`, or `[num, R, 2]` for R keys.
    """
    words = _key_words(key)
    x0, x1 = _threefry2x32(words, *_counters((num,), words.shape[1:]))
    # Computed once: otherwise XLA recomputes the hash inside every draw that uses one of the keys.
    return computed_once(jnp.stack([x0, x1], axis=-1))


def computed_once(words: jax.Array) -> jax.Array:
    """`words` (uint32), computed into memory once rather than inside each of their consumers.

    XLA fuses an elementwise producer into every consumer, and into a consumer that reads each of
    its elements many times (a word unpacked into 32 random actions) it copies the producer, the
    whole hash, for each read. A reduction is never fused into its consumers: `words` pass through
    one, an exclusive-or with zeros. (XLA's CPU pipeline removes `lax.optimization_barrier` before
    it fuses.)
    """
    return lax.reduce(jnp.stack([words, jnp.zeros_like(words)]), np.uint32(0), lax.bitwise_xor,
                      (0,))
