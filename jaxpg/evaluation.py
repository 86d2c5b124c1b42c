"""Evaluates a policy on any environment of `jaxpg.envs`, in jaxpg (one compiled batch) or in
Gymnasium itself, and many policies in many physics settings at once (`robustness`).

Both backends can start from the very same initial states: `gymnasium_reset_states` reads the
float64 states that Gymnasium's `reset(seed=seed + i)` produces, and `evaluate(...,
init_states=...)` starts jaxpg's episodes from them.
"""

import functools
import math
import re
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple, TypeGuard, cast

import flax.linen as nn
import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

from jaxpg import budget, envs, rng, rollout, sweeps, train_config
from jaxpg.envs import cartpole
from jaxpg.policies import basic_policy, init_network, network_policy
from jaxpg.types import Action, Observation, Params, Policy, PRNGKey
from jaxpg.validation import (
    check_callback,
    check_choice,
    check_finite,
    check_int,
    check_representable,
    shown,
)

BACKENDS = ("jaxpg", "gymnasium")
# Steps of episodes (episodes x max_steps) that `evaluate` plays at once in jaxpg, 80 MiB in float32
# (`budget.EVAL_STEP_FLOATS`), and `robustness` in each of its `BLOCK` runs: more play in chunks of
# as many episodes, on any machine.
STEPS_AT_ONCE = 2**21
# Runs that `robustness` plays side by side; chosen for speed (docs/performance.md).
BLOCK = 16

# An environment to play in: a name of `envs.MODULES`, or an environment's params.
Env = Any


class EvalResult(NamedTuple):
    """Statistics of the episode returns (Python floats) and the returns themselves."""

    mean: float  # the mean return
    std: float  # population standard deviation, as np.std
    min: float  # the lowest return
    max: float  # the highest return
    returns: np.ndarray  # [episodes] float64


def resolve_env(env: Env) -> tuple[Any, str]:
    """An environment's name or params, validated, as (env_params, Gymnasium env id).

    Custom params map to their module's id (`CartPole-v1` for CartPole's), whose settings
    `make_gymnasium_env` then replaces. Only scalar settings can be evaluated (one environment,
    not a sweep over many).

    Args:
      env: a name of `envs.MODULES` ("CartPole-v1", "Acrobot-v1", ...) or an environment's params.

    Returns:
      (env_params, env_id): the preset's or the given params, and the Gymnasium id to make.

    Raises:
      ValueError: for an unknown name, anything else than a name or params, or settings that
        the environment's `check_params` refuses or that are arrays.
    """
    env_params = envs.resolve(env)
    return env_params, env if isinstance(env, str) else envs.module_of(env_params).NAME


def make_gymnasium_env(env_params: Any, env_id: str = "CartPole-v1") -> gymnasium.Env:
    """`gymnasium.make(env_id)` with its environment set to `env_params`.

    The TimeLimit truncates at `env_params.max_steps`. CartPole's physics may be any: its fields
    are set on the CartPoleEnv, and `total_mass` and `polemass_length` recomputed the way
    `CartPoleEnv.__init__` does, from the masses and length, never copied from `env_params`:
    Gymnasium stays the reference even for a `CartPoleParams` that derives them wrongly. Another
    environment plays Gymnasium's own physics and resets, so its params may differ from its
    preset in `max_steps` only.

    Args:
      env_params: scalar physics and episode settings.
      env_id: the Gymnasium id of the environment.

    Returns:
      The environment, its TimeLimit outermost, as `gymnasium.make` wraps it.

    Raises:
      ValueError: naming `env` for another environment's params that differ from its preset in
        more than `max_steps`.
    """
    module = envs.module_of(env_params)
    if module is not cartpole:
        preset = module.PRESETS[module.NAME]
        if env_params.replace(max_steps=preset.max_steps) != preset:
            raise ValueError(f"env: Gymnasium plays {env_id} with its own physics; the gymnasium "
                             f"backend takes {env_id}'s preset, max_steps aside")
        return gymnasium.make(env_id, max_episode_steps=int(env_params.max_steps))
    gym_env = gymnasium.make(
        env_id,
        max_episode_steps=int(env_params.max_steps),
        sutton_barto_reward=bool(env_params.sutton_barto_reward),
    )
    reference = cast(CartPoleEnv, gym_env.unwrapped)
    # CartPoleEnv keeps every physical field as an attribute of the same name.
    for name in train_config.PHYSICS:
        setattr(reference, name, float(getattr(env_params, name)))
    # Gymnasium integrates semi-implicitly for any value other than "euler".
    reference.kinematics_integrator = env_params.integrator
    reference.total_mass = reference.masspole + reference.masscart
    reference.polemass_length = reference.masspole * reference.length
    return gym_env


