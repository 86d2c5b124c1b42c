"""Batched episodes of any environment (`lax.scan` over time, every episode at once), and
auto-reset streams of any environment.

The environment is the module of the params given (`jaxpg.envs.module_of`): CartPole or another
of `jaxpg.envs`. A policy for `rollout` is a function `(obs [E, K], u [E]) -> action [E]` acting
on a whole batch of observations at once; `u` is uniform in [0, 1), drawn in bulk by the rollout
for every step. Actions are integers for a discrete environment, floats for a continuous one.
`rollout` also plays R independent runs at once (R keys, a policy with R sets of weights): every
array then has a trailing run axis, which XLA vectorises over, and run r's episodes are exactly
those it would play alone. Without run axes XLA vectorises over the episodes, in whole vectors
only: `rollout(..., lanes=LANES)` plays a multiple of `LANES` episodes, the first ones again in
the lanes left over, and drops the copies from what it returns (its policy sees them all); one
episode it plays twice (`played_episodes`).
"""

import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple, Protocol, TypeVar, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg import envs, rng, sums
from jaxpg.envs import cartpole
from jaxpg.types import Action, ArrayLike, Observation, Policy, PRNGKey

# The policy of a stream, which draws its own random numbers: (obs `[N, K]`, key) -> action `[N]`.
StreamPolicy = Callable[[Observation, PRNGKey], Action]

_Tree = TypeVar("_Tree")
# A step's record, or the records of every step `[..., T, E, ...]`: the observation's K features
# `[K, ...]`, its outcome `[3, ...]` (action, reward, alive, as floats) and, for a
# `RecordingPolicy`, the policy's features `[F, ...]`.
Records = tuple[jax.Array, ...]


@runtime_checkable
class RecordingPolicy(Protocol):
    """A policy in two stages, which `rollout` records between: features of each observation,
    then actions from them (`policies.HiddenRecordingPolicy`: a network's hidden activations;
    `replay.ReplayPolicy`: the values of a module's pass that its gradient reads).

    The rollout computes a step's features once, writes them into its records
    (`Episodes.policy_features`) and acts on them as read back from them, so that a gradient
    reads them rather than computing them again (compiled, XLA would compute them anew for each
    of their two uses). Called as a policy, it is `act(features(obs), u)`.
    """

    def features(self, obs: Observation) -> tuple[jax.Array, ...]:
        """Features, each `[F, E, ...]` of observations `[E, K]` (`[E, R, K]`, the run axis among
        the feature's trailing axes): each recorded `[F, T, E, ...]`."""
        ...

    def act(self, features: tuple[jax.Array, ...], u: jax.Array) -> Action:
        """Actions `[E]` (`[E, R]`) from `features` and uniforms `u`."""
        ...

    def __call__(self, obs: Observation, u: jax.Array) -> Action:
        """`act(features(obs), u)`."""
        ...


class Transition(NamedTuple):
    """What happened at each step; `[T, E]` leading axes. Steps after an episode ended are masked.

    With R runs, every field has a run axis after the episodes' (`[T, E, R, ...]`).
    """

    obs: jax.Array  # [T, E, K] observation the action was chosen from
    action: jax.Array  # [T, E] int32 (float for a continuous action)
    reward: jax.Array  # [T, E], 0 where not alive
    alive: jax.Array  # [T, E] bool: the step belongs to the episode


class Episodes(NamedTuple):
    """A batch of finished (or cut at T steps) episodes; `[E, R]` in place of `[E]` for R runs."""

    transitions: Transition  # [T, E, ...]
    returns: jax.Array  # [E] sum of rewards over the alive steps, in the rewards' float dtype
    lengths: jax.Array  # [E] int32 number of alive steps
    # [] bool ([R] for R runs): whether the policy gave an action outside the environment's on an
    # alive step (CartPole played another than 0 or 1 as 0, push left; a continuous environment
    # one that is not finite); a caller of a user's policy raises it (`check_played_actions`).
    invalid_action: jax.Array | None = None
    # Each [F, T, E, ...]: the features a `RecordingPolicy` computed at each step; None for
    # another policy.
    policy_features: tuple[jax.Array, ...] | None = None
    # The records as the rollout wrote them, of every step of whole chunks and every played
    # episode: observations [K, T', E', ...], action, reward and alive [3, T', E', ...], and any
    # policy features; a later `rollout(..., records=...)` of the same shapes writes over them.
    records: Records | None = None


