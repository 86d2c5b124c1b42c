"""MountainCarContinuous as pure, jittable JAX functions, equal to Gymnasium's classic_control
`Continuous_MountainCarEnv`.

MountainCar (`mountain_car`, whose state and `move` it shares) with a continuous push: the action,
clipped to [min_action, max_action], times `power` is the push; the reward is 100 on reaching the
goal less 0.1 times the square of the action as given (not clipped), as Gymnasium computes it.

Gymnasium stores the new state as float32 (the termination is decided before, in float64);
`step` rounds it the same way. From a float32 state Gymnasium's next step mixes float32 and
float64 arithmetic (NumPy 2 keeps float32 scalars float32), so its last bits depend on the dtypes
it is given; `step` computes in the default float dtype throughout, as Gymnasium does from its
float64 reset state and with a float64 action.
"""

from typing import TYPE_CHECKING, Any, Self

import jax
import jax.numpy as jnp
from flax import struct

from jaxpg.envs import common
from jaxpg.envs.mountain_car import MountainCarState, hill_cos, initial_state, move, observe
from jaxpg.types import ArrayLike, Observation, PRNGKey

NAME = "MountainCarContinuous-v0"
OBS_SIZE = 2  # position, velocity
ACTION_LOW = -1.0  # the preset's action range, [min_action, max_action]
ACTION_HIGH = 1.0


@struct.dataclass
class ContinuousMountainCarParams:
    """Physics and episode settings; a pytree, so a sweep can vmap over any number in it.

    The fields are Gymnasium's `Continuous_MountainCarEnv` attributes of the same names, but
    `gravity`, which Gymnasium writes as a number in `step`, and the reset bounds and
    `max_steps`. Each number is a Python number, or an array of any shape (under `vmap`, a traced
    one); `check_params` validates them.

    Attributes:
      min_action: actions are clipped to [min_action, max_action].
      max_action: the high end of the actions.
      min_position: the left wall: positions are clipped to [min_position, max_position].
      max_position: the right end of the track.
      max_speed: velocities are clipped to [-max_speed, max_speed].
      goal_position: the episode terminates once the position reaches it...
      goal_velocity: ...with a velocity of at least this.
      power: the velocity a push of 1 adds in one step.
      gravity: the velocity gravity takes away in one step at slope 1.
      reset_low: the low bound of the initial position, drawn uniform in [reset_low, reset_high).
      reset_high: its high bound.
      max_steps: Gymnasium's TimeLimit: an episode is truncated once this many steps were taken.
    """

    min_action: float = ACTION_LOW
    max_action: float = ACTION_HIGH
    min_position: float = -1.2
    max_position: float = 0.6
    max_speed: float = 0.07
    goal_position: float = 0.45
    goal_velocity: float = 0.0
    power: float = 0.0015
    gravity: float = 0.0025
    reset_low: float = -0.6
    reset_high: float = -0.4
    max_steps: int = 999

    if TYPE_CHECKING:  # flax.struct adds it to the class
        def replace(self, **updates: Any) -> Self:
            """A copy with the fields `updates` names replaced."""
            ...


V0 = ContinuousMountainCarParams()
PRESETS = {NAME: V0}
REWARD_THRESHOLDS = {NAME: 90.0}
# The state is MountainCar's: position, velocity and steps taken.
ContinuousMountainCarState = MountainCarState


def make_params(env: str = NAME, **overrides: Any) -> ContinuousMountainCarParams:
    """A preset by name (`MountainCarContinuous-v0`), with any field overridden, validated.

    Raises:
      ValueError: for an unknown preset or field, or an invalid value (`check_params`).
    """
    return common.make_params(PRESETS, check_params, env, overrides)


def check_params(env_params: ContinuousMountainCarParams) -> None:
    """Checks every concrete value of `env_params`; values under a trace are skipped.

    Raises:
      ValueError: naming the first invalid field: a value that is not finite, a speed limit or
        power at or below 0, a `max_steps` that is not an integer in [1, 2**31), action range,
        track ends or reset bounds out of order, or `env_params` not a
        `ContinuousMountainCarParams`.
    """
    common.check_numbers(env_params, ContinuousMountainCarParams, ("max_speed", "power"))
    common.check_below(env_params, "min_action", "max_action")
    common.check_below(env_params, "min_position", "max_position")
    common.check_below(env_params, "reset_low", "reset_high")


def reset(key: PRNGKey, env_params: ContinuousMountainCarParams
          ) -> tuple[Observation, MountainCarState]:
    """Samples an initial state: position uniform in [reset_low, reset_high), velocity 0.

    Args:
      key: PRNG key.
      env_params: `ContinuousMountainCarParams`.

    Returns:
      (obs `[2]`, state with `[]` leaves), in the default float dtype.
    """
    check_params(env_params)
    return initial_state(key, env_params)


def action_bounds(env_params: ContinuousMountainCarParams) -> tuple[Any, Any]:
    """The pushes `step` takes unclipped: (min_action, max_action) of `env_params`."""
    return env_params.min_action, env_params.max_action


def step(state: MountainCarState, action: ArrayLike, env_params: ContinuousMountainCarParams
         ) -> tuple[Observation, MountainCarState, jax.Array, jax.Array, jax.Array]:
    """Advances one step with the push `action`, clipped to [min_action, max_action].

    Args:
      state: `MountainCarState` with `[...]` leaves.
      action: float `[...]` (or broadcasting against the state): Gymnasium's action `[1]` holds
        one such number.
      env_params: `ContinuousMountainCarParams`.

    Returns:
      (obs `[..., 2]`, state, reward `[...]` in the state's float dtype, terminated `[...]` bool,
      truncated `[...]` bool). The reward is 100 on reaching the goal, less 0.1 action^2 on
      every step. Reaching the goal on the step that reaches `max_steps` is both terminated and
      truncated.

    Raises:
      ValueError: outside a trace, for invalid `env_params` or an action that is not finite.
    """
    check_params(env_params)
    common.check_continuous_action(action)
    p = env_params
    dtype = state.position.dtype
    action = jnp.asarray(action, dtype)
    low, high = action_bounds(p)
    force = jnp.minimum(jnp.maximum(action, low), high)
    position, velocity, terminated = move(
        state.position, state.velocity, force * p.power - p.gravity * hill_cos(state.position), p)
    state = MountainCarState(common.float32_values(position.astype(dtype)),
                             common.float32_values(velocity.astype(dtype)), state.time + 1)
    reward = jnp.where(terminated, 100.0, 0.0).astype(dtype) - action**2 * 0.1
    return observe(state), state, reward, terminated, state.time >= p.max_steps