def reset_gymnasium(gym_env: gymnasium.Env, seed: int, env_params: Any) -> np.ndarray:
    """`gym_env.reset(seed=seed)` within the reset bounds of `env_params` (CartPole's; another
    environment resets as Gymnasium's preset does, `make_gymnasium_env`).

    Args:
      gym_env: an environment of `make_gymnasium_env`.
      seed: the seed of the reset.
      env_params: whose `reset_low` and `reset_high` bound CartPole's initial values.

    Returns:
      The first observation, float32 `[K]`.
    """
    if envs.module_of(env_params) is not cartpole:
        return gym_env.reset(seed=seed)[0]
    bounds = {"low": float(env_params.reset_low), "high": float(env_params.reset_high)}
    obs, _ = gym_env.reset(seed=seed, options=bounds)
    return obs


def gymnasium_reset_states(episodes: int, seed: int = 0, env: Env = "CartPole-v1") -> np.ndarray:
    """The float64 states that Gymnasium's `reset(seed=seed + i)` gives, for i in [0, episodes).

    Args:
      episodes: how many states, a positive integer.
      seed: the seed of the first, an integer in [0, 2**32).
      env: a preset name or a `cartpole.CartPoleParams` (`resolve_env`).

    Returns:
      `[episodes, 4]` float64 (x, x_dot, theta, theta_dot), as `env.unwrapped.state` holds them;
      `cartpole.CartPoleState.from_array` turns them into jaxpg's initial states.

    Raises:
      ValueError: naming the argument out of range, or `env` for another environment than
        CartPole.
    """
    check_int("episodes", episodes)
    check_int("seed", seed, 0, 2**32)
    env_params, env_id = _cartpole_only(env, "env")
    gym_env = make_gymnasium_env(env_params, env_id)
    states = []
    for episode in range(episodes):
        reset_gymnasium(gym_env, seed + episode, env_params)
        states.append(np.array(cast(CartPoleEnv, gym_env.unwrapped).state, dtype=np.float64))
    return np.stack(states)


