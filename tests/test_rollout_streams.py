"""Auto-reset streams and random policies of every environment, against their single steps."""

import functools
import pathlib

import jax
import numpy as np
import pytest
import scipy.stats

from jaxpg import cartpole, envs, rollout, xla_options

TASKS = [name for name, module in envs.MODULES.items() if module is not cartpole]
CPUINFO = pathlib.Path("/proc/cpuinfo")
AVX512 = CPUINFO.exists() and "avx512f" in CPUINFO.read_text(errors="ignore")


def task_params(name, **overrides):
    return envs.MODULES[name].PRESETS[name].replace(**overrides)


@pytest.mark.parametrize("name", TASKS)
def test_autoreset_step_steps_or_resets_each_environment(name):
    """Environments whose last step ended take the reset state drawn from the key, reward 0 and
    no flags; the others step as the module's `step` does."""
    n = 12
    module, env_params = envs.MODULES[name], task_params(name)
    _, state = rollout.reset_batch(jax.random.PRNGKey(0), n, env_params)
    obs = module.observe(state)
    action = rollout.random_policy(obs, jax.random.PRNGKey(1), env_params)
    prev_done = np.arange(n) % 3 == 0
    step = jax.jit(rollout.autoreset_step)
    obs, stream_state, reward, terminated, truncated = step(
        jax.random.PRNGKey(2), rollout.StreamState(state, prev_done), action, env_params)

    _, stepped, stepped_reward, stepped_terminated, stepped_truncated = jax.jit(
        jax.vmap(module.step, in_axes=(0, 0, None)))(state, action, env_params)
    _, fresh = rollout.reset_batch(jax.random.PRNGKey(2), n, env_params)
    for got, reset, moved in zip(jax.tree.leaves(stream_state.env_state), jax.tree.leaves(fresh),
                                 jax.tree.leaves(stepped)):
        np.testing.assert_array_equal(np.asarray(got)[prev_done], np.asarray(reset)[prev_done])
        # One compiled program against another: rounding may differ in the last bit.
        np.testing.assert_allclose(np.asarray(got)[~prev_done], np.asarray(moved)[~prev_done],
                                   rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(reward)[prev_done], 0.0)
    np.testing.assert_allclose(np.asarray(reward)[~prev_done],
                               np.asarray(stepped_reward)[~prev_done], rtol=1e-6)
    assert not np.asarray(terminated | truncated)[prev_done].any()
    np.testing.assert_array_equal(np.asarray(terminated)[~prev_done],
                                  np.asarray(stepped_terminated)[~prev_done])
    np.testing.assert_array_equal(np.asarray(truncated)[~prev_done],
                                  np.asarray(stepped_truncated)[~prev_done])
    np.testing.assert_array_equal(stream_state.prev_done, terminated | truncated)
    np.testing.assert_array_equal(obs, module.observe(stream_state.env_state))


