"""jaxpg's CartPole against Gymnasium's classic_control CartPoleEnv, and its own invariants."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from jaxpg import cartpole, conformance

N_STATES = 10_000
TAU = 0.02

# Single (unbatched) steps, compiled once and shared by the tests below; eager steps run on
# scalars only, since every new shape costs eager dispatch a compilation of each operation.
jit_step = jax.jit(cartpole.step)


def random_states(rng, n):
    """`[n, 4]` float64 states inside and just beyond the thresholds.

    Two thirds fill a box 10% wider than the thresholds (x 2.4, theta 0.2094 rad) with velocities
    beyond what an episode reaches. The last third is placed so that one Euler step lands within
    +-2e-6 (x) or +-2e-7 (theta) of a threshold, about 8 and 13 float32 spacings there, where the
    float32 and float64 comparisons can legitimately disagree.
    """
    high = np.array([2.64, 3.0, 0.23, 3.5])
    values = rng.uniform(-high, high, size=(n, 4))
    edge = np.arange(n) >= 2 * n // 3
    side = rng.choice([-1.0, 1.0], size=n)
    on_x = edge & (rng.random(n) < 0.5)
    on_theta = edge & ~on_x
    # Euler: x' = x + tau * x_dot, so x = threshold - tau * x_dot + delta gives threshold + delta.
    values[on_x, 0] = (side * 2.4 - TAU * values[:, 1] + rng.uniform(-2e-6, 2e-6, n))[on_x]
    theta_threshold = cartpole.V1.theta_threshold_radians
    values[on_theta, 2] = (side * theta_threshold - TAU * values[:, 3]
                           + rng.uniform(-2e-7, 2e-7, n))[on_theta]
    return values


@pytest.fixture(scope="module")
def gymnasium_steps():
    """Per variant: states, times, actions (each state with both actions) and Gymnasium's steps.

    Times are uniform in [0, 600), so that v0's 200-step and v1's 500-step limits fall inside.
    """
    rng = np.random.default_rng(0)
    states = random_states(rng, N_STATES)
    values = np.concatenate([states, states])
    actions = np.repeat([0, 1], N_STATES)
    times = np.tile(rng.integers(0, 600, N_STATES), 2)
    steps = {}
    for name, overrides in conformance.VARIANTS.items():
        env_params = cartpole.V1.replace(**overrides)
        gym_env = conformance.make_gymnasium_env(env_params)
        outcome = conformance.step_gymnasium(gym_env, values, times, actions)
        steps[name] = (env_params, values, times, actions, outcome)
    return steps


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "float64"])
@pytest.mark.parametrize("variant", list(conformance.VARIANTS))
def test_single_steps_match_gymnasium(gymnasium_steps, variant, x64):
    env_params, values, times, actions, gym_outcome = gymnasium_steps[variant]
    with jax.enable_x64(x64):
        dtype = conformance.jaxpg_dtype()
        jaxpg_outcome = conformance.step_jaxpg(values, times, actions, env_params)
    assert jaxpg_outcome.values.dtype == (np.float64 if x64 else np.float32)
    stats = conformance.compare(jaxpg_outcome, gym_outcome, env_params, dtype)
    # 1e-6 in float32 (its spacing is 1.2e-7 relative) and 1e-12 in float64, relative above 1.
    assert stats.tolerance == (1e-12 if x64 else 1e-6)
    assert max(stats.max_error) <= stats.tolerance, stats
    assert stats.reward_mismatches == stats.terminated_mismatches == 0, stats
    assert stats.truncated_mismatches == 0, stats
    # The set exercises both ends: many terminations and truncations.
    assert stats.terminated > N_STATES // 2 and stats.truncated > N_STATES // 10, stats
    # Float64 needs no excuse at all; float32 only within 4 spacings of a threshold, where the
    # states placed at the edge do put some on different sides (see test_near_threshold_window).
    assert stats.near_threshold == 0 or not x64, stats


def test_near_threshold_window():
    # float32 spacing at 2.4 is 2**-21 * 1.0 ~ 2.4e-7, so 4 spacings ~ 9.5e-7; at 0.2094 rad it is
    # 2**-26 ~ 1.5e-8, so 4 spacings ~ 6e-8.
    theta = cartpole.V1.theta_threshold_radians
    values = np.array([
        [2.4 + 5e-7, 0, 0, 0],  # near
        [-2.4 - 9e-7, 0, 0, 0],  # near, other side
        [2.4 + 2e-6, 0, 0, 0],  # not near
        [0, 0, theta - 5e-8, 0],  # near
        [0, 0, -theta + 1e-7, 0],  # not near
    ])
    near = conformance.near_threshold(values, cartpole.V1, np.float32)
    np.testing.assert_array_equal(near, [True, True, False, True, False])
    # In float64 the spacing at 2.4 is 4.4e-16: none of them is near.
    assert not conformance.near_threshold(values, cartpole.V1, np.float64).any()


def test_reset_is_uniform_within_bounds():
    keys = jax.random.split(jax.random.PRNGKey(0), 10_000)
    obs, state = jax.jit(jax.vmap(cartpole.reset, in_axes=(0, None)))(keys, cartpole.V1)
    values = np.asarray(state.to_array())
    np.testing.assert_array_equal(np.asarray(obs), values)
    assert values.min() >= -0.05 and values.max() < 0.05
    assert (np.asarray(state.time) == 0).all()
    for component in values.T:
        # Uniform on [-0.05, 0.05): scipy's uniform(loc, scale). 1e-3 with a fixed key is
        # deterministic; a wrong range or a skew gives p ~ 0.
        assert scipy.stats.kstest(component, "uniform", args=(-0.05, 0.1)).pvalue > 1e-3


@pytest.mark.parametrize("typed", [False, True])
def test_reset_draws_jax_randoms_numbers(typed):
    # A user's key gives the states `jax.random.uniform` draws from it, under vmap over keys and
    # over bounds alike.
    keys = jax.random.split(jax.random.key(3) if typed else jax.random.PRNGKey(3), 64)
    low = jnp.linspace(-0.5, -0.05, 64)
    _, state = jax.jit(jax.vmap(lambda key, low: cartpole.reset(
        key, cartpole.V1.replace(reset_low=low))))(keys, low)
    expected = jax.vmap(lambda key, low: jax.random.uniform(
        key, (4,), minval=low, maxval=0.05))(keys, low)
    np.testing.assert_array_equal(state.to_array(), expected)


@pytest.mark.parametrize("env, limit", [("CartPole-v1", 500), ("CartPole-v0", 200)])
def test_truncation_at_the_step_limit(env, limit):
    env_params = cartpole.make_params(env)
    upright = np.zeros((2, 4))
    state = cartpole.CartPoleState.from_array(upright, time=np.array([limit - 2, limit - 1]))
    _, state, reward, terminated, truncated = jit_step(state, jnp.array([1, 1]), env_params)
    # Step limit - 1 (counted from 1) does not truncate, step `limit` does; the pole stays up.
    np.testing.assert_array_equal(state.time, [limit - 1, limit])
    np.testing.assert_array_equal(truncated, [False, True])
    np.testing.assert_array_equal(terminated, [False, False])
    np.testing.assert_array_equal(reward, [1.0, 1.0])


def test_fall_on_the_last_step_is_terminated_and_truncated():
    # x = 2.39, x_dot = 1: Euler gives x' = 2.39 + 0.02 * 1 = 2.41 > 2.4 on step 500.
    start = cartpole.CartPoleState.from_array(np.array([2.39, 1.0, 0.0, 0.0]), time=499)
    _, state, reward, terminated, truncated = jit_step(start, 1, cartpole.V1)
    assert float(state.x) > 2.4 and int(state.time) == 500
    assert bool(terminated) and bool(truncated)
    assert float(reward) == 1.0  # reward 1 on the terminating step too
    sutton_barto = cartpole.V1.replace(sutton_barto_reward=True)
    _, _, reward, _, _ = jit_step(start, 1, sutton_barto)
    assert float(reward) == -1.0


def states_and_actions(n, seed=0):
    values = random_states(np.random.default_rng(seed), n)
    actions = np.random.default_rng(seed + 1).integers(0, 2, n)
    return cartpole.CartPoleState.from_array(values), jnp.asarray(actions)


def one(tree, i):
    return jax.tree.map(lambda leaf: leaf[i], tree)


def stack(trees):
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *trees)


@pytest.mark.parametrize("integrator", cartpole.INTEGRATORS)
def test_jit_equals_no_jit(integrator):
    env_params = cartpole.V1.replace(integrator=integrator)
    state, actions = states_and_actions(8)
    eager = stack([cartpole.step(one(state, i), actions[i], env_params) for i in range(8)])
    jitted = stack([jit_step(one(state, i), actions[i], env_params) for i in range(8)])
    # Fusion may reorder float32 rounding by an ulp or so, never more.
    chex.assert_trees_all_close(jitted, eager, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(jitted[3], eager[3])  # terminated


def test_vmap_equals_loop():
    state, actions = states_and_actions(16)
    batched = jax.jit(jax.vmap(cartpole.step, in_axes=(0, 0, None)))(state, actions, cartpole.V1)
    looped = stack([jit_step(one(state, i), actions[i], cartpole.V1) for i in range(16)])
    chex.assert_trees_all_close(batched, looped, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(batched[3], looped[3])


def test_step_traces_once_per_shape():
    chex.clear_trace_counter()
    step = jax.jit(jax.vmap(chex.assert_max_traces(cartpole.step, n=2), in_axes=(0, 0, None)))
    for n, seed, env_params in [(8, 0, cartpole.V1), (8, 1, cartpole.V0),
                                (8, 2, cartpole.V1.replace(masspole=0.2)), (16, 3, cartpole.V1)]:
        # New values of the state and of the (traced) physics reuse the program; a new batch
        # size traces once more.
        step(*states_and_actions(n, seed), env_params)
    with pytest.raises(AssertionError):
        step(*states_and_actions(32), cartpole.V1)  # a third shape exceeds n=2


@pytest.mark.parametrize("make, match", [
    (lambda: cartpole.make_params("CartPole-v2"), "env"),
    (lambda: cartpole.make_params(masscart=0.0), "masscart"),
    (lambda: cartpole.make_params(masspole=-0.1), "masspole"),
    (lambda: cartpole.make_params(length=0.0), "length"),
    (lambda: cartpole.make_params(tau=-0.02), "tau"),
    (lambda: cartpole.make_params(integrator="rk4"), "integrator"),
    (lambda: cartpole.make_params(gravityy=9.8), "env_params"),
    (lambda: cartpole.make_params(masspole=np.inf), "masspole"),
    (lambda: cartpole.make_params(tau=np.inf), "tau"),
    (lambda: cartpole.make_params(gravity=np.nan), "gravity"),
    (lambda: cartpole.make_params(length="0.5"), "length"),
    (lambda: cartpole.make_params(max_steps=0.5), "max_steps"),
    (lambda: cartpole.make_params(max_steps=2**40), "max_steps"),  # steps count in int32
    (lambda: cartpole.make_params(max_steps=0), "max_steps"),
    (lambda: cartpole.CartPoleState.from_array(np.zeros(3)), "state"),
    (lambda: cartpole.CartPoleState.from_array(np.zeros((5, 2))), "state"),
    (lambda: cartpole.step(cartpole.CartPoleState.from_array(np.zeros(4)), 2, cartpole.V1),
     "action"),
    (lambda: cartpole.step(cartpole.CartPoleState.from_array(np.zeros((2, 4))),
                           jnp.array([1, -1]), cartpole.V1), "action"),
    (lambda: cartpole.step(cartpole.CartPoleState.from_array(np.zeros(4)), 1,
                           cartpole.V1.replace(length=0.0)), "length"),
])
def test_bad_input_raises(make, match):
    with pytest.raises(ValueError, match=f"^{match}:"):
        make()
