"""Pendulum as pure, jittable JAX functions, equal to Gymnasium's classic_control `PendulumEnv`.

A pendulum swings about a fixed end; the action is the torque at that end, clipped to
[-max_torque, max_torque]. The reward is minus the cost of the state before the step and of the
torque, `angle_normalize(theta)^2 + 0.1 theta_dot^2 + 0.001 torque^2`; episodes never terminate
and are truncated at `max_steps`. Operation order follows Gymnasium's `step` exactly, so that in
float64 the two agree to rounding.

Gymnasium computes the torque's terms in the dtype of the action it is given: in float32 for a
float32 action (NumPy 2 keeps float32 scalars float32). `step` computes in the default float
dtype throughout, as Gymnasium does with a float64 action.
"""

import math
from typing import TYPE_CHECKING, Any, Self

import jax
import jax.numpy as jnp
from flax import struct

from jaxpg import rng
from jaxpg.envs import common
from jaxpg.envs.cartpole import sincos
from jaxpg.types import ArrayLike, Observation, PRNGKey

NAME = "Pendulum-v1"
OBS_SIZE = 3  # cos theta, sin theta, theta_dot
ACTION_LOW = -2.0  # the preset's action range, [-max_torque, max_torque]
ACTION_HIGH = 2.0


@struct.dataclass
class PendulumParams:
    """Physics and episode settings; a pytree, so a sweep can vmap over any number in it.

    The fields are Gymnasium's `PendulumEnv` attributes, `max_speed`, `max_torque` and `dt`
    under their names, `g`, `m` and `l` as `gravity`, `mass` and `length`, and the reset bounds
    (Gymnasium's `DEFAULT_X` and `DEFAULT_Y`) and `max_steps`. Each number is a Python number,
    or an array of any shape (under `vmap`, a traced one); `check_params` validates them.

    Attributes:
      max_speed: angular velocities are clipped to [-max_speed, max_speed].
      max_torque: torques are clipped to [-max_torque, max_torque].
      dt: seconds between state updates.
      gravity: the acceleration of gravity, m/s^2 (Gymnasium's `g`).
      mass: the pendulum's mass, kg (`m`).
      length: its length, m (`l`).
      reset_theta: the initial angle is uniform in [-reset_theta, reset_theta).
      reset_theta_dot: the initial angular velocity, in [-reset_theta_dot, reset_theta_dot).
      max_steps: Gymnasium's TimeLimit: an episode is truncated once this many steps were taken.
    """

    max_speed: float = 8.0
    max_torque: float = ACTION_HIGH
    dt: float = 0.05
    gravity: float = 10.0
    mass: float = 1.0
    length: float = 1.0
    reset_theta: float = math.pi
    reset_theta_dot: float = 1.0
    max_steps: int = 200

    if TYPE_CHECKING:  # flax.struct adds it to the class
        def replace(self, **updates: Any) -> Self:
            """A copy with the fields `updates` names replaced."""
            ...


V1 = PendulumParams()
PRESETS = {NAME: V1}


@struct.dataclass
class PendulumState(common.ArrayState):
    """The pendulum's angle and angular velocity and the number of steps taken in the episode.

    Every leaf has the same batch shape `[...]` (`[]` for one environment).

    Attributes:
      theta: the angle from upright, radians, not wrapped.
      theta_dot: the angular velocity.
      time: int32 steps taken in the episode.
    """

    VALUES = ("theta", "theta_dot")

    theta: jax.Array
    theta_dot: jax.Array
    time: jax.Array


def make_params(env: str = NAME, **overrides: Any) -> PendulumParams:
    """A preset by name (`Pendulum-v1`), with any field overridden, validated.

    Raises:
      ValueError: for an unknown preset or field, or an invalid value (`check_params`).
    """
    return common.make_params(PRESETS, check_params, env, overrides)


_POSITIVE = ("max_speed", "max_torque", "dt", "mass", "length", "reset_theta", "reset_theta_dot")


def check_params(env_params: PendulumParams) -> None:
    """Checks every concrete value of `env_params`; values under a trace are skipped.

    Raises:
      ValueError: naming the first invalid field: a value that is not finite, a bound, time
        step, mass or length at or below 0, a `max_steps` that is not an integer in [1, 2**31),
        or `env_params` not a `PendulumParams`.
    """
    common.check_numbers(env_params, PendulumParams, _POSITIVE)


def observe(state: PendulumState) -> Observation:
    """The observation `[..., 3]` (cos theta, sin theta, theta_dot) of a state, in the state's
    float dtype."""
    sin, cos = sincos(state.theta)
    return jnp.stack([cos, sin, state.theta_dot], axis=-1)


def reset(key: PRNGKey, env_params: PendulumParams) -> tuple[Observation, PendulumState]:
    """Samples an initial state: theta uniform in [-reset_theta, reset_theta), theta_dot in
    [-reset_theta_dot, reset_theta_dot).

    Args:
      key: PRNG key.
      env_params: `PendulumParams`.

    Returns:
      (obs `[3]`, state with `[]` leaves), in the default float dtype.
    """
    check_params(env_params)
    high = jnp.stack([jnp.asarray(env_params.reset_theta, float),
                      jnp.asarray(env_params.reset_theta_dot, float)])
    state = PendulumState.from_array(rng.uniform(key, (2,), -high, high))
    return observe(state), state


def action_bounds(env_params: PendulumParams) -> tuple[Any, Any]:
    """The torques `step` takes unclipped: (-max_torque, max_torque) of `env_params`."""
    return -env_params.max_torque, env_params.max_torque


def step(state: PendulumState, action: ArrayLike, env_params: PendulumParams
         ) -> tuple[Observation, PendulumState, jax.Array, jax.Array, jax.Array]:
    """Advances one step of `dt` seconds with the torque `action`, clipped to the torque limit.

    Args:
      state: `PendulumState` with `[...]` leaves.
      action: float `[...]` (or broadcasting against the state): Gymnasium's action `[1]` holds
        one such number.
      env_params: `PendulumParams`.

    Returns:
      (obs `[..., 3]`, state, reward `[...]` in the state's float dtype, terminated `[...]` bool,
      always False, truncated `[...]` bool). The reward is minus the cost of the state before
      the step and of the clipped torque.

    Raises:
      ValueError: outside a trace, for invalid `env_params` or an action that is not finite.
    """
    check_params(env_params)
    common.check_continuous_action(action)
    p = env_params
    th, thdot = state.theta, state.theta_dot
    dtype = th.dtype
    low, high = action_bounds(p)
    u = jnp.minimum(jnp.maximum(jnp.asarray(action, dtype), low), high)
    costs = angle_normalize(th) ** 2 + 0.1 * thdot**2 + 0.001 * (u**2)
    newthdot = thdot + (3 * p.gravity / (2 * p.length) * sincos(th)[0]
                        + 3.0 / (p.mass * p.length**2) * u) * p.dt
    newthdot = jnp.minimum(jnp.maximum(newthdot, -p.max_speed), p.max_speed)
    newth = th + newthdot * p.dt
    state = PendulumState(newth.astype(dtype), newthdot.astype(dtype), state.time + 1)
    terminated = jnp.zeros(state.time.shape, bool)
    return (observe(state), state, (-costs).astype(dtype), terminated,
            state.time >= p.max_steps)


def angle_normalize(x: jax.Array) -> jax.Array:
    """Gymnasium's `angle_normalize`: `x` moved into [-pi, pi) by whole turns, `[...]`."""
    return ((x + jnp.pi) % (2 * jnp.pi)) - jnp.pi
