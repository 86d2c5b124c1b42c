"""CartPole as pure, jittable JAX functions, equal to Gymnasium's classic_control `CartPoleEnv`.

Operation order follows Gymnasium's `step` exactly, so that in float64 the two agree to rounding.
"""

import math
from typing import TYPE_CHECKING, Any, Protocol, Self, TypeVar, overload

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxpg import rng
from jaxpg.envs import common
from jaxpg.types import ArrayLike, Observation, PRNGKey
from jaxpg.validation import check_bool, check_choice, check_representable, in_float64

NAME = "CartPole-v1"
OBS_SIZE = 4  # x, x_dot, theta, theta_dot
NUM_ACTIONS = 2  # push left, push right
INTEGRATORS = ("euler", "semi-implicit")

# The values that the pieces of `step` compute with, all of one kind: JAX arrays inside `step`,
# numpy arrays or scalars in the Gymnasium adapters (`jaxpg.envs.gym`).
Value = TypeVar("Value", jax.Array, np.ndarray, np.floating)


@struct.dataclass
class CartPoleParams:
    """Physics and episode settings; a pytree, so a sweep can vmap over any number in it.

    `total_mass` and `polemass_length` are derived from the masses and the length, never stored, so
    that vmapping over `masspole` changes them too. The integrator and the reward scheme change the
    program, so they are static fields. Each number is a Python number, or an array of any shape
    (under `vmap`, a traced one); `check_params` validates them.

    Attributes:
      gravity: the acceleration of gravity, m/s^2.
      masscart: the cart's mass, kg.
      masspole: the pole's mass, kg.
      length: half the pole's length, m.
      force_mag: the magnitude of the force of a push, N.
      tau: seconds between state updates.
      x_threshold: the episode terminates once |x| exceeds it, m.
      theta_threshold_radians: the episode terminates once |theta| exceeds it.
      reset_low: the low bound of each initial value, drawn uniform in [reset_low, reset_high).
      reset_high: the high bound of each initial value.
      max_steps: Gymnasium's TimeLimit: an episode is truncated once this many steps were taken.
      integrator: static: "euler" (Gymnasium's default) or "semi-implicit" (velocities first).
      sutton_barto_reward: static: reward 0 per step and -1 on termination, instead of 1 per step.
    """

    gravity: float = 9.8
    masscart: float = 1.0
    masspole: float = 0.1
    length: float = 0.5  # half the pole's length
    force_mag: float = 10.0
    tau: float = 0.02  # seconds between state updates
    x_threshold: float = 2.4
    theta_threshold_radians: float = 12 * 2 * math.pi / 360
    reset_low: float = -0.05
    reset_high: float = 0.05
    max_steps: int = 500  # Gymnasium's TimeLimit: truncated once this many steps were taken
    integrator: str = struct.field(pytree_node=False, default="euler")
    sutton_barto_reward: bool = struct.field(pytree_node=False, default=False)

    if TYPE_CHECKING:  # flax.struct adds it to the class
        def replace(self, **updates: Any) -> Self:
            """A copy with the fields `updates` names replaced."""
            ...

    @property
    def total_mass(self) -> float:
        """`masspole + masscart`."""
        return self.masspole + self.masscart

    @property
    def polemass_length(self) -> float:
        """`masspole * length`."""
        return self.masspole * self.length


class Physics(Protocol):
    """What `accelerations` reads of its `env_params`: a `CartPoleParams`, or numpy values of it.

    Attributes:
      gravity: the acceleration of gravity.
      masspole: the pole's mass.
      length: half the pole's length.
      polemass_length: `masspole * length`.
      total_mass: `masspole + masscart`.
    """

    # Any: a Python number, a numpy value or a JAX array, which every `Value` computes with.
    @property
    def gravity(self) -> Any: ...

    @property
    def masspole(self) -> Any: ...

    @property
    def length(self) -> Any: ...

    @property
    def polemass_length(self) -> Any: ...

    @property
    def total_mass(self) -> Any: ...


V1 = CartPoleParams(max_steps=500)
V0 = CartPoleParams(max_steps=200)
PRESETS = {"CartPole-v1": V1, "CartPole-v0": V0}
REWARD_THRESHOLDS = {"CartPole-v1": 475.0, "CartPole-v0": 195.0}


