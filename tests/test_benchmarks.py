"""The numpy book trainer used as the training baseline computes what the book and jaxpg compute.

No timing here: benchmarks are scripts, run by hand.
"""

import os
import pathlib
import shutil
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from jaxpg import policies, returns

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
import book_numpy  # noqa: E402


def test_discount_rewards_is_the_books_example_and_jaxpgs():
    # G = [10 + 0.8 * (0 + 0.8 * -50), 0 + 0.8 * -50, -50] = [-22, -40, -50]
    got = book_numpy.discount_rewards([10, 0, -50], discount_factor=0.8)
    np.testing.assert_allclose(got, [-22, -40, -50])
    np.testing.assert_allclose(got, returns.discount_rewards([10, 0, -50], 0.8), rtol=1e-6)


def test_discount_and_normalize_rewards_is_the_books_example_and_jaxpgs():
    all_rewards = [[10, 0, -50], [10, 20]]
    got = book_numpy.discount_and_normalize_rewards(all_rewards, discount_factor=0.8)
    expected = [[-0.28435071, -0.86597718, -1.18910299], [1.26665318, 1.0727777]]
    jaxpg_got = returns.discount_and_normalize_rewards(all_rewards, 0.8)
    for g, e, j in zip(got, expected, jaxpg_got):
        np.testing.assert_allclose(g, e, rtol=1e-6)
        np.testing.assert_allclose(g, j, rtol=1e-5)


def _model(seed=0):
    return book_numpy.init_model(np.random.default_rng(seed), n_inputs=4)


def test_init_is_glorot_uniform_with_zero_biases():
    w1, b1, w2, b2 = _model()
    assert w1.shape == (4, 5) and w2.shape == (5, 1)
    assert not b1.any() and not b2.any()
    # U(-b, b), b = sqrt(6 / (fan_in + fan_out)): the kernels of 64 seeds pooled.
    models = [_model(seed) for seed in range(64)]
    for layer, bound in ((0, np.sqrt(6 / (4 + 5))), (2, np.sqrt(6 / (5 + 1)))):
        values = np.ravel([model[layer] for model in models])
        assert scipy.stats.kstest(values, "uniform", args=(-bound, 2 * bound)).pvalue > 1e-3


def test_forward_is_jaxpgs_policy_network_with_the_same_weights():
    model = _model()
    network = policies.PolicyNetwork(hidden=(5,), activation="elu")
    policy_params = {"params": {
        "Dense_0": {"kernel": jnp.asarray(model[0]), "bias": jnp.asarray(model[1] + 0.1)},
        "Dense_1": {"kernel": jnp.asarray(model[2]), "bias": jnp.asarray(model[3] - 0.2)},
    }}
    model = [model[0], model[1] + 0.1, model[2], model[3] - 0.2]
    obs = np.random.default_rng(1).normal(size=(6, 4)).astype(np.float32)
    logits = network.apply(policy_params, obs)
    for o, logit in zip(obs, logits):
        left_proba, _ = book_numpy.forward(model, o)
        np.testing.assert_allclose(left_proba, jax.nn.sigmoid(logit), rtol=1e-5)


@pytest.mark.parametrize("action", [0, 1])
def test_bce_gradients_are_jax_grad_of_the_cross_entropy(action):
    model = _model(2)
    obs = np.array([0.03, -0.4, 0.05, 0.6], np.float32)
    y_target = 1.0 - action

    def bce(variables):
        w1, b1, w2, b2 = variables
        h = jax.nn.elu(obs @ w1 + b1)
        p = jax.nn.sigmoid(h @ w2 + b2)[0]
        return -(y_target * jnp.log(p) + (1 - y_target) * jnp.log(1 - p))

    expected = jax.grad(bce)([jnp.asarray(v) for v in model])
    left_proba, cache = book_numpy.forward(model, obs)
    got = book_numpy.bce_gradients(model, cache, left_proba, y_target)
    for g, e in zip(got, expected):
        assert g.shape == e.shape
        np.testing.assert_allclose(g, e, rtol=1e-4, atol=1e-7)


