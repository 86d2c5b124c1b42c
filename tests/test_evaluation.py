"""Evaluation in jaxpg against evaluation in Gymnasium itself; many policies in many physics
settings (`robustness`) against each evaluated alone."""

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from conftest import xla_compiles
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

from jaxpg import cartpole, policies, stats
from jaxpg.evaluation import (
    EvalResult,
    Robustness,
    evaluate,
    gymnasium_reset_states,
    robustness,
)
from jaxpg.policies import basic_policy


@pytest.fixture(scope="module")
def book_states():
    """The initial states of the book's evaluation: Gymnasium's reset(seed=i), i = 0..499."""
    return gymnasium_reset_states(500)


def test_reset_states_are_gymnasiums(book_states):
    assert book_states.shape == (500, 4) and book_states.dtype == np.float64
    # seed + i: the states from seed 100 are those of episodes 100.. from seed 0.
    np.testing.assert_array_equal(gymnasium_reset_states(3, seed=100), book_states[100:103])
    assert np.abs(book_states).max() < 0.05


def test_book_evaluation_equal_in_both_backends(book_states):
    in_gymnasium = evaluate(basic_policy, backend="gymnasium")
    in_jaxpg = evaluate(basic_policy, init_states=book_states)
    # Every one of the 500 episodes lasts equally long, so the statistics are equal too.
    np.testing.assert_array_equal(in_jaxpg.returns, in_gymnasium.returns)
    assert in_jaxpg[:4] == in_gymnasium[:4]
    # Computed by running the book's loop in Gymnasium 1.4 (the book prints about 42, 9, 24, 68
    # from an older Gym): mean 41.698, std 8.389, min 24, max 63.
    np.testing.assert_allclose(in_jaxpg[:4], (41.698, 8.389445512070509, 24.0, 63.0), rtol=1e-12)


def test_custom_params_equal_in_both_backends(book_states):
    # A heavier pole (so total_mass and polemass_length change too) and a 40-step limit that
    # Gymnasium's TimeLimit applies; the basic policy keeps it up for 25 to 59 steps.
    env = cartpole.CartPoleParams(masspole=0.2, max_steps=40)
    in_gymnasium = evaluate(basic_policy, episodes=60, env=env, backend="gymnasium")
    in_jaxpg = evaluate(basic_policy, episodes=60, env=env, init_states=book_states[:60])
    np.testing.assert_array_equal(in_jaxpg.returns, in_gymnasium.returns)
    assert in_jaxpg.max == 40.0 and in_jaxpg.min < 40.0  # some truncated, some fell


def gymnasium_vector_returns(episodes, seed, max_steps=200):
    """Basic-policy returns of the first episode of each of Gymnasium's vectorized CartPoles."""
    vec = CartPoleVectorEnv(num_envs=episodes, max_episode_steps=max_steps)
    obs, _ = vec.reset(seed=seed)
    returns = np.zeros(episodes)
    running = np.ones(episodes, dtype=bool)
    while running.any():
        obs, reward, terminated, truncated, _ = vec.step(np.where(obs[:, 2] < 0, 0, 1))
        returns += np.where(running, reward, 0.0)
        running &= ~(terminated | truncated)
    return returns


def test_random_resets_indistinguishable_from_gymnasium():
    in_jaxpg = evaluate(basic_policy, episodes=10_000, seed=1).returns
    in_gymnasium = gymnasium_vector_returns(10_000, seed=1)
    # Two independent samples of 10,000 returns from the same distribution: with fixed seeds the
    # p-values are deterministic (KS 0.98, Mann-Whitney 0.74 when measured); level 1e-3. Resets
    # on [-0.06, 0.06) instead would move the mean return by 0.7 and give KS p ~ 1e-8.
    assert scipy.stats.ks_2samp(in_jaxpg, in_gymnasium).pvalue > 1e-3
    assert scipy.stats.mannwhitneyu(in_jaxpg, in_gymnasium).pvalue > 1e-3
    assert abs(in_jaxpg.mean() - in_gymnasium.mean()) < 0.5


def test_result_type():
    result = evaluate(basic_policy, episodes=3, max_steps=5)
    assert isinstance(result, EvalResult)
    assert all(isinstance(v, float) for v in result[:4])
    # Every episode of the basic policy lasts more than 5 steps: return 5 each.
    np.testing.assert_array_equal(result.returns, [5.0, 5.0, 5.0])