@struct.dataclass
class CartPoleState:
    """The four physical values and the number of steps taken in the episode.

    Every leaf has the same batch shape `[...]` (`[]` for one environment).

    Attributes:
      x: the cart's position, float.
      x_dot: the cart's velocity, float of the same dtype.
      theta: the pole's angle from upright, radians, positive to the right.
      theta_dot: the pole's angular velocity.
      time: int32 steps taken in the episode.
    """

    x: jax.Array
    x_dot: jax.Array
    theta: jax.Array
    theta_dot: jax.Array
    time: jax.Array

    @classmethod
    def from_array(cls, values: ArrayLike, time: ArrayLike = 0) -> Self:
        """Builds a state from values (x, x_dot, theta, theta_dot), e.g. Gymnasium's state.

        Args:
          values: `[..., 4]` values; integers become the default float dtype.
          time: int steps taken, broadcast to `[...]`.

        Returns:
          A state with `[...]` leaves.

        Raises:
          ValueError: if `values` is not shaped `[..., 4]`.
        """
        values = jnp.asarray(values)
        if values.ndim == 0 or values.shape[-1] != 4:
            raise ValueError(
                f"state: expected an array of shape [..., 4] (x, x_dot, theta, theta_dot), "
                f"got shape {tuple(values.shape)}"
            )
        if not jnp.issubdtype(values.dtype, jnp.floating):
            values = values.astype(jnp.result_type(float))
        time = jnp.broadcast_to(jnp.asarray(time, jnp.int32), values.shape[:-1])
        return cls(values[..., 0], values[..., 1], values[..., 2], values[..., 3], time)

    def to_array(self, axis: int = -1) -> jax.Array:
        """The physical values as `[..., 4]`, or with the four values on another `axis`."""
        return jnp.stack([self.x, self.x_dot, self.theta, self.theta_dot], axis=axis)


def make_params(env: str = "CartPole-v1", **overrides: Any) -> CartPoleParams:
    """A preset by name, with any field overridden, validated.

    Args:
      env: `CartPole-v1` or `CartPole-v0`.
      **overrides: values of `CartPoleParams` fields.

    Returns:
      The `CartPoleParams`.

    Raises:
      ValueError: for an unknown preset or field, or an invalid value (`check_params`).
    """
    check_choice("env", env, PRESETS, "preset")
    unknown = set(overrides) - set(CartPoleParams.__dataclass_fields__)
    if unknown:
        raise ValueError(f"env_params: unknown field(s) {', '.join(sorted(unknown))}")
    env_params = PRESETS[env].replace(**overrides)
    check_params(env_params)
    return env_params


_POSITIVE = ("masscart", "masspole", "length", "force_mag", "tau", "x_threshold",
             "theta_threshold_radians")

# The quantities that `step` and `reset` derive from the fields, as `check_params` names them.
_DERIVED = {"masspole + masscart": (np.add, "masspole", "masscart"),
            "masspole * length": (np.multiply, "masspole", "length"),
            "reset_high - reset_low": (np.subtract, "reset_high", "reset_low")}
_POSITIVE_DERIVED = ("masspole + masscart", "masspole * length")


def check_params(env_params: CartPoleParams) -> None:
    """Checks every concrete value of `env_params`; values under a trace are skipped.

    Each number is checked in the float dtype that `step` computes in, JAX's default
    (`jax.dtypes.canonicalize_dtype(float)`: float32 unless `jax_enable_x64`), by
    `check_representable`: none may overflow there, and a field that must be positive must be
    at least the dtype's smallest normal number, not 0 or subnormal once converted (a `tau` of
    1e-300 is 0 in float32: the cart would never move). So are the quantities `step` derives:
    `total_mass` and `polemass_length` (positive too), and the width `reset_high - reset_low`
    that `reset` draws in.

    Raises:
      ValueError: naming the first invalid field: a value that is not finite, a mass, length,
        force, time step or threshold at or below 0, a value or derived quantity that overflows
        or underflows as above, a `max_steps` that is not an integer in [1, 2**31),
        reset bounds out of order, an unknown integrator, a `sutton_barto_reward` that is not
        True or False, or `env_params` not a `CartPoleParams`.
    """
    common.check_numbers(env_params, CartPoleParams, _POSITIVE)  # each field on its own
    check_choice("integrator", env_params.integrator, INTEGRATORS)
    check_bool("sutton_barto_reward", env_params.sutton_barto_reward)
    floats = jax.dtypes.canonicalize_dtype(float)
    for name, (operation, *operands) in _DERIVED.items():
        values = [common.concrete(getattr(env_params, operand)) for operand in operands]
        if all(value is not None for value in values):
            check_representable(name, in_float64(operation, *values), floats,
                                name in _POSITIVE_DERIVED)
    low, high = common.concrete(env_params.reset_low), common.concrete(env_params.reset_high)
    if low is not None and high is not None and not np.all(low.astype(floats)
                                                           < high.astype(floats)):
        raise ValueError(f"reset_low: must be below reset_high in {floats}, got {low} >= {high}")


