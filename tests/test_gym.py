"""The Gymnasium adapters against Gymnasium's own CartPoleEnv and CartPoleVectorEnv."""

import functools
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.env_match import check_environments_match

from jaxpg import cartpole, render
from jaxpg import gym as jaxpg_gym

jaxpg_gym.register()


@pytest.fixture(autouse=True)
def _quiet_gymnasium():
    # CartPole-v0 is "out of date" and stepping a finished episode warns; both are expected here.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def test_register_is_idempotent_and_mirrors_gymnasium_specs():
    jaxpg_gym.register()  # a second time: no error, nothing replaced
    for name in ("CartPole-v1", "CartPole-v0"):
        ours, theirs = gymnasium.spec(f"jaxpg/{name}"), gymnasium.spec(name)
        assert ours.max_episode_steps == theirs.max_episode_steps
        assert ours.reward_threshold == theirs.reward_threshold
        env, reference = gymnasium.make(f"jaxpg/{name}"), gymnasium.make(name)
        assert env.observation_space == reference.observation_space
        assert env.action_space == reference.action_space


def test_passes_gymnasium_env_checker():
    check_env(gymnasium.make("jaxpg/CartPole-v1", render_mode="rgb_array").unwrapped)


def test_passes_gymnasiums_environment_match_over_10000_steps():
    # Gymnasium's comparison of observations (float32 and np.allclose), rewards, terminations and
    # truncations, with random actions and every episode reset with seed 0.
    check_environments_match(gymnasium.make("CartPole-v1"), gymnasium.make("jaxpg/CartPole-v1"),
                             num_steps=10_000)


def _with_integrator(env, integrator):
    """Gymnasium's `env` (an Env or a VectorEnv), set to integrate by `integrator`."""
    env.unwrapped.kinematics_integrator = integrator
    return env


@pytest.mark.parametrize("name, sutton_barto_reward, integrator", [
    ("CartPole-v1", False, "euler"),
    ("CartPole-v0", True, "euler"),
    ("CartPole-v1", False, "semi-implicit"),
])
def test_env_steps_as_gymnasium_to_the_last_bit(name, sutton_barto_reward, integrator):
    # max_episode_steps=40 makes some episodes end by truncation as well as by falling.
    kwargs = {"max_episode_steps": 40, "sutton_barto_reward": sutton_barto_reward}
    env = gymnasium.make(f"jaxpg/{name}", env_params=cartpole.make_params(
        name, integrator=integrator), **kwargs)
    reference = _with_integrator(gymnasium.make(name, **kwargs), integrator)
    rng = np.random.default_rng(0)
    endings = {"terminated": 0, "truncated": 0}
    for episode in range(30):
        reference.reset(seed=episode)
        env.reset(seed=episode)
        for _ in range(41):
            action = int(rng.integers(2))
            expected = reference.step(action)
            got = env.step(action)
            # The same float64 states, never re-synced: the same operations in the same order.
            np.testing.assert_array_equal(env.unwrapped.state, reference.unwrapped.state)
            np.testing.assert_array_equal(got[0], expected[0])
            assert got[0].dtype == np.float32 and env.unwrapped.state.dtype == np.float64
            assert got[1:4] == expected[1:4]
            if expected[2] or expected[3]:
                endings["terminated" if expected[2] else "truncated"] += 1
                break
        if expected[2]:
            # A step past termination: a caller error that both answer with the same reward.
            assert env.step(0)[1] == reference.step(0)[1]
    assert endings["terminated"] > 0 and endings["truncated"] > 0


