"""Gymnasium `Env` and `VectorEnv` of jaxpg's CartPole, stepped in numpy.

After `register()`, `gymnasium.make("jaxpg/CartPole-v1")` and
`gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=N)` (also `-v0`) behave as Gymnasium's own
`CartPole-v1` and its `CartPoleVectorEnv`: the same spaces, float32 observations, rewards,
termination, time limits and next-step autoreset, and the same initial states for the same seed
(drawn as Gymnasium draws them, then rounded to jaxpg's float dtype).

The dynamics are jaxpg's, not Gymnasium's: `cartpole.step` in jaxpg's float dtype (float32, or
float64 under `jax_enable_x64`), its float32 sine and cosine included. The adapters run the
pieces of `cartpole.step` (`cartpole.accelerations`, `cartpole.integrate`,
`cartpole.reduce_angle`, `cartpole.sincos_polynomials`; `cartpole.is_terminated`'s comparisons)
on numpy values, one rounding per operation. A step equals the compiled `cartpole.step` to its
last bit, which XLA rounds otherwise now and then: it fuses a multiplication and an addition into
one rounding, and divides by a number through its reciprocal (the tests bound the difference).
One environment steps as numpy scalars and N as numpy arrays, without JAX's dispatch per call.
"""

from typing import Any, NamedTuple, TypeVar

import gymnasium
import jax
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.envs.classic_control import utils
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from jaxpg import cartpole, render
from jaxpg.cartpole import CartPoleParams
from jaxpg.types import HostArray
from jaxpg.validation import check_int

# Numpy values that the adapters step: scalars for one environment, arrays for N.
_Numbers = TypeVar("_Numbers", np.ndarray, np.floating)


def observation_space(env_params: CartPoleParams) -> spaces.Box:
    """Gymnasium's CartPole observation space `[4]`: twice the termination thresholds, float32."""
    high = np.array(
        [env_params.x_threshold * 2, np.inf, env_params.theta_threshold_radians * 2, np.inf],
        dtype=np.float32,
    )
    return spaces.Box(-high, high, dtype=np.float32)


def _make_params(env_params: CartPoleParams | None, sutton_barto_reward: bool) -> CartPoleParams:
    """The `CartPoleParams` of an environment: `env_params` (default v1), validated."""
    env_params = cartpole.V1 if env_params is None else env_params
    cartpole.check_params(env_params)
    if sutton_barto_reward:
        env_params = env_params.replace(sutton_barto_reward=True)
    return env_params


def _host_params(env_params: CartPoleParams) -> CartPoleParams:
    """`env_params` with any JAX array among its values as numpy: the same dtypes, so the same
    promotions (a Python number stays one, as weakly typed in numpy as in JAX)."""
    return jax.tree.map(lambda value: np.asarray(value) if isinstance(value, jax.Array) else value,
                        env_params)


def _check_render_mode(render_mode: str | None, metadata: dict[str, Any]) -> None:
    """A ValueError unless `render_mode` is None or one of `metadata["render_modes"]`."""
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(
            f"render_mode: must be None or one of {', '.join(metadata['render_modes'])}, "
            f"got {render_mode!r}"
        )


def _float_dtype(values: HostArray | None = None) -> np.dtype:
    """The dtype of a state made of `values`, as `CartPoleState.from_array` makes it: their float
    dtype (canonical: float32 without `jax_enable_x64`), or the default float dtype."""
    dtype = (values.dtype if values is not None and np.issubdtype(values.dtype, np.floating)
             else float)
    dtype = np.dtype(jax.dtypes.canonicalize_dtype(dtype))
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"state: expected float32 or float64 values, got {dtype}")
    return dtype


def _initial_values(np_random: np.random.Generator, env_params: CartPoleParams,
                    options: dict[str, Any] | None, shape: tuple[int, ...]
                    ) -> tuple[HostArray, tuple[float, float]]:
    """Initial states `shape` (`(4,)` or `(4, N)`): uniform within the reset bounds, which
    `options` ("low", "high") may set, drawn as Gymnasium's CartPole draws them; and the bounds
    (low, high)."""
    low, high = utils.maybe_parse_reset_bounds(
        options, float(env_params.reset_low), float(env_params.reset_high))
    return np_random.uniform(low=low, high=high, size=shape).astype(_float_dtype()), (low, high)