@pytest.mark.parametrize("name", TASKS)
def test_stream_of_short_episodes_counts_every_episode(name):
    """Episodes truncated after 5 steps, which no task ends sooner from its reset states: shorter
    than a chunk of STREAM_CHUNK = 8 steps."""
    num_envs, num_steps, limit = 16, 3 * rollout.STREAM_CHUNK + 5, 5
    env_params = task_params(name, max_steps=limit)
    policy = functools.partial(rollout.random_policy, env_params=env_params)
    state, stats = jax.jit(rollout.stream, static_argnums=(1, 3, 4))(
        jax.random.PRNGKey(3), policy, env_params, num_envs, num_steps)
    # An episode of 5 steps and the step that resets it: a truncation at steps 5, 11, 17, 23, 29
    # of 29, (29 + 1) // (5 + 1) = 5 episodes per environment, the last one just ended.
    assert int(stats.episodes) == num_envs * ((num_steps + 1) // (limit + 1))
    np.testing.assert_array_equal(state.env_state.time, num_steps % (limit + 1))
    assert np.asarray(state.prev_done).all()
    assert np.isfinite(float(stats.total_return))


@pytest.mark.skipif(not AVX512, reason="without AVX-512 the option changes nothing")
@pytest.mark.parametrize("name", envs.MODULES)
def test_stream_compiled_with_wide_vectors_steps_the_same(name):
    """`xla_options.WIDE_VECTORS` (512-bit vectors where the CPU has them): the same bits, also for
    the environments of a vector's remainder (37 = 2 x 16 + 5)."""
    env_params = task_params(name)
    policy = functools.partial(rollout.random_policy, env_params=env_params)

    def program(key):
        return rollout.stream(key, policy, env_params, 37, 4 * rollout.STREAM_CHUNK + 3)

    key = jax.random.PRNGKey(9)
    plain = jax.jit(program)(key)
    wide = jax.jit(program, compiler_options=xla_options.WIDE_VECTORS)(key)
    for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(wide), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_an_environment_resetting_every_other_step_draws_a_new_state_each_time():
    """Episodes of one step: an environment resets at steps 1, 3, 5 and 7 of its first chunk of
    STREAM_CHUNK = 8 steps, each time to a state of its own, within the reset bounds."""
    env_params = cartpole.V1.replace(max_steps=1)
    stream = jax.jit(rollout.stream, static_argnums=(1, 3, 4))
    resets = []
    for num_steps in (2, 4, 6, 8):  # the stream's steps 0 to num_steps - 1, ending on a reset
        state, stats = stream(jax.random.PRNGKey(8), rollout.random_policy, env_params, 4,
                              num_steps)
        assert int(stats.episodes) == 4 * num_steps // 2
        np.testing.assert_array_equal(state.env_state.time, 0)
        resets.append(np.asarray(state.env_state.to_array()))
    resets = np.stack(resets)  # [4 resets, 4 environments, 4 values]
    assert np.all(np.abs(resets) <= 0.05)
    for env in range(4):
        assert len({tuple(values) for values in resets[:, env]}) == 4


@pytest.mark.parametrize("name", ["Acrobot-v1", "MountainCar-v0"])
def test_stream_returns_the_rewards_of_its_steps(name):
    """-1 on every step of these tasks but a reset step (0) and a goal (none within 5 steps)."""
    num_envs, num_steps, limit = 16, 2 * rollout.STREAM_CHUNK + 3, 5
    env_params = task_params(name, max_steps=limit)
    policy = functools.partial(rollout.random_policy, env_params=env_params)
    state, stats = jax.jit(rollout.stream, static_argnums=(1, 3, 4))(
        jax.random.PRNGKey(4), policy, env_params, num_envs, num_steps)
    resets = int(stats.episodes) - int(np.asarray(state.prev_done).sum())
    assert resets > 0
    assert float(stats.total_return) == -(num_envs * num_steps - resets)


def test_random_policy_takes_cartpoles_actions_from_the_bits_of_each_word():
    num, key = 100, jax.random.PRNGKey(5)
    words = np.asarray(jax.random.bits(key, (-(-num // 32), 1))).ravel()  # 4 words of 32 actions
    expected = (words[np.arange(num) // 32] >> (np.arange(num) % 32)) & 1
    actions = rollout.random_policy(np.zeros((num, 4), np.float32), key)
    np.testing.assert_array_equal(actions, expected)
    assert actions.dtype == np.int32


@pytest.mark.parametrize("name", ["Acrobot-v1", "MountainCar-v0"])
def test_random_policy_draws_three_actions_from_sixteen_bits_of_a_word_each(name):
    num, key = 30_000, jax.random.PRNGKey(6)
    words = np.asarray(jax.random.bits(key, (num, 1))).ravel().astype(np.uint64)
    expected = ((words & 0xFFFF) * 3) >> 16  # e.g. 0xFFFF: 196605 >> 16 = 2
    actions = np.asarray(rollout.random_policy(np.zeros((num, 2), np.float32), key,
                                               task_params(name)))
    np.testing.assert_array_equal(actions, expected)
    # Uniform over 0, 1, 2: chi-square at level 1e-3, fixed key, so deterministic.
    assert scipy.stats.chisquare(np.bincount(actions, minlength=3)).pvalue > 1e-3


@pytest.mark.parametrize("name, overrides, low, high", [
    ("MountainCarContinuous-v0", {}, -1.0, 1.0),
    ("MountainCarContinuous-v0", {"min_action": -0.25, "max_action": 0.5}, -0.25, 0.5),
    ("Pendulum-v1", {}, -2.0, 2.0),
    ("Pendulum-v1", {"max_torque": 5.0}, -5.0, 5.0),  # the params' range, not the preset's
])
def test_random_policy_draws_continuous_actions_uniform_in_the_action_range(name, overrides,
                                                                            low, high):
    module, key = envs.MODULES[name], jax.random.PRNGKey(7)
    actions = rollout.random_policy(np.zeros((1000, module.OBS_SIZE), np.float32), key,
                                    module.make_params(name, **overrides))
    expected = jax.random.uniform(key, (1000,), minval=low, maxval=high)
    np.testing.assert_array_equal(actions, expected)