@pytest.mark.parametrize("kwargs, match", [
    ({"episodes": 0}, "episodes"),
    ({"episodes": 2.5}, "episodes"),
    ({"episodes": True}, "episodes"),
    ({"max_steps": -1}, "max_steps"),
    ({"seed": -1}, "seed"),
    ({"seed": "0"}, "seed"),
    ({"backend": "x"}, "backend"),
    ({"policy": "basic"}, "policy"),
    ({"env": "CartPole-v9"}, "env"),
    ({"env": 3}, "env"),
    ({"env": cartpole.CartPoleParams(masspole=0.0)}, "masspole"),
    ({"env": cartpole.CartPoleParams(masspole=np.array([0.1, 0.2]))}, "env"),
    ({"init_states": np.zeros((4, 4))}, "init_states"),  # not [episodes, 4]
    ({"init_states": np.zeros((10, 4)), "backend": "gymnasium"}, "init_states"),
])
def test_bad_arguments_raise(kwargs, match):
    kwargs = {"policy": basic_policy, "episodes": 10, **kwargs}
    with pytest.raises(ValueError, match=f"^{match}:"):
        evaluate(**kwargs)


def test_bad_reset_states_arguments_raise():
    with pytest.raises(ValueError, match="^episodes:"):
        gymnasium_reset_states(0)
    with pytest.raises(ValueError, match="^env:"):
        gymnasium_reset_states(5, env="Pendulum-v1")


# --- robustness: many policies in many physics settings -------------------------------------------

GRID = {"length": [0.25, 1.0, 2.0], "masspole": [0.1, 0.5]}


class CategoricalPolicy(nn.Module):
    """A module of the user's own: the two logits of (left, right), from one hidden layer."""

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(2)(nn.tanh(nn.Dense(8)(obs)))


def stacked_params(network, grid_shape, seed=0):
    """Freshly initialised parameters of `network`, stacked `[G, S, ...]`."""
    keys = jax.random.split(jax.random.PRNGKey(seed), math.prod(grid_shape))
    params = jax.vmap(lambda key: policies.init_network(key, network))(keys)
    # Scaled up so that the policies differ: some keep the pole up for a while, some do not.
    return jax.tree.map(lambda leaf: 3 * leaf.reshape(*grid_shape, *leaf.shape[1:]), params)


def assert_cells_equal_evaluate_alone(result, policy_of, episodes, max_steps, seed,
                                      env=cartpole.V1):
    grid_shape = result.returns.shape[:2]
    for g, s in np.ndindex(grid_shape):
        for p, setting in enumerate(result.settings):
            alone = evaluate(policy_of(g, s), episodes=episodes, max_steps=max_steps,
                             env=env.replace(**setting), seed=seed)
            np.testing.assert_array_equal(result.returns[g, s, p], alone.returns,
                                          err_msg=f"cell {(g, s, p)}: {setting}")


@pytest.mark.parametrize("network", [policies.PolicyNetwork(), CategoricalPolicy()],
                         ids=["default-network", "own-module"])
def test_each_cell_is_evaluate_of_that_policy_alone(network):
    params = stacked_params(network, (2, 3))
    result = robustness(params, GRID, episodes=12, max_steps=80, seed=3, network=network)
    assert result.returns.shape == (2, 3, 6, 12) and result.returns.dtype == np.float64
    assert result.settings[:2] == [{"length": 0.25, "masspole": 0.1},
                                   {"length": 0.25, "masspole": 0.5}]  # the last field fastest
    assert len(np.unique(result.mean)) > 10  # the cells differ: the check below means something
    assert_cells_equal_evaluate_alone(
        result, lambda g, s: policies.network_policy(
            network, jax.tree.map(lambda leaf: leaf[g, s], params)), 12, 80, seed=3)


def test_a_sweeps_policies_and_a_list_of_settings_in_float64(small_sweep):
    settings = [{"gravity": 5.0, "tau": 0.01}, {"force_mag": 20.0}, {"x_threshold": 1.0}]
    with jax.enable_x64(True):
        result = robustness(small_sweep, settings, episodes=5, max_steps=40, env="CartPole-v0")
        assert_cells_equal_evaluate_alone(
            result, lambda g, s: policies.network_policy(
                policies.PolicyNetwork(), jax.tree.map(lambda leaf: leaf[g, s],
                                                       small_sweep.policy_params)),
            5, 40, seed=0, env=cartpole.V0)
    assert result.returns.shape == (2, 5, 3, 5)
    # A list's settings name every field any of them sets; the others keep the preset's values.
    assert result.settings[1] == {"gravity": 9.8, "force_mag": 20.0, "tau": 0.02,
                                  "x_threshold": 2.4}