def evaluate(
    policy: Policy,
    episodes: int = 500,
    max_steps: int = 200,
    env: Env = "CartPole-v1",
    seed: int = 0,
    backend: str = "jaxpg",
    init_states: npt.ArrayLike | None = None,
    on_chunk: Callable[[int], None] | None = None,
) -> EvalResult:
    """Plays `episodes` episodes of at most `max_steps` steps and summarizes their returns.

    With backend "jaxpg" the episodes run as one compiled `rollout.rollout` from
    `jax.random.PRNGKey(seed)`; more than `STEPS_AT_ONCE` steps (episodes x `max_steps`) play in
    chunks of C = `chunk_episodes(episodes, max_steps)` episodes, chunk c as one rollout of C
    episodes from `fold_in(PRNGKey(seed), c)` (the last one's extra episodes dropped), one
    program for every chunk. With backend "gymnasium", episode i runs in `gymnasium.make(env)`
    from `reset(seed=seed + i)`, one step at a time, as the book does; the policy's uniform at step
    t of episode i is drawn from `fold_in(fold_in(PRNGKey(seed), i), t)`. An episode also ends when
    the environment's own time limit (`max_steps` of its params) truncates it.

    Args:
      policy: `(obs [E, K], u [E]) -> action [E]` with u uniform in [0, 1), e.g.
        `policies.basic_policy` (CartPole's) or `policies.network_policy(network, params,
        num_actions=...)`. A policy that is a pytree of arrays (`policies.network_policy`)
        is an argument of the compiled program: a new one of the same shapes compiles nothing.
      episodes: E, a positive integer.
      max_steps: the longest an episode may run, a positive integer.
      env: a name of `envs.MODULES` ("CartPole-v1", "Acrobot-v1", ...) or an environment's
        params (the gymnasium backend plays another environment than CartPole in its preset's
        physics, `make_gymnasium_env`).
      seed: a non-negative integer.
      backend: "jaxpg" or "gymnasium".
      init_states: optional `[E, 4]` initial states of CartPole (jaxpg only), e.g.
        `gymnasium_reset_states`.
      on_chunk: optional: called on the host after each chunk in jaxpg with the episodes played
        so far (progress).

    Returns:
      `EvalResult` with the returns `[E]`.

    Raises:
      ValueError: one line naming the argument, for a policy that is not callable, an argument out
        of range, episodes that need more memory than the machine's (a chunk's
        `budget.evaluation_bytes`, and every return kept twice in float64),
        `init_states` of another shape than `[E, 4]`, not finite in JAX's default float, or with
        backend "gymnasium" or another environment, or a policy that plays an action the
        environment does not have.
    """
    if not callable(policy):
        raise ValueError(f"policy: must be a callable (obs, u) -> action, got {shown(policy)}")
    check_int("episodes", episodes)
    check_int("max_steps", max_steps)
    check_int("seed", seed, 0, 2**32)
    check_callback("on_chunk", on_chunk, "(episodes played) -> None")
    check_choice("backend", backend, BACKENDS)
    env_params, env_id = resolve_env(env)
    _check_plays("policy", policy, env_params)
    if backend == "gymnasium":
        if init_states is not None:
            raise ValueError(
                "init_states: only with backend jaxpg; Gymnasium starts from reset(seed=seed + i)"
            )
        returns = _gymnasium_returns(policy, episodes, max_steps, env_params, env_id, seed)
    else:
        chunk = chunk_episodes(episodes, max_steps)
        # The returns are kept in float64, and summarize's deviations are as many again.
        budget.check_fits(budget.evaluation_bytes(chunk, max_steps) + 16 * episodes, "episodes",
                          f"playing {episodes} episodes of at most {max_steps} steps, {chunk} "
                          f"at once")
        init_state = None if init_states is None else _init_state(init_states, episodes, env)
        returns = _jaxpg_chunks(jax.random.PRNGKey(seed), env_params, init_state,
                                _as_argument(policy), episodes, max_steps, chunk, on_chunk)
    return summarize(returns)