def observe(state: CartPoleState) -> Observation:
    """The observation `[..., 4]` of a state, in the state's float dtype."""
    return state.to_array()


def reset(key: PRNGKey, env_params: CartPoleParams) -> tuple[Observation, CartPoleState]:
    """Samples an initial state, each value uniform in [reset_low, reset_high).

    Args:
      key: PRNG key.
      env_params: `CartPoleParams`.

    Returns:
      (obs `[4]`, state with `[]` leaves), in the default float dtype.
    """
    check_params(env_params)
    # `jax.random.uniform`'s numbers, hashed by elementwise arithmetic that XLA fuses into the
    # program rather than by JAX's loop of kernels (`jaxpg.rng`).
    values = rng.uniform(key, (4,), minval=env_params.reset_low, maxval=env_params.reset_high)
    state = CartPoleState.from_array(values)
    return observe(state), state


def step(state: CartPoleState, action: ArrayLike, env_params: CartPoleParams
         ) -> tuple[Observation, CartPoleState, jax.Array, jax.Array, jax.Array]:
    """Advances one step of `tau` seconds; action 1 pushes right, 0 pushes left.

    Args:
      state: `CartPoleState` with `[...]` leaves.
      action: int `[...]` (or broadcasting against the state), each 0 or 1.
      env_params: `CartPoleParams`.

    Returns:
      (obs `[..., 4]`, state, reward `[...]` in the state's float dtype, terminated `[...]` bool,
      truncated `[...]` bool). A fall on the step that reaches `max_steps` is both terminated and
      truncated. The reward is 1 on every step, including the terminating one; with
      `sutton_barto_reward`, 0 per step and -1 on termination.

    Raises:
      ValueError: outside a trace, for invalid `env_params` or an action other than 0 or 1.
    """
    check_params(env_params)
    _check_action(action)
    p = env_params
    force = jnp.where(action == 1, p.force_mag, -p.force_mag)
    xacc, thetaacc = accelerations(state.theta_dot, force, *sincos(state.theta), p)
    x, x_dot, theta, theta_dot = integrate(
        state.x, state.x_dot, state.theta, state.theta_dot, xacc, thetaacc, p)
    time = state.time + 1
    state = CartPoleState(x.astype(state.x.dtype), x_dot.astype(state.x.dtype),
                          theta.astype(state.x.dtype), theta_dot.astype(state.x.dtype), time)
    terminated = is_terminated(x, theta, p)
    truncated = time >= p.max_steps
    if p.sutton_barto_reward:
        reward = jnp.where(terminated, -1.0, 0.0).astype(state.x.dtype)
    else:
        reward = jnp.ones_like(state.x)
    return observe(state), state, reward, terminated, truncated


# The pieces of `step` below use arithmetic operators only, so that numpy values (arrays or
# scalars) go through the same operations in the same order: the Gymnasium adapters
# (`jaxpg.envs.gym`) step in numpy with them.


def accelerations(theta_dot: Value, force: Value | float, sintheta: Value, costheta: Value,
                  env_params: Physics) -> tuple[Value, Value]:
    """The cart's and the pole's accelerations, in Gymnasium's operation order.

    Args:
      theta_dot: the pole's angular velocity `[...]`.
      force: the force of the push `[...]`, `force_mag` signed.
      sintheta: the sine of the pole's angle `[...]`.
      costheta: its cosine `[...]`.
      env_params: `CartPoleParams`, or its numbers as numpy values.

    Returns:
      (xacc `[...]`, thetaacc `[...]`).
    """
    p = env_params
    temp = (force + p.polemass_length * (theta_dot * theta_dot) * sintheta) / p.total_mass
    thetaacc = (p.gravity * sintheta - costheta * temp) / (
        p.length * (4.0 / 3.0 - p.masspole * (costheta * costheta) / p.total_mass)
    )
    xacc = temp - p.polemass_length * thetaacc * costheta / p.total_mass
    return xacc, thetaacc


