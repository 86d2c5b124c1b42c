"""jaxpg's fused threefry draws are jax.random's, bit for bit, alone and for many keys at once."""

import jax
import numpy as np
import pytest

from jaxpg import rng

KEYS = [jax.random.PRNGKey(0), jax.random.PRNGKey(123456), jax.random.key(7)]
SHAPES = [(1,), (7,), (3, 5), (1000,)]


@pytest.mark.parametrize("key", KEYS)
@pytest.mark.parametrize("shape", SHAPES)
def test_draws_equal_jax_random(key, shape):
    np.testing.assert_array_equal(rng.bits(key, shape), jax.random.bits(key, shape))
    np.testing.assert_array_equal(
        rng.uniform(key, shape, -0.05, 0.05),
        jax.random.uniform(key, shape, minval=-0.05, maxval=0.05),
    )


def test_split_equals_jax_random():
    key = jax.random.PRNGKey(5)
    np.testing.assert_array_equal(rng.split(key, 6), jax.random.split(key, 6))


def test_many_keys_at_once_put_each_keys_draws_on_the_last_axis():
    keys = jax.random.split(jax.random.PRNGKey(3), 5)
    uniforms = rng.uniform(keys, (7, 3))
    split = rng.split(keys, 4)
    assert uniforms.shape == (7, 3, 5) and split.shape == (4, 5, 2)
    for r, key in enumerate(keys):
        np.testing.assert_array_equal(uniforms[..., r], jax.random.uniform(key, (7, 3)))
        np.testing.assert_array_equal(split[:, r], jax.random.split(key, 4))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("axis, size", [(0, 7), (1, 16), (-1, 12), (1, 5)])
def test_repeated_draws_are_the_draws_repeated_along_the_axis(dtype, axis, size):
    key, keys, shape = jax.random.PRNGKey(4), jax.random.split(jax.random.PRNGKey(9), 3), (3, 5)
    index = np.arange(size) % shape[axis]
    with jax.enable_x64(dtype == np.float64):
        for k in (key, keys):  # one key, and three keys at once (a run axis last)
            repeated = rng.uniform(k, shape, -1.0, 2.0, dtype, repeat=(axis, size))
            drawn = np.asarray(rng.uniform(k, shape, -1.0, 2.0, dtype))
            assert repeated.dtype == dtype
            np.testing.assert_array_equal(repeated, np.take(drawn, index, axis % len(shape)))


@pytest.mark.parametrize("repeat", [(2, 9), (-3, 9), (1, 4)])
def test_a_repeat_outside_the_shape_or_shorter_than_its_axis_is_refused(repeat):
    with pytest.raises(ValueError, match="repeat: expected"):
        rng.uniform(jax.random.PRNGKey(0), (3, 5), repeat=repeat)