def test_a_policy_function_and_the_statistics():
    result = robustness(basic_policy, {"length": [0.5, 2.0]}, episodes=30, max_steps=100)
    assert result.returns.shape == (1, 1, 2, 30)
    assert_cells_equal_evaluate_alone(result, lambda g, s: basic_policy, 30, 100, seed=0)
    assert result.mean[0, 0, 1] > result.mean[0, 0, 0]  # a longer pole falls more slowly
    for name in ("mean", "median", "std", "min", "max"):
        np.testing.assert_array_equal(getattr(result, name),
                                      getattr(np, name)(result.returns, axis=-1))
    default = robustness(basic_policy, episodes=30, max_steps=100)
    assert default.settings == [{}]
    np.testing.assert_array_equal(default.returns[0, 0, 0], result.returns[0, 0, 0])


def test_new_policies_and_physics_of_the_same_shapes_compile_nothing():
    network = policies.PolicyNetwork()
    robustness(stacked_params(network, (2, 2)), GRID, episodes=4, max_steps=20)
    policy_params = policies.init_network(jax.random.PRNGKey(0), network)
    evaluate(policies.network_policy(network, policy_params), episodes=4, max_steps=20)
    with xla_compiles() as compiled:
        robustness(stacked_params(network, (2, 2), seed=1), {"length": [3.0, 4.0, 5.0],
                                                             "masspole": [0.2, 0.3]},
                   episodes=4, max_steps=20, seed=7)
        evaluate(policies.network_policy(
            network, policies.init_network(jax.random.PRNGKey(1), network)), episodes=4,
            max_steps=20, env=cartpole.CartPoleParams(length=0.7), seed=2)
    assert compiled == []


@pytest.mark.parametrize("kwargs, match", [
    ({"env_grid": {"lenght": [1.0]}}, "env_grid: unknown field"),
    ({"env_grid": {"learning_rate": [0.1]}}, "env_grid: unknown field"),
    ({"env_grid": {"length": []}}, "length: "),
    ({"env_grid": {"length": [0.5, 0.5]}}, "length: "),
    ({"env_grid": {"length": [0.0]}}, "length: must be positive"),
    ({"env_grid": {"masspole": [-0.1]}}, "masspole: must be positive"),
    ({"env_grid": {"masscart": [0.0]}}, "masscart: must be positive"),
    ({"env_grid": {"tau": [0.0]}}, "tau: must be positive"),
    ({"env_grid": {"gravity": [np.inf]}}, "gravity: must be finite"),
    ({"env_grid": [{"length": 1.0}, {"length": 1}]}, "env_grid: the list repeats"),
    ({"env_grid": []}, "env_grid: "),
    ({"env_grid": "length"}, "env_grid: "),
    ({"policies": {"params": {}}}, "policies: "),
    ({"policies": stacked_params(policies.PolicyNetwork(), (2, 2))}, "policies: "),  # hidden=3
    ({"episodes": 0}, "episodes: "),
    ({"max_steps": 1.5}, "max_steps: "),
    ({"seed": -1}, "seed: "),
    ({"env": "CartPole-v9"}, "env: "),
])
def test_bad_robustness_arguments_raise_one_line_before_compiling(kwargs, match):
    kwargs = {"policies": stacked_params(policies.PolicyNetwork((3,)), (1, 2)),
              "network": policies.PolicyNetwork((3,)), **kwargs}
    with xla_compiles() as compiled, pytest.raises(ValueError, match=f"^{match}") as error:
        robustness(**kwargs)
    assert "\n" not in str(error.value) and not any("robustness" in name for name in compiled)


def _always(action):
    """A policy that plays `action` everywhere, of the dtype JAX gives it."""
    return lambda obs, u: jnp.full(obs.shape[:-1], action)


PLAYED_AS_0 = "policy: returned an action other than 0 (push left) or 1 (push right), which "
NO_ACTION = "policy: must return one integer action per observation, shaped "