def chunk_episodes(episodes: int, max_steps: int) -> int:
    """How many episodes `evaluate` plays at once in jaxpg: all of them, or as evenly many in
    each chunk as keeps a chunk within `STEPS_AT_ONCE` steps (one episode at least).

    Args:
      episodes: E, a positive integer.
      max_steps: the longest an episode may run, a positive integer.

    Returns:
      C, at most E: the episodes of every chunk, the last one's padded to C.
    """
    most = max(1, STEPS_AT_ONCE // max_steps)
    chunks = -(-episodes // most)
    return -(-episodes // chunks)


def _jaxpg_chunks(key: PRNGKey, env_params: Any, init_state: Any, policy: Policy, episodes: int,
                  max_steps: int, chunk: int, on_chunk: Callable[[int], None] | None
                  ) -> np.ndarray:
    """The returns `[episodes]` of `evaluate`'s episodes in jaxpg, played `chunk` at a time."""

    def play(key: PRNGKey, start: int, count: int) -> tuple[jax.Array, jax.Array | None]:
        """The returns `[chunk]` of the chunk of episodes from `start`."""
        # The last chunk starts from its own states again in the lanes it does not need.
        states = None if init_state is None else jax.tree.map(
            lambda leaf: np.asarray(leaf)[start + np.arange(chunk) % count], init_state)
        return _jaxpg_returns(key, env_params, states, policy, chunk, max_steps)

    return _in_chunks(play, key, episodes, chunk, env_params, on_chunk)


def _in_chunks(play: Callable[[PRNGKey, int, int], tuple[jax.Array, jax.Array | None]],
               key: PRNGKey, episodes: int, chunk: int, env_params: Any,
               on_chunk: Callable[[int], None] | None) -> np.ndarray:
    """The returns `[..., episodes]` of episodes played `chunk` at a time (`evaluate`).

    Args:
      play: `(key, start, count) -> (returns [..., chunk], invalid)` of the chunk whose first
        `count` episodes are `start` onwards.
      key: the key of all the episodes, the one chunk's where there is one; chunk c's is
        `fold_in(key, c)` where there are more.
      episodes: E.
      chunk: the episodes of every chunk (`chunk_episodes`).
      env_params: the environment, whose actions the policy must play.
      on_chunk: optional: called after each chunk with the episodes played so far.

    Returns:
      The returns, float64.
    """
    parts = []
    for c, start in enumerate(range(0, episodes, chunk)):
        count = min(chunk, episodes - start)
        played, invalid = play(key if chunk == episodes else jax.random.fold_in(key, c), start,
                               count)
        rollout.check_played_actions(invalid, env_params)
        parts.append(np.asarray(played, np.float64)[..., :count])
        if on_chunk is not None:
            on_chunk(start + count)
    return np.concatenate(parts, axis=-1)


def summarize(returns: npt.ArrayLike) -> EvalResult:
    """`EvalResult` of returns `[E]`.

    Args:
      returns: `[E]` episode returns.

    Returns:
      Their statistics, and the returns as float64.
    """
    returns = np.asarray(returns, dtype=np.float64)
    return EvalResult(
        float(returns.mean()), float(returns.std()), float(returns.min()), float(returns.max()),
        returns,
    )


def _cartpole_only(env: Env, name: str) -> tuple[cartpole.CartPoleParams, str]:
    """`resolve_env(env)`, or a ValueError naming `name` for another environment than CartPole."""
    env_params, env_id = resolve_env(env)
    if envs.module_of(env_params) is not cartpole:
        raise ValueError(f"{name}: for CartPole only, got {env_id}")
    return env_params, env_id


def _check_plays(name: str, policy: object, env_params: Any) -> None:
    """A ValueError naming `name` where `policy` is the basic policy and the environment is not
    CartPole, whose pole's angle it reads (in another task's observation, some other number)."""
    if policy is basic_policy and envs.module_of(env_params) is not cartpole:
        raise ValueError(f"{name}: basic_policy plays CartPole (it pushes toward the pole's "
                         f"lean), got {envs.module_of(env_params).NAME}")


def _init_state(init_states: npt.ArrayLike, episodes: int, env: Env) -> cartpole.CartPoleState:
    """`init_states` `[episodes, 4]` as a `CartPoleState`, in jaxpg's float dtype."""
    _cartpole_only(env, "init_states")
    shape = np.shape(init_states)
    if shape != (episodes, 4):
        raise ValueError(f"init_states: expected shape ({episodes}, 4), got {shape}")
    # A NaN state never falls: its episode would last to the time limit.
    floats = jax.dtypes.canonicalize_dtype(float)
    checked = check_representable("init_states", check_finite("init_states", init_states), floats)
    return cartpole.CartPoleState.from_array(checked)


def _as_argument(policy: Policy) -> Policy:
    """`policy` as an argument of a compiled function.

    A pytree (`policies.NetworkPolicy`) as it is, its arrays traced; a plain function wrapped, as a
    static part of the program (hashed by identity, so a module-level function such as
    basic_policy compiles once per shape).
    """
    if _is_function(policy):
        return jax.tree_util.Partial(policy)
    return policy


def _is_function(policy: object) -> TypeGuard[Policy]:
    """Whether `policy` is a callable that is not a pytree of arrays (a plain function)."""
    return callable(policy) and jax.tree_util.treedef_is_leaf(jax.tree.structure(policy))


def reset_states(key: PRNGKey, episodes: int, env_params: Any) -> Any:
    """The initial states of `evaluate`'s (and `robustness`'s) episodes from `key`.

    Args:
      key: the key of the episodes, as `rollout.rollout(key, ...)` takes it.
      episodes: E, how many.
      env_params: the physics, whose reset bounds the states are drawn within.

    Returns:
      The environment's state with `[E]` leaves: the states that `rollout.rollout(key, ...)`
      draws.
    """
    key_reset, _ = rng.split(key)
    return rollout.reset_batch(key_reset, episodes, env_params)[1]


@functools.partial(jax.jit, static_argnames=("episodes", "max_steps"))
def _jaxpg_returns(
    key: PRNGKey,
    env_params: Any,
    init_state: Any,
    policy: Policy,
    episodes: int,
    max_steps: int,
) -> tuple[jax.Array, jax.Array | None]:
    """The returns `[E]` of `evaluate`'s episodes in jaxpg, and whether any action was invalid."""
    if init_state is None:
        init_state = reset_states(key, episodes, env_params)
    played = rollout.rollout(key, policy, env_params, episodes, max_steps, init_state)
    return played.returns, played.invalid_action


@jax.jit
def _act(policy: Policy, obs: Observation, key: PRNGKey, episode: int, t: int) -> Action:
    """The policy's action for one observation `[K]`, with the uniform of step t of `episode`."""
    key = jax.random.fold_in(jax.random.fold_in(key, episode), t)
    return policy(obs[None], jax.random.uniform(key, (1,)))[0]


def _gymnasium_returns(
    policy: Policy,
    episodes: int,
    max_steps: int,
    env_params: Any,
    env_id: str,
    seed: int,
) -> np.ndarray:
    """Returns `[episodes]` of episodes played in Gymnasium, one Python step at a time."""
    gym_env = make_gymnasium_env(env_params, env_id)
    module = envs.module_of(env_params)
    discrete = envs.is_discrete(module)
    key = jax.random.PRNGKey(seed)
    policy = _as_argument(policy)
    returns = np.zeros(episodes)
    for episode in range(episodes):
        obs = reset_gymnasium(gym_env, seed + episode, env_params)
        for t in range(max_steps):
            chosen = np.asarray(_act(policy, obs, key, episode, t))
            # Checked as the jaxpg backend checks its actions, before Gymnasium takes them.
            rollout.check_actions(chosen[None], np.asarray(obs)[None], discrete)
            if rollout.outside_actions(chosen, module):
                raise ValueError(f"policy: returned the action {chosen}; allowed: "
                                 f"{rollout.allowed_actions(module)}")
            # Gymnasium's continuous action is `[1]` float32.
            action = int(chosen) if discrete else chosen.astype(np.float32).reshape(1)
            obs, reward, terminated, truncated, _ = gym_env.step(action)
            returns[episode] += reward
            if terminated or truncated:
                break
    return returns


# --- Many policies in many physics settings ------------------------------------------------------


class Robustness(NamedTuple):
    """The returns of G x S policies, each in P physics settings, and their statistics."""

    returns: np.ndarray  # [G, S, P, E] float64: cell (g, s, p) as `evaluate` plays it
    settings: list[dict[str, float]]  # P dicts {field: value} of the physical fields `env_grid` set

    @property
    def labels(self) -> list[str]:
        """The P settings in words (`physics_label`)."""
        return [physics_label(setting) for setting in self.settings]

    @property
    def pooled(self) -> np.ndarray:
        """`[P, G * S * E]` every policy's returns in each setting."""
        return np.moveaxis(self.returns, 2, 0).reshape(len(self.settings), -1)

    @property
    def mean(self) -> np.ndarray:
        """`[G, S, P]` mean return over the episodes."""
        return self.returns.mean(axis=-1)

    @property
    def median(self) -> np.ndarray:
        """`[G, S, P]` median return over the episodes."""
        return np.median(self.returns, axis=-1)

    @property
    def std(self) -> np.ndarray:
        """`[G, S, P]` population standard deviation of the returns, as `EvalResult.std`."""
        return self.returns.std(axis=-1)

    @property
    def min(self) -> np.ndarray:
        """`[G, S, P]` lowest return."""
        return self.returns.min(axis=-1)

    @property
    def max(self) -> np.ndarray:
        """`[G, S, P]` highest return."""
        return self.returns.max(axis=-1)

    def bootstrap_ci(self, setting: int = 0, statistic: Any = "iqm",
                     **interval: Any) -> tuple[float, float]:
        """A bootstrap interval of an aggregate of one grid setting's policies over every physics.

        The scores are `mean[setting]`, `[S, P]`; the same S policies play every physics setting,
        so whole policies are resampled (`stats.bootstrap_ci(..., paired=True)`).

        Args:
          setting: g, the grid setting whose S policies are scored.
          statistic: as `stats.bootstrap_ci`'s ("iqm", "mean", "median" or a function).
          **interval: `confidence`, `reps`, `seed`, as `stats.bootstrap_ci` takes them.

        Returns:
          (low, high) floats.

        Raises:
          ValueError: naming `setting` out of range, or an argument `stats` refuses.
        """
        from jaxpg import stats  # here: stats imports scipy, which evaluating does not need
        return stats.bootstrap_ci(self.mean[self._setting("setting", setting)], statistic,
                                  paired=True, **interval)

    def _setting(self, name: str, setting: Any) -> int:
        """`setting`, checked to be a grid setting's index, g in [0, G)."""
        return check_int(name, setting, 0, self.returns.shape[0])

    def improvement_ci(self, other: "Robustness", setting: int = 0, other_setting: int = 0,
                       **interval: Any) -> tuple[float, float]:
        """An interval of P(a policy of this table beats one of `other`) over the physics settings.

        For two tables of the same seeds in the same physics settings (two grid settings of one
        sweep, or two sweeps' tables): policy s of each is drawn together, whole
        (`stats.improvement_ci(..., paired=True)`).

        Args:
          other: the `Robustness` of the policies compared against, in the same settings.
          setting: g of this table.
          other_setting: g of `other`.
          **interval: `confidence`, `reps`, `seed`, as `stats.improvement_ci` takes them.

        Returns:
          (low, high) floats.

        Raises:
          ValueError: naming `other`, for another kind of value or tables of other physics
            settings or seeds counts; naming `setting` or `other_setting` out of range.
        """
        from jaxpg import stats
        if not isinstance(other, Robustness):
            raise ValueError(f"other: expected a Robustness, got {type(other).__name__}")
        setting = self._setting("setting", setting)
        other_setting = other._setting("other_setting", other_setting)
        if other.settings != self.settings or other.returns.shape[1] != self.returns.shape[1]:
            raise ValueError(f"other: must play the same physics settings with as many seeds, "
                             f"got {len(other.settings)} settings x {other.returns.shape[1]} "
                             f"seeds against {len(self.settings)} x {self.returns.shape[1]}")
        return stats.improvement_ci(self.mean[setting], other.mean[other_setting], paired=True,
                                    **interval)


def physics_label(setting: Mapping[str, float], none: str = "default physics") -> str:
    """A physics setting in words, e.g. "length=0.5, masspole=0.1"; `none` for no field."""
    return ", ".join(f"{name}={value:g}" for name, value in setting.items()) or none


def physics_settings(env_grid: sweeps.Grid, env_params: Any) -> list[dict[str, float]]:
    """The physics settings of `env_grid`, validated against `env_params`, as a list of P dicts.

    Args:
      env_grid: None (`env_params` alone: one empty setting); a dict of the environment's
        physical fields (`envs.physics`) to values, whose product the settings are, in
        `sweeps.expand_grid`'s order (the last field varying fastest); or a list of dicts, the
        settings themselves.
      env_params: the environment's params that every setting modifies.

    Returns:
      P dicts {field: value} of the physical fields that the grid names (one empty dict for None).

    Raises:
      ValueError: one line naming the field, for an unknown field, an empty list, a repeated
        value or setting, or a value that is not physical (a mass, length or tau at or below 0,
        anything not finite).
    """
    physics = envs.physics(envs.module_of(env_params))
    unknown = _fields(env_grid) - set(physics)
    if unknown:
        raise ValueError(f"env_grid: unknown field(s) {', '.join(sorted(map(str, unknown)))}; "
                         f"allowed: {', '.join(physics)}")
    try:
        settings = sweeps.expand_grid(train_config.TrainConfig(env=env_params), env_grid)
    except ValueError as error:  # the grid's own messages, for the argument of this name
        raise ValueError(re.sub("^grid:", "env_grid:", str(error))) from None
    return [{name: value for name, value in setting.items() if name in physics}
            for setting in settings]


def _fields(env_grid: object) -> set[Any]:
    """The fields that a dict or a list of dicts names (none for anything else)."""
    if isinstance(env_grid, dict):
        return set(env_grid)
    if isinstance(env_grid, list | tuple):
        return {name for setting in env_grid if isinstance(setting, dict) for name in setting}
    return set()


def robustness(
    policies: sweeps.SweepResult | Params | Policy,
    env_grid: sweeps.Grid = None,
    episodes: int = 100,
    max_steps: int = 200,
    seed: int = 0,
    network: nn.Module | None = None,
    env: Env = None,
    on_chunk: Callable[[int], None] | None = None,
) -> Robustness:
    """Plays every policy in every physics setting, as one compiled program.

    Cell (g, s, p) holds the very episodes of `evaluate(policy (g, s), episodes, max_steps,
    env=<env with setting p>, seed=seed)`: the same initial states and uniforms, in the same
    chunks of episodes, the same returns.
    The runs (a policy in a setting) play side by side on the last axis of every array, `BLOCK`
    at a time. Parameters and physics are arguments of the program: other policies and values of
    the same shapes compile nothing.

    Args:
      policies: a `SweepResult`, or policy parameters stacked `[G, S, ...]` (every leaf) of
        `network`; or a policy function `(obs [..., K], u [...]) -> action [...]` of any batch
        shape, such as `policies.basic_policy` (G = S = 1).
      env_grid: the physics settings (`physics_settings`): a dict of the environment's fields
        to values (their product), a list of dicts, or None for `env` itself.
      episodes: E, a positive integer.
      max_steps: the longest an episode may run, a positive integer.
      seed: a non-negative integer; every cell plays the episodes of `PRNGKey(seed)`.
      network: the policy module of the parameters (`TrainConfig.network`); by default a
        `SweepResult`'s own, else the environment's default network (`TrainConfig.network`).
      env: a name of `envs.MODULES` or an environment's params: the physics that the settings
        modify; by default a `SweepResult`'s environment, else CartPole-v1.
      on_chunk: optional: called on the host after each chunk of episodes with the episodes
        played so far (progress).

    Returns:
      `Robustness` with returns `[G, S, P, E]` and the P settings.

    Raises:
      ValueError: one line naming the argument, for policies of other shapes than `network`'s, a
        bad `env_grid` (`physics_settings`), an argument out of range, episodes that need more
        memory than the machine's (a chunk's `budget.evaluation_bytes` for a block of runs, and
        every return kept twice in float64), or a policy that plays an action the
        environment does not have.
    """
    check_int("episodes", episodes)
    check_int("max_steps", max_steps)
    check_int("seed", seed, 0, 2**32)
    check_callback("on_chunk", on_chunk, "(episodes played) -> None")
    config = policies.config if isinstance(policies, sweeps.SweepResult) else None
    if env is None:
        env = config.env if config else "CartPole-v1"
    env_params, _ = resolve_env(env)
    _check_plays("policies", policies, env_params)
    settings = physics_settings(env_grid, env_params)
    if network is None:
        network = (config or train_config.TrainConfig(env=env_params)).network
    if not isinstance(network, nn.Module):
        raise ValueError(f"network: expected the policy's flax module (TrainConfig.network) or "
                         f"None, got {type(network).__name__}")
    function, policy_params = _split_policies(policies, network, env_params)
    grid_shape = (1, 1) if function else jax.tree.leaves(policy_params)[0].shape[:2]
    runs = math.prod(grid_shape) * len(settings)
    chunk = chunk_episodes(episodes, max_steps)
    # A block of runs plays a chunk at once; the returns of every run are kept, twice as they are
    # put together.
    needed = budget.evaluation_bytes(chunk, max_steps, BLOCK) + runs * episodes * 16
    budget.check_fits(needed, "episodes", f"playing {episodes} episodes of at most {max_steps} "
                      f"steps in each of {runs} runs, {chunk} in each of {BLOCK} runs at once")
    physics = {name: np.asarray([getattr(env_params.replace(**setting), name)
                                 for setting in settings], jnp.result_type(float))
               for name in envs.physics(envs.module_of(env_params))}
    flat_params = jax.tree.map(lambda leaf: leaf.reshape(-1, *leaf.shape[2:]), policy_params)
    returns = _in_chunks(
        lambda key, start, count: _robustness_returns(
            key, flat_params, physics, env_params, None if function else network, function, chunk,
            max_steps),
        jax.random.PRNGKey(seed), episodes, chunk, env_params, on_chunk)
    return Robustness(returns.reshape(*grid_shape, *returns.shape[1:]), settings)


def _split_policies(
    policies: sweeps.SweepResult | Params | Policy, network: nn.Module, env_params: Any
) -> tuple[Policy | None, Params | None]:
    """(a policy function, None), or (None, the parameters `[G, S, ...]` of `network` for the
    environment's observations), checked."""
    if isinstance(policies, sweeps.SweepResult):
        policies = policies.policy_params
    if _is_function(policies):
        return policies, None
    obs_size = envs.module_of(env_params).OBS_SIZE
    want = jax.eval_shape(lambda key: init_network(key, network, obs_size),
                          jax.ShapeDtypeStruct((2,), jnp.uint32))
    shapes = [np.shape(leaf) for leaf in jax.tree.leaves(policies)]
    # jaxlib's stubs leave PyTreeDef unresolved, so mypy cannot compare two of them.
    if (jax.tree.structure(policies) != jax.tree.structure(want)  # type: ignore[operator]
            or len({shape[:2] for shape in shapes}) != 1
            or any(shape[2:] != leaf.shape for shape, leaf in zip(shapes, jax.tree.leaves(want)))):
        raise ValueError(
            f"policies: expected a SweepResult, a policy function, or parameters of the "
            f"{type(network).__name__} stacked [G, S, ...] on "
            f"{jax.tree.map(lambda leaf: leaf.shape, want)}; got "
            f"{jax.tree.map(np.shape, policies) if isinstance(policies, dict) else policies!r}")
    return None, policies


@functools.partial(jax.jit, static_argnames=("network", "function", "episodes", "max_steps"))
def _robustness_returns(
    key: PRNGKey,
    policy_params: Params | None,
    physics: dict[str, np.ndarray],
    env_params: Any,
    network: nn.Module | None,
    function: Policy | None,
    episodes: int,
    max_steps: int,
) -> tuple[jax.Array, jax.Array]:
    """The returns `[N, P, E]` of N policies in P settings, and whether any action was invalid.

    The policies are parameters `[N, ...]` of `network`, or one `function`; the settings are
    `physics`, `[P]` values of each physical field. An invalid action is one the environment
    does not have.
    """
    num_policies = 1 if function else jax.tree.leaves(policy_params)[0].shape[0]
    num_settings = len(next(iter(physics.values())))
    num_runs = num_policies * num_settings
    num_blocks = -(-num_runs // BLOCK)
    # Run r is policy r // P in setting r % P; the last block is padded with copies of the last run.
    runs = np.minimum(np.arange(num_blocks * BLOCK), num_runs - 1).reshape(num_blocks, BLOCK)
    init_state = jax.tree.map(
        lambda leaf: jnp.broadcast_to(leaf[:, None], (episodes, BLOCK, *leaf.shape[1:])),
        reset_states(key, episodes, env_params))

    def play_block(
        block: tuple[Params, dict[str, jax.Array]],
    ) -> tuple[jax.Array, jax.Array | None]:
        """The returns `[E, BLOCK]` of one block of runs, and whether any action was invalid."""
        block_params, block_physics = block  # [BLOCK, ...] and [BLOCK] leaves
        act = function or network_policy(  # without a function, a network
            cast(nn.Module, network),
            jax.tree.map(lambda leaf: jnp.moveaxis(leaf, 0, -1), block_params), runs=True,
            num_actions=getattr(envs.module_of(env_params), "NUM_ACTIONS", None))

        def policy(obs: Observation, u: jax.Array) -> Action:
            """`act` with the uniforms `[E]` of `evaluate`, the same for every run."""
            return act(obs, jnp.broadcast_to(u[:, None], obs.shape[:-1]))

        played = rollout.rollout(key, policy, env_params.replace(**block_physics), episodes,
                                 max_steps, init_state)
        return played.returns, played.invalid_action

    returns, invalid = jax.lax.map(play_block, (
        jax.tree.map(lambda leaf: leaf[runs // num_settings], policy_params),
        jax.tree.map(lambda leaf: leaf[runs % num_settings], physics)))  # [blocks, E, BLOCK]
    returns = jnp.moveaxis(returns, 1, 2).reshape(num_blocks * BLOCK, episodes)[:num_runs]
    return returns.reshape(num_policies, num_settings, episodes), jnp.any(invalid)
