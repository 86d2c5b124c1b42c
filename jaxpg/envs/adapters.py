"""Gymnasium `Env`s of jaxpg's Acrobot, MountainCar, MountainCarContinuous and Pendulum, each
stepped as Gymnasium's own.

After `register()`, `gymnasium.make("jaxpg/Acrobot-v1")` (and `jaxpg/MountainCar-v0`,
`jaxpg/MountainCarContinuous-v0`, `jaxpg/Pendulum-v1`) behaves as Gymnasium's env of the same id:
the same spaces, float32 observations, rewards of the same Python or NumPy type, termination,
time limit (the `TimeLimit` wrapper, after the preset's `max_steps`) and reward threshold, the
same initial state for the same seed and reset options, and the same state after each step, to
its last bit. `gymnasium.make_vec` steps several in Gymnasium's `SyncVectorEnv`, as it does
Gymnasium's own (none of the four has a vector entry point). `env_params` sets other physics.

The state is held as Gymnasium holds it, and each step runs Gymnasium's NumPy operations, in
Gymnasium's order, on values of the types Gymnasium gives them (the action's type included), so
that NumPy rounds each result as it does for Gymnasium:

- Acrobot: float32 after a reset, float64 after a step. `acrobot.rk4` integrates numpy float64
  scalars by `acrobot.dsdt` with NumPy's sine and cosine (`_numpy_sin_cos`; XLA's differ in
  the last bits); the angles are wrapped by Gymnasium's loop and the velocities
  bounded by Python's `min` and `max`, as Gymnasium's `wrap` and `bound`.
- MountainCar: float64, the slope by `math.cos`, as Gymnasium's.
- MountainCarContinuous: float32 after each step (rounded after termination is decided); a
  float32 action makes the push float32 arithmetic, as NumPy makes Gymnasium's.
- Pendulum: float64, the torque's terms in the action's dtype; `pendulum.angle_normalize`.

Measured (`tests/test_envs_adapters.py`): under random actions the states equal Gymnasium's bit
for bit, never re-synced within an episode, over 100,000 steps of each environment under
Gymnasium's time limits (each episode reset with its own seed), and over 50,000 steps without
time limits under other physics (Acrobot's NIPS equations and torque noise among them). So
`gymnasium.utils.env_match.check_environments_match` holds for each however many steps it runs
(10,000 in the tests), Acrobot's included: a last-bit difference would part its states within
a few thousand steps (DESIGN.md, "Chaos limits").
"""

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.envs.classic_control import utils

from jaxpg import _register_ids, envs
from jaxpg.envs import acrobot, continuous_mountain_car, mountain_car, pendulum
from jaxpg.envs.gym import _host_params
from jaxpg.types import HostArray
from jaxpg.validation import check_choice, shown

State = Any  # as Gymnasium's env holds it: a numpy array, or MountainCar's (position, velocity)
Action = Any  # an int for discrete actions; an array `[1]` (float32 from the space) otherwise


class _Dynamics(NamedTuple):
    """What one environment's adapter does, each a function of host params (`_host_params`).

    Attributes:
      make_spaces: `params -> (action_space, observation_space)`.
      initial: `(np_random, params, options) -> state`: Gymnasium's draw of an initial state.
      step: `(state, action, params, np_random) -> (state, reward, terminated)`.
      observe: `state -> obs` float32.
      render_fps: Gymnasium's `metadata["render_fps"]` for the environment.
    """

    make_spaces: Callable[[Any], tuple[spaces.Space, spaces.Box]]
    initial: Callable[[np.random.Generator, Any, dict[str, Any] | None], State]
    step: Callable[[State, Action, Any, np.random.Generator], tuple[State, Any, bool]]
    observe: Callable[[State], HostArray]
    render_fps: int


def _box(high: list[float], low: list[float] | None = None) -> spaces.Box:
    """A float32 `Box` from `low` (`-high` if None) to `high`."""
    high_array = np.array(high, dtype=np.float32)
    low_array = -high_array if low is None else np.array(low, dtype=np.float32)
    return spaces.Box(low=low_array, high=high_array, dtype=np.float32)


def _action_box(low: float, high: float) -> spaces.Box:
    """One float32 action `[1]` from `low` to `high`, as Gymnasium's continuous actions."""
    return spaces.Box(low=low, high=high, shape=(1,), dtype=np.float32)


def _uniform_in_bounds(np_random: np.random.Generator, p: Any, options: dict[str, Any] | None,
                       size: tuple[int, ...] | None = None) -> Any:
    """A uniform draw within the reset bounds, which `options` ("low", "high") may set, as
    Gymnasium's Acrobot and MountainCars draw it."""
    low, high = utils.maybe_parse_reset_bounds(options, p.reset_low, p.reset_high)
    return np_random.uniform(low=low, high=high, size=size)