def test_mean_weighted_grads_averages_over_every_step_of_every_episode():
    rng = np.random.default_rng(3)
    all_grads = [[[rng.normal(size=(2, 3))] for _ in range(n)] for n in (3, 1)]
    final_rewards = [np.array([1.0, -2.0, 0.5]), np.array([4.0])]
    steps = [(r, g[0]) for rs, gs in zip(final_rewards, all_grads) for r, g in zip(rs, gs)]
    expected = sum(r * g for r, g in steps) / 4
    got = book_numpy.mean_weighted_grads(final_rewards, all_grads)
    np.testing.assert_allclose(got[0], expected, rtol=1e-6)


def test_adams_first_step_is_keras_with_epsilon_outside_the_bias_correction():
    # Keras: var -= lr * sqrt(1 - b2) / (1 - b1) * m / (sqrt(v) + eps), m = (1 - b1) g and
    # v = (1 - b2) g^2 after one step, so the step is lr * g / (|g| + eps / sqrt(1 - b2)):
    # lr * sign(g) for |g| >> 3.2e-6, and for g = 1e-3 it is 0.01 * 1e-3 / (1e-3 + 3.162e-6).
    g = np.array([0.5, -2.0, 1e-3], np.float32)
    variables = [np.zeros(3, np.float32)]
    book_numpy.Adam(variables, learning_rate=0.01).apply_gradients([g], variables)
    np.testing.assert_allclose(variables[0], [-0.01, 0.01, -0.01 * 1e-3 / (1e-3 + 3.1623e-6)],
                               rtol=1e-5)


def test_a_tiny_run_trains_and_is_reproducible():
    history = book_numpy.run(seed=3, iterations=2)
    assert len(history.mean_returns) == len(history.steps) == len(history.seconds) == 2
    # Reward 1 per step: an iteration's mean return is its steps over the 10 episodes.
    np.testing.assert_allclose(np.asarray(history.steps) / 10, history.mean_returns)
    assert all(1 <= r <= book_numpy.N_MAX_STEPS for r in history.mean_returns)
    assert book_numpy.train(seed=3, iterations=2) == history.mean_returns


@pytest.mark.filterwarnings("ignore:.*CartPole-v0 is out of date")
def test_runs_on_another_env_id():
    assert len(book_numpy.train(seed=0, iterations=1, env_id="CartPole-v0")) == 1


def test_runs_on_jaxpgs_registered_env():
    pytest.importorskip("jaxpg.envs.gym")
    assert len(book_numpy.train(seed=0, iterations=1, env_id="jaxpg/CartPole-v1")) == 1


SHARDED_STREAM = """
import sys
import jax
import numpy as np
sys.path.insert(0, sys.argv[1])
import env_throughput

assert jax.device_count() == 2, jax.devices()
key = jax.random.PRNGKey(7)
one = env_throughput.jaxpg_program(64, 300)(key)
two = env_throughput.jaxpg_program(64, 300, sharded=True)(key)
assert len(two[0].prev_done.sharding.device_set) == 2
for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(two)):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
print(int(one[1].episodes))
"""


def test_the_sharded_stream_steps_as_one_device():
    benchmarks = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    result = subprocess.run([sys.executable, "-c", SHARDED_STREAM, str(benchmarks)], env=env,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout) > 64  # every environment ended an episode, many several


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc builds the C program")
def test_limit_builds_the_c_program_and_reads_its_table(tmp_path):
    import limit

    rows, output = limit.run_limit(limit.build("avx2", tmp_path), runs=16, repeats=1)
    assert [(row["runs"], row["threads"]) for row in rows] == [(16, 1), (16, 2), (1, 1)]
    # 16 runs of 150 iterations x 10 episodes take at least 8 steps each (no episode of
    # CartPole ends sooner) and at most 200.
    assert 16 * 1500 * 8 <= rows[0]["real_steps"] <= 16 * 1500 * 200
    assert rows[0]["real_steps"] == rows[1]["real_steps"]  # the same runs on 1 and 2 threads
    assert all(row["run_s"] > 0 for row in rows), output
