"""Acrobot as pure, jittable JAX functions, equal to Gymnasium's classic_control `AcrobotEnv`.

Two links hang from a joint; the torque (action 0: -1, 1: 0, 2: +1) drives the joint between
them, and the episode terminates once the free end rises more than one link above the first
joint. Each step integrates the book's (or NIPS paper's) equations over `dt` by one step of
fourth-order Runge-Kutta (`rk4`, as Gymnasium writes it, with its `dsdt`), wraps both angles into
[-pi, pi] (`wrap`) and clips both angular velocities (`bound`). Operation order follows
Gymnasium's, so that in float64 the two agree to rounding: within 1e-12 from the same state.

Not to the last bit, though: compiled, XLA fuses multiplications and additions into one rounding
(FMA) where NumPy rounds twice, and the dynamics are chaotic. Unsynced, float64 steps under random
actions stay within 1e-5 of Gymnasium's (`np.allclose`) for a median of about 1000 steps, 95% of
runs for a whole episode (500), the least of 80 runs for 373 (`tests/test_envs_conformance.py`).
From its fastest states a float32 step is ill-conditioned: a change of the state by half a
float32 spacing moves Gymnasium's own float64 step by up to 6e-5 relative.

Gymnasium's reset state is float32 (uniform draws in float64, rounded); `reset` rounds the same way.
Gymnasium's torque noise (`torque_noise_max`, 0 by default) is drawn here from a key the state
carries, so that `step` stays a function of the state alone.
"""

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Self

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxpg import rng
from jaxpg.envs import common
from jaxpg.envs.cartpole import sincos
from jaxpg.types import ArrayLike, Observation, PRNGKey
from jaxpg.validation import check_choice, shown

NAME = "Acrobot-v1"
OBS_SIZE = 6  # cos theta1, sin theta1, cos theta2, sin theta2, dtheta1, dtheta2
NUM_ACTIONS = 3  # torque -1, 0, +1
DYNAMICS = ("book", "nips")
# Whole turns `wrap` takes one at a time, as Gymnasium's loop does: exact up to |angle| = 13 pi.
# One step from any state inside the ranges reaches 9.5 pi at most (velocities at their bounds).
WRAP_TURNS = 6


@struct.dataclass
class AcrobotParams:
    """Physics and episode settings; a pytree, so a sweep can vmap over any number in it.

    The fields are Gymnasium's `AcrobotEnv` attributes of the same names in lower case, but
    `gravity` and `torque`, which Gymnasium writes as numbers in `_dsdt` and `AVAIL_TORQUE`, and
    the reset bounds and `max_steps`. The torque noise and the dynamics change the program, so
    they are static fields. Each number is a Python number, or an array of any shape (under
    `vmap`, a traced one); `check_params` validates them.

    Attributes:
      dt: seconds integrated by one step.
      link_length_1: the first link's length, m.
      link_mass_1: the first link's mass, kg.
      link_mass_2: the second link's mass, kg.
      link_com_pos_1: the first link's centre of mass from its joint, m.
      link_com_pos_2: the second link's centre of mass from its joint, m.
      link_moi: each link's moment of inertia.
      max_vel_1: the first joint's angular velocity is clipped to [-max_vel_1, max_vel_1].
      max_vel_2: the second joint's, to [-max_vel_2, max_vel_2].
      torque: the magnitude of the torque of actions 0 and 2.
      gravity: the acceleration of gravity, m/s^2.
      reset_low: the low bound of each initial value, drawn uniform in [reset_low, reset_high).
      reset_high: the high bound of each initial value.
      max_steps: Gymnasium's TimeLimit: an episode is truncated once this many steps were taken.
      torque_noise_max: static: noise uniform in [-torque_noise_max, torque_noise_max) is added
        to every torque; 0 (Gymnasium's default) adds none and draws nothing.
      book_or_nips: static: "book" (Gymnasium's default) or "nips" equations.
    """

    dt: float = 0.2
    link_length_1: float = 1.0
    link_mass_1: float = 1.0
    link_mass_2: float = 1.0
    link_com_pos_1: float = 0.5
    link_com_pos_2: float = 0.5
    link_moi: float = 1.0
    max_vel_1: float = 4 * math.pi
    max_vel_2: float = 9 * math.pi
    torque: float = 1.0
    gravity: float = 9.8
    reset_low: float = -0.1
    reset_high: float = 0.1
    max_steps: int = 500
    torque_noise_max: float = struct.field(pytree_node=False, default=0.0)
    book_or_nips: str = struct.field(pytree_node=False, default="book")

    if TYPE_CHECKING:  # flax.struct adds it to the class
        def replace(self, **updates: Any) -> Self:
            """A copy with the fields `updates` names replaced."""
            ...