# --- Acrobot ---------------------------------------------------------------------------------


def _acrobot_spaces(p: Any) -> tuple[spaces.Space, spaces.Box]:
    """Gymnasium's Acrobot spaces: 3 actions; cosines, sines and bounded velocities `[6]`."""
    return spaces.Discrete(acrobot.NUM_ACTIONS), _box([1, 1, 1, 1, p.max_vel_1, p.max_vel_2])


def _acrobot_initial(np_random: np.random.Generator, p: Any, options: dict[str, Any] | None
                     ) -> HostArray:
    """Gymnasium's Acrobot initial state `[4]`: uniform within the bounds, rounded to float32."""
    return _uniform_in_bounds(np_random, p, options, (4,)).astype(np.float32)


def _numpy_sin_cos(x: Any) -> tuple[Any, Any]:
    """(sin x, cos x) by NumPy, as Gymnasium's `_dsdt` computes them."""
    return np.sin(x), np.cos(x)


_WRAP_TURNS = 1_000  # turns `_wrap_angle` takes one at a time, as Gymnasium's `wrap`


def _wrap_angle(x: Any) -> Any:
    """Gymnasium's `wrap(x, -pi, pi)`: whole turns subtracted, then added, one at a time, up to
    `_WRAP_TURNS` (a step from a state within the preset's ranges needs 5 at most); beyond, and
    for values that are not finite, on which Gymnasium's loop would not end, by a remainder."""
    turn = 2 * math.pi
    if not abs(x) <= math.pi + _WRAP_TURNS * turn:
        return -math.pi + np.remainder(x + math.pi, turn)
    while x > math.pi:
        x = x - turn
    while x < -math.pi:
        x = x + turn
    return x


def _acrobot_step(state: HostArray, action: Action, p: Any, np_random: np.random.Generator
                  ) -> tuple[HostArray, float, bool]:
    """Gymnasium's `AcrobotEnv.step`: (state float64 `[4]`, reward, terminated). Its torque is
    a Python number whatever the action's type, as Gymnasium's `AVAIL_TORQUE[action]` (an
    unsigned 0 less 1 would wrap round)."""
    torque = (int(action) - 1) * p.torque
    if p.torque_noise_max > 0:
        torque += np_random.uniform(-p.torque_noise_max, p.torque_noise_max)
    values = tuple(np.asarray(state, np.float64))
    theta1, theta2, dtheta1, dtheta2 = acrobot.rk4(
        lambda s: acrobot.dsdt(s, torque, p, _numpy_sin_cos), values, p.dt)
    state = np.array([_wrap_angle(theta1), _wrap_angle(theta2),
                      _clip(dtheta1, -p.max_vel_1, p.max_vel_1),
                      _clip(dtheta2, -p.max_vel_2, p.max_vel_2)])
    terminated = bool(-np.cos(state[0]) - np.cos(state[1] + state[0]) > 1.0)
    return state, 0.0 if terminated else -1.0, terminated


def _acrobot_observe(state: HostArray) -> HostArray:
    """Gymnasium's Acrobot observation `[6]` float32, the sines and cosines in the state's dtype."""
    s = state
    return np.array([np.cos(s[0]), np.sin(s[0]), np.cos(s[1]), np.sin(s[1]), s[2], s[3]],
                    dtype=np.float32)


# --- MountainCar and MountainCarContinuous ---------------------------------------------------


def _car_spaces(p: Any, action_space: spaces.Space) -> tuple[spaces.Space, spaces.Box]:
    """(action_space, the observation space of either mountain car)."""
    return action_space, _box([p.max_position, p.max_speed], [p.min_position, -p.max_speed])


def _car_initial(np_random: np.random.Generator, p: Any, options: dict[str, Any] | None
                 ) -> HostArray:
    """Gymnasium's initial state `[2]` float64 of either mountain car: at rest, uniform within
    the bounds."""
    return np.array([_uniform_in_bounds(np_random, p, options), 0])


def _clip(x: Any, low: float, high: float) -> Any:
    """`x` clipped by comparisons (Python's `min` and `max`), as Gymnasium's `if` statements and
    `bound` clip: `low` or `high` as they are, `x` of its own type otherwise."""
    return min(max(x, low), high)


def _move(position: Any, velocity: Any, acceleration: Any, p: Any,
          clip: Callable[[Any, float, float], Any]) -> tuple[Any, Any, bool]:
    """`mountain_car.move` of numpy scalars as Gymnasium's mountain cars move: velocity and
    position clipped by `clip` (`np.clip` for MountainCar, which rounds a bound to a float32
    value's dtype; `_clip` for MountainCarContinuous), the car stopped at the left wall:
    (position, velocity, terminated)."""
    velocity = clip(velocity + acceleration, -p.max_speed, p.max_speed)
    position = clip(position + velocity, p.min_position, p.max_position)
    if position == p.min_position and velocity < 0:
        velocity = 0
    return position, velocity, bool(position >= p.goal_position
                                    and velocity >= p.goal_velocity)