@pytest.mark.parametrize("max_episode_steps, num_steps, integrator", [
    (25, 300, "euler"), (25, 300, "semi-implicit"), (500, 10_000, "euler")
])
def test_vector_env_steps_and_autoresets_as_gymnasium_to_the_last_bit(
        max_episode_steps, num_steps, integrator):
    num_envs = 8
    envs = gymnasium.make_vec(
        "jaxpg/CartPole-v1", num_envs, max_episode_steps=max_episode_steps,
        env_params=cartpole.make_params(integrator=integrator))
    reference = _with_integrator(gymnasium.make_vec(
        "CartPole-v1", num_envs, vectorization_mode="vector_entry_point",
        max_episode_steps=max_episode_steps,
    ), integrator)
    assert envs.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.NEXT_STEP
    assert envs.observation_space == reference.observation_space
    assert envs.action_space == reference.action_space
    envs.reset(seed=1)
    reference.reset(seed=1)
    actions = np.random.default_rng(1).integers(2, size=(num_steps, num_envs))
    got, expected = _play(envs, actions), _play(reference, actions)
    # The same float64 states, never re-synced; resets draw the same random numbers.
    for ours, theirs in zip(got, expected):
        assert ours.dtype == theirs.dtype
        np.testing.assert_array_equal(ours, theirs)
    obs, _, terminated, truncated, states = got
    assert obs.dtype == np.float32 and states.dtype == np.float64
    # Random pushes keep the pole up some 20 steps: a time limit of 25 truncates a few episodes.
    assert terminated.any() and truncated.any() == (max_episode_steps == 25)


def _play(envs, actions):
    """Steps `envs` by each of `actions` `[T, N]`: (obs `[T, N, 4]`, reward `[T, N]`, terminated
    `[T, N]`, truncated `[T, N]`, the states after each step `[T, 4, N]`)."""
    steps = [(*envs.step(step_actions)[:4], envs.unwrapped.state) for step_actions in actions]
    return [np.stack(column) for column in zip(*steps)]


def _states(rng, n, angle):
    """`[n, 4]` states with angles up to `angle` radians (beyond a quarter turn, the sine and
    cosine reduce the angle) and other values up to 3 (beyond the track)."""
    return rng.uniform(-1, 1, (n, 4)) * [3.0, 3.0, angle, 3.0]


@pytest.mark.parametrize("env_params", [
    cartpole.V1,
    cartpole.make_params(integrator="semi-implicit", masspole=0.3, sutton_barto_reward=True),
], ids=["v1", "semi-implicit-sutton-barto"])
def test_steps_agree_with_cartpole_step_in_either_dtype(env_params):
    """Both adapters step in float64 whatever `jax_enable_x64`, one environment exactly as N do.
    The compiled `cartpole.step`, in float32 or in float64, agrees with them within an episode's
    angles and far beyond them to the last bits of its dtype: in float64, XLA rounds otherwise
    where it fuses a multiplication and an addition, or divides by a number through its
    reciprocal; in float32, every operation rounds to float32 (the final rounding alone is half
    an ulp, rtol eps / 2). Measured: within rtol 2 eps plus 0.35 eps in either dtype."""
    rng = np.random.default_rng(5)
    step = jax.jit(cartpole.step)
    for angle in (0.3, 20.0):
        # float32 values, so that both dtypes start from the adapters' state.
        values = _states(rng, 512, angle).astype(np.float32).astype(np.float64)
        actions = rng.integers(2, size=512)
        stepped = []
        for x64 in (False, True):
            with jax.enable_x64(x64):
                eps = np.finfo(np.float64 if x64 else np.float32).eps
                _, state, reward, terminated, _ = step(
                    cartpole.CartPoleState.from_array(values), jnp.asarray(actions), env_params)
                assert state.x.dtype == (np.float64 if x64 else np.float32)
                envs = jaxpg_gym.CartPoleVectorEnv(512, env_params=env_params)
                envs.reset(seed=0)
                envs.state = values.T
                _, got_reward, got_terminated, _, _ = envs.step(actions)
                stepped.append(envs.state)
                np.testing.assert_allclose(envs.state.T, state.to_array(), rtol=2 * eps,
                                           atol=4 * eps)
                np.testing.assert_array_equal(got_terminated, terminated)
                np.testing.assert_array_equal(got_reward, reward)
                env = jaxpg_gym.CartPoleEnv(env_params=env_params)
                for row in range(0, 512, 8):
                    env.reset(seed=0)
                    env.state = values[row]
                    _, got_reward, got_terminated, _, _ = env.step(int(actions[row]))
                    np.testing.assert_array_equal(env.state, envs.state[:, row])
                    assert (got_reward, got_terminated) == (reward[row], terminated[row])
        np.testing.assert_array_equal(*stepped)
        assert stepped[0].dtype == np.float64


