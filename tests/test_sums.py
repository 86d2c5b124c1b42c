"""Fixed-order sums: right, and rounded the same for one run as for many runs at once."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpg import sums


@pytest.mark.parametrize("shape", [(200, 10), (37, 3), (1, 1), (20, 10, 4)])
def test_sum_is_a_sum(shape):
    x = np.random.default_rng(0).normal(size=shape).astype(np.float32)
    np.testing.assert_allclose(sums.invariant_sum(jnp.asarray(x), (0, 1)),
                               x.sum(axis=(0, 1)), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("runs", [2, 3, 64, 1024])
def test_a_runs_sum_is_the_same_beside_other_runs(runs):
    """Runs on the trailing axis, as training lays them out: run 0's sum alone == in a batch."""
    x = np.random.default_rng(1).normal(size=(200, 10, runs)).astype(np.float32)
    batched = jax.jit(lambda x: sums.invariant_sum(jnp.exp(x) * x, (0, 1)))
    alone = batched(x[..., :1])
    np.testing.assert_array_equal(batched(x)[:1], alone)


def test_mean_counts_only_where_true():
    x = jnp.arange(6.0).reshape(3, 2)
    where = jnp.asarray([[True, False], [True, False], [False, False]])
    assert float(sums.invariant_mean(x, (0, 1), where)) == 1.0  # (0 + 2) / 2
    assert float(sums.invariant_mean(x, (0, 1), jnp.zeros_like(where))) == 0.0
