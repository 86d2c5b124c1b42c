"""The Gymnasium adapters of Acrobot, MountainCar, MountainCarContinuous and Pendulum against
Gymnasium's own envs."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.env_match import check_environments_match

from jaxpg import cartpole, envs
from jaxpg.envs import acrobot, adapters, continuous_mountain_car, mountain_car, pendulum

adapters.register()

# Gymnasium's checker advises a symmetric action range in [-1, 1]: Pendulum's is its own [-2, 2].
pytestmark = pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")

NAMES = adapters.NAMES

# Other physics for each environment: (Gymnasium's `make` kwargs, the same physics set as
# attributes of Gymnasium's unwrapped env, and as jaxpg's params).
OTHER_PHYSICS = {
    "Acrobot-v1": ({}, {"dt": 0.1, "LINK_MASS_2": 1.5, "book_or_nips": "nips",
                        "torque_noise_max": 0.2},
                   acrobot.make_params(dt=0.1, link_mass_2=1.5, book_or_nips="nips",
                                       torque_noise_max=0.2)),
    "MountainCar-v0": ({"goal_velocity": 0.01}, {"force": 0.0015, "gravity": 0.002},
                       mountain_car.make_params(goal_velocity=0.01, force=0.0015,
                                                gravity=0.002)),
    "MountainCarContinuous-v0": ({"goal_velocity": 0.01}, {"power": 0.002},
                                 continuous_mountain_car.make_params(goal_velocity=0.01,
                                                                     power=0.002)),
    "Pendulum-v1": ({"g": 9.81}, {"m": 1.2, "l": 0.9},
                    pendulum.make_params(gravity=9.81, mass=1.2, length=0.9)),
}


def _pair(name, other_physics=False):
    """(Gymnasium's env `name`, jaxpg's), unwrapped, with the preset's or `OTHER_PHYSICS`."""
    if not other_physics:
        return gymnasium.make(name).unwrapped, gymnasium.make(f"jaxpg/{name}").unwrapped
    kwargs, attributes, env_params = OTHER_PHYSICS[name]
    reference = gymnasium.make(name, **kwargs).unwrapped
    for attribute, value in attributes.items():
        setattr(reference, attribute, value)
    return reference, adapters.ClassicControlEnv(env_params)


def _random_action(rng, env):
    """An action of `env`: an integer, or one number `[1]` beyond the action range (clipped),
    float32 or float64 (Gymnasium computes the push in the action's dtype)."""
    if isinstance(env.action_space, gymnasium.spaces.Discrete):
        return int(rng.integers(env.action_space.n))
    dtype = rng.choice([np.float32, np.float64])
    return (rng.uniform(-1.5, 1.5, 1) * env.action_space.high).astype(dtype)


def _assert_same_step(got, expected):
    """The same observation (float32), reward (of the same type) and flags, to the last bit."""
    assert got[0].dtype == expected[0].dtype == np.float32
    np.testing.assert_array_equal(got[0], expected[0])
    assert type(got[1]) is type(expected[1]) and got[1:] == expected[1:]


def _outline(env_id):
    """What an id promises: its time limit and reward threshold, its env's spaces and frame
    rate."""
    spec, env = gymnasium.spec(env_id), gymnasium.make(env_id)
    return (spec.max_episode_steps, spec.reward_threshold, env.observation_space,
            env.action_space, env.metadata["render_fps"])


@pytest.mark.parametrize("name", NAMES)
def test_register_is_idempotent_and_mirrors_gymnasium_specs(name):
    adapters.register()  # a second time: no error, nothing replaced
    assert gymnasium.spec(f"jaxpg/{name}").entry_point == "jaxpg.envs.adapters:ClassicControlEnv"
    assert _outline(f"jaxpg/{name}") == _outline(name)


@pytest.mark.parametrize("name", NAMES)
def test_passes_gymnasium_env_checker(name):
    check_env(gymnasium.make(f"jaxpg/{name}").unwrapped)