def _sincos(theta: _Numbers, small: bool | np.bool_) -> tuple[_Numbers, _Numbers]:
    """`cartpole.sincos` in numpy: the same float32 arithmetic, or numpy's float64 sine and cosine
    (which are XLA's on CPU, both being the C library's; the tests check it). `small`: whether
    every |theta| <= `_SMALL_ANGLE`, as while an episode lasts."""
    if theta.dtype is not _FLOAT32:
        return np.sin(theta), np.cos(theta)
    if small:
        return cartpole.sincos_polynomials(theta)
    quarter_turns = np.round(theta * cartpole.QUARTER_TURN_PER_RADIAN)
    sin_r, cos_r = cartpole.sincos_polynomials(cartpole.reduce_angle(theta, quarter_turns))
    quadrant = quarter_turns.astype(np.int32) & 3
    return (np.choose(quadrant, (sin_r, cos_r, -sin_r, -cos_r)),
            np.choose(quadrant, (cos_r, -sin_r, -cos_r, sin_r)))


# Up to it, an angle rounds to no quarter turn (0.75 * 2 / pi < 0.5) and its reduction subtracts
# zeros: the polynomials of the angle itself give the same sine and cosine, but for the sign of a
# zero sine, which no step's result shows (the force, never zero, is added to it).
_SMALL_ANGLE = 0.75
_FLOAT32 = np.dtype(np.float32)


def _step_one(values: tuple[np.floating, ...], action: int | np.integer, env_params: CartPoleParams
              ) -> tuple[tuple[np.floating, ...], bool]:
    """`cartpole.step` of one environment: (values, terminated), values as numpy scalars
    (x, x_dot, theta, theta_dot) of the state's dtype."""
    x, x_dot, theta, theta_dot = values
    p = env_params
    force = p.force_mag if action == 1 else -p.force_mag
    sincos = _sincos(theta, abs(theta) <= _SMALL_ANGLE)
    xacc, thetaacc = cartpole.accelerations(theta_dot, force, *sincos, p)
    stepped = cartpole.integrate(x, x_dot, theta, theta_dot, xacc, thetaacc, p)
    terminated = bool(cartpole.is_terminated(stepped[0], stepped[2], p))
    if stepped[0].dtype is not x.dtype:  # (float64 values of the physics, a float32 state)
        stepped = tuple(np.asarray(stepped, x.dtype))
    return stepped, terminated


class _Physics(NamedTuple):
    """What a step of N environments reads of their `CartPoleParams`, for values of one dtype:
    each number as JAX would meet it beside such arrays, as a 0-d array (by which numpy multiplies
    an array sooner than by a Python number), and the forces and thresholds as arrays."""

    gravity: np.ndarray  # []
    masspole: np.ndarray  # []
    length: np.ndarray  # []
    polemass_length: np.ndarray  # []
    total_mass: np.ndarray  # []
    tau: np.ndarray  # []
    integrator: str  # as `CartPoleParams.integrator`
    forces: np.ndarray  # [2]: pushing left, right
    limits: np.ndarray  # [2, 1]: x_threshold, theta_threshold_radians


def _physics(env_params: CartPoleParams, dtype: np.dtype) -> _Physics:
    """The `_Physics` of `env_params` (`_host_params`) for values of `dtype`."""
    p = env_params

    def beside(value: Any) -> np.ndarray:
        """`value` as a 0-d array, of the dtype JAX gives it beside an array of `dtype`."""
        # (a Python number, weakly typed, takes the arrays' dtype)
        return np.asarray(value, np.result_type(value, dtype))

    return _Physics(beside(p.gravity), beside(p.masspole), beside(p.length),
                    beside(p.polemass_length), beside(p.total_mass), beside(p.tau), p.integrator,
                    forces=np.stack([beside(-p.force_mag), beside(p.force_mag)]),
                    limits=np.stack([beside(p.x_threshold),
                                     beside(p.theta_threshold_radians)])[:, None])