def _mountain_car_step(state: Any, action: Action, p: Any, np_random: np.random.Generator
                       ) -> tuple[tuple[Any, Any], float, bool]:
    """Gymnasium's `MountainCarEnv.step`: ((position, velocity), reward, terminated)."""
    position, velocity = state
    acceleration = (action - 1) * p.force + math.cos(3 * position) * -p.gravity
    position, velocity, terminated = _move(position, velocity, acceleration, p, np.clip)
    return (position, velocity), -1.0, terminated


def _continuous_car_step(state: HostArray, action: Action, p: Any,
                         np_random: np.random.Generator) -> tuple[HostArray, float, bool]:
    """Gymnasium's `Continuous_MountainCarEnv.step`: (state float32 `[2]`, reward, terminated)."""
    force = min(max(action[0], p.min_action), p.max_action)
    acceleration = force * p.power - p.gravity * math.cos(3 * state[0])
    position, velocity, terminated = _move(state[0], state[1], acceleration, p, _clip)
    reward = (100.0 if terminated else 0) - math.pow(action[0], 2) * 0.1
    return np.array([position, velocity], dtype=np.float32), reward, terminated


def _car_observe(state: Any) -> HostArray:
    """Either mountain car's observation `[2]` float32: (position, velocity)."""
    return np.array(state, dtype=np.float32)


# --- Pendulum --------------------------------------------------------------------------------


def _pendulum_spaces(p: Any) -> tuple[spaces.Space, spaces.Box]:
    """Gymnasium's Pendulum spaces: one torque; cosine, sine and bounded velocity `[3]`."""
    return _action_box(*pendulum.action_bounds(p)), _box([1.0, 1.0, p.max_speed])


def _pendulum_initial(np_random: np.random.Generator, p: Any, options: dict[str, Any] | None
                      ) -> HostArray:
    """Gymnasium's draw: theta and theta_dot uniform within the bounds, which `options`
    ("x_init", "y_init") may set."""
    options = {} if options is None else options
    high = np.array([utils.verify_number_and_cast(options.get("x_init", p.reset_theta)),
                     utils.verify_number_and_cast(options.get("y_init", p.reset_theta_dot))])
    return np_random.uniform(low=-high, high=high)


def _pendulum_step(state: HostArray, action: Action, p: Any, np_random: np.random.Generator
                   ) -> tuple[HostArray, Any, bool]:
    """Gymnasium's `PendulumEnv.step`: (state float64 `[2]`, reward numpy float64, False)."""
    th, thdot = state
    u = np.clip(action, -p.max_torque, p.max_torque)[0]
    costs = pendulum.angle_normalize(th) ** 2 + 0.1 * thdot**2 + 0.001 * (u**2)
    newthdot = thdot + (3 * p.gravity / (2 * p.length) * np.sin(th)
                        + 3.0 / (p.mass * p.length**2) * u) * p.dt
    newthdot = np.clip(newthdot, -p.max_speed, p.max_speed)
    return np.array([th + newthdot * p.dt, newthdot]), -costs, False


def _pendulum_observe(state: HostArray) -> HostArray:
    """Gymnasium's Pendulum observation `[3]` float32: cos theta, sin theta, theta_dot."""
    return np.array([np.cos(state[0]), np.sin(state[0]), state[1]], dtype=np.float32)


_DYNAMICS = {
    acrobot: _Dynamics(_acrobot_spaces, _acrobot_initial, _acrobot_step, _acrobot_observe, 15),
    mountain_car: _Dynamics(lambda p: _car_spaces(p, spaces.Discrete(mountain_car.NUM_ACTIONS)),
                            _car_initial, _mountain_car_step, _car_observe, 30),
    continuous_mountain_car: _Dynamics(
        lambda p: _car_spaces(p, _action_box(*continuous_mountain_car.action_bounds(p))),
        _car_initial, _continuous_car_step, _car_observe, 30),
    pendulum: _Dynamics(_pendulum_spaces, _pendulum_initial, _pendulum_step, _pendulum_observe,
                        30),
}
NAMES = tuple(module.NAME for module in _DYNAMICS)  # the Gymnasium ids of the four


