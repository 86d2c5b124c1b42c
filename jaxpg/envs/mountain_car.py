"""MountainCar as pure, jittable JAX functions, equal to Gymnasium's classic_control
`MountainCarEnv`.

A car in a valley between two hills pushes left (action 0), not at all (1) or right (2); gravity
along the slope `cos(3 position)` pulls it back. The velocity is clipped to the speed limit, the
position to the track, and the car stops at the left wall; the episode terminates on reaching
the goal on the right hill. Operation order follows Gymnasium's `step` exactly (`move`), so that
in float64 the two agree to rounding. `continuous_mountain_car` moves the car the same way.
"""

from typing import TYPE_CHECKING, Any, Protocol, Self

import jax
import jax.numpy as jnp
from flax import struct

from jaxpg import rng
from jaxpg.envs import common
from jaxpg.envs.cartpole import sincos
from jaxpg.types import ArrayLike, Observation, PRNGKey

NAME = "MountainCar-v0"
OBS_SIZE = 2  # position, velocity
NUM_ACTIONS = 3  # push left, no push, push right


@struct.dataclass
class MountainCarParams:
    """Physics and episode settings; a pytree, so a sweep can vmap over any number in it.

    The fields are Gymnasium's `MountainCarEnv` attributes of the same names, but the reset
    bounds and `max_steps`. Each number is a Python number, or an array of any shape (under
    `vmap`, a traced one); `check_params` validates them.

    Attributes:
      min_position: the left wall: positions are clipped to [min_position, max_position].
      max_position: the right end of the track.
      max_speed: velocities are clipped to [-max_speed, max_speed].
      goal_position: the episode terminates once the position reaches it...
      goal_velocity: ...with a velocity of at least this.
      force: the velocity a push adds in one step.
      gravity: the velocity gravity takes away in one step at slope 1.
      reset_low: the low bound of the initial position, drawn uniform in [reset_low, reset_high).
      reset_high: its high bound.
      max_steps: Gymnasium's TimeLimit: an episode is truncated once this many steps were taken.
    """

    min_position: float = -1.2
    max_position: float = 0.6
    max_speed: float = 0.07
    goal_position: float = 0.5
    goal_velocity: float = 0.0
    force: float = 0.001
    gravity: float = 0.0025
    reset_low: float = -0.6
    reset_high: float = -0.4
    max_steps: int = 200

    if TYPE_CHECKING:  # flax.struct adds it to the class
        def replace(self, **updates: Any) -> Self:
            """A copy with the fields `updates` names replaced."""
            ...


V0 = MountainCarParams()
PRESETS = {NAME: V0}
REWARD_THRESHOLDS = {NAME: -110.0}


class Track(Protocol):
    """What `move` and `initial_state` read of their `env_params`: the settings of either
    mountain car.

    Attributes:
      min_position: the left wall.
      max_position: the right end of the track.
      max_speed: the speed limit.
      goal_position: the goal's position.
      goal_velocity: the least velocity at the goal.
      reset_low: the low bound of the initial position.
      reset_high: its high bound.
    """

    # Any: a Python number or a JAX array.
    @property
    def min_position(self) -> Any: ...

    @property
    def max_position(self) -> Any: ...

    @property
    def max_speed(self) -> Any: ...

    @property
    def goal_position(self) -> Any: ...

    @property
    def goal_velocity(self) -> Any: ...

    @property
    def reset_low(self) -> Any: ...

    @property
    def reset_high(self) -> Any: ...


@struct.dataclass
class MountainCarState(common.ArrayState):
    """The car's position and velocity and the number of steps taken in the episode.

    Every leaf has the same batch shape `[...]` (`[]` for one environment).

    Attributes:
      position: the car's position along the track.
      velocity: its velocity, per step.
      time: int32 steps taken in the episode.
    """

    VALUES = ("position", "velocity")

    position: jax.Array
    velocity: jax.Array
    time: jax.Array


def make_params(env: str = NAME, **overrides: Any) -> MountainCarParams:
    """A preset by name (`MountainCar-v0`), with any field overridden, validated.

    Raises:
      ValueError: for an unknown preset or field, or an invalid value (`check_params`).
    """
    return common.make_params(PRESETS, check_params, env, overrides)