def _step_many(values: HostArray, indices: HostArray, physics: _Physics
               ) -> tuple[HostArray, HostArray]:
    """`cartpole.step` of N environments, values `[4, N]` (rows x, x_dot, theta, theta_dot):
    (values `[4, N]`, terminated `[N]`). `indices`: the actions, 0 or 1; `physics`: from
    `_physics`. The four rows are integrated at once, by `cartpole.integrate`'s operations."""
    x, x_dot, theta, theta_dot = values
    p = physics
    sincos = _sincos(theta, (abs(theta) <= _SMALL_ANGLE).all())
    xacc, thetaacc = cartpole.accelerations(theta_dot, p.forces[indices], *sincos, p)
    if p.integrator == "euler":
        stepped = values + p.tau * np.stack((x_dot, xacc, theta_dot, thetaacc))
    else:
        velocities = values[1::2] + p.tau * np.stack((xacc, thetaacc))
        positions = values[::2] + p.tau * velocities
        stepped = np.stack((positions[0], velocities[0], positions[1], velocities[1]))
    # `cartpole.is_terminated` of x and theta at once (|v| > t is v < -t or v > t).
    terminated = (abs(stepped[::2]) > p.limits).any(axis=0)
    return stepped.astype(values.dtype, copy=False), terminated


class CartPoleEnv(gymnasium.Env):
    """One CartPole, stepped as `jaxpg.cartpole.step`; a drop-in for Gymnasium's `CartPoleEnv`.

    As Gymnasium's, it never truncates by itself: `gymnasium.make` adds the `TimeLimit` wrapper
    (500 steps for v1, 200 for v0), so `env_params.max_steps` plays no part here. Stepping after
    termination gives reward 0 (-1 with the Sutton-Barto reward) and a warning, as Gymnasium does.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, sutton_barto_reward: bool = False, render_mode: str | None = None,
                 env_params: CartPoleParams | None = None) -> None:
        """Creates the environment.

        Args:
          sutton_barto_reward: 0 per step and -1 on termination instead of 1 per step.
          render_mode: None or "rgb_array".
          env_params: `CartPoleParams` for other physics; CartPole-v1's by default.

        Raises:
          ValueError: for an unknown render mode or invalid `env_params`.
        """
        _check_render_mode(render_mode, self.metadata)
        self.env_params = _make_params(env_params, sutton_barto_reward)
        self._params = _host_params(self.env_params)
        self.render_mode = render_mode
        self.action_space = spaces.Discrete(2)
        self.observation_space = observation_space(self.env_params)
        # x, x_dot, theta, theta_dot: numpy scalars of the state's dtype
        self._values: tuple[np.floating, ...] | None = None
        self._steps_beyond_terminated: int | None = None

    @property
    def state(self) -> HostArray | None:
        """The physical state `[4]` (x, x_dot, theta, theta_dot), float64; None before reset.

        Settable, as Gymnasium's `CartPoleEnv.state`, e.g. to start from a chosen state.
        """
        return None if self._values is None else np.array(self._values, np.float64)

    @state.setter
    def state(self, values: npt.ArrayLike) -> None:
        values = np.asarray(values)
        if values.shape != (4,):
            raise ValueError(f"state: expected shape (4,), got {values.shape}")
        self._values = tuple(values.astype(_float_dtype(values)))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[HostArray, dict[str, Any]]:
        """Starts an episode; `options` may set the reset bounds "low" and "high".

        Returns:
          (obs float32 `[4]`, {}).
        """
        super().reset(seed=seed)
        values, _ = _initial_values(self.np_random, self._params, options, (4,))
        self._values = tuple(values)
        self._steps_beyond_terminated = None
        return values.astype(np.float32), {}

    def step(self, action: int | np.integer) -> tuple[HostArray, float, bool, bool, dict[str, Any]]:
        """One step: 1 pushes right, 0 left.

        Returns:
          (obs float32 `[4]`, reward, terminated, False, {}).

        Raises:
          ValueError: for an action other than 0 or 1.
          gymnasium.error.ResetNeeded: before the first `reset`.
        """
        if not (type(action) is int and 0 <= action <= 1 or self.action_space.contains(action)):
            raise ValueError(f"action: must be 0 (push left) or 1 (push right), got {action!r}")
        if self._values is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        self._values, terminated = _step_one(self._values, action, self._params)
        sutton_barto = self.env_params.sutton_barto_reward
        reward = (-1.0 if terminated else 0.0) if sutton_barto else 1.0
        if terminated:
            if self._steps_beyond_terminated is None:
                self._steps_beyond_terminated = 0
            else:
                if self._steps_beyond_terminated == 0:
                    gymnasium.logger.warn(
                        "You are calling 'step()' even though this environment has already "
                        "returned terminated = True; call 'reset()' first."
                    )
                self._steps_beyond_terminated += 1
                reward = -1.0 if sutton_barto else 0.0
        return np.array(self._values, np.float32), reward, terminated, False, {}

    def render(self) -> HostArray | None:
        """The current frame as uint8 `[400, 600, 3]` in "rgb_array" mode; None before reset or
        without a render mode (with a warning)."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "You are calling render method without specifying any render mode, e.g. "
                'gymnasium.make("jaxpg/CartPole-v1", render_mode="rgb_array")'
            )
            return None
        if self._values is None:
            return None
        return render.render_frame(self._values, self.env_params)


