"""runwise: a function of one run evaluated for many runs at once equals `jax.vmap` of it, and a
run alone rounds as it does among others."""

import functools

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxpg.runwise import runs_first, runwise

RUNS = 5


class _Net(nn.Module):
    @nn.compact
    def __call__(self, obs):
        features = nn.LayerNorm()(nn.Dense(8)(obs))
        return nn.Dense(2)(nn.relu(features))


def _runs_last(fn, *args):
    """`jax.vmap` over a trailing run axis, the reference."""
    return jax.vmap(fn, in_axes=-1, out_axes=-1)(*args)


@pytest.fixture(scope="module")
def runs():
    """(network, parameters of RUNS runs, observations [T, E, 4, R])."""
    net = _Net()
    keys = jax.random.split(jax.random.PRNGKey(0), RUNS)
    params = jax.vmap(lambda key: net.init(key, jnp.zeros(4)), out_axes=-1)(keys)
    obs = jax.random.normal(jax.random.PRNGKey(1), (7, 3, 4, RUNS))
    return net, params, obs


def _loss(net, params, obs):
    return jnp.mean(jax.nn.log_softmax(net.apply(params, obs))[..., 0] ** 2)


def test_a_module_equals_its_vmap(runs):
    net, params, obs = runs
    chex.assert_trees_all_close(runwise(net.apply, True)(params, obs),
                                _runs_last(net.apply, params, obs), rtol=1e-6, atol=1e-6)


def test_a_gradient_taken_inside_equals_its_vmap(runs):
    net, params, obs = runs
    value_and_grad = jax.value_and_grad(functools.partial(_loss, net))
    chex.assert_trees_all_close(jax.jit(runwise(value_and_grad, True))(params, obs),
                                _runs_last(value_and_grad, params, obs), rtol=1e-5, atol=1e-6)


def test_an_optimizer_step_equals_its_vmap(runs):
    _, params, _ = runs
    optimizer = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(0.01))

    def step(params, grads):
        updates, _ = optimizer.update(grads, optimizer.init(params), params)
        return optax.apply_updates(params, updates)

    grads = jax.tree.map(lambda leaf: jnp.cos(leaf * 3.0), params)
    chex.assert_trees_all_close(jax.jit(runwise(step, True))(params, grads),
                                _runs_last(step, params, grads), rtol=1e-6, atol=1e-7)


def test_a_call_marked_runs_first_takes_the_runs_first(runs):
    """The marked step is evaluated with the runs moved first (a transpose in the program, none
    unmarked), equals its vmap with a shared argument reaching every run, and a run alone gets its
    own result without a run axis."""
    _, params, _ = runs

    def step(params, rate):
        return jax.tree.map(lambda leaf: leaf * rate + 1.0, params)

    rate = jnp.float32(0.5)  # shared by every run
    marked = runwise(runs_first(step), (True, False))
    assert "transpose" in str(jax.make_jaxpr(marked)(params, rate))
    assert "transpose" not in str(jax.make_jaxpr(runwise(step, (True, False)))(params, rate))
    together = jax.jit(marked)(params, rate)
    chex.assert_trees_all_equal(
        together, jax.vmap(step, in_axes=(-1, None), out_axes=-1)(params, rate))
    alone = jax.jit(runwise(runs_first(step), False))(
        jax.tree.map(lambda leaf: leaf[..., 1], params), rate)
    chex.assert_trees_all_equal(alone, jax.tree.map(lambda leaf: leaf[..., 1], together))


def test_a_run_alone_rounds_as_among_others(runs):
    net, params, obs = runs
    value_and_grad = jax.value_and_grad(functools.partial(_loss, net))
    together = jax.jit(runwise(value_and_grad, True))(params, obs)
    for run in (0, RUNS - 1):
        alone = jax.jit(runwise(value_and_grad, False))(
            *jax.tree.map(lambda leaf: leaf[..., run], (params, obs)))
        chex.assert_trees_all_equal(alone, jax.tree.map(lambda leaf: leaf[..., run], together))


@pytest.mark.parametrize("features, steps", [(5, 100), (20, 100), (64, 100), (100, 100),
                                             (20, 101)])
