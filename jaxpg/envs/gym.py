"""Gymnasium `Env` and `VectorEnv` of jaxpg's CartPole, stepped in numpy float64 as Gymnasium's.

After `register()`, `gymnasium.make("jaxpg/CartPole-v1")` and
`gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=N)` (also `-v0`) behave as Gymnasium's own
`CartPole-v1` and its `CartPoleVectorEnv`: the same spaces, float32 observations, rewards,
termination, time limits and next-step autoreset, the same initial states for the same seed, and
the same states after each step.

As Gymnasium's, the adapters hold their state in float64 and step in float64, whatever JAX's
`jax_enable_x64`. They run the pieces of `cartpole.step` (`cartpole.accelerations`,
`cartpole.integrate`, `cartpole.is_terminated`'s comparisons) on numpy float64 values, with
numpy's sine and cosine: Gymnasium's operations in Gymnasium's order, one rounding each, so a step
equals Gymnasium's to its last bit. The compiled `cartpole.step` agrees with them to about 1e-13
under `jax_enable_x64` (XLA fuses a multiplication and an addition into one rounding now and then,
and divides by a number through its reciprocal), and to float32's precision without it. One
environment steps as numpy scalars and N as numpy arrays, without JAX's dispatch per call.
"""

from typing import Any, NamedTuple

import gymnasium
import jax
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.envs.classic_control import utils
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from jaxpg import _register_ids
from jaxpg.envs import cartpole, render
from jaxpg.envs.cartpole import CartPoleParams
from jaxpg.types import HostArray
from jaxpg.validation import check_bool, check_int, shown


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
    if check_bool("sutton_barto_reward", sutton_barto_reward):
        env_params = env_params.replace(sutton_barto_reward=True)
    return env_params


def _host_params(env_params: CartPoleParams) -> CartPoleParams:
    """`env_params` with each number a Python float (float64), as Gymnasium's CartPoleEnv holds
    its physics.

    Raises:
      ValueError: for a field that holds more than one number (the adapters step one physics).
    """
    for path, value in jax.tree_util.tree_leaves_with_path(env_params):
        if np.ndim(value):
            name = jax.tree_util.keystr(path, simple=True)
            raise ValueError(f"env_params: expected one number per field, got {name} of shape "
                             f"{np.shape(value)}")
    return jax.tree.map(float, env_params)


def _check_render_mode(render_mode: str | None, metadata: dict[str, Any]) -> None:
    """A ValueError unless `render_mode` is None or one of `metadata["render_modes"]`."""
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(
            f"render_mode: must be None or one of {', '.join(metadata['render_modes'])}, "
            f"got {render_mode!r}"
        )


def _initial_values(np_random: np.random.Generator, env_params: CartPoleParams,
                    options: dict[str, Any] | None, shape: tuple[int, ...]
                    ) -> tuple[HostArray, tuple[float, float]]:
    """Initial float64 states `shape` (`(4,)` or `(4, N)`): uniform within the reset bounds,
    which `options` ("low", "high") may set, drawn as Gymnasium's CartPole draws them; and the
    bounds (low, high)."""
    low, high = utils.maybe_parse_reset_bounds(options, env_params.reset_low,
                                               env_params.reset_high)
    return np_random.uniform(low=low, high=high, size=shape), (low, high)


def _step_one(values: tuple[np.float64, ...], action: int | np.integer, env_params: CartPoleParams
              ) -> tuple[tuple[np.float64, ...], bool]:
    """Gymnasium's `CartPoleEnv.step` of one environment: (values, terminated), values as numpy
    float64 scalars (x, x_dot, theta, theta_dot). `env_params`: from `_host_params`."""
    x, x_dot, theta, theta_dot = values
    p = env_params
    force = p.force_mag if action == 1 else -p.force_mag
    xacc, thetaacc = cartpole.accelerations(theta_dot, force, np.sin(theta), np.cos(theta), p)
    stepped = cartpole.integrate(x, x_dot, theta, theta_dot, xacc, thetaacc, p)
    return stepped, bool(cartpole.is_terminated(stepped[0], stepped[2], p))


class _Physics(NamedTuple):
    """What a step of N environments reads of their `CartPoleParams`: each number as a float64
    0-d array (by which numpy multiplies an array sooner than by a Python number), and the forces
    and thresholds as arrays."""

    gravity: np.ndarray  # []
    masspole: np.ndarray  # []
    length: np.ndarray  # []
    polemass_length: np.ndarray  # []
    total_mass: np.ndarray  # []
    tau: np.ndarray  # []
    integrator: str  # as `CartPoleParams.integrator`
    forces: np.ndarray  # [2]: pushing left, right
    limits: np.ndarray  # [2, 1]: x_threshold, theta_threshold_radians


def _physics(env_params: CartPoleParams) -> _Physics:
    """The `_Physics` of `env_params` (`_host_params`)."""
    p = env_params
    return _Physics(np.asarray(p.gravity), np.asarray(p.masspole), np.asarray(p.length),
                    np.asarray(p.polemass_length), np.asarray(p.total_mass), np.asarray(p.tau),
                    p.integrator, forces=np.array([-p.force_mag, p.force_mag]),
                    limits=np.array([[p.x_threshold], [p.theta_threshold_radians]]))


