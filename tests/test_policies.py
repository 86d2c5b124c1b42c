"""Policies: the book's angle policy, the network's initialisation, sampling, log-probabilities."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from jaxpg import basic_policy, distributions, losses, policies, runwise


def test_basic_policy_pushes_towards_the_lean():
    obs = jnp.asarray([[0, 0, -0.1, 0], [0, 0, 0.1, 0], [0, 0, 0.0, 0]])
    # angle < 0 -> 0 (left); otherwise 1, including exactly 0 as the book's `0 if angle < 0 else 1`.
    np.testing.assert_array_equal(basic_policy(obs), [0, 1, 1])


def test_network_shapes_and_keras_initialisation():
    network = policies.PolicyNetwork(hidden=(5,), activation="elu")
    params = policies.init_network(jax.random.PRNGKey(0), network)["params"]
    assert params["Dense_0"]["kernel"].shape == (4, 5)
    assert params["Dense_1"]["kernel"].shape == (5, 1)
    np.testing.assert_array_equal(params["Dense_0"]["bias"], 0)
    # Glorot uniform: U(-b, b), b = sqrt(6 / (fan_in + fan_out)), sqrt(6 / 9) for the first layer;
    # the kernels of 64 keys pooled.
    kernels = [policies.init_network(key, network)["params"]["Dense_0"]["kernel"]
               for key in jax.random.split(jax.random.PRNGKey(1), 64)]
    bound = np.sqrt(6 / 9)
    assert scipy.stats.kstest(np.ravel(kernels), "uniform", args=(-bound, 2 * bound)).pvalue > 1e-3
    assert network.apply({"params": params}, jnp.zeros((7, 3, 4))).shape == (7, 3)


def test_dense_and_its_gradient_equal_a_matrix_product():
    key_x, key_w, key_b = jax.random.split(jax.random.PRNGKey(1), 3)
    x = jax.random.normal(key_x, (6, 3, 4))
    kernel = jax.random.normal(key_w, (4, 5))
    bias = jax.random.normal(key_b, (5,))

    def reference(x, kernel, bias):
        return jnp.sum(jnp.tanh(x @ kernel + bias))

    def ours(x, kernel, bias):
        features = jnp.moveaxis(x, -1, 0)  # dense takes the features first
        return jnp.sum(jnp.tanh(jnp.moveaxis(policies.dense(features, kernel, bias), 0, -1)))

    chex.assert_trees_all_close(ours(x, kernel, bias), reference(x, kernel, bias), rtol=1e-5)
    chex.assert_trees_all_close(
        jax.grad(ours, argnums=(0, 1, 2))(x, kernel, bias),
        jax.grad(reference, argnums=(0, 1, 2))(x, kernel, bias),
        rtol=1e-5, atol=1e-5,
    )


def test_log_prob_and_sampling_agree():
    logit = jnp.asarray(0.7)
    p_left = jax.nn.sigmoid(logit)
    np.testing.assert_allclose(jnp.exp(losses.log_prob(logit, 0)), p_left, rtol=1e-6)
    np.testing.assert_allclose(jnp.exp(losses.log_prob(logit, 1)), 1 - p_left, rtol=1e-6)
    u = jax.random.uniform(jax.random.PRNGKey(0), (20000,))
    actions = distributions.sample(jnp.full((20000,), logit), u)
    # 20,000 Bernoulli draws: the share of left pushes is within 4 standard errors of P(left).
    assert abs(float(np.mean(actions == 0)) - float(p_left)) < 4 * np.sqrt(0.25 / 20000)


def test_forward_equals_the_module_also_for_many_runs_at_once():
    """`forward` adds a layer's products in the order `runwise` adds the module's matrix
    products: bit for bit alike; and the module's own `apply` (XLA's matrix products) to
    rounding."""
    network = policies.PolicyNetwork(hidden=(5, 3), activation="tanh")
    keys = jax.random.split(jax.random.PRNGKey(2), 3)
    runs = [policies.init_network(key, network) for key in keys]
    obs = jax.random.normal(jax.random.PRNGKey(3), (6, 3, 4))  # [E, R, 4]
    stacked = jax.tree.map(lambda *leaves: jnp.stack(leaves, axis=-1), *runs)  # runs last
    together = policies.forward(stacked, obs, "tanh")
    for r, params in enumerate(runs):
        alone = runwise.runwise(network.apply, False)(params, obs[:, r])
        np.testing.assert_array_equal(policies.forward(params, obs[:, r], "tanh"), alone)
        np.testing.assert_allclose(together[:, r], alone, rtol=1e-6)
        np.testing.assert_allclose(network.apply(params, obs[:, r]), alone, rtol=1e-6)


@pytest.mark.parametrize("hidden", [(5,), (3, 7), tuple(range(1, 12))])  # 11 layers: Dense_10
def test_parameters_flatten_into_one_vector_and_back(hidden):
    network = policies.PolicyNetwork(hidden=hidden)
    keys = jax.random.split(jax.random.PRNGKey(4), 3)
    runs = [policies.init_network(key, network) for key in keys]
    assert jax.tree.map(np.shape, runs[0]) == policies.parameter_shapes(network)
    stacked = jax.tree.map(lambda *leaves: jnp.stack(leaves, axis=-1), *runs)  # runs last
    flat = policies.flatten(stacked, network)
    size = sum(leaf.size for leaf in jax.tree.leaves(runs[0]))
    assert flat.shape == (size, 3)
    np.testing.assert_array_equal(
        flat[:, 1], np.concatenate([leaf.ravel() for leaf in jax.tree.leaves(runs[1])]))
    # On the host, as `schedule.train_blocks` does.
    back = policies.unflatten(np.asarray(flat), network)
    assert all(isinstance(leaf, np.ndarray) for leaf in jax.tree.leaves(back))
    chex.assert_trees_all_equal(back, jax.tree.map(np.asarray, stacked))
    chex.assert_trees_all_equal(policies.unflatten(policies.flatten(runs[2], network), network),
                                runs[2])


@pytest.mark.parametrize("hidden, activation, match", [
    ((5,), "nope", "activation"), ((0,), "elu", "hidden"), ((2, -1), "elu", "hidden"),
    (5, "elu", "hidden: must be a tuple of positive layer sizes"), ("5", "elu", "hidden")])
def test_bad_network_settings(hidden, activation, match):
    with pytest.raises(ValueError, match=match):
        policies.check_network(hidden, activation)


def test_a_default_network_of_two_logits_on_cartpole_acts_on_their_difference():
    network = policies.PolicyNetwork((4,), "elu", outputs=2)
    params = policies.init_network(jax.random.PRNGKey(0), network)
    obs = jax.random.normal(jax.random.PRNGKey(1), (1000, 4))
    u = jax.random.uniform(jax.random.PRNGKey(2), (1000,))
    logits = network.apply(params, obs)
    want = (u > jax.nn.sigmoid(logits[:, 0] - logits[:, 1])).astype(jnp.int32)
    np.testing.assert_array_equal(policies.network_policy(network, params)(obs, u), want)