CHUNK = 20  # steps simulated between checks whether every episode has ended
LANES = 16  # floats in a vector of AVX-512, two of AVX2


def played_episodes(num_episodes: int, lanes: int) -> int:
    """How many episodes `rollout(..., lanes=lanes)` plays: a multiple of `lanes`, and one episode
    twice.

    Played once, XLA drops its axis of one entry and compiles the physics' and the policy's
    multiplications and additions into FMAs otherwise than beside other episodes, so a run played
    one episode in a block otherwise than alone.
    """
    played = -(-num_episodes // lanes) * lanes
    return 2 if played == 1 else played


def reset_batch(key: PRNGKey, num: int, env_params: Any, repeat_to: int | None = None
                ) -> tuple[Observation, Any]:
    """`num` initial states of the environment of `env_params`.

    CartPole's are drawn with one call to the random number generator; another environment's by
    its own `reset`, from a key per episode (`rng.split(key, num)`).

    Args:
      key: PRNG key, or R keys `[R, 2]`.
      num: the number of states drawn.
      env_params: the environment's params, whose reset bounds the values are drawn within.
      repeat_to: optional: that many states (in place of `num` in the shapes below), the `num`
        drawn ones, then the first ones again, drawn so that the copies cost nothing more.

    Returns:
      (obs `[num, K]`, state with `[num]` leaves); with R keys, `[num, R, K]` and `[num, R]`.
    """
    module = envs.module_of(env_params)
    if module is not cartpole:
        keys = rng.split(key, num)
        if repeat_to is not None:
            keys = keys[np.arange(repeat_to) % num]
        batch = keys.shape[:-1]
        # Every leaf of the params spread over the episodes (and runs), reset one by one.
        spread = jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, batch).reshape(-1), env_params)
        obs, state = jax.vmap(module.reset)(keys.reshape(-1, 2), spread)
        return jax.tree.map(lambda leaf: leaf.reshape(*batch, *leaf.shape[1:]), (obs, state))
    repeat = None if repeat_to is None else (0, repeat_to)
    values = rng.uniform(key, (num, 4), env_params.reset_low, env_params.reset_high, repeat=repeat)
    state = cartpole.CartPoleState.from_array(jnp.moveaxis(values, 1, -1))
    return cartpole.observe(state), state


def _select(done: jax.Array, old: _Tree, new: _Tree) -> _Tree:
    """Per environment, `old` where `done` `[N]`, else `new` (leaves `[N, ...]`)."""
    return jax.tree.map(
        lambda o, n: jnp.where(done.reshape(done.shape + (1,) * (o.ndim - done.ndim)), o, n),
        old, new)


def _record(features: jax.Array, action: jax.Array, reward: jax.Array, alive: jax.Array
            ) -> Records:
    """One step's transition: (the observation's K features `[K, E, ...]`, action, reward and
    alive `[3, E, ...]`)."""
    dtype = features.dtype
    return features, jnp.stack([action.astype(dtype), reward.astype(dtype), alive.astype(dtype)])


def _read(records: jax.Array, t: jax.Array) -> jax.Array:
    """Step `t` of `records` `[F, T, ...]`: `[F, ...]`."""
    return jax.lax.dynamic_index_in_dim(records, t, 1, keepdims=False)


def _write(records: jax.Array, values: jax.Array, t: jax.Array) -> jax.Array:
    """`records` `[F, T, ...]` with step `t`'s `values` `[F, ...]` written in place."""
    return jax.lax.dynamic_update_index_in_dim(records, values, t, 1)


def _transitions(records: tuple[jax.Array, jax.Array], discrete: bool) -> Transition:
    """`Transition` from records `[K, T, E, ...]` and `[3, T, E, ...]`; int32 actions if
    `discrete`."""
    # Stored field first: the gradient reads the observations back features first, `[K, T, E]`,
    # and each other field is one contiguous array.
    features, outcome = records
    return Transition(obs=jnp.moveaxis(features, 0, -1),
                      action=outcome[0].astype(jnp.int32) if discrete else outcome[0],
                      reward=outcome[1],
                      alive=outcome[2] != 0)