def integrate(x: Value, x_dot: Value, theta: Value, theta_dot: Value, xacc: Value,
              thetaacc: Value, env_params: CartPoleParams) -> tuple[Value, Value, Value, Value]:
    """(x, x_dot, theta, theta_dot) `tau` seconds later, by the integrator of `env_params`.

    Euler moves the positions by the old velocities; "semi-implicit" updates the velocities
    first and moves the positions by the new ones.

    Args:
      x: the cart's position `[...]`.
      x_dot: its velocity `[...]`.
      theta: the pole's angle `[...]`.
      theta_dot: its angular velocity `[...]`.
      xacc: the cart's acceleration `[...]` (`accelerations`).
      thetaacc: the pole's angular acceleration `[...]`.
      env_params: `CartPoleParams`, whose `tau` and `integrator` are read.

    Returns:
      (x, x_dot, theta, theta_dot), `[...]` each.
    """
    p = env_params
    if p.integrator == "euler":
        return (x + p.tau * x_dot, x_dot + p.tau * xacc,
                theta + p.tau * theta_dot, theta_dot + p.tau * thetaacc)
    x_dot = x_dot + p.tau * xacc
    theta_dot = theta_dot + p.tau * thetaacc
    return x + p.tau * x_dot, x_dot, theta + p.tau * theta_dot, theta_dot


@overload
def is_terminated(x: jax.Array, theta: jax.Array, env_params: CartPoleParams) -> jax.Array: ...


@overload
def is_terminated(x: np.ndarray | np.floating, theta: np.ndarray | np.floating,
                  env_params: CartPoleParams) -> np.ndarray | np.bool_: ...


def is_terminated(x: jax.Array | np.ndarray | np.floating,
                  theta: jax.Array | np.ndarray | np.floating,
                  env_params: CartPoleParams) -> jax.Array | np.ndarray | np.bool_:
    """Whether the cart left the track or the pole fell (strictly past the thresholds).

    Args:
      x: the cart's position `[...]`.
      theta: the pole's angle `[...]`.
      env_params: `CartPoleParams`, whose `x_threshold` and `theta_threshold_radians` are read.

    Returns:
      bool `[...]`.
    """
    p = env_params
    return ((x < -p.x_threshold) | (x > p.x_threshold)
            | (theta < -p.theta_threshold_radians) | (theta > p.theta_threshold_radians))


def sincos(theta: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(sin, cos) of `theta` `[...]`: in float32 by vectorisable arithmetic, else by `jnp`.

    The float32 path is Cephes' `sinf`/`cosf`: the angle less the nearest multiple of pi/2
    (`reduce_angle`: subtracted in three parts, exact for |theta| < 2**15), then a polynomial on
    [-pi/4, pi/4] (`sincos_polynomials`). Its absolute error is below 1e-7 over |theta| < 1e5.
    """
    # XLA's float32 sin and cos on CPU are a scalar library call per element (docs/performance.md).
    if theta.dtype != jnp.float32:
        return jnp.sin(theta), jnp.cos(theta)
    quarter_turns = jnp.round(theta * QUARTER_TURN_PER_RADIAN)
    sin_r, cos_r = sincos_polynomials(reduce_angle(theta, quarter_turns))
    quadrant = quarter_turns.astype(jnp.int32) & 3
    sin = jax.lax.select_n(quadrant, sin_r, cos_r, -sin_r, -cos_r)
    cos = jax.lax.select_n(quadrant, cos_r, -sin_r, -cos_r, sin_r)
    return sin, cos


_f32 = np.float32
QUARTER_TURN_PER_RADIAN = _f32(2 / np.pi)
_PI_2 = (_f32(1.5703125), _f32(4.837512969970703125e-4), _f32(7.54978995489188216e-8))  # sum: pi/2
_SIN = (_f32(-1.6666654611e-1), _f32(8.3321608736e-3), _f32(-1.9515295891e-4))
_COS = (_f32(0.5), _f32(4.166664568298827e-2), _f32(-1.388731625493765e-3),
        _f32(2.443315711809948e-5))


def reduce_angle(theta: Value, quarter_turns: Value) -> Value:
    """The float32 `theta` less `quarter_turns` quarter turns (`sincos`)."""
    r: Value = theta - quarter_turns * _PI_2[0]
    r = r - quarter_turns * _PI_2[1]
    return r - quarter_turns * _PI_2[2]


def sincos_polynomials(r: Value) -> tuple[Value, Value]:
    """(sin, cos) of the float32 `r` in [-pi/4, pi/4], by Cephes' polynomials (`sincos`)."""
    z = r * r
    sin_r = r + r * z * (_SIN[0] + z * (_SIN[1] + z * _SIN[2]))
    cos_r = 1 - _COS[0] * z + z * z * (_COS[1] + z * (_COS[2] + z * _COS[3]))
    return sin_r, cos_r


def _check_action(action: ArrayLike) -> None:
    """In eager use, rejects any action other than 0 or 1."""
    value = common.concrete(action)
    if value is not None and not np.all((value == 0) | (value == 1)):
        raise ValueError(f"action: must be 0 (push left) or 1 (push right), got {value}")