@pytest.mark.parametrize("name", NAMES)
def test_passes_gymnasiums_environment_match_over_10000_steps(name):
    """Gymnasium's comparison (observations by `np.allclose` at 1e-5; rewards, terminations and
    truncations equal), random actions, every episode reset with seed 0. The states are equal to
    the last bit (next test), so no chaos parts them: measured over 100,000 steps of each
    environment (some 10 s apiece), 10,000 here."""
    check_environments_match(gymnasium.make(name), gymnasium.make(f"jaxpg/{name}"),
                             num_steps=10_000)


@pytest.mark.parametrize("other_physics", [False, True], ids=["preset", "other-physics"])
@pytest.mark.parametrize("name", NAMES)
def test_states_equal_gymnasiums_to_the_last_bit_never_resynced(name, other_physics):
    """Without time limits (a Pendulum episode of 5,000 steps), Acrobot's torque noise drawn from
    each env's own generator; an episode that terminates is followed by a reset without a seed.
    Measured: equal over 100,000 steps under the preset and 50,000 under the other physics, for
    each environment."""
    reference, env = _pair(name, other_physics)
    rng = np.random.default_rng(1)
    reference.reset(seed=2)
    env.reset(seed=2)
    for _ in range(5_000):
        action = _random_action(rng, env)
        expected = reference.step(action)
        _assert_same_step(env.step(action), expected)
        theirs, ours = np.asarray(reference.state), np.asarray(env.state)
        assert ours.dtype == theirs.dtype
        np.testing.assert_array_equal(ours, theirs)
        if expected[2]:
            np.testing.assert_array_equal(env.reset()[0], reference.reset()[0])


@pytest.mark.parametrize("name", NAMES)
def test_resets_draw_gymnasiums_initial_states(name):
    options = {"Pendulum-v1": {"x_init": 0.5, "y_init": 2.0}}.get(
        name, {"low": -0.3, "high": -0.2})
    for seed in range(5):
        for reset_options in (None, options):
            reference, env = _pair(name)
            obs, _ = env.reset(seed=seed, options=reset_options)
            expected, _ = reference.reset(seed=seed, options=reset_options)
            assert obs.dtype == expected.dtype == np.float32
            np.testing.assert_array_equal(obs, expected)
            theirs, ours = np.asarray(reference.state), np.asarray(env.state)
            assert ours.dtype == theirs.dtype  # float32 for Acrobot, float64 for the others
            np.testing.assert_array_equal(ours, theirs)
    assert not np.array_equal(env.reset(seed=0)[0], env.reset(seed=1)[0])


def _random_states(rng, name, n):
    """`n` states `[n, K]` across and beyond each environment's range, float32 and float64
    alternately: angles over four turns, velocities up to 1.5 times their bounds, positions
    over the track and a little beyond its ends (the walls and the goal)."""
    scales = {
        "Acrobot-v1": ([0, 0, 0, 0], [4 * np.pi, 4 * np.pi, 6 * np.pi, 13 * np.pi]),
        "MountainCar-v0": ([-0.3, 0.0], [0.95, 0.1]),
        "MountainCarContinuous-v0": ([-0.3, 0.0], [0.95, 0.1]),
        "Pendulum-v1": ([0, 0], [4 * np.pi, 12.0]),
    }
    centre, half_width = scales[name]
    states = centre + rng.uniform(-1, 1, (n, len(centre))) * half_width
    return [state.astype(np.float32 if i % 2 else np.float64) for i, state in enumerate(states)]


@pytest.mark.parametrize("name", NAMES)
def test_rewards_and_terminations_equal_gymnasiums_from_random_states(name):
    """Re-synced: each step starts both envs from the same state, drawn across and beyond the
    environment's range, in either float dtype."""
    reference, env = _pair(name)
    rng = np.random.default_rng(3)
    reference.reset(seed=0)
    env.reset(seed=0)
    terminated = []
    for state in _random_states(rng, name, 1_000):
        reference.state = state.copy()
        env.state = state.copy()
        action = _random_action(rng, env)
        expected = reference.step(action)
        _assert_same_step(env.step(action), expected)
        np.testing.assert_array_equal(np.asarray(env.state), np.asarray(reference.state))
        terminated.append(expected[2])
    # Both outcomes are met, but for Pendulum, which never terminates.
    assert set(terminated) == ({False} if name == "Pendulum-v1" else {False, True})