def test_resets_draw_gymnasiums_initial_states():
    for seed in range(4):
        for env, reference in [
            (gymnasium.make("jaxpg/CartPole-v1"), gymnasium.make("CartPole-v1")),
            (gymnasium.make_vec("jaxpg/CartPole-v1", 5),
             gymnasium.make_vec("CartPole-v1", 5, vectorization_mode="vector_entry_point")),
        ]:
            obs, theirs = env.reset(seed=seed)[0], reference.reset(seed=seed)[0]
            assert obs.dtype == theirs.dtype == np.float32
            np.testing.assert_array_equal(obs, theirs)
            # float64 states, not rounded to the observations' float32
            assert env.unwrapped.state.dtype == np.float64
            np.testing.assert_array_equal(env.unwrapped.state, reference.unwrapped.state)


def test_reset_with_a_seed_is_deterministic():
    env = gymnasium.make("jaxpg/CartPole-v1")
    first, _ = env.reset(seed=7)
    following, _ = env.reset()
    again, _ = env.reset(seed=7)
    np.testing.assert_array_equal(first, again)
    env.reset(seed=7)
    np.testing.assert_array_equal(following, env.reset()[0])
    assert not np.array_equal(first, env.reset(seed=8)[0])
    assert not np.array_equal(first, following)

    envs = gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=3)
    obs, _ = envs.reset(seed=7)
    assert len({tuple(row) for row in obs}) == 3  # each environment has its own start
    np.testing.assert_array_equal(obs, envs.reset(seed=7)[0])


def test_reset_options_set_the_bounds():
    env = gymnasium.make("jaxpg/CartPole-v1")
    obs, _ = env.reset(seed=0, options={"low": 0.1, "high": 0.2})
    assert np.all((obs >= 0.1) & (obs <= 0.2))
    envs = gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=4)
    obs, _ = envs.reset(seed=0, options={"low": -0.3, "high": -0.2})
    assert np.all((obs >= -0.3) & (obs <= -0.2))


def test_render_returns_the_frame_of_the_state():
    env = gymnasium.make("jaxpg/CartPole-v1", render_mode="rgb_array")
    env.reset(seed=0)
    env.unwrapped.state = np.array([1.0, 0.0, 0.15, 0.0])
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, render.render_frame(np.array([1.0, 0.0, 0.15, 0.0])))

    envs = gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=2, render_mode="rgb_array")
    envs.reset(seed=0)
    envs.unwrapped.state = np.array([[-1.0, 1.0], [0.0, 0.0], [0.1, -0.1], [0.0, 0.0]])
    frames = envs.render()
    assert len(frames) == 2
    np.testing.assert_array_equal(frames[1], render.render_frame(np.array([1.0, 0, -0.1, 0])))


def test_custom_physics_and_bad_arguments():
    heavy = cartpole.make_params(masspole=0.5)
    env = gymnasium.make("jaxpg/CartPole-v1", env_params=heavy)
    env.reset(seed=0)
    env.unwrapped.state = np.zeros(4) + [0, 0, 0.1, 0]
    light = gymnasium.make("jaxpg/CartPole-v1")
    light.reset(seed=0)
    light.unwrapped.state = env.unwrapped.state
    assert not np.allclose(env.step(1)[0], light.step(1)[0])

    with pytest.raises(ValueError, match="action"):
        env.unwrapped.step(2)
    envs = jaxpg_gym.CartPoleVectorEnv(num_envs=2)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="actions"):
        envs.step(np.array([0, 1, 1]))
    for actions in ([0, 2], [-1, 0], [0.0, 1.0]):
        with pytest.raises(ValueError, match="actions"):
            envs.step(np.array(actions))
    with pytest.raises(ValueError, match="num_envs"):
        jaxpg_gym.CartPoleVectorEnv(num_envs=0)
    with pytest.raises(ValueError, match="env_params: .* masspole of shape \\(2,\\)"):
        jaxpg_gym.CartPoleVectorEnv(env_params=cartpole.make_params(masspole=np.array([.1, .2])))
    with pytest.raises(ValueError, match="render_mode"):
        jaxpg_gym.CartPoleEnv(render_mode="human")
    for make in (gymnasium.make, functools.partial(gymnasium.make_vec, num_envs=2)):
        with pytest.raises(ValueError, match="^sutton_barto_reward: must be True or False"):
            make("jaxpg/CartPole-v1", sutton_barto_reward="no")  # (not a truthy value as yes)