def test_a_wide_product_rounds_alone_as_among_others(features, steps):
    """Matrix products of fewer and more features than one chain of multiply-adds holds
    (`runwise.GROUP`: chains in a loop) and than `runwise.LOOPED`, and their gradients over 100
    steps of 3 episodes (the weights' summed as one axis of steps and episodes where they have
    more than `LOOPED` entries, from 20 features, else per episode; the products computed in tiles
    of `runwise.TILE` steps, 101 steps whole): a run alone rounds as among others, and equals
    `jax.vmap`'s to rounding."""
    keys = jax.random.split(jax.random.PRNGKey(2), 2)
    weights = jax.random.normal(keys[0], (features, features, RUNS)) / np.sqrt(features)
    obs = jax.random.normal(keys[1], (steps, 3, features, RUNS))

    def loss(weights, obs):
        hidden = jnp.tanh(obs @ weights)
        return jnp.mean(jnp.square(hidden @ weights.T))

    value_and_grad = jax.value_and_grad(loss)
    together = jax.jit(runwise(value_and_grad, True))(weights, obs)
    chex.assert_trees_all_close(together, _runs_last(value_and_grad, weights, obs),
                                rtol=1e-5, atol=1e-6)
    for run in (0, RUNS - 1):
        alone = jax.jit(runwise(value_and_grad, False))(weights[..., run], obs[..., run])
        chex.assert_trees_all_equal(alone, jax.tree.map(lambda leaf: leaf[..., run], together))


def test_a_scan_rounds_alone_as_among_others_shared_or_not(runs):
    """A scan over one run's arrays and a scan over arrays every run shares (a long sum in its
    body), then combined with each run's own: a run alone rounds as among others."""
    _, params, obs = runs
    shared = jax.random.normal(jax.random.PRNGKey(3), (6, 1000)) * 100.0

    def fn(kernel, obs, shared):
        def step(total, row):
            return total + jnp.sum(row), None

        own, _ = jax.lax.scan(step, 0.0, obs.reshape(-1, 4))
        common, _ = jax.lax.scan(step, 0.0, shared)
        return own * kernel + common * kernel

    kernel = params["params"]["Dense_0"]["kernel"]
    together = jax.jit(runwise(fn, (True, True, False)))(kernel, obs, shared)
    for run in (0, RUNS - 1):
        alone = jax.jit(runwise(fn, False))(kernel[..., run], obs[..., run], shared)
        chex.assert_trees_all_equal(alone, together[..., run])


def test_a_long_sum_adds_in_order():
    x = np.random.default_rng(0).normal(size=(300, 2)).astype(np.float32) * 1e3
    in_order = x[0].copy()
    for row in x[1:]:
        in_order = in_order + row  # float32, one after another
    np.testing.assert_array_equal(jax.jit(runwise(lambda v: v.sum(0), False))(x), in_order)


def test_shared_arguments_meet_every_run(runs):
    net, params, obs = runs
    shared = obs[..., 0]
    fn = runwise(net.apply, (True, False))
    chex.assert_trees_all_close(
        fn(params, shared), jax.vmap(net.apply, in_axes=(-1, None), out_axes=-1)(params, shared),
        rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("fn", [
    lambda a, b: jnp.einsum("bij,bjk->bik", a, b),  # a matrix product with batch axes
    lambda a, b: jnp.sort(a, axis=1) + b[:, :1, :1],  # sort: no rule, evaluated by jax.vmap
    lambda a, b: jnp.cumsum(a, axis=2) * jnp.max(b),
    lambda a, b: jnp.concatenate([a.reshape(-1), b.T.reshape(-1)])[::2],
])
def test_operations_equal_their_vmap(fn):
    rng = np.random.default_rng(1)
    a = rng.normal(size=(2, 3, 4, RUNS)).astype(np.float32)
    b = rng.normal(size=(2, 4, 3, RUNS)).astype(np.float32)
    chex.assert_trees_all_close(runwise(fn, True)(a, b), _runs_last(fn, a, b),
                                rtol=1e-6, atol=1e-6)


def test_run_axes_of_different_sizes_are_refused():
    with pytest.raises(ValueError, match="run axes differ"):
        runwise(jnp.add, True)(jnp.zeros((3, 2)), jnp.zeros((3, 4)))