def check_params(env_params: MountainCarParams) -> None:
    """Checks every concrete value of `env_params`; values under a trace are skipped.

    Raises:
      ValueError: naming the first invalid field: a value that is not finite, a speed limit or
        force at or below 0, a `max_steps` that is not an integer in [1, 2**31), track ends or
        reset bounds out of order, or `env_params` not a `MountainCarParams`.
    """
    common.check_numbers(env_params, MountainCarParams, ("max_speed", "force"))
    common.check_below(env_params, "min_position", "max_position")
    common.check_below(env_params, "reset_low", "reset_high")


def observe(state: MountainCarState) -> Observation:
    """The observation `[..., 2]` (position, velocity) of a state, in the state's float dtype."""
    return state.to_array()


def reset(key: PRNGKey, env_params: MountainCarParams) -> tuple[Observation, MountainCarState]:
    """Samples an initial state: position uniform in [reset_low, reset_high), velocity 0.

    Args:
      key: PRNG key.
      env_params: `MountainCarParams`.

    Returns:
      (obs `[2]`, state with `[]` leaves), in the default float dtype.
    """
    check_params(env_params)
    return initial_state(key, env_params)


def initial_state(key: PRNGKey, env_params: Track) -> tuple[Observation, MountainCarState]:
    """`reset` without its check, for either mountain car."""
    position = rng.uniform(key, (), env_params.reset_low, env_params.reset_high)
    state = MountainCarState.from_array(jnp.stack([position, jnp.zeros_like(position)]))
    return observe(state), state


def step(state: MountainCarState, action: ArrayLike, env_params: MountainCarParams
         ) -> tuple[Observation, MountainCarState, jax.Array, jax.Array, jax.Array]:
    """Advances one step; action 0 pushes left, 1 not at all, 2 right.

    An action of any integer dtype pushes as its value says: an unsigned 0 pushes left, where
    Gymnasium's `(action - 1) * force` wraps it round to 255 pushes right (the
    `jaxpg/MountainCar-v0` adapter does as Gymnasium does).

    Args:
      state: `MountainCarState` with `[...]` leaves.
      action: int `[...]` (or broadcasting against the state), each 0, 1 or 2.
      env_params: `MountainCarParams`.

    Returns:
      (obs `[..., 2]`, state, reward `[...]` in the state's float dtype, terminated `[...]` bool,
      truncated `[...]` bool). The reward is -1 on every step. Reaching the goal on the step that
      reaches `max_steps` is both terminated and truncated.

    Raises:
      ValueError: outside a trace, for invalid `env_params` or an action other than 0, 1 or 2.
    """
    check_params(env_params)
    common.check_discrete_action(action, NUM_ACTIONS, "0 (push left), 1 (none) or 2 (push right)")
    p = env_params
    dtype = state.position.dtype
    push = common.centred_action(action, dtype) * p.force
    position, velocity, terminated = move(
        state.position, state.velocity, push + hill_cos(state.position) * (-p.gravity), p)
    state = MountainCarState(position.astype(dtype), velocity.astype(dtype), state.time + 1)
    reward = jnp.full_like(state.position, -1.0)
    return observe(state), state, reward, terminated, state.time >= p.max_steps


def hill_cos(position: jax.Array) -> jax.Array:
    """`cos(3 position)` `[...]`, the slope of the hills up to a factor."""
    return sincos(3 * position)[1]


def move(position: jax.Array, velocity: jax.Array, acceleration: jax.Array, env_params: Track
         ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Moves the car one step, in Gymnasium's order: the velocity changes by `acceleration` and
    is clipped, the position moves by it and is clipped, and the car stops at the left wall.

    Args:
      position: the position `[...]`.
      velocity: the velocity `[...]`.
      acceleration: the change of velocity `[...]`.
      env_params: the settings of either mountain car.

    Returns:
      (position, velocity, terminated), `[...]` each: terminated where the new position and
      velocity reach the goal's.
    """
    p = env_params
    velocity = jnp.minimum(jnp.maximum(velocity + acceleration, -p.max_speed), p.max_speed)
    position = jnp.minimum(jnp.maximum(position + velocity, p.min_position), p.max_position)
    velocity = jnp.where((position == p.min_position) & (velocity < 0), 0.0, velocity)
    terminated = (position >= p.goal_position) & (velocity >= p.goal_velocity)
    return position, velocity, terminated