def _check_action(action: Action, action_space: spaces.Space) -> None:
    """A ValueError unless `action` is one of the discrete `action_space`, or one finite number
    shaped `[1]` for a continuous one (any finite value: the step clips it)."""
    if isinstance(action_space, spaces.Discrete):
        if not action_space.contains(action):
            raise ValueError(f"action: must be an integer in [0, {action_space.n}), "
                             f"got {shown(action)}")
        return
    value = np.asarray(action)
    if value.shape != (1,) or value.dtype.kind not in "iuf" or not np.isfinite(value).all():
        raise ValueError(f"action: must be one finite number, shaped (1,), got {shown(action)}")


class ClassicControlEnv(gymnasium.Env):
    """Acrobot, MountainCar, MountainCarContinuous or Pendulum, after its `env_params`, stepped
    as Gymnasium's env of the same name, for which it is a drop-in.

    As Gymnasium's, it never truncates by itself: `gymnasium.make` adds the `TimeLimit` wrapper
    (the preset's `max_steps`), so `env_params.max_steps` plays no part here. It does not render.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, env_params: Any, render_mode: str | None = None,
                 task: str | None = None) -> None:
        """Creates the environment.

        Args:
          env_params: the params of one of the four environments (`jaxpg.envs`), such as
            `pendulum.make_params(gravity=9.81)`, or the name of its preset (`NAMES`).
          render_mode: None.
          task: optional: the name (`NAMES`) of the environment that `env_params` must be, as
            the id `jaxpg/{task}` registers it: `gymnasium.make` replaces `env_params` with the
            caller's, whose other environment would play under the id's time limit.

        Raises:
          ValueError: for a render mode, an unknown name, or `env_params` that are invalid or
            another environment's (CartPole's: `jaxpg.envs.gym.CartPoleEnv`; another than
            `task`'s).
        """
        if render_mode is not None:
            raise ValueError(f"render_mode: must be None (no rendering), got {render_mode!r}")
        if isinstance(env_params, str):
            if env_params not in NAMES:
                raise ValueError(f"env_params: expected one of {', '.join(NAMES)} or its "
                                 f"params, got {shown(env_params)}")
            env_params = envs.MODULES[env_params].make_params(env_params)
        module = envs.module_of(env_params)
        if module not in _DYNAMICS:
            raise ValueError(f"env_params: expected the params of one of {', '.join(NAMES)}, "
                             f"got {type(env_params).__name__}")
        if task is not None and module is not envs.MODULES[check_choice("task", task, NAMES)]:
            raise ValueError(f"env_params: jaxpg/{task} plays {task}, expected its name or "
                             f"params, got {module.NAME}'s")
        module.check_params(env_params)
        self.env_params = env_params
        self._params = _host_params(env_params)
        self._dynamics = _DYNAMICS[module]
        self.metadata = {**self.metadata, "render_fps": self._dynamics.render_fps}
        self.render_mode = render_mode
        self.action_space, self.observation_space = self._dynamics.make_spaces(self._params)
        self.state: State | None = None  # as Gymnasium's env holds it; None before reset

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[HostArray, dict[str, Any]]:
        """Starts an episode, drawing the initial state as Gymnasium's env does; `options` may
        set its bounds as Gymnasium's ("low" and "high"; Pendulum's "x_init" and "y_init").

        Returns:
          (obs float32 `[K]`, {}).
        """
        super().reset(seed=seed)
        self.state = self._dynamics.initial(self.np_random, self._params, options)
        return self._dynamics.observe(self.state), {}

    def step(self, action: Action) -> tuple[HostArray, Any, bool, bool, dict[str, Any]]:
        """One step.

        Args:
          action: an integer of the action space, or one number `[1]` for a continuous one,
            clipped to its range.

        Returns:
          (obs float32 `[K]`, reward, terminated, False, {}), the reward of the type Gymnasium's
          env gives (Pendulum's a numpy float64, the others' a float).

        Raises:
          ValueError: for an action outside the discrete space, or not one finite number.
          gymnasium.error.ResetNeeded: before the first `reset`.
        """
        _check_action(action, self.action_space)
        if self.state is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        self.state, reward, terminated = self._dynamics.step(self.state, action, self._params,
                                                             self.np_random)
        return self._dynamics.observe(self.state), reward, terminated, False, {}


def register() -> None:
    """Registers `jaxpg/Acrobot-v1`, `jaxpg/MountainCar-v0`, `jaxpg/MountainCarContinuous-v0`
    and `jaxpg/Pendulum-v1` with Gymnasium (idempotent).

    `import jaxpg` has registered them already, as `gymnasium` was imported: each has
    `ClassicControlEnv` as entry point with the task's name as `env_params` and `task`, and the
    time limit and reward threshold of Gymnasium's id of the same name;
    `gymnasium.make(id, env_params=...)` sets other physics of that task.
    """
    _register_ids(gymnasium)
