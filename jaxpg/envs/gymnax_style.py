"""A gymnax environment, or a user's own with gymnax's interface, as an environment of jaxpg.

`from_gymnax(env)` gives params that `TrainConfig(env=...)`, `sweep`, `evaluate` and `robustness`
take as they take `CartPoleParams`. What is read of `env` (gymnax's `Environment` interface):
`reset_env(key, params) -> (obs, state)`, `step_env(key, state, action, params) -> (obs, state,
reward, terminated, info)` (gymnax 1.0's: `terminated` without the time limit, which jaxpg's
`max_steps` applies), `default_params`, `name`, `observation_space(params).shape`, and
`action_space(params)`: a space with `n` (discrete actions) or a continuous one of one number.

The environment's state (its leaves as floats, integers such as `time` among them, which float32
holds exactly below 2**24) and its last observation travel as one array (`GymnaxState`), as the
other environments' states do. What is not supported, unlike jaxpg's own environments:

- randomness in `step_env`: its key is `fold_in(PRNGKey(0), t)` at step t, the same in every
  episode (the classic-control tasks step deterministically; their resets draw from the
  episode's own key);
- grids and randomisation over the environment's params (one pytree, a constant of the program);
- saving a config that holds one in a checkpoint, and the Gymnasium backend of `evaluate`.
"""

import functools
import math
from typing import TYPE_CHECKING, Any, Self

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.flatten_util import ravel_pytree

from jaxpg.types import ArrayLike, Observation, PRNGKey

_STEP_KEY = 0  # the seed of every step's key


class Fixed:
    """A value the program holds as a constant, equal to another only when it is the same
    object (gymnax params hold arrays, which neither hash nor compare as one bool)."""

    def __init__(self, value: Any) -> None:
        self.value = value

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Fixed) and other.value is self.value

    def __hash__(self) -> int:
        return id(self.value)

    def __repr__(self) -> str:
        return f"Fixed({self.value!r})"


@struct.dataclass
class GymnaxParams:
    """A gymnax-style environment, its params and the time limit jaxpg applies.

    Attributes:
      env: static: the environment object (gymnax's `Environment` interface).
      params: static: its params (`env.default_params` by default), as a `Fixed`.
      max_steps: an episode is truncated once this many steps were taken.
    """

    env: Any = struct.field(pytree_node=False)
    params: Fixed = struct.field(pytree_node=False)
    max_steps: int

    if TYPE_CHECKING:  # flax.struct adds it to the class
        def replace(self, **updates: Any) -> Self:
            """A copy with the fields `updates` names replaced."""
            ...


@struct.dataclass
class GymnaxState:
    """The environment's state leaves and its observation `[..., S + K]`, and the steps taken.

    Attributes:
      values: float `[..., S + K]`: the S numbers of the state (`ravel_pytree`), then the K of
        its observation.
      time: int32 `[...]`, steps taken in the episode.
    """

    values: jax.Array
    time: jax.Array

    @classmethod
    def from_array(cls, values: ArrayLike, time: ArrayLike = 0) -> Self:
        """The state of values `[..., S + K]` after `time` steps."""
        values = jnp.asarray(values)
        return cls(values, jnp.broadcast_to(jnp.asarray(time, jnp.int32), values.shape[:-1]))

    def to_array(self, axis: int = -1) -> jax.Array:
        """The values, their S + K numbers on `axis`."""
        return jnp.moveaxis(self.values, -1, axis)


def from_gymnax(env: Any, params: Any = None, max_steps: int | None = None) -> GymnaxParams:
    """A gymnax-style environment as params that jaxpg trains on.

    Args:
      env: the environment (gymnax's `Environment` interface, see the module's docstring).
      params: its params; `env.default_params` by default.
      max_steps: the time limit; `params.max_steps_in_episode` by default (gymnax's).

    Returns:
      `GymnaxParams`, checked (`check_params`).

    Raises:
      ValueError: naming `env` where it lacks the interface, or `max_steps` out of range.
    """
    missing = [name for name in ("reset_env", "step_env", "default_params", "name",
                                 "observation_space", "action_space") if not hasattr(env, name)]
    if missing:
        raise ValueError(f"env: expected a gymnax-style environment, {type(env).__name__} has no "
                         f"{', '.join(missing)}")
    params = env.default_params if params is None else params
    if max_steps is None:
        if not hasattr(params, "max_steps_in_episode"):
            raise ValueError("max_steps: the params have no max_steps_in_episode; give max_steps")
        max_steps = params.max_steps_in_episode
    env_params = GymnaxParams(env, Fixed(params), max_steps)
    check_params(env_params)
    return env_params


def check_params(env_params: GymnaxParams) -> None:
    """Raises a ValueError naming `env` or `max_steps` for params that are not usable."""
    if not isinstance(env_params, GymnaxParams):
        raise ValueError(f"env_params: expected GymnaxParams, got {type(env_params).__name__}")
    steps = env_params.max_steps
    if not isinstance(steps, jax.core.Tracer) and not (
            np.ndim(steps) == 0 and isinstance(np.asarray(steps).item(), int)
            and 0 < int(steps) < 2**31):
        raise ValueError(f"max_steps: must be an integer in [1, 2**31), got {steps!r}")