@pytest.mark.parametrize("policy, message", [
    (_always(2), PLAYED_AS_0),  # found by the program, raised after the rollout
    (_always(-1), PLAYED_AS_0),
    (_always(0.5), NO_ACTION + "(10,) (on CartPole 0 pushes left, 1 right), got float32 (10,)"),
    (lambda obs, u: obs,
     NO_ACTION + "(10,) (on CartPole 0 pushes left, 1 right), got float32 (10, 4)"),
])
def test_actions_other_than_0_or_1_are_refused_not_played_as_0(policy, message):
    with pytest.raises(ValueError) as error:
        evaluate(policy, episodes=10, max_steps=20)
    assert str(error.value).startswith(message) and "\n" not in str(error.value)
    with pytest.raises(ValueError) as error:
        robustness(policy, {"length": [0.5, 1.0]}, episodes=3, max_steps=10)
    assert str(error.value).startswith(message[:40])
    assert evaluate(lambda obs, u: obs[:, 2] > 0, episodes=10, max_steps=20).mean == (
        evaluate(basic_policy, episodes=10, max_steps=20).mean)  # bools are actions too


def test_robustness_intervals_resample_whole_policies():
    """The same policies play every setting: a good policy is good in all of them, so resampling
    policies whole gives wider intervals than resampling each setting on its own."""
    rng = np.random.default_rng(0)
    skill = rng.normal(100, 30, size=(2, 16, 1, 1))  # [G, S]: each policy's own level
    returns = skill + np.array([0, 20, 40, 60])[:, None] + rng.normal(0, 1, (2, 16, 4, 5))
    table = Robustness(returns, [{"length": v} for v in (0.5, 1.0, 1.5, 2.0)])
    low, high = table.bootstrap_ci(1, "mean", seed=3)
    assert (low, high) == stats.bootstrap_ci(returns[1].mean(-1), "mean", seed=3, paired=True)
    stratified = stats.bootstrap_ci(returns[1].mean(-1), "mean", seed=3)
    assert high - low > 2 * (stratified[1] - stratified[0])
    assert table.improvement_ci(table, 1, 0) == stats.improvement_ci(
        returns[1].mean(-1), returns[0].mean(-1), paired=True)
    with pytest.raises(ValueError, match="^other: must play the same physics settings"):
        table.improvement_ci(Robustness(returns[:, :, :2], table.settings[:2]))


_FLOAT_ACTIONS = "policy: must return one integer action"  # both backends, as traced


@pytest.mark.parametrize("env, policy, in_jaxpg, in_gymnasium", [
    # Gymnasium would play 0.9 as 0, assert on 2 and sum NaN rewards.
    ("CartPole-v1", lambda obs, u: (obs[..., 2] > 0).astype(jnp.float32) * 0.9, _FLOAT_ACTIONS,
     _FLOAT_ACTIONS),
    ("CartPole-v1", lambda obs, u: jnp.full(obs.shape[:-1], 2),
     "policy: returned an action other than 0 .push left. or 1",
     "policy: returned the action 2; allowed: 0 to 1"),
    ("Pendulum-v1", lambda obs, u: jnp.full(obs.shape[:-1], jnp.nan),
     "policy: returned an action other than a finite number",
     "policy: returned the action nan; allowed: a finite number"),
])
def test_both_backends_refuse_a_policys_actions_outside_the_environments(
        env, policy, in_jaxpg, in_gymnasium):
    for backend, match in (("jaxpg", in_jaxpg), ("gymnasium", in_gymnasium)):
        with pytest.raises(ValueError, match=f"^{match}"):
            evaluate(policy, episodes=2, max_steps=5, env=env, backend=backend)


def test_a_robustness_tables_intervals_name_bad_arguments():
    table = Robustness(np.arange(2 * 4 * 3 * 5, dtype=np.float64).reshape(2, 4, 3, 5),
                       [{"length": value} for value in (0.5, 1.0, 2.0)])
    for call, match in [(lambda: table.bootstrap_ci(2), "setting: must be an integer in"),
                        (lambda: table.bootstrap_ci(-1), "setting: must be an integer in"),
                        (lambda: table.improvement_ci(None), "other: expected a Robustness"),
                        (lambda: table.improvement_ci(table, other_setting=2), "other_setting: ")]:
        with pytest.raises(ValueError, match=f"^{match}"):
            call()
    low, high = table.bootstrap_ci(1)
    assert low <= high and table.improvement_ci(table, 1, 0) == (1.0, 1.0)  # g 1 beats g 0 always