class CartPoleVectorEnv(gymnasium.vector.VectorEnv):
    """N CartPoles stepped together as `jaxpg.cartpole.step`; as Gymnasium's `CartPoleVectorEnv`.

    Next-step autoreset, as `rollout.autoreset_step`: the step after an environment terminates or
    truncates ignores its action and resets it, with reward 0 and terminated and truncated False.
    Truncation happens after `max_episode_steps` steps.
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        sutton_barto_reward: bool = False,
        env_params: CartPoleParams | None = None,
    ) -> None:
        """Creates the environments.

        Args:
          num_envs: N.
          max_episode_steps: the time limit; `env_params.max_steps` (500) by default.
          render_mode: None or "rgb_array".
          sutton_barto_reward: 0 per step and -1 on termination instead of 1 per step.
          env_params: `CartPoleParams` for other physics; CartPole-v1's by default.

        Raises:
          ValueError: for a `num_envs` below 1, an unknown render mode or invalid `env_params`
            (a `max_episode_steps` below 1 included).
        """
        check_int("num_envs", num_envs)
        _check_render_mode(render_mode, self.metadata)
        env_params = _make_params(env_params, sutton_barto_reward)
        if max_episode_steps is not None:
            env_params = env_params.replace(max_steps=max_episode_steps)
            cartpole.check_params(env_params)
        self.env_params = env_params
        self._params = _host_params(env_params)
        self._physics: _Physics | None = None  # `_physics` for the values' dtype
        self.num_envs = num_envs
        self.max_episode_steps = int(env_params.max_steps)
        self.render_mode = render_mode
        self.single_action_space = spaces.Discrete(2)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.single_observation_space = observation_space(env_params)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._values: HostArray | None = None  # [4, N] of the state's dtype
        self._time: HostArray | None = None  # [N] steps taken in each episode
        self._prev_done: HostArray | None = None  # [N] whether each resets at its next step
        self._bounds: tuple[float, float] | None = None  # the reset bounds of the last reset

    @property
    def state(self) -> HostArray | None:
        """The physical states `[4, N]` (rows x, x_dot, theta, theta_dot), float64, as Gymnasium's.

        Settable; setting it keeps each environment's step count and pending autoreset.
        """
        return None if self._values is None else self._values.astype(np.float64)

    @state.setter
    def state(self, values: npt.ArrayLike) -> None:
        if self._values is None:
            raise gymnasium.error.ResetNeeded("call reset() before setting the state")
        values = np.asarray(values)
        if values.shape != (4, self.num_envs):
            raise ValueError(f"state: expected shape (4, {self.num_envs}), got {values.shape}")
        self._set_values(values.astype(_float_dtype(values)))

    def _set_values(self, values: HostArray) -> None:
        """Sets the states `[4, N]` and the physics for their dtype."""
        self._values = values
        self._physics = _physics(self._params, values.dtype)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[HostArray, dict[str, Any]]:
        """Resets every environment; `options` may set the reset bounds "low" and "high".

        Returns:
          (obs float32 `[N, 4]`, {}).
        """
        super().reset(seed=seed)
        values, self._bounds = _initial_values(
            self.np_random, self._params, options, (4, self.num_envs))
        self._set_values(values)
        self._time = np.zeros(self.num_envs, np.int32)
        self._prev_done = np.zeros(self.num_envs, bool)
        return values.T.astype(np.float32), {}

    def step(self, actions: npt.ArrayLike
             ) -> tuple[HostArray, HostArray, HostArray, HostArray, dict[str, Any]]:
        """Steps every environment: action 1 pushes right, 0 left.

        Args:
          actions: N integer (or bool) actions, each 0 or 1.

        Returns:
          (obs float32 `[N, 4]`, reward float32 `[N]`, terminated bool `[N]`, truncated bool
          `[N]`, {}).

        Raises:
          ValueError: unless there are N actions, each 0 or 1.
          gymnasium.error.ResetNeeded: before the first `reset`.
        """
        actions = np.asarray(actions)
        # As indices (a negative action wraps round to a large one), for integers and booleans.
        indices = actions.astype(np.uintp) if actions.dtype.kind in "biu" else None
        if actions.shape != (self.num_envs,) or indices is None or (indices > 1).any():
            raise ValueError(
                f"actions: expected {self.num_envs} integer actions, each 0 (push left) or 1 "
                f"(push right), got {actions!r}"
            )
        if self._values is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        # (`reset` sets them all with the values.)
        assert self._physics is not None and self._bounds is not None
        assert self._time is not None and self._prev_done is not None
        values, terminated = _step_many(self._values, indices, self._physics)
        time = self._time + 1
        truncated = time >= self.max_episode_steps
        if self.env_params.sutton_barto_reward:
            reward = np.where(terminated, np.float32(-1), np.float32(0))
        else:
            reward = np.ones(self.num_envs, np.float32)
        done = self._prev_done
        if done.any():  # drawn as Gymnasium's CartPoleVectorEnv draws them
            low, high = self._bounds
            values[:, done] = self.np_random.uniform(low, high, size=(4, done.sum()))
            time[done] = 0
            reward[done] = 0
            terminated[done] = False
            truncated[done] = False
        self._values, self._time, self._prev_done = values, time, terminated | truncated
        return values.T.astype(np.float32), reward, terminated, truncated, {}

    def render(self) -> tuple[HostArray, ...] | None:
        """One uint8 frame `[400, 600, 3]` per environment, in "rgb_array" mode; None without a
        render mode (with a warning).

        Raises:
          ValueError: before the first `reset`.
        """
        if self.render_mode is None:
            gymnasium.logger.warn(
                "You are calling render method without specifying any render mode, e.g. "
                'gymnasium.make_vec("jaxpg/CartPole-v1", render_mode="rgb_array")'
            )
            return None
        if self._values is None:
            raise ValueError("cannot render before reset()")
        return tuple(render.render_frame(self._values.T, self.env_params))


def register() -> None:
    """Registers `jaxpg/CartPole-v1` and `jaxpg/CartPole-v0` with Gymnasium (idempotent)."""
    for name, env_params in cartpole.PRESETS.items():
        env_id = f"jaxpg/{name}"
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="jaxpg.gym:CartPoleEnv",
            vector_entry_point="jaxpg.gym:CartPoleVectorEnv",
            max_episode_steps=int(env_params.max_steps),
            reward_threshold=cartpole.REWARD_THRESHOLDS[name],
            kwargs={"env_params": env_params},
        )
