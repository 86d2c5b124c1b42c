"""Batched episodes and auto-reset streams against plain loops and Gymnasium's CartPoleVectorEnv."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

from jaxpg import cartpole, rollout
from jaxpg.evaluation import gymnasium_reset_states
from jaxpg.policies import basic_policy

jit_rollout = jax.jit(rollout.rollout, static_argnums=(1, 3, 4))
jit_step = jax.jit(cartpole.step)

E, T = 32, 60
# The basic policy keeps Gymnasium's reset states up for 24 to 63 steps: a 40-step limit truncates
# some episodes while the others fall before it.
LIMITED = cartpole.V1.replace(max_steps=40)


@pytest.fixture(scope="module")
def init_state():
    return cartpole.CartPoleState.from_array(gymnasium_reset_states(E))


def test_rollout_equals_python_loop(init_state):
    episodes = jit_rollout(jax.random.PRNGKey(0), basic_policy, LIMITED, E, T, init_state)
    expected = jax.tree.map(np.asarray, episodes.transitions)
    state, alive = init_state, np.ones(E, dtype=bool)
    for t in range(T):
        obs = np.asarray(cartpole.observe(state))
        action = np.asarray(basic_policy(obs))
        _, state, reward, terminated, truncated = jit_step(state, action, LIMITED)
        np.testing.assert_array_equal(expected.alive[t], alive)
        # Rounding may differ by an ulp between the scan body and a lone step; no more.
        np.testing.assert_allclose(expected.obs[t][alive], obs[alive], rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(expected.action[t][alive], action[alive])
        np.testing.assert_array_equal(expected.reward[t], np.where(alive, reward, 0))
        alive &= ~np.asarray(terminated | truncated)
    assert not alive.any()  # every episode ended within T steps


def test_steps_after_the_end_are_masked(init_state):
    episodes = jit_rollout(jax.random.PRNGKey(0), basic_policy, LIMITED, E, T, init_state)
    alive = np.asarray(episodes.transitions.alive)
    lengths = np.asarray(episodes.lengths)
    # alive is True for exactly the first `length` steps: steps 0 .. length - 1, the last one the
    # terminal step (terminated or truncated).
    np.testing.assert_array_equal(alive, np.arange(T)[:, None] < lengths)
    np.testing.assert_array_equal(np.asarray(episodes.transitions.reward)[~alive], 0.0)
    np.testing.assert_array_equal(episodes.returns, lengths)  # reward 1 per step of an episode
    assert (lengths == 40).any() and (lengths < 40).any()  # truncated and terminated ones

    # The terminal step is the first where the state leaves the thresholds (or step 40), as the
    # obs of the next step shows: it is frozen at the final state after the end.
    obs = np.asarray(episodes.transitions.obs)
    fell = lengths < 40
    final = obs[lengths[fell], np.flatnonzero(fell)]
    out = (np.abs(final[:, 0]) > 2.4) | (np.abs(final[:, 2]) > cartpole.V1.theta_threshold_radians)
    assert out.all()
    before = obs[lengths[fell] - 1, np.flatnonzero(fell)]
    assert not ((np.abs(before[:, 0]) > 2.4)
                | (np.abs(before[:, 2]) > cartpole.V1.theta_threshold_radians)).any()


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "float64"])
@pytest.mark.parametrize("sutton_barto", [False, True], ids=["reward 1", "Sutton-Barto reward"])
def test_returns_and_lengths_are_the_sums_of_the_steps(x64, sutton_barto):
    """Summed as integers (the rollout's reduction), in the dtypes of the rewards and of int32."""
    with jax.enable_x64(x64):
        episodes = jit_rollout(jax.random.PRNGKey(0), basic_policy,
                               LIMITED.replace(sutton_barto_reward=sutton_barto), E, T)
    episodes = jax.tree.map(np.asarray, episodes)  # compared outside the float64 context
    assert episodes.returns.dtype == (np.float64 if x64 else np.float32)
    assert episodes.lengths.dtype == np.int32
    np.testing.assert_array_equal(episodes.returns, episodes.transitions.reward.sum(axis=0))
    np.testing.assert_array_equal(episodes.lengths, episodes.transitions.alive.sum(axis=0))
    # -1 for a fall, 0 for a truncation at 40 steps; 1 per step otherwise.
    assert (episodes.returns == -1).any() if sutton_barto else (episodes.returns >= 1).all()


def test_episode_in_a_batch_equals_episode_alone(init_state):
    batch = jit_rollout(jax.random.PRNGKey(0), basic_policy, LIMITED, E, T, init_state)
    for i in range(0, E, 8):
        alone = jit_rollout(jax.random.PRNGKey(0), basic_policy, LIMITED, 1, T,
                            jax.tree.map(lambda leaf: leaf[i:i + 1], init_state))
        chex.assert_trees_all_close(
            jax.tree.map(lambda leaf: leaf[:, i], batch.transitions),
            jax.tree.map(lambda leaf: leaf[:, 0], alone.transitions), rtol=1e-5, atol=1e-6)
        assert int(alone.lengths[0]) == int(batch.lengths[i])


def test_reset_batch_is_uniform_within_bounds():
    obs, state = jax.jit(rollout.reset_batch, static_argnums=1)(
        jax.random.PRNGKey(1), 10_000, cartpole.V1)
    values = np.asarray(obs)
    assert values.min() >= -0.05 and values.max() < 0.05
    assert (np.asarray(state.time) == 0).all()
    for component in values.T:
        # KS against uniform on [-0.05, 0.05) at level 1e-3, fixed key: deterministic.
        assert scipy.stats.kstest(component, "uniform", args=(-0.05, 0.1)).pvalue > 1e-3


def test_autoreset_follows_gymnasium_vector_env():
    """Next-step autoreset as CartPoleVectorEnv, with jaxpg re-synced to Gymnasium's states.

    Before each step jaxpg takes the float64 states of the vector env (keeping its own step
    counts), then both step with the same actions. The random resets themselves differ (two
    generators), so a resetting environment is checked for what a reset is.
    """
    n, limit = 8, 15
    vec = CartPoleVectorEnv(num_envs=n, max_episode_steps=limit)
    vec.reset(seed=0)
    env_params = cartpole.V1.replace(max_steps=limit)
    stream_state = rollout.StreamState(cartpole.CartPoleState.from_array(vec.state.T),
                                       jnp.zeros(n, dtype=bool))
    step = jax.jit(rollout.autoreset_step)
    rng = np.random.default_rng(0)
    key = jax.random.PRNGKey(0)
    counts = np.zeros(3, dtype=int)  # resets, terminations, truncations seen
    for _ in range(80):
        actions = rng.integers(0, 2, n)
        env_state = cartpole.CartPoleState.from_array(vec.state.T, stream_state.env_state.time)
        stream_state = stream_state._replace(env_state=env_state)
        resets = np.asarray(stream_state.prev_done)
        gym_obs, gym_reward, gym_terminated, gym_truncated, _ = vec.step(actions)
        key, key_step = jax.random.split(key)
        obs, stream_state, reward, terminated, truncated = step(
            key_step, stream_state, jnp.asarray(actions), env_params)

        np.testing.assert_array_equal(reward, gym_reward)
        np.testing.assert_array_equal(terminated, gym_terminated)
        np.testing.assert_array_equal(truncated, gym_truncated)
        np.testing.assert_array_equal(stream_state.prev_done, vec.prev_done)
        np.testing.assert_array_equal(stream_state.env_state.time, vec.steps)
        np.testing.assert_allclose(np.asarray(obs)[~resets], gym_obs[~resets], rtol=1e-6,
                                   atol=1e-6)
        # A resetting environment ignores its action: a fresh state, reward 0, not done.
        assert (np.abs(np.asarray(obs)[resets]) <= 0.05).all()
        assert not np.asarray(terminated | truncated)[resets].any()
        counts += [resets.sum(), gym_terminated.sum(), gym_truncated.sum()]
    assert (counts > 0).all(), counts


def test_stream_accounts_for_every_step():
    num_envs, num_steps = 16, 200
    stream = jax.jit(rollout.stream, static_argnums=(1, 3, 4))
    state, stats = stream(jax.random.PRNGKey(0), rollout.random_policy,
                          cartpole.V1.replace(max_steps=50), num_envs, num_steps)
    # Every step earns 1 except a reset step, which earns 0; each finished episode is followed by
    # one reset step, except those that finished on the very last step (still prev_done).
    resets = int(stats.episodes) - int(state.prev_done.sum())
    assert int(stats.episodes) > num_envs  # random pushes fall in ~20 steps: many episodes
    assert float(stats.total_return) == num_envs * num_steps - resets


def test_stream_redraws_when_an_environment_resets_twice_in_a_chunk():
    """Episodes of one or two steps reset several times per chunk of STREAM_CHUNK steps."""
    num_envs, num_steps = 8, 3 * rollout.STREAM_CHUNK + 3
    env_params = cartpole.V1.replace(theta_threshold_radians=0.01, x_threshold=0.01)
    stream = jax.jit(rollout.stream, static_argnums=(1, 3, 4))
    state, stats = stream(jax.random.PRNGKey(1), rollout.random_policy, env_params,
                          num_envs, num_steps)
    resets = int(stats.episodes) - int(state.prev_done.sum())
    assert resets > num_envs * num_steps // 4  # most chunks reset every environment twice or more
    assert float(stats.total_return) == num_envs * num_steps - resets


@pytest.mark.parametrize("num_episodes", [1, 10, 16, 20])
def test_episodes_played_in_whole_vectors_are_the_episodes(init_state, num_episodes):
    """`lanes` pads the batch with copies of its first episodes, which the result leaves out."""
    policy = lambda obs, u: (u > 0.5).astype(jnp.int32)  # noqa: E731
    seen = []

    def watched(obs, u):
        seen.append(obs.shape[0])
        return policy(obs, u)

    key = jax.random.PRNGKey(3)
    plain = rollout.rollout(key, policy, LIMITED, num_episodes, 30)
    padded = rollout.rollout(key, watched, LIMITED, num_episodes, 30, lanes=rollout.LANES)
    # Everything but the records as written, which hold every lane played.
    chex.assert_trees_all_equal(padded._replace(records=None), plain._replace(records=None))
    assert seen and all(lanes % rollout.LANES == 0 and lanes - num_episodes < rollout.LANES
                        for lanes in seen)
    assert {r.shape[2] for r in padded.records} == set(seen)
    given = jax.tree.map(lambda leaf: leaf[:num_episodes], init_state)
    chex.assert_trees_all_equal(
        rollout.rollout(key, basic_policy, LIMITED, num_episodes, 30, given,
                        lanes=rollout.LANES)._replace(records=None),
        rollout.rollout(key, basic_policy, LIMITED, num_episodes, 30, given)._replace(records=None))


def test_many_runs_at_once_play_as_each_run_alone():
    keys = jax.random.split(jax.random.PRNGKey(2), 3)
    policy = lambda obs, u: (u > 0.5).astype(jnp.int32)  # noqa: E731
    together = rollout.rollout(keys, policy, LIMITED, 4, 30)
    for r, key in enumerate(keys):
        alone = rollout.rollout(key, policy, LIMITED, 4, 30)
        chex.assert_trees_all_equal(jax.tree.map(lambda leaf: leaf[:, :, r], together.transitions),
                                    alone.transitions)


def test_a_policy_that_gives_no_action_of_each_observation_is_refused_as_traced():
    key = jax.random.PRNGKey(0)
    for policy, got in [(lambda obs, u: obs, r"float32 \(6, 4\)"),
                        (lambda obs, u: u, r"float32 \(6,\)"),
                        (lambda obs, u: jnp.zeros((), jnp.int32), r"int32 \(\)")]:
        with pytest.raises(ValueError, match=r"^policy: must return one integer action per "
                                             rf"observation, shaped \(6,\) .* got {got}"):
            jax.jit(lambda key: rollout.rollout(key, policy, cartpole.V1, 6, 10).returns)(key)


def test_an_action_other_than_0_or_1_is_flagged_per_run():
    keys = jax.random.split(jax.random.PRNGKey(0), 3)

    def policy(obs, u):  # run 1 plays 2 on its first step, which CartPole plays as 0
        first = jnp.all(obs == obs, axis=-1) & (jnp.arange(3) == 1)
        return jnp.where(first & (u < 2), 2, basic_policy(obs))

    episodes = jax.jit(lambda keys: rollout.rollout(keys, policy, cartpole.V1, 4, 10))(keys)
    np.testing.assert_array_equal(episodes.invalid_action, [False, True, False])
    assert not rollout.rollout(keys[0], basic_policy, cartpole.V1, 4, 10).invalid_action


def test_a_rollout_written_over_an_earlier_ones_records_is_the_rollout():
    """Every entry of the records is written: over the records of a rollout whose episodes
    lasted longer, one whose episodes all end early (its last chunks never played) is the same."""
    random_actions = lambda obs, u: (u > 0.5).astype(jnp.int32)  # noqa: E731
    always_left = lambda obs, u: jnp.zeros(u.shape, jnp.int32)  # noqa: E731
    earlier = rollout.rollout(jax.random.PRNGKey(1), random_actions, cartpole.V1, 6, 120)
    fresh = rollout.rollout(jax.random.PRNGKey(2), always_left, cartpole.V1, 6, 120)
    assert int(fresh.lengths.max()) < rollout.CHUNK < int(earlier.lengths.max())
    chex.assert_trees_all_equal(
        rollout.rollout(jax.random.PRNGKey(2), always_left, cartpole.V1, 6, 120,
                        records=earlier.records), fresh)


def test_records_of_other_shapes_are_refused_in_one_line():
    policy = lambda obs, u: (u > 0.5).astype(jnp.int32)  # noqa: E731
    earlier = rollout.rollout(jax.random.PRNGKey(1), policy, cartpole.V1, 6, 40)
    with pytest.raises(ValueError, match=r"^records: expected the Episodes.records of a rollout "
                                         r"of the same shapes, float32 \[\(4, 40, 5\)[^\n]*$"):
        rollout.rollout(jax.random.PRNGKey(1), policy, cartpole.V1, 5, 40, records=earlier.records)
    with pytest.raises(ValueError, match=r"^records: expected [^\n]*, got list$"):
        rollout.rollout(jax.random.PRNGKey(1), policy, cartpole.V1, 6, 40,
                        records=list(earlier.records))