V1 = AcrobotParams()
PRESETS = {NAME: V1}
REWARD_THRESHOLDS = {NAME: -100.0}


@struct.dataclass
class AcrobotState(common.ArrayState):
    """The two angles, their velocities, the steps taken and the key of the torque noise.

    Every leaf but `key` has the same batch shape `[...]` (`[]` for one environment).

    Attributes:
      theta1: the first link's angle from hanging down, radians, in [-pi, pi].
      theta2: the second link's angle relative to the first, in [-pi, pi].
      dtheta1: theta1's angular velocity.
      dtheta2: theta2's angular velocity.
      time: int32 steps taken in the episode.
      key: PRNG key `[..., 2]` of the torque noise, split only when there is noise.
    """

    VALUES = ("theta1", "theta2", "dtheta1", "dtheta2")

    theta1: jax.Array
    theta2: jax.Array
    dtheta1: jax.Array
    dtheta2: jax.Array
    time: jax.Array
    key: jax.Array

    @classmethod
    def from_array(cls, values: ArrayLike, time: ArrayLike = 0,
                   key: PRNGKey | None = None) -> Self:
        """Builds a state from values (theta1, theta2, dtheta1, dtheta2), e.g. Gymnasium's state.

        Args:
          values: `[..., 4]` values; integers become the default float dtype.
          time: int steps taken, broadcast to `[...]`.
          key: optional PRNG key of the torque noise, broadcast to `[..., 2]`; `PRNGKey(0)` if
            None.

        Returns:
          A state with `[...]` leaves and a `[..., 2]` key.

        Raises:
          ValueError: if `values` is not shaped `[..., 4]`.
        """
        fields = common.array_fields(cls.VALUES, values, time)
        key = jax.random.PRNGKey(0) if key is None else jnp.asarray(key)
        return cls(**fields, key=jnp.broadcast_to(key, (*fields["time"].shape, 2)))


def make_params(env: str = NAME, **overrides: Any) -> AcrobotParams:
    """A preset by name (`Acrobot-v1`), with any field overridden, validated.

    Raises:
      ValueError: for an unknown preset or field, or an invalid value (`check_params`).
    """
    return common.make_params(PRESETS, check_params, env, overrides)


_POSITIVE = ("dt", "link_length_1", "link_mass_1", "link_mass_2", "link_com_pos_1",
             "link_com_pos_2", "link_moi", "max_vel_1", "max_vel_2", "torque")


def check_params(env_params: AcrobotParams) -> None:
    """Checks every concrete value of `env_params`; values under a trace are skipped.

    Raises:
      ValueError: naming the first invalid field: a value that is not finite, a time step,
        length, mass, inertia, velocity bound or torque at or below 0, a `max_steps` that is not
        an integer in [1, 2**31), reset bounds out of order, a `torque_noise_max` below 0 or not
        finite, unknown dynamics, or `env_params` not an `AcrobotParams`.
    """
    common.check_numbers(env_params, AcrobotParams, _POSITIVE)
    common.check_below(env_params, "reset_low", "reset_high")
    check_choice("book_or_nips", env_params.book_or_nips, DYNAMICS)
    noise = env_params.torque_noise_max
    # A Python or numpy number (static: hashed, not traced), not a bool: True would be noise 1.
    is_number = isinstance(noise, int | float | np.integer | np.floating) and not isinstance(
        noise, bool)
    if not (is_number and math.isfinite(noise) and noise >= 0):
        raise ValueError(f"torque_noise_max: must be a finite number >= 0, got {shown(noise)}")


