"""The vectorisable float32 activations against float64 references and `jax.nn`'s derivatives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpg import fastmath


def _ulps(got, exact):
    """|got - exact| in float32 ulps of `exact` (of the smallest normal number below it)."""
    unit = np.spacing(np.maximum(np.abs(exact), np.finfo(np.float32).tiny).astype(np.float32))
    return np.abs(np.asarray(got, np.float64) - exact) / unit.astype(np.float64)


def _grid(low, high):
    """Float32 points over [low, high]: evenly spaced, and logarithmically towards 0 both sides."""
    tiny = np.logspace(-30, np.log10(max(abs(low), abs(high))), 200_001)
    points = np.concatenate([np.linspace(low, high, 1_000_001), tiny, -tiny, [0.0]])
    return points[(points >= low) & (points <= high)].astype(np.float32)


def test_elu_is_within_one_ulp_of_expm1_below_zero_and_x_above():
    x = _grid(-100.0, 20.0)
    got = np.asarray(jax.jit(fastmath.elu)(x))
    x64 = x.astype(np.float64)
    exact = np.where(x64 > 0, x64, np.expm1(np.minimum(x64, 0)))
    assert _ulps(got, exact).max() <= 1.0
    np.testing.assert_array_equal(got[x > 0], x[x > 0])
    assert np.all(got[x < -18] == -1.0)


def test_log_sigmoid_is_within_four_ulps_of_the_exact_value():
    z = _grid(-100.0, 100.0)
    got = np.asarray(jax.jit(fastmath.log_sigmoid)(z))
    z64 = z.astype(np.float64)
    exact = np.minimum(z64, 0) - np.log1p(np.exp(-np.abs(z64)))
    normal = np.abs(exact) >= np.finfo(np.float32).tiny  # below, float32 flushes to zero
    assert _ulps(got, exact)[normal].max() <= 4.0
    assert np.all(np.isfinite(got)) and np.all(got <= 0)


@pytest.mark.parametrize("ours, theirs", [(fastmath.elu, jax.nn.elu),
                                          (fastmath.log_sigmoid, jax.nn.log_sigmoid)])
def test_derivatives_are_jax_nns(ours, theirs):
    # Both compute the derivative from the value (elu's `y + 1`), so they differ where the value
    # rounds: by at most an ulp of 1 (elu is -1 below -18, where jax.nn's is 6e-8 above it).
    x = jnp.asarray(_grid(-30.0, 30.0)[::50])
    got = jax.vmap(jax.grad(ours))(x)
    expected = jax.vmap(jax.grad(theirs))(x)
    np.testing.assert_allclose(got, expected, rtol=2e-6, atol=1e-7)
    _, tangent = jax.jvp(ours, (x,), (jnp.full_like(x, 2.0),))
    np.testing.assert_allclose(tangent, 2 * expected, rtol=2e-6, atol=2e-7)


@pytest.mark.parametrize("ours, theirs", [(fastmath.elu, jax.nn.elu),
                                          (fastmath.log_sigmoid, jax.nn.log_sigmoid)])
def test_other_float_dtypes_take_jax_nns_own(ours, theirs):
    x = jnp.linspace(-5, 5, 101, dtype=jnp.float16)
    np.testing.assert_array_equal(ours(x), theirs(x))


def test_elu_of_its_value_is_that_value_with_elus_derivative():
    x = jnp.asarray(_grid(-30.0, 30.0)[::50])
    y = fastmath.elu(x)
    weights = jnp.linspace(-1.0, 1.0, x.size)
    np.testing.assert_array_equal(fastmath.elu_of_value(x, y), y)
    np.testing.assert_array_equal(
        jax.grad(lambda x: (fastmath.elu_of_value(x, y) * weights).sum())(x),
        jax.grad(lambda x: (fastmath.elu(x) * weights).sum())(x))