class Module:
    """The environment interface of jaxpg (`jaxpg.envs`) for one gymnax-style environment.

    Attributes:
      NAME: the environment's `name`.
      OBS_SIZE: K, the size of its observations.
      NUM_ACTIONS: its discrete actions (absent for a continuous action).
      PRESETS: `{NAME: from_gymnax(env)}`.
      REWARD_THRESHOLDS: `{NAME: 0.0}`: jaxpg knows no threshold of a user's environment.
      PHYSICS: none: grids and randomisation do not vary its params.
    """

    PHYSICS: tuple[str, ...] = ()

    def __init__(self, env: Any) -> None:
        self.env = env
        preset = from_gymnax(env)
        self.NAME = str(env.name)
        self.PRESETS = {self.NAME: preset}
        self.REWARD_THRESHOLDS = {self.NAME: 0.0}
        self.OBS_SIZE = math.prod(env.observation_space(preset.params.value).shape)
        space = env.action_space(preset.params.value)
        if hasattr(space, "n"):
            self.NUM_ACTIONS = int(space.n)
        elif math.prod(getattr(space, "shape", ()) or (1,)) != 1:
            raise ValueError(f"env: {self.NAME}'s actions must be discrete or one number, got "
                             f"shape {space.shape}")
        obs, state = jax.eval_shape(env.reset_env, jax.random.PRNGKey(0), preset.params.value)
        self._flat, self._unravel = _raveller(state)

    def make_params(self, name: str) -> GymnaxParams:
        """The preset (`from_gymnax(env)`)."""
        del name
        return self.PRESETS[self.NAME]

    check_params = staticmethod(check_params)

    def reset(self, key: PRNGKey, env_params: GymnaxParams) -> tuple[Observation, GymnaxState]:
        """`env.reset_env(key, params)` as (obs `[K]`, `GymnaxState` with `[]` leaves)."""
        obs, state = self.env.reset_env(key, env_params.params.value)
        return obs, self._state(state, obs, jnp.zeros((), jnp.int32))

    def observe(self, state: GymnaxState) -> Observation:
        """The observation `[..., K]` kept in the state."""
        return state.values[..., state.values.shape[-1] - self.OBS_SIZE:]

    def step(self, state: GymnaxState, action: ArrayLike, env_params: GymnaxParams
             ) -> tuple[Observation, GymnaxState, jax.Array, jax.Array, jax.Array]:
        """`env.step_env` of every environment of the batch `[...]`, one at a time (`vmap`).

        Returns:
          (obs `[..., K]`, state, reward `[...]`, terminated `[...]`, truncated `[...]`: the
          steps taken reach `max_steps`).
        """
        batch = state.time.shape
        action = jnp.broadcast_to(jnp.asarray(action), batch)
        step_one = functools.partial(self._step_one, params=env_params.params.value)
        flat = jax.vmap(step_one)(state.values.reshape(-1, state.values.shape[-1]),
                                  state.time.reshape(-1), action.reshape(-1))
        obs, values, reward, terminated = jax.tree.map(
            lambda leaf: leaf.reshape(*batch, *leaf.shape[1:]), flat)
        time = state.time + 1
        return (obs, GymnaxState(values, time), reward, terminated,
                time >= env_params.max_steps)

    def _step_one(self, values: jax.Array, time: jax.Array, action: jax.Array, params: Any
                  ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        """One environment's step: (obs `[K]`, values `[S + K]`, reward, terminated)."""
        key = jax.random.fold_in(jax.random.PRNGKey(_STEP_KEY), time)
        state = self._unravel(values[:self._flat])
        obs, state, reward, terminated, _ = self.env.step_env(key, state, action, params)
        new = self._state(state, obs, time + 1)
        return (jnp.asarray(obs, values.dtype).reshape(-1), new.values,
                jnp.asarray(reward, values.dtype), jnp.asarray(terminated, bool))

    def _state(self, state: Any, obs: jax.Array, time: jax.Array) -> GymnaxState:
        """A `GymnaxState` of one environment's gymnax state and observation."""
        flat = ravel_pytree(state)[0]
        dtype = jnp.result_type(float)
        values = jnp.concatenate([flat.astype(dtype), jnp.asarray(obs, dtype).reshape(-1)])
        return GymnaxState(values, time)


def _raveller(state: Any) -> tuple[int, Any]:
    """(the number S of a state's leaves' entries, the function from `[S]` floats to a state)."""
    example = jax.tree.map(lambda leaf: jnp.zeros(leaf.shape, leaf.dtype), state)
    flat, unravel = ravel_pytree(example)
    return flat.shape[0], unravel


_MODULES: dict[int, tuple[Any, Module]] = {}


def module(env: Any) -> Module:
    """The `Module` of `env`, made once per environment object."""
    if id(env) not in _MODULES or _MODULES[id(env)][0] is not env:
        _MODULES[id(env)] = (env, Module(env))
    return _MODULES[id(env)][1]
