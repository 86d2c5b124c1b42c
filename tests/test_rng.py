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


@pytest.mark.parametrize("axis, size", [(0, 7), (1, 16), (1, 3)])
def test_repeated_draws_are_the_draws_repeated_along_the_axis(axis, size):
    key, keys, shape = jax.random.PRNGKey(4), jax.random.split(jax.random.PRNGKey(9), 3), (3, 5)
    index = np.arange(size) % shape[axis]
    np.testing.assert_array_equal(rng.uniform(key, shape, -1.0, 2.0, repeat=(axis, size)),
                                  np.take(np.asarray(rng.uniform(key, shape, -1.0, 2.0)), index, axis))
    np.testing.assert_array_equal(rng.uniform(keys, shape, repeat=(axis, size)),
                                  np.take(np.asarray(rng.uniform(keys, shape)), index, axis))