def observe(state: AcrobotState) -> Observation:
    """The observation `[..., 6]` (cos theta1, sin theta1, cos theta2, sin theta2, dtheta1,
    dtheta2) of a state, in the state's float dtype."""
    sin1, cos1 = sincos(state.theta1)
    sin2, cos2 = sincos(state.theta2)
    return jnp.stack([cos1, sin1, cos2, sin2, state.dtheta1, state.dtheta2], axis=-1)


def reset(key: PRNGKey, env_params: AcrobotParams) -> tuple[Observation, AcrobotState]:
    """Samples an initial state, each value uniform in [reset_low, reset_high), as float32.

    Args:
      key: PRNG key.
      env_params: `AcrobotParams`.

    Returns:
      (obs `[6]`, state with `[]` leaves), in the default float dtype.
    """
    check_params(env_params)
    key_values, key_noise = rng.split(key)
    values = rng.uniform(
        key_values, (4,), minval=env_params.reset_low, maxval=env_params.reset_high
    )
    state = AcrobotState.from_array(common.float32_values(values), key=key_noise)
    return observe(state), state


def step(state: AcrobotState, action: ArrayLike, env_params: AcrobotParams
         ) -> tuple[Observation, AcrobotState, jax.Array, jax.Array, jax.Array]:
    """Advances one step of `dt` seconds; actions 0, 1, 2 apply the torques -1, 0, +1.

    Args:
      state: `AcrobotState` with `[...]` leaves.
      action: int `[...]` (or broadcasting against the state), each 0, 1 or 2.
      env_params: `AcrobotParams`.

    Returns:
      (obs `[..., 6]`, state, reward `[...]` in the state's float dtype, terminated `[...]` bool,
      truncated `[...]` bool). The reward is -1, and 0 on the terminating step. A termination on
      the step that reaches `max_steps` is both terminated and truncated.

    Raises:
      ValueError: outside a trace, for invalid `env_params` or an action other than 0, 1 or 2.
    """
    check_params(env_params)
    common.check_discrete_action(action, NUM_ACTIONS, "0 (torque -1), 1 (0) or 2 (+1)")
    p = env_params
    dtype = state.theta1.dtype
    torque = common.centred_action(action, dtype) * p.torque
    key = state.key
    if p.torque_noise_max > 0:
        key, noise = torque_noise(key, p.torque_noise_max, dtype)
        torque = torque + noise
    new = rk4(lambda s: dsdt(s, torque, p), (state.theta1, state.theta2, state.dtheta1,
                                             state.dtheta2), p.dt)
    state = AcrobotState(
        wrap(new[0], -math.pi, math.pi).astype(dtype),
        wrap(new[1], -math.pi, math.pi).astype(dtype),
        bound(new[2], -p.max_vel_1, p.max_vel_1).astype(dtype),
        bound(new[3], -p.max_vel_2, p.max_vel_2).astype(dtype),
        state.time + 1,
        key,
    )
    terminated = is_terminated(state)
    reward = jnp.where(terminated, 0.0, -1.0).astype(dtype)
    return observe(state), state, reward, terminated, state.time >= p.max_steps


def is_terminated(state: AcrobotState) -> jax.Array:
    """Whether the free end is more than one link length above the first joint: Gymnasium's
    `-cos(theta1) - cos(theta2 + theta1) > 1`, bool `[...]`."""
    return -_cos(state.theta1) - _cos(state.theta2 + state.theta1) > 1.0


def torque_noise(key: PRNGKey, noise_max: float, dtype: jnp.dtype
                 ) -> tuple[PRNGKey, jax.Array]:
    """Each environment's next key and noise uniform in [-noise_max, noise_max).

    Args:
      key: PRNG keys `[..., 2]`.
      noise_max: the bound of the noise.
      dtype: the float dtype of the noise.

    Returns:
      (keys `[..., 2]`, noise `[...]`).
    """
    pairs = jax.vmap(jax.random.split)(key.reshape(-1, 2))
    noise = jax.vmap(lambda k: jax.random.uniform(k, (), dtype, -noise_max, noise_max))(
        pairs[:, 1])
    return pairs[:, 0].reshape(key.shape), noise.reshape(key.shape[:-1])


Values = tuple[jax.Array, ...]  # (theta1, theta2, dtheta1, dtheta2) or their derivatives