def _step_many(values: HostArray, indices: HostArray, physics: _Physics
               ) -> tuple[HostArray, HostArray]:
    """Gymnasium's `CartPoleVectorEnv.step` of N environments without its autoreset, float64
    values `[4, N]` (rows x, x_dot, theta, theta_dot): (values `[4, N]`, terminated `[N]`).
    `indices`: the actions, 0 or 1; `physics`: from `_physics`. The four rows are integrated at
    once, by `cartpole.integrate`'s operations."""
    x, x_dot, theta, theta_dot = values
    p = physics
    xacc, thetaacc = cartpole.accelerations(theta_dot, p.forces[indices], np.sin(theta),
                                            np.cos(theta), p)
    if p.integrator == "euler":
        stepped = values + p.tau * np.stack((x_dot, xacc, theta_dot, thetaacc))
    else:
        velocities = values[1::2] + p.tau * np.stack((xacc, thetaacc))
        positions = values[::2] + p.tau * velocities
        stepped = np.stack((positions[0], velocities[0], positions[1], velocities[1]))
    # `cartpole.is_terminated` of x and theta at once (|v| > t is v < -t or v > t).
    terminated = (abs(stepped[::2]) > p.limits).any(axis=0)
    return stepped, terminated


class CartPoleEnv(gymnasium.Env):
    """One CartPole, stepped in float64 as Gymnasium's `CartPoleEnv`, for which it is a drop-in.

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
        # x, x_dot, theta, theta_dot: numpy float64 scalars
        self._values: tuple[np.float64, ...] | None = None
        self._steps_beyond_terminated: int | None = None

    @property
    def state(self) -> HostArray | None:
        """The physical state `[4]` (x, x_dot, theta, theta_dot), float64; None before reset.

        Settable, as Gymnasium's `CartPoleEnv.state`, e.g. to start from a chosen state; the
        values are kept as float64.
        """
        return None if self._values is None else np.array(self._values)

    @state.setter
    def state(self, values: npt.ArrayLike) -> None:
        values = np.asarray(values, np.float64)
        if values.shape != (4,):
            raise ValueError(f"state: expected shape (4,), got {values.shape}")
        self._values = tuple(values)

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
            raise ValueError(f"action: must be 0 (push left) or 1 (push right), got "
                             f"{shown(action)}")
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
    """N CartPoles stepped together in float64, as Gymnasium's `CartPoleVectorEnv`.

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
          ValueError: for a `num_envs` below 1 or beyond the machine's memory, an unknown render
            mode or invalid `env_params` (a `max_episode_steps` below 1 included).
        """
        check_int("num_envs", num_envs)
        _check_render_mode(render_mode, self.metadata)
        env_params = _make_params(env_params, sutton_barto_reward)
        if max_episode_steps is not None:
            check_int("max_episode_steps", max_episode_steps)
            env_params = env_params.replace(max_steps=max_episode_steps)
            cartpole.check_params(env_params)
        self.env_params = env_params
        self._params = _host_params(env_params)
        self._physics = _physics(self._params)
        self.num_envs = num_envs
        self.max_episode_steps = int(env_params.max_steps)
        self.render_mode = render_mode
        self.single_action_space = spaces.Discrete(2)
        self.single_observation_space = observation_space(env_params)
        try:  # (Gymnasium's spaces hold arrays of N entries)
            self.action_space = batch_space(self.single_action_space, num_envs)
            self.observation_space = batch_space(self.single_observation_space, num_envs)
        except MemoryError:
            raise ValueError(f"num_envs: {num_envs} environments need more memory than this "
                             "machine has") from None
        self._values: HostArray | None = None  # [4, N] float64
        self._time: HostArray | None = None  # [N] steps taken in each episode
        self._prev_done: HostArray | None = None  # [N] whether each resets at its next step
        self._bounds: tuple[float, float] | None = None  # the reset bounds of the last reset

    @property
    def state(self) -> HostArray | None:
        """The physical states `[4, N]` (rows x, x_dot, theta, theta_dot), float64, as Gymnasium's.

        Settable, the values kept as float64; setting it keeps each environment's step count and
        pending autoreset.
        """
        return None if self._values is None else self._values.copy()

    @state.setter
    def state(self, values: npt.ArrayLike) -> None:
        if self._values is None:
            raise gymnasium.error.ResetNeeded("call reset() before setting the state")
        values = np.array(values, np.float64)
        if values.shape != (4, self.num_envs):
            raise ValueError(f"state: expected shape (4, {self.num_envs}), got {values.shape}")
        self._values = values

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[HostArray, dict[str, Any]]:
        """Resets every environment; `options` may set the reset bounds "low" and "high".

        Returns:
          (obs float32 `[N, 4]`, {}).
        """
        super().reset(seed=seed)
        self._values, self._bounds = _initial_values(
            self.np_random, self._params, options, (4, self.num_envs))
        self._time = np.zeros(self.num_envs, np.int32)
        self._prev_done = np.zeros(self.num_envs, bool)
        return self._values.T.astype(np.float32), {}

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
                f"(push right), got {shown(actions)}"
            )
        if self._values is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        # (`reset` sets them all with the values.)
        assert self._bounds is not None and self._time is not None and self._prev_done is not None
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
    """Registers `jaxpg/CartPole-v1` and `jaxpg/CartPole-v0` with Gymnasium (idempotent).

    `import jaxpg` has registered them already, as `gymnasium` was imported: each has the time
    limit and reward threshold of Gymnasium's id of the same name and the adapters above as entry
    points, with CartPole-v1's `env_params` by default (the time limit is the `TimeLimit`
    wrapper's, or `make_vec`'s `max_episode_steps`).
    """
    _register_ids(gymnasium)
