"""Batched CartPole episodes: `vmap` over episodes, `lax.scan` over time.

A policy is a function `(obs [E, 4], key) -> action [E]` acting on a whole batch of observations
at once, so that it draws its random numbers in bulk, one key per step for all episodes.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxpg import cartpole


class Transition(NamedTuple):
    """What happened at each step; `[T, E]` leading axes. Steps after an episode ended are masked."""

    obs: jax.Array  # [T, E, 4] observation the action was chosen from
    action: jax.Array  # [T, E]
    reward: jax.Array  # [T, E], 0 where not alive
    alive: jax.Array  # [T, E] bool: the step belongs to the episode


class Episodes(NamedTuple):
    """A batch of finished (or cut at T steps) episodes."""

    transitions: Transition
    returns: jax.Array  # [E] sum of rewards over the alive steps
    lengths: jax.Array  # [E] number of alive steps


CHUNK = 20  # steps simulated between checks whether every episode has ended


def reset_batch(key, num, env_params):
    """`num` initial states drawn with one call to the random number generator.

    Returns:
      (obs `[num, 4]`, state with `[num]` leaves)
    """
    values = jax.random.uniform(
        key, (num, 4), minval=env_params.reset_low, maxval=env_params.reset_high
    )
    state = cartpole.CartPoleState.from_array(values)
    return cartpole.observe(state), state


def _select(done, old, new):
    """Per environment, `old` where done, else `new` (a frozen episode stays where it ended)."""
    return jax.tree.map(lambda o, n: jnp.where(done, o, n), old, new)


def rollout(key, policy, env_params, num_episodes, max_steps, init_state=None, axis_name=None):
    """Plays `num_episodes` episodes of at most `max_steps` steps with `policy`.

    Time runs in chunks of `CHUNK` steps; once every episode has ended, the remaining chunks are
    skipped, not simulated. Their transitions are all masked (obs of the final state, action 0).

    Args:
      key: PRNG key for the initial states and the policy's randomness.
      policy: `(obs [E, 4], key) -> action [E]`.
      env_params: `CartPoleParams`; an episode also ends when `env_params.max_steps` truncates it.
      num_episodes: E.
      max_steps: T, the length of the trajectory.
      init_state: optional `CartPoleState` with `[E]` leaves, instead of random resets.
      axis_name: under `vmap(..., axis_name=...)`, skip a chunk only once the episodes of every
        vmapped rollout have ended, so the skip stays a real branch rather than a select.

    Returns:
      `Episodes` with transitions of shape `[T, E, ...]`.
    """
    key_reset, key_policy = jax.random.split(key)
    if init_state is None:
        _, init_state = reset_batch(key_reset, num_episodes, env_params)
    chunk = min(CHUNK, max_steps)
    num_chunks = -(-max_steps // chunk)
    step_keys = jax.random.split(key_policy, num_chunks * chunk).reshape(num_chunks, chunk, -1)
    batched_step = jax.vmap(cartpole.step, in_axes=(0, 0, None))

    def one_step(carry, step_key):
        state, done = carry
        obs = cartpole.observe(state)
        action = policy(obs, step_key)
        _, next_state, reward, terminated, truncated = batched_step(state, action, env_params)
        alive = ~done
        reward = jnp.where(alive, reward, 0.0)
        next_state = _select(done, state, next_state)
        done = done | terminated | truncated
        return (next_state, done), Transition(obs, action, reward, alive)

    def play_chunk(carry, keys):
        return jax.lax.scan(one_step, carry, keys)

    def skip_chunk(carry, keys):
        state, done = carry
        obs = cartpole.observe(state)
        frozen = Transition(
            obs=jnp.broadcast_to(obs, (chunk, *obs.shape)),
            action=jnp.zeros((chunk, num_episodes), jnp.int32),
            reward=jnp.zeros((chunk, num_episodes), obs.dtype),
            alive=jnp.zeros((chunk, num_episodes), bool),
        )
        return carry, frozen

    def one_chunk(carry, keys):
        all_done = jnp.all(carry[1])
        if axis_name is not None:
            all_done = jax.lax.pmin(all_done.astype(jnp.int32), axis_name) > 0
        return jax.lax.cond(all_done, skip_chunk, play_chunk, carry, keys)

    done = jnp.zeros(num_episodes, dtype=bool)
    _, transitions = jax.lax.scan(one_chunk, (init_state, done), step_keys)
    transitions = jax.tree.map(
        lambda leaf: leaf.reshape(num_chunks * chunk, *leaf.shape[2:])[:max_steps], transitions
    )
    returns = transitions.reward.sum(axis=0)
    lengths = transitions.alive.sum(axis=0)
    return Episodes(transitions, returns, lengths)


class StreamState(NamedTuple):
    """Carry of an auto-reset stream of N environments."""

    env_state: cartpole.CartPoleState  # [N] leaves
    prev_done: jax.Array  # [N] bool: the last step ended the episode, so the next one resets


class StreamStats(NamedTuple):
    """What a stream did: episodes finished and their summed return."""

    episodes: jax.Array
    total_return: jax.Array


def stream_reset(key, num_envs, env_params):
    """A fresh stream of `num_envs` environments. Returns (obs `[N, 4]`, `StreamState`)."""
    obs, state = reset_batch(key, num_envs, env_params)
    return obs, StreamState(state, jnp.zeros(num_envs, dtype=bool))


def autoreset_step(key, stream_state, action, env_params):
    """One step of N environments with Gymnasium's next-step autoreset (as `CartPoleVectorEnv`).

    An environment whose previous step terminated or truncated ignores `action` and resets: reward
    0, terminated and truncated False.

    Returns:
      (obs `[N, 4]`, `StreamState`, reward `[N]`, terminated `[N]`, truncated `[N]`)
    """
    prev_done = stream_state.prev_done
    _, fresh = reset_batch(key, prev_done.shape[0], env_params)
    _, stepped, reward, terminated, truncated = jax.vmap(cartpole.step, in_axes=(0, 0, None))(
        stream_state.env_state, action, env_params
    )
    state = _select(prev_done, fresh, stepped)
    reward = jnp.where(prev_done, 0.0, reward)
    terminated = terminated & ~prev_done
    truncated = truncated & ~prev_done
    return (
        cartpole.observe(state),
        StreamState(state, terminated | truncated),
        reward,
        terminated,
        truncated,
    )


def random_policy(obs, key):
    """Pushes left or right with equal probability, one random bit per environment."""
    return jax.random.bernoulli(key, shape=obs.shape[:-1]).astype(jnp.int32)


def stream(key, policy, env_params, num_envs, num_steps):
    """Runs `num_envs` auto-resetting environments for `num_steps` steps.

    Returns:
      (`StreamState` at the end, `StreamStats` over the run)
    """
    key_reset, key_steps = jax.random.split(key)
    obs, state = stream_reset(key_reset, num_envs, env_params)
    step_keys = jax.random.split(key_steps, num_steps)

    def one_step(carry, step_key):
        obs, state, stats = carry
        key_policy, key_reset = jax.random.split(step_key)
        action = policy(obs, key_policy)
        obs, state, reward, terminated, truncated = autoreset_step(
            key_reset, state, action, env_params
        )
        ended = terminated | truncated
        stats = StreamStats(
            stats.episodes + ended.sum(),
            stats.total_return + reward.sum(),
        )
        return (obs, state, stats), None

    stats = StreamStats(jnp.zeros((), jnp.int32), jnp.zeros(()))
    (_, state, stats), _ = jax.lax.scan(one_step, (obs, state, stats), step_keys)
    return state, stats
