"""The tasks' reset states are `jax.random`'s numbers, drawn by `jaxpg.rng` (fused, bit for bit)."""

import jax
import numpy as np
import pytest

from jaxpg.envs import acrobot, continuous_mountain_car, mountain_car, pendulum

KEYS = jax.random.split(jax.random.PRNGKey(11), 64)


def _acrobot_values(key):
    key_values, key_noise = jax.random.split(key)
    values = jax.random.uniform(key_values, (4,), minval=-0.1, maxval=0.1)  # reset bounds
    return np.float32(values), key_noise  # Gymnasium's float32 reset state


def test_acrobot_resets_to_jax_randoms_numbers():
    _, state = jax.vmap(acrobot.reset, in_axes=(0, None))(KEYS, acrobot.V1)
    for key, values, noise_key in zip(KEYS, state.to_array(), state.key):
        expected_values, expected_key = _acrobot_values(key)
        np.testing.assert_array_equal(values, expected_values)
        np.testing.assert_array_equal(noise_key, expected_key)


def test_pendulum_resets_to_jax_randoms_numbers():
    _, state = jax.vmap(pendulum.reset, in_axes=(0, None))(KEYS, pendulum.V1)
    high = np.array([np.pi, 1.0], np.float32)  # reset_theta, reset_theta_dot
    expected = jax.vmap(lambda key: jax.random.uniform(key, (2,), minval=-high, maxval=high))(KEYS)
    np.testing.assert_array_equal(state.to_array(), expected)


@pytest.mark.parametrize("module", [mountain_car, continuous_mountain_car])
def test_mountain_cars_reset_to_jax_randoms_numbers(module):
    _, state = jax.vmap(module.reset, in_axes=(0, None))(KEYS, module.V0)
    expected = jax.vmap(lambda key: jax.random.uniform(key, (), minval=-0.6, maxval=-0.4))(KEYS)
    np.testing.assert_array_equal(state.position, expected)
    np.testing.assert_array_equal(state.velocity, 0.0)
