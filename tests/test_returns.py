"""Discounted returns: the book's values, the masked batched versions, and a plain Python loop."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxpg import discount_and_normalize_rewards, discount_rewards, returns


def test_discount_rewards_book_example():
    # -50; 0 + 0.8 * -50 = -40; 10 + 0.8 * -40 = -22
    np.testing.assert_allclose(discount_rewards([10, 0, -50], 0.8), [-22.0, -40.0, -50.0])


def test_discount_and_normalize_book_example():
    # Discounted: [-22, -40, -50] and [10 + 0.8 * 20, 20] = [26, 20]; over all five values the
    # mean is -13.2 and the population std 30.9477..., so (-22 + 13.2) / 30.9477 = -0.28435071.
    got = discount_and_normalize_rewards([[10, 0, -50], [10, 20]], 0.8)
    np.testing.assert_allclose(got[0], [-0.28435071, -0.86597718, -1.18910299], rtol=1e-6)
    np.testing.assert_allclose(got[1], [1.26665318, 1.0727777], rtol=1e-6)


def _loop_discount(rewards, lengths, rate):
    out = np.zeros_like(rewards)
    for e, n in enumerate(lengths):
        running = 0.0
        for t in reversed(range(n)):
            running = rewards[t, e] + rate * running
            out[t, e] = running
    return out


def test_masked_discount_equals_a_python_loop():
    rng = np.random.default_rng(0)
    rewards = rng.normal(size=(30, 7)).astype(np.float32)
    lengths = rng.integers(1, 31, size=7)
    alive = np.arange(30)[:, None] < lengths[None, :]
    got = returns.discount_masked(jnp.asarray(rewards), jnp.asarray(alive), 0.9)
    np.testing.assert_allclose(got, _loop_discount(rewards, lengths, 0.9), rtol=1e-5, atol=1e-5)
    # Rewards beyond an episode's end must not leak into its returns.
    assert np.all(np.asarray(got)[~alive] == 0)


def test_gae_equals_a_python_loop_and_is_the_return_minus_values_at_lambda_one():
    rng = np.random.default_rng(1)
    rewards = rng.normal(size=(30, 7)).astype(np.float32)
    values = rng.normal(size=(30, 7)).astype(np.float32)
    lengths = rng.integers(1, 31, size=7)
    alive = np.arange(30)[:, None] < lengths[None, :]
    expected = np.zeros_like(rewards)
    for e, n in enumerate(lengths):
        running = 0.0
        for t in reversed(range(n)):
            following = values[t + 1, e] if t + 1 < n else 0.0  # 0 after the last step
            running = rewards[t, e] + 0.9 * following - values[t, e] + 0.9 * 0.8 * running
            expected[t, e] = running
    got = returns.gae_masked(jnp.asarray(rewards), jnp.asarray(values), jnp.asarray(alive),
                             0.9, 0.8)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)
    assert np.all(np.asarray(got)[~alive] == 0)
    at_one = returns.gae_masked(jnp.asarray(rewards), jnp.asarray(values), jnp.asarray(alive),
                                0.9, 1.0)
    np.testing.assert_allclose(at_one, np.where(alive, _loop_discount(rewards, lengths, 0.9)
                                                - values, 0), rtol=1e-4, atol=1e-4)


def test_normalize_uses_alive_steps_and_population_std():
    values = jnp.asarray([[1.0, 5.0], [3.0, 100.0]])
    alive = jnp.asarray([[True, True], [True, False]])
    got = np.asarray(returns.normalize_masked(values, alive))
    # Alive values 1, 5, 3: mean 3, population std sqrt(8 / 3).
    expected = (np.array([1.0, 5.0, 3.0]) - 3.0) / np.sqrt(8 / 3)
    np.testing.assert_allclose(got[alive], expected, rtol=1e-6)
    assert got[1, 1] == 0


def test_normalize_is_safe_when_std_is_zero():
    got = returns.normalize_masked(jnp.full((4, 3), 7.0), jnp.ones((4, 3), bool))
    assert np.all(np.isfinite(got)) and np.all(np.asarray(got) == 0)


@pytest.mark.parametrize("call, match", [
    (lambda: discount_rewards([], 0.9), "rewards: every episode needs at least one reward"),
    (lambda: discount_rewards([1.0, 2.0], 1.5), r"discount_rate: must be a number in \[0, 1\]"),
    (lambda: discount_rewards([1.0, 2.0], float("nan")), "discount_rate"),
    (lambda: discount_rewards([1.0, 2.0], [0.9, 0.8]), "discount_rate"),
    (lambda: discount_and_normalize_rewards([], 0.9), "all_rewards: expected at least one"),
    (lambda: discount_and_normalize_rewards([[1.0], []], 0.9), "rewards: every episode"),
    (lambda: discount_and_normalize_rewards([[1.0]], -0.1), "discount_rate"),
])
def test_bad_input_raises_one_line(call, match):
    with pytest.raises(ValueError, match=f"^{match}"):
        call()