@pytest.mark.parametrize("name", NAMES)
def test_make_vec_steps_and_autoresets_as_gymnasiums(name):
    # Gymnasium's SyncVectorEnv for both; a time limit of 30 makes every env autoreset.
    num_envs = 3
    vector_env, reference = (gymnasium.make_vec(env_id, num_envs, max_episode_steps=30)
                             for env_id in (f"jaxpg/{name}", name))
    assert vector_env.action_space == reference.action_space
    vector_env.reset(seed=4)
    reference.reset(seed=4)
    vector_env.action_space.seed(5)
    truncations = 0
    for _ in range(100):
        actions = vector_env.action_space.sample()
        got, expected = vector_env.step(actions), reference.step(actions)
        for ours, theirs in zip(got[:4], expected[:4]):
            assert ours.dtype == theirs.dtype
            np.testing.assert_array_equal(ours, theirs)
        truncations += expected[3].sum()
    assert truncations >= num_envs * 3


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32, np.int8, np.int64])
def test_acrobot_steps_an_action_of_any_integer_type_as_gymnasiums(dtype):
    """Gymnasium looks the torque up (`AVAIL_TORQUE[action]`): an unsigned 0 is -1, where
    `action - 1` wrapped round to 255."""
    reference, env = _pair("Acrobot-v1")
    for action in range(3):
        reference.reset(seed=action)
        env.reset(seed=action)
        _assert_same_step(env.step(dtype(action)), reference.step(dtype(action)))
        np.testing.assert_array_equal(env.state, reference.state)


def test_bad_arguments():
    env = adapters.ClassicControlEnv(acrobot.V1)
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step(0)
    env.reset(seed=0)
    for action in (3, -1, 1.0, np.array([1])):
        with pytest.raises(ValueError, match="action: must be an integer in \\[0, 3\\)"):
            env.step(action)
    car = adapters.ClassicControlEnv(continuous_mountain_car.V0)
    car.reset(seed=0)
    for action in (0.5, np.array([0.5, 0.5]), np.array([np.nan]), np.array(["a"])):
        with pytest.raises(ValueError, match="action: must be one finite number"):
            car.step(action)
    with pytest.raises(ValueError, match="render_mode"):
        adapters.ClassicControlEnv(pendulum.V1, render_mode="rgb_array")
    with pytest.raises(ValueError, match="env_params: expected the params of one of"):
        adapters.ClassicControlEnv(cartpole.V1)
    with pytest.raises(ValueError, match="dt: must be positive"):
        adapters.ClassicControlEnv(acrobot.V1.replace(dt=-0.1))
    with pytest.raises(ValueError, match="env_params: expected one of Acrobot-v1, .* got 'x'"):
        adapters.ClassicControlEnv("x")
    with pytest.raises(ValueError, match="env: expected"):
        adapters.ClassicControlEnv(1.0)
    with pytest.raises(ValueError, match="env_params: .* dt of shape \\(2,\\)"):
        adapters.ClassicControlEnv(acrobot.V1.replace(dt=np.array([0.1, 0.2])))
    assert set(NAMES) == set(envs.MODULES) - set(cartpole.PRESETS)


@pytest.mark.parametrize("name, other", [
    ("Acrobot-v1", "Pendulum-v1"),
    ("MountainCar-v0", continuous_mountain_car.V0),  # a name alike, another task
    ("Pendulum-v1", acrobot.V1),
])
def test_an_id_refuses_another_tasks_params(name, other):
    """`make` replaces the id's own `env_params`: another task would play under its time limit."""
    with pytest.raises(ValueError, match=f"^env_params: jaxpg/{name} plays {name}, expected its "
                                         f"name or params, got .*'s$"):
        gymnasium.make(f"jaxpg/{name}", env_params=other)
    assert gymnasium.make(f"jaxpg/{name}", env_params=name).unwrapped.env_params == (
        envs.MODULES[name].make_params(name))