def dsdt(s: Values, torque: Any, env_params: Any,
         sin_cos: Callable[[Any], tuple[Any, Any]] = sincos) -> Values:
    """Gymnasium's `_dsdt`: the time derivative of (theta1, theta2, dtheta1, dtheta2).

    Args:
      s: (theta1, theta2, dtheta1, dtheta2), `[...]` each.
      torque: the torque `[...]` at the joint between the links.
      env_params: `AcrobotParams`.
      sin_cos: `x -> (sin x, cos x)`: jaxpg's `sincos` by default; NumPy's for the Gymnasium
        adapter's float64 step (`jaxpg.envs.adapters`), which then rounds as Gymnasium's.

    Returns:
      (dtheta1, dtheta2, ddtheta1, ddtheta2), `[...]` each.
    """
    p = env_params
    m1, m2, l1 = p.link_mass_1, p.link_mass_2, p.link_length_1
    lc1, lc2, i1, i2, g = p.link_com_pos_1, p.link_com_pos_2, p.link_moi, p.link_moi, p.gravity
    theta1, theta2, dtheta1, dtheta2 = s
    sin2, cos2 = sin_cos(theta2)
    d1 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * cos2) + i1 + i2
    d2 = m2 * (lc2**2 + l1 * lc2 * cos2) + i2
    phi2 = m2 * lc2 * g * sin_cos(theta1 + theta2 - math.pi / 2.0)[1]
    phi1 = (
        -m2 * l1 * lc2 * dtheta2**2 * sin2
        - 2 * m2 * l1 * lc2 * dtheta2 * dtheta1 * sin2
        + (m1 * lc1 + m2 * l1) * g * sin_cos(theta1 - math.pi / 2)[1]
        + phi2
    )
    if p.book_or_nips == "nips":
        ddtheta2 = (torque + d2 / d1 * phi1 - phi2) / (m2 * lc2**2 + i2 - d2**2 / d1)
    else:
        ddtheta2 = (
            torque + d2 / d1 * phi1 - m2 * l1 * lc2 * dtheta1**2 * sin2 - phi2
        ) / (m2 * lc2**2 + i2 - d2**2 / d1)
    ddtheta1 = -(d2 * ddtheta2 + phi1) / d1
    return dtheta1, dtheta2, ddtheta1, ddtheta2


def rk4(derivs: Callable[[Values], Values], y0: Values, dt: ArrayLike) -> Values:
    """Gymnasium's `rk4` over the times [0, dt]: one fourth-order Runge-Kutta step.

    Args:
      derivs: `y -> dy/dt`, tuples of four `[...]` arrays.
      y0: the values at time 0.
      dt: the step.

    Returns:
      The values at time `dt`.
    """
    dt2 = dt / 2.0
    k1 = derivs(y0)
    k2 = derivs(tuple(y + dt2 * k for y, k in zip(y0, k1)))
    k3 = derivs(tuple(y + dt2 * k for y, k in zip(y0, k2)))
    k4 = derivs(tuple(y + dt * k for y, k in zip(y0, k3)))
    return tuple(y + dt / 6.0 * (a + 2 * b + 2 * c + d)
                 for y, a, b, c, d in zip(y0, k1, k2, k3, k4))


def wrap(x: jax.Array, low: float, high: float) -> jax.Array:
    """Gymnasium's `wrap`: `x` moved into [low, high] by whole turns of `high - low`.

    Gymnasium subtracts a turn while x > high, then adds one while x < low. The first `WRAP_TURNS`
    turns are taken the same way, one at a time, so that the result is the same to the last bit
    (a turn at once rounds otherwise); a value still outside the range after them, only from a
    state far outside the velocity bounds, is brought in by a remainder.
    """
    diff = high - low
    for _ in range(WRAP_TURNS):
        x = jnp.where(x > high, x - diff, jnp.where(x < low, x + diff, x))
    return jnp.where((x > high) | (x < low), low + jnp.remainder(x - low, diff), x)


def bound(x: jax.Array, low: ArrayLike, high: ArrayLike) -> jax.Array:
    """Gymnasium's `bound`: `min(max(x, low), high)`."""
    return jnp.minimum(jnp.maximum(x, low), high)


def _cos(x: jax.Array) -> jax.Array:
    """The cosine of `x` `[...]`, by `sincos`."""
    return sincos(x)[1]