def _written(records: Records, record: Records, t: jax.Array) -> Records:
    """`records` `[..., T, E, ...]` with step `t`'s `record` `[..., E, ...]` written in place."""
    return tuple(_write(r, x, t) for r, x in zip(records, record, strict=True))


def rollout(key: PRNGKey, policy: Policy, env_params: Any, num_episodes: int,
            max_steps: int, init_state: Any = None, lanes: int = 1,
            records: Records | None = None) -> Episodes:
    """Plays `num_episodes` episodes of at most `max_steps` steps with `policy`.

    Time runs in chunks of `CHUNK` steps; once every episode has ended, the remaining chunks are
    skipped, not simulated. Their transitions are all masked (obs of the final state, action 0).

    Args:
      key: PRNG key for the initial states and the policy's uniforms; or R keys `[R, 2]` to play R
        runs at once, each as its key alone would.
      policy: `(obs [E, K], u [E]) -> action [E]`; for R runs, `(obs [E, R, K], u [E, R])`. A
        `RecordingPolicy`'s features are recorded (`Episodes.policy_features`).
      env_params: the environment's params (`CartPoleParams` or another of `jaxpg.envs`); an
        episode also ends when `env_params.max_steps` truncates it.
      num_episodes: E.
      max_steps: T, the length of the trajectory.
      init_state: optional state of the environment with `[E]` (or `[E, R]`) leaves, in place
        of random resets.
      lanes: the episodes are played in a multiple of this many lanes, the first ones again in the
        lanes left over (one episode in two: `played_episodes`); the policy sees every lane, the
        result only the E episodes.
      records: optional, `Episodes.records` of an earlier rollout of the same shapes, written over
        (every entry is) rather than new memory cleared for them.

    Returns:
      `Episodes` with transitions of shape `[T, E, ...]` (`[T, E, R, ...]` for R runs).

    Raises:
      ValueError: as it is traced, if the policy does not return one action of the
        environment's kind per observation (`check_actions`).
    """
    module = envs.module_of(env_params)
    discrete = envs.is_discrete(module)
    key_reset, key_policy = rng.split(key)
    played = played_episodes(num_episodes, lanes)
    if init_state is None:
        _, init_state = reset_batch(key_reset, num_episodes, env_params, played)
    elif played > num_episodes:
        init_state = jax.tree.map(lambda leaf: leaf[np.arange(played) % num_episodes], init_state)
    chunk = min(CHUNK, max_steps)
    num_chunks = -(-max_steps // chunk)
    noise = rng.uniform(key_policy, (num_chunks, chunk, num_episodes), repeat=(2, played))

    # The carry is one array, the state's S values and whether the episode ended `[S + 1, E, R]`:
    # few kernels per step, which XLA runs in sequence (docs/performance.md).
    size = init_state.to_array(axis=0).shape[0]
    recorder = policy if isinstance(policy, RecordingPolicy) else None

    def state_of(features: jax.Array, t: jax.Array) -> Any:
        """The environment's state of values `[S, ...]` after `t` steps of the trajectory."""
        return type(init_state).from_array(jnp.moveaxis(features, 0, -1), init_state.time + t)

    def one_step(loop: tuple[jax.Array, Records], step: tuple[jax.Array, jax.Array]
                 ) -> tuple[tuple[jax.Array, Records], None]:
        """One step of every episode: the carry `[S + 1, E, ...]`, and its record written into
        the records at step `t`."""
        (carry, records), (u, t) = loop, step
        features, done = carry[:size], carry[size] != 0
        state = state_of(features, t)
        obs = module.observe(state)
        if recorder is not None:
            records = (*records[:2], *_written(records[2:], recorder.features(obs), t))
            action = recorder.act(tuple(_read(r, t) for r in records[2:]), u)
        else:
            action = policy(obs, u)
        check_actions(action, obs, discrete)
        _, next_state, reward, terminated, truncated = module.step(state, action, env_params)
        alive = ~done
        record = _record(jnp.moveaxis(obs, -1, 0), action, jnp.where(alive, reward, 0.0), alive)
        next_features = jnp.where(done, features, next_state.to_array(axis=0))
        done = done | terminated | truncated
        return (jnp.concatenate([next_features, done[None].astype(features.dtype)]),
                (*_written(records[:2], record, t), *records[2:])), None

    def playing(loop: tuple[jax.Array, jax.Array, Records]) -> jax.Array:
        """Whether chunk `c` is to be played: some episode has not ended."""
        c, carry, _ = loop
        return (c < num_chunks) & ~jnp.all(carry[size] != 0)

    def play_chunk(loop: tuple[jax.Array, jax.Array, Records]
                   ) -> tuple[jax.Array, jax.Array, Records]:
        """Chunk `c`'s `CHUNK` steps simulated, their records written."""
        c, carry, records = loop
        chunk_steps = (jax.lax.dynamic_index_in_dim(noise, c, keepdims=False),
                       c * chunk + jnp.arange(chunk, dtype=jnp.int32))
        return c + 1, *jax.lax.scan(one_step, (carry, records), chunk_steps)[0]

    def write_ended(features: jax.Array, t: jax.Array, records: Records) -> Records:
        """`records` with step `t` masked, every episode having ended in the state of values
        `features`: its observation (at the chunk's first step), action 0."""
        obs = module.observe(state_of(features, t - t % chunk))
        frozen = _record(jnp.moveaxis(obs, -1, 0), jnp.zeros(features.shape[1:], jnp.int32),
                         jnp.zeros(features.shape[1:], features.dtype),
                         jnp.zeros(features.shape[1:], bool))
        return _written(records, frozen if recorder is None
                        else (*frozen, *recorder.features(obs)), t)

    features = init_state.to_array(axis=0)
    carry = jnp.concatenate([features, jnp.zeros((1, *features.shape[1:]), features.dtype)])
    # Every step writes its record in place, field first: `[K, T, E, ...]` and `[3, T, E, ...]`.
    # The chunks after every episode ended are not simulated: their steps are written masked.
    steps = num_chunks * chunk
    shapes = [(n, steps, *features.shape[1:])
              for n in (jax.eval_shape(module.observe, init_state).shape[-1], 3)]
    if recorder is not None:
        shapes += [(leaf.shape[0], steps, *leaf.shape[1:]) for leaf in jax.eval_shape(
            lambda s: recorder.features(module.observe(s)), init_state)]
    if records is None:
        records = tuple(jnp.zeros(shape, features.dtype) for shape in shapes)
    elif (not isinstance(records, tuple) or [np.shape(r) for r in records] != shapes
          or any(jnp.result_type(r) != features.dtype for r in records)):
        got = ([f"{jnp.result_type(r)} {np.shape(r)}" for r in records]
               if isinstance(records, tuple) else type(records).__name__)
        raise ValueError(f"records: expected the Episodes.records of a rollout of the same shapes, "
                         f"{features.dtype} {shapes}, got {got}")
    played_chunks, carry, records = jax.lax.while_loop(
        playing, play_chunk, (jnp.int32(0), carry, records))
    records = jax.lax.fori_loop(played_chunks * chunk, num_chunks * chunk,
                                functools.partial(write_ended, carry[:size]), records)
    written = records
    records = jax.tree.map(lambda r: r[:, :max_steps, :num_episodes], records)
    outcome = records[1]
    action, alive = outcome[0], outcome[2] != 0
    if module is cartpole:  # rewards and alive steps: whole numbers, summed exactly
        returns, alive_steps = _over_time(outcome, slice(1, 3))
        returns = returns.astype(outcome.dtype)
    else:  # any rewards, summed in a fixed order, a run alike alone and beside others
        returns, alive_steps = sums.invariant_sum(outcome[1], 0), _over_time(outcome, 2)
    invalid = jnp.any(alive & outside_actions(action, module), axis=(0, 1))
    return Episodes(_transitions((records[0], records[1]), discrete), returns, alive_steps,
                    invalid, records[2:] if recorder is not None else None, written)


def _over_time(records: jax.Array, rows: int | slice) -> jax.Array:
    """The `rows` of records `[F, T, ...]` summed over time, one step after another, as int32 (for
    whole numbers).

    A loop, which XLA compiles whole, rather than its reduction over the time axis: as a float
    sum XLA hands that to a library call, which splits the training program's loop, and as an
    integer sum it runs slower than the loop (docs/performance.md). Each step's rows are read out
    of the records in the loop, never copied out of them first.
    """
    def add(t: jax.Array, total: jax.Array) -> jax.Array:
        """`total` with step `t`'s rows added."""
        return total + _read(records, t)[rows].astype(total.dtype)

    return jax.lax.fori_loop(0, records.shape[1], add,
                             jnp.zeros(records[rows, 0].shape, jnp.int32))


def check_actions(action: ArrayLike, obs: ArrayLike, discrete: bool = True) -> None:
    """Checks a policy's actions for `obs` `[..., K]` as the rollout is traced.

    Raises:
      ValueError: unless `action` holds one action per observation, `[...]`: an integer (or
        bool) for a discrete environment, a float for a continuous one.
    """
    dtype = jnp.result_type(action)
    if discrete and (jnp.shape(action) != jnp.shape(obs)[:-1] or not (
            jnp.issubdtype(dtype, jnp.integer) or dtype == jnp.bool_)):
        raise ValueError(f"policy: must return one integer action per observation, shaped "
                         f"{jnp.shape(obs)[:-1]} (on CartPole 0 pushes left, 1 right), got {dtype} "
                         f"{jnp.shape(action)}")
    if not discrete and (jnp.shape(action) != jnp.shape(obs)[:-1]
                         or not jnp.issubdtype(dtype, jnp.floating)):
        raise ValueError(f"policy: must return one float action per observation, shaped "
                         f"{jnp.shape(obs)[:-1]}, got {dtype} {jnp.shape(action)}")


def outside_actions(action: ArrayLike, module: Any) -> Any:
    """Where `action` is none of the environment module's actions: a discrete one outside 0 to
    `NUM_ACTIONS - 1`, a continuous one not finite (elementwise, on the host or traced)."""
    if envs.is_discrete(module):
        return (action < 0) | (action > module.NUM_ACTIONS - 1)  # type: ignore[operator]
    return ~jnp.isfinite(action)


def allowed_actions(module: Any) -> str:
    """The actions of an environment module, in words."""
    return f"0 to {module.NUM_ACTIONS - 1}" if envs.is_discrete(module) else "a finite number"


def check_played_actions(invalid_action: ArrayLike | None, env_params: Any = cartpole.V1
                         ) -> None:
    """Checks on the host that a rollout's policy gave the environment's actions only.

    Args:
      invalid_action: `Episodes.invalid_action`, `[]` or `[R]` bool; None passes.
      env_params: the environment's params (CartPole's by default).

    Raises:
      ValueError: if any is True: the policy gave another action (CartPole played it as 0).
    """
    if not np.any(invalid_action):
        return
    module = envs.module_of(env_params)
    if module is cartpole:
        raise ValueError("policy: returned an action other than 0 (push left) or 1 (push right), "
                         "which CartPole played as 0")
    raise ValueError(f"policy: returned an action other than {allowed_actions(module)}")


class StreamState(NamedTuple):
    """Carry of an auto-reset stream of N environments."""

    env_state: Any  # the environment's state, [N] leaves
    prev_done: jax.Array  # [N] bool: the last step ended the episode, so the next one resets


class StreamStats(NamedTuple):
    """What a stream did: episodes finished and their summed return."""

    episodes: jax.Array  # [] int32 episodes that ended (terminated or truncated), all environments
    total_return: jax.Array  # [] float sum of every reward of the stream


def stream_reset(key: PRNGKey, num_envs: int, env_params: Any
                 ) -> tuple[Observation, StreamState]:
    """A fresh stream of N = `num_envs` environments.

    Args:
      key: PRNG key of the initial states.
      num_envs: N.
      env_params: the environment's params (`CartPoleParams` or another of `jaxpg.envs`).

    Returns:
      (obs `[N, K]`, `StreamState`), no environment due to reset.
    """
    obs, state = reset_batch(key, num_envs, env_params)
    return obs, StreamState(state, jnp.zeros(num_envs, dtype=bool))


def autoreset_step(key: PRNGKey, stream_state: StreamState, action: Action, env_params: Any
                   ) -> tuple[Observation, StreamState, jax.Array, jax.Array, jax.Array]:
    """One step of N environments with Gymnasium's next-step autoreset (as `CartPoleVectorEnv`).

    An environment whose previous step terminated or truncated ignores `action` and resets: reward
    0, terminated and truncated False.

    Args:
      key: PRNG key of the states of the environments that reset.
      stream_state: the `StreamState` of N environments.
      action: `[N]` actions of the environment (on CartPole each 0 or 1).
      env_params: the environment's params (`CartPoleParams` or another of `jaxpg.envs`).

    Returns:
      (obs `[N, K]`, `StreamState`, reward `[N]`, terminated `[N]`, truncated `[N]`)
    """
    _, fresh = reset_batch(key, stream_state.prev_done.shape[0], env_params)
    return _autoreset(fresh, stream_state, action, env_params)


def _autoreset(fresh: Any, stream_state: StreamState, action: Action, env_params: Any
               ) -> tuple[Observation, StreamState, jax.Array, jax.Array, jax.Array]:
    """`autoreset_step` with the states `fresh` `[N]` for the environments that reset."""
    module = envs.module_of(env_params)
    prev_done = stream_state.prev_done
    _, stepped, reward, terminated, truncated = jax.vmap(module.step, in_axes=(0, 0, None))(
        stream_state.env_state, action, env_params
    )
    state = _select(prev_done, fresh, stepped)
    reward = jnp.where(prev_done, 0.0, reward)
    terminated = terminated & ~prev_done
    truncated = truncated & ~prev_done
    return (
        module.observe(state),
        StreamState(state, terminated | truncated),
        reward,
        terminated,
        truncated,
    )


def random_policy(obs: Observation, key: PRNGKey, env_params: Any = cartpole.V1) -> Action:
    """Uniformly random actions of the environment of `env_params` (CartPole's by default).

    2**k discrete actions come from k-bit fields of random 32-bit words, 32 // k from each word
    (CartPole's 32 actions from each word, one bit each); n others from one word each, its low
    16 bits f giving `(f * n) >> 16`, each action's probability within 2**-16 of 1/n. Continuous
    actions are uniform in the params' `action_bounds`, [low, high), one word each.

    Args:
      obs: `[..., K]` observations, of which only the shape and dtype are read.
      key: PRNG key.
      env_params: the environment's params (a stream's policy takes two arguments:
        `functools.partial(random_policy, env_params=...)` for another environment).

    Returns:
      Actions `[...]`: int32 for a discrete environment, floats of `obs`'s dtype otherwise.

    Raises:
      ValueError: as it is traced, for more than 2**16 discrete actions that are not a power of
        two.
    """
    module = envs.module_of(env_params)
    shape = obs.shape[:-1]
    if not envs.is_discrete(module):
        low, high = module.action_bounds(env_params)
        return rng.uniform(key, shape, low, high, obs.dtype)
    n = module.NUM_ACTIONS
    if n & (n - 1) == 0:
        width = max(1, n.bit_length() - 1)
        per_word = 32 // width
    elif n <= 2**16:
        # A word each: fields of one word interleave neighbours' actions, which XLA computes
        # slower than a word per action unless the fields are single bits (docs/performance.md).
        width, per_word = 16, 1
    else:
        raise ValueError(f"env_params: random_policy draws at most 2**16 actions that are not a "
                         f"power of two, got {n}")
    num = math.prod(shape)
    # Hashed once, not once per action that a word holds (`rng.computed_once`).
    words = rng.computed_once(rng.bits(key, (-(-num // per_word), 1)))
    fields = (words >> (jnp.arange(per_word, dtype=jnp.uint32) * width)) & ((1 << width) - 1)
    # (f * n) >> width is f itself for n = 2**width (CartPole's bits), and 0 for n = 1.
    actions = (fields * np.uint32(n)) >> width
    return actions.reshape(-1)[:num].reshape(shape).astype(jnp.int32)


STREAM_CHUNK = 8  # steps per draw of reset states: shorter than CartPole's shortest episode

# A stream's carry within a chunk: obs, state, fresh reset states, how many times each environment
# reset in the chunk, episodes and total return per environment.
_StepCarry = tuple[Observation, StreamState, Any, jax.Array, jax.Array, jax.Array]
# Between chunks: obs, state, episodes, total return.
_ChunkCarry = tuple[Observation, StreamState, jax.Array, jax.Array]


def stream(key: PRNGKey, policy: StreamPolicy, env_params: Any, num_envs: int,
           num_steps: int) -> tuple[StreamState, StreamStats]:
    """Runs `num_envs` auto-resetting environments for `num_steps` steps.

    The policy of a stream draws its own random numbers: `(obs [N, K], key) -> action [N]`, such
    as `random_policy`.

    Reset states are drawn once per environment every `STREAM_CHUNK` steps rather than every step:
    an episode of the default CartPole lasts at least 8 steps (and of the other tasks far longer),
    so an environment resets at most once in a chunk. One that resets twice (with other
    `env_params`) draws again for that step: such a chunk is played again, checking every step
    (under `jax.vmap` the choice is a select, so both plays always run).

    `jax.jit(..., compiler_options=xla_options.WIDE_VECTORS)` steps it about 1.5x as fast on a CPU
    with 512-bit vectors (docs/performance.md), with the same results for `random_policy` on
    every task (a policy's own arithmetic may round otherwise). The options count only on the
    outermost `jax.jit`: where the stream is part of a program of yours, pass them to its.

    Args:
      key: PRNG key.
      policy: `(obs [N, K], key) -> action [N]`.
      env_params: the environment's params (`CartPoleParams` or another of `jaxpg.envs`).
      num_envs: N.
      num_steps: steps of every environment.

    Returns:
      (`StreamState` at the end, `StreamStats` over the run)
    """
    key_reset, key_steps = jax.random.split(key)
    obs, state = stream_reset(key_reset, num_envs, env_params)

    def one_step(carry: _StepCarry, step_key: PRNGKey, checked: bool
                 ) -> tuple[_StepCarry, None]:
        """One step of every environment, `fresh` holding the states of those that reset; if
        `checked`, one that resets a second time in the chunk draws a state of its own."""
        obs, state, fresh, resets, episodes, total = carry
        if checked:
            again = state.prev_done & (resets > 0)
            fresh = jax.lax.cond(
                jnp.any(again),
                lambda: _select(again, reset_batch(jax.random.fold_in(step_key, 1), num_envs,
                                                   env_params)[1], fresh),
                lambda: fresh,
            )
        resets = resets + state.prev_done
        action = policy(obs, step_key)
        obs, state, reward, terminated, truncated = _autoreset(fresh, state, action, env_params)
        episodes = episodes + (terminated | truncated)
        return (obs, state, fresh, resets, episodes, total + reward), None

    def one_chunk(carry: _ChunkCarry, chunk_key: PRNGKey, length: int) -> tuple[_ChunkCarry, None]:
        """`length` steps, with reset states drawn once for them."""
        key_fresh, key_steps = rng.split(chunk_key)
        _, fresh = reset_batch(key_fresh, num_envs, env_params)
        step_keys = rng.split(key_steps, length)

        def play(checked: bool) -> tuple[_ChunkCarry, jax.Array]:
            """The chunk's steps: (carry, resets `[N]` of each environment)."""
            obs, state, episodes, total = carry
            resets = jnp.zeros(num_envs, jnp.int32)
            (obs, state, _, resets, episodes, total), _ = jax.lax.scan(
                functools.partial(one_step, checked=checked),
                (obs, state, fresh, resets, episodes, total), step_keys)
            return (obs, state, episodes, total), resets

        # Unchecked: the check is a reduction over every environment at every step (across
        # devices when the environments are split over them) and a branch. A chunk in which an
        # environment reset twice, rare, is played again, checked (docs/performance.md).
        played, resets = play(checked=False)
        return jax.lax.cond(jnp.any(resets > 1), lambda: play(checked=True)[0],
                            lambda: played), None

    num_chunks, rest = divmod(num_steps, STREAM_CHUNK)
    chunk_keys = rng.split(key_steps, num_chunks + 1)
    carry = (obs, state, jnp.zeros(num_envs, jnp.int32), jnp.zeros(num_envs))
    carry, _ = jax.lax.scan(
        functools.partial(one_chunk, length=STREAM_CHUNK), carry, chunk_keys[:num_chunks]
    )
    if rest:
        carry, _ = one_chunk(carry, chunk_keys[num_chunks], rest)
    _, state, episodes, total = carry
    return state, StreamStats(episodes.sum(), total.sum())
