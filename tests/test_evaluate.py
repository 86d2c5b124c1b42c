"""Evaluation in jaxpg against evaluation in Gymnasium itself."""

import numpy as np
import pytest
import scipy.stats
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

from jaxpg import cartpole
from jaxpg.evaluate import EvalResult, evaluate, gymnasium_reset_states
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
