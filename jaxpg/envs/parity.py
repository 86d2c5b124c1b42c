"""The parity harness of Acrobot, both mountain cars and Pendulum against Gymnasium's own.

Steps are compared re-synced: Gymnasium's environment (`gymnasium.make` of the task's id, its
physics set to jaxpg's params) is set to each of N states and stepped once, and jaxpg's pure step,
vmapped, takes the same steps from the same states. The states are float32 numbers (as
Gymnasium's Acrobot and MountainCarContinuous hold them), so that float32 and float64 start from
the same values; Gymnasium computes in float64 either way. jaxpg's new states must lie within
1e-5 (float32) or 1e-12 (float64) of Gymnasium's, relative above each value's scale; rewards
within the same; truncations equal; terminations equal except where Gymnasium's new state lies
within the float32 step's own error of a threshold ("near threshold", not a failure). Resets are
compared as distributions: the same ranges, means and shapes.

CartPole's harness, which also plays whole episodes, is `jaxpg.envs.conformance`; it steps
both sides with `step_gymnasium` and `step_jaxpg` here (a `Task`).
"""

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any, NamedTuple

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

from jaxpg.envs import acrobot, continuous_mountain_car, mountain_car, pendulum
from jaxpg.validation import check_int

MAX_STATES = 2**24  # drawn per variant at most: each variant holds them in float64
EDGE = 0.1  # the share of values drawn at an end of their range instead of inside it
FLOAT32_TOLERANCE = 1e-5  # the largest relative error of a float32 step, where well-conditioned
FLOAT64_TOLERANCE = 1e-12
RESET_P_VALUE = 1e-3  # the least Kolmogorov-Smirnov p-value of a reset value's two samples
RESET_SIGMAS = 5.0  # the most standard errors between the two samples' means
PI = math.pi


class Outcome(NamedTuple):
    """N steps' results as numpy arrays."""

    values: np.ndarray  # [N, K] the new states
    reward: np.ndarray  # [N]
    terminated: np.ndarray  # [N] bool
    truncated: np.ndarray  # [N] bool


@dataclasses.dataclass(frozen=True)
class Task:
    """An environment as `step_gymnasium` and `step_jaxpg` step it: a `Case`, or CartPole's
    (`jaxpg.envs.conformance.TASK`).

    Attributes:
      module: the jaxpg module.
      state: its state class, with `from_array` and `to_array`.
      restart: optional, keyword only: `(Gymnasium's unwrapped env) -> None`, run before each
        step to clear what the env keeps of earlier steps (CartPole's `steps_beyond_terminated`).
    """

    module: ModuleType
    state: Any  # a state class, with `from_array`
    restart: Callable[[Any], None] | None = dataclasses.field(default=None, kw_only=True)

    def gym_action(self, action: Any) -> Any:
        """An action as Gymnasium takes it: an int, or a float64 `[1]` (see `pendulum`)."""
        if hasattr(self.module, "NUM_ACTIONS"):
            return int(action)
        return np.array([action], np.float64)


@dataclasses.dataclass(frozen=True)
class Case(Task):
    """How one environment is drawn, stepped in Gymnasium and compared: a `Task` whose
    Gymnasium environment keeps nothing of earlier steps (no `restart`).

    Attributes:
      module: the jaxpg module.
      state: its state class.
      low: `[K]` the low end of each state value's range (drawn uniform, or at an end).
      high: `[K]` the high end.
      actions: `(numpy generator, n) -> actions [n]`.
      scale: `[K]` each value's magnitude below which its errors count absolutely.
      angles: the state values compared modulo a turn (Gymnasium wraps them).
      configure: `(Gymnasium's env, env_params) -> None` sets the env's physics to `env_params`.
      near: `(Gymnasium's new values [N, K], env_params, window [N, K]) -> [N] bool`: the steps
        whose values lie within `window` of a threshold of the termination, where a float32 step
        within that distance of Gymnasium's may decide otherwise.
      variants: named `env_params`, the first the preset.
      aim: optional: (value index, target field) of the states moved to land near a threshold.
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    actions: Callable[[np.random.Generator, int], np.ndarray]
    scale: tuple[float, ...]
    angles: tuple[int, ...]
    configure: Callable[[Any, Any], None]
    near: Callable[[np.ndarray, Any, np.ndarray], np.ndarray]
    variants: dict[str, Any]
    aim: tuple[int, str] | None = None


def set_attributes(names: dict[str, str]) -> Callable[[Any, Any], None]:
    """A `Case.configure` that sets each attribute `names[field]` to the params' `field`.

    Args:
      names: Gymnasium's attribute name by params field.

    Returns:
      `(Gymnasium's env, env_params) -> None`.
    """
    def configure(env: Any, env_params: Any) -> None:
        for field, attribute in names.items():
            setattr(env, attribute, float(getattr(env_params, field)))
    return configure


def configure_acrobot(env: Any, env_params: acrobot.AcrobotParams) -> None:
    """Sets Gymnasium's `AcrobotEnv` to `env_params` (its upper-case class attributes).

    Raises:
      ValueError: naming `env_params` where gravity is not 9.8, a number in Gymnasium's `_dsdt`.
    """
    if float(env_params.gravity) != 9.8:
        raise ValueError(f"env_params: Gymnasium's Acrobot fixes gravity at 9.8, got "
                         f"{float(env_params.gravity)}")
    set_attributes({name: name.upper() for name in (
        "link_length_1", "link_mass_1", "link_mass_2", "link_com_pos_1", "link_com_pos_2",
        "link_moi", "max_vel_1", "max_vel_2")} | {"dt": "dt"})(env, env_params)
    env.AVAIL_TORQUE = [-float(env_params.torque), 0.0, float(env_params.torque)]
    env.book_or_nips = env_params.book_or_nips


def near_acrobot(values: np.ndarray, env_params: Any, window: np.ndarray) -> np.ndarray:
    """`Case.near` of Acrobot: the tip's height within reach of 1 (its goal)."""
    # The height -cos(t1) - cos(t1 + t2) moves by at most 2 |d t1| + |d t2| for changes d.
    height = -np.cos(values[:, 0]) - np.cos(values[:, 0] + values[:, 1])
    return np.abs(height - 1.0) <= 3 * window[:, :2].max(axis=1)


def near_goal(values: np.ndarray, env_params: Any, window: np.ndarray) -> np.ndarray:
    """`Case.near` of the mountain cars: the position, or the velocity past the goal, at its
    threshold."""
    (position, velocity), (position_window, velocity_window) = values.T, window.T
    goal, goal_velocity = float(env_params.goal_position), float(env_params.goal_velocity)
    return ((np.abs(position - goal) <= position_window)
            | ((position >= goal - position_window)
               & (np.abs(velocity - goal_velocity) <= velocity_window)))


def never(values: np.ndarray, env_params: Any, window: np.ndarray) -> np.ndarray:
    """`Case.near` of a task that never terminates (Pendulum)."""
    return np.zeros(len(values), bool)


def discrete(num: int) -> Callable[[np.random.Generator, int], np.ndarray]:
    """`Case.actions`: integers uniform in [0, num)."""
    return lambda rng, n: rng.integers(0, num, n)


def continuous(limit: float, beyond: float) -> Callable[[np.random.Generator, int], np.ndarray]:
    """`Case.actions`: uniform in [-beyond, beyond] (past the clip at `limit`), a share `EDGE`
    exactly at +-limit."""
    def draw_actions(rng: np.random.Generator, n: int) -> np.ndarray:
        actions = rng.uniform(-beyond, beyond, n)
        at_limit = rng.random(n) < EDGE
        return np.where(at_limit, rng.choice([-limit, limit], n), actions)
    return draw_actions


CASES = {
    acrobot.NAME: Case(
        acrobot, acrobot.AcrobotState, (-PI, -PI, -4 * PI, -9 * PI), (PI, PI, 4 * PI, 9 * PI),
        discrete(3),
        scale=(PI, PI, 4 * PI, 9 * PI), angles=(0, 1), configure=configure_acrobot,
        near=near_acrobot,
        variants={"preset": acrobot.V1, "nips": acrobot.V1.replace(book_or_nips="nips"),
                  "physics": acrobot.V1.replace(
                      link_mass_2=2.0, link_length_1=1.5, link_com_pos_1=0.7, link_moi=0.8,
                      dt=0.1, max_vel_1=3 * PI, torque=2.0, max_steps=300)}),
    mountain_car.NAME: Case(
        mountain_car, mountain_car.MountainCarState, (-1.2, -0.07), (0.6, 0.07), discrete(3),
        scale=(1.2, 0.07), angles=(),
        configure=set_attributes({name: name for name in (
            "min_position", "max_position", "max_speed", "goal_position", "goal_velocity",
            "force", "gravity")}),
        near=near_goal, aim=(0, "goal_position"),
        variants={"preset": mountain_car.V0, "physics": mountain_car.V0.replace(
            force=0.0015, gravity=0.003, max_speed=0.05, goal_position=0.4,
            goal_velocity=0.01, max_steps=100)}),
    pendulum.NAME: Case(
        pendulum, pendulum.PendulumState, (-4 * PI, -8.0), (4 * PI, 8.0), continuous(2.0, 3.0),
        scale=(PI, 8.0),
        angles=(), configure=set_attributes({
            "max_speed": "max_speed", "max_torque": "max_torque", "dt": "dt", "gravity": "g",
            "mass": "m", "length": "l"}),
        near=never,
        variants={"preset": pendulum.V1, "physics": pendulum.V1.replace(
            gravity=9.81, mass=1.3, length=0.8, dt=0.04, max_speed=6.0, max_torque=1.5,
            max_steps=300)}),
    continuous_mountain_car.NAME: Case(
        continuous_mountain_car, continuous_mountain_car.ContinuousMountainCarState,
        (-1.2, -0.07), (0.6, 0.07), continuous(1.0, 1.5),
        scale=(1.2, 0.07), angles=(),
        configure=set_attributes({name: name for name in (
            "min_action", "max_action", "min_position", "max_position", "max_speed",
            "goal_position", "goal_velocity", "power")}),
        near=near_goal, aim=(0, "goal_position"),
        variants={"preset": continuous_mountain_car.V0, "physics": continuous_mountain_car.V0
                  .replace(power=0.002, max_speed=0.05, goal_position=0.5, goal_velocity=0.005,
                           min_action=-0.8, max_action=0.8, max_steps=400)}),
}


# ---------------------------------------------------------------- both sides of a step


def make_gymnasium(case: Case, env_params: Any) -> gymnasium.Env:
    """`gymnasium.make` of the case's id, its physics and TimeLimit those of `env_params`.

    Args:
      case: the task.
      env_params: scalar params of the case's module.

    Returns:
      The environment, reset (its wrappers refuse a step before the first reset).
    """
    gym_env = gymnasium.make(case.module.NAME, max_episode_steps=int(env_params.max_steps),
                             disable_env_checker=True)
    gym_env.reset(seed=0)
    case.configure(gym_env.unwrapped, env_params)
    return gym_env


def step_gymnasium(task: Task, gym_env: gymnasium.Env, values: np.ndarray, times: np.ndarray,
                   actions: np.ndarray) -> Outcome:
    """Gymnasium's step from each of N states set on one environment.

    Each float64 state goes into the unwrapped env's `state` (then `task.restart`, if any) and its
    step count into the TimeLimit, so Gymnasium's own `step`s decide everything.

    Args:
      task: a `Case` or CartPole's `conformance.TASK`; its `gym_action` casts each action.
      gym_env: an environment of `make_gymnasium` or `evaluation.make_gymnasium_env`, its
        TimeLimit outermost; reset here first if it never was (its wrappers refuse a step before).
      values: `[N, K]` states.
      times: `[N]` steps already taken in each episode.
      actions: `[N]` actions.

    Returns:
      `Outcome` of the N steps, the states in float64.
    """
    reference: Any = gym_env.unwrapped
    if getattr(reference, "state", None) is None:
        gym_env.reset(seed=0)
    out = Outcome(np.empty(values.shape), np.empty(len(values)), np.empty(len(values), bool),
                  np.empty(len(values), bool))
    for i, (state, time, action) in enumerate(zip(values, times, actions, strict=True)):
        reference.state = np.array(state, np.float64)
        if task.restart is not None:
            task.restart(reference)
        gym_env._elapsed_steps = int(time)  # type: ignore[attr-defined]
        _, out.reward[i], out.terminated[i], out.truncated[i], _ = gym_env.step(
            task.gym_action(action))
        out.values[i] = np.asarray(reference.state, np.float64)
    return out


def batched_step(module: ModuleType, env_params: Any) -> Callable[..., Any]:
    """The module's step, jitted and vmapped over states, actions and the numbers of
    `env_params` that are arrays.

    Args:
      module: an environment module.
      env_params: its params, whose array leaves `[N]` are vmapped over.

    Returns:
      `(state [N], action [N], env_params) -> (obs, state, reward, terminated, truncated)`.
    """
    return _jitted_step(module, jax.tree.map(lambda leaf: 0 if np.ndim(leaf) else None,
                                             env_params))


@functools.cache
def _jitted_step(module: ModuleType, params_axes: Any) -> Callable[..., Any]:
    """`batched_step`'s function, one per module and axes: compiled once per shape."""
    return jax.jit(jax.vmap(module.step, in_axes=(0, 0, params_axes)))


def step_jaxpg(task: Task, env_params: Any, values: np.ndarray, times: np.ndarray,
               actions: np.ndarray) -> Outcome:
    """jaxpg's vmapped step from N states, in JAX's default float dtype (jaxpg's).

    Args:
      task: a `Case` or CartPole's `conformance.TASK`.
      env_params: the params; its numbers that are arrays `[N]` are vmapped over with the states.
      values: `[N, K]` states (rounded to JAX's default float).
      times: `[N]` steps already taken in each episode.
      actions: `[N]` actions.

    Returns:
      `Outcome` of the N steps, the states in JAX's default float.
    """
    return Outcome(*(np.asarray(leaf) for leaf in _step_values(
        task.module, task.state, np.asarray(values, jnp.result_type(float)), times, actions,
        env_params)))


@functools.partial(jax.jit, static_argnums=(0, 1))
def _step_values(module: ModuleType, state: Any, values: jax.Array, times: jax.Array,
                 actions: jax.Array, env_params: Any) -> tuple[jax.Array, ...]:
    """`step_jaxpg`'s compiled part, from arrays to arrays: (states `[N, K]`, reward,
    terminated, truncated); compiled once per module, params' static fields and shape."""
    _, new, reward, terminated, truncated = batched_step(module, env_params)(
        state.from_array(values, times), actions, env_params)
    return new.to_array(), reward, terminated, truncated


def draw(case: Case, env_params: Any, rng: np.random.Generator, n: int
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """N float32 states, inside their ranges and at their ends, with times and actions.

    Times are uniform in [0, 1.2 max_steps), so that the step limit falls inside. With
    `case.aim`, a sixth of the states are moved (by Gymnasium's own steps) to land within +-2e-6
    of the threshold, some 30 float32 spacings there.

    Args:
      case: the task.
      env_params: scalar params.
      rng: the numpy generator that draws everything.
      n: N.

    Returns:
      (states `[N, K]` float32 numbers as float64, times `[N]`, actions `[N]`).
    """
    low, high = np.array(case.low), np.array(case.high)
    values = rng.uniform(low, high, (n, len(low)))
    at_end = rng.random(values.shape) < EDGE
    values = np.where(at_end, np.where(rng.random(values.shape) < 0.5, low, high), values)
    actions = case.actions(rng, n)
    times = rng.integers(0, int(1.2 * env_params.max_steps), n)
    if case.aim is not None:
        index, field = case.aim
        aimed = np.arange(n) < n // 6
        target = float(getattr(env_params, field)) + rng.uniform(-2e-6, 2e-6, aimed.sum())
        gym_env = make_gymnasium(case, env_params)
        for _ in range(3):  # Newton's steps: the new position moves one for one with the old
            landed = step_gymnasium(case, gym_env, values[aimed], times[aimed], actions[aimed])
            values[aimed, index] += target - landed.values[:, index]
    return values.astype(np.float32).astype(np.float64), times, actions


def differences(case: Case, got: Outcome, want: Outcome) -> np.ndarray:
    """`[N, K]` |got - want| of each new state value, angles compared modulo a turn."""
    diff = got.values - want.values
    for i in case.angles:
        diff[:, i] = np.remainder(diff[:, i] + PI, 2 * PI) - PI
    return np.abs(diff)


def float32_tolerances(case: Case, env_params: Any, values: np.ndarray, times: np.ndarray,
                       actions: np.ndarray, new_values: np.ndarray) -> np.ndarray:
    """Per step and value: 1e-5, or ten times what float32-sized changes of the state can change
    the result by, where that is more (the step is ill-conditioned there).

    The change is the first-order one, each value moved by half a float32 spacing (2^-24
    relative) in the worst direction: sum_j |d new_i / d x_j| |x_j| 2^-24, relative as the
    errors are. The Jacobian is the float64 step's (equal to Gymnasium's to 1e-12). Only
    Acrobot needs it: its Runge-Kutta step over 0.2 s from its fastest states multiplies input
    changes up to ~1000-fold (Gymnasium itself, its float64 state moved by 2^-24, moves its
    result by up to 6e-5 there), and no float32 arithmetic holds 1e-5; float32 errors measured
    up to 3 times this first-order change.

    Args:
      case: the task.
      env_params: scalar params.
      values: `[N, K]` states.
      times: `[N]` steps taken.
      actions: `[N]` actions.
      new_values: `[N, K]` Gymnasium's new states.

    Returns:
      `[N, K]` relative tolerances.
    """
    with jax.enable_x64(True):
        jacobians = np.asarray(_jacobians(case.module, case.state)(values, times, actions,
                                                                   env_params))
    change = (np.abs(jacobians) @ np.abs(values)[..., None])[..., 0] * 2.0**-24
    return np.maximum(FLOAT32_TOLERANCE,
                      10 * change / np.maximum(np.abs(new_values), case.scale))


@functools.cache
def _jacobians(module: ModuleType, state: Any) -> Callable[..., jax.Array]:
    """`(values [N, K], times [N], actions [N], env_params) -> [N, K, K]`: each step's Jacobian
    of the new state by the old, compiled once per module and static fields."""
    def new(value: jax.Array, time: jax.Array, action: jax.Array, env_params: Any) -> jax.Array:
        return module.step(state.from_array(value, time), action, env_params)[1].to_array()

    return jax.jit(jax.vmap(jax.jacfwd(new), in_axes=(0, 0, 0, None)))


# ---------------------------------------------------------------- comparing them


@dataclasses.dataclass(frozen=True)
class Comparison:
    """jaxpg's N steps against Gymnasium's from the same states, value by value.

    Attributes:
      value_errors: `[N, K]` |jaxpg - Gymnasium| / max(|Gymnasium|, scale) of the new states.
      tolerance: `[N, K]` the largest of each allowed (`float32_tolerances`, or 1e-12).
      reward_errors: `[N]` |jaxpg - Gymnasium| / max(|Gymnasium|, 1) of the rewards.
      flipped: `[N]` bool: the terminations differ.
      excused: `[N]` bool: Gymnasium's new state lies within float32's reach of a threshold.
      truncated_differs: `[N]` bool: the truncations differ.
      terminated: `[N]` bool: Gymnasium's terminations (the coverage).
      truncated: `[N]` bool: Gymnasium's truncations.
    """

    value_errors: np.ndarray
    tolerance: np.ndarray
    reward_errors: np.ndarray
    flipped: np.ndarray
    excused: np.ndarray
    truncated_differs: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray

    @property
    def worst(self) -> float:
        """The largest error over its tolerance: within where <= 1."""
        return float((self.value_errors / self.tolerance).max(initial=0.0))

    @property
    def near_threshold(self) -> int:
        """Steps whose terminations differ where float32 may decide a threshold otherwise."""
        return int((self.flipped & self.excused).sum())

    @property
    def terminated_mismatches(self) -> int:
        """Steps whose terminations differ away from a threshold."""
        return int((self.flipped & ~self.excused).sum())

    @property
    def reward_mismatches(self) -> int:
        """Steps whose rewards differ by more than the least tolerance (flipped steps aside: a
        termination decides a reward)."""
        return int((self.reward_errors[~self.flipped] > self.tolerance.min(initial=1.0)).sum())

    @property
    def ok(self) -> bool:
        """Every value within its tolerance, and no reward, termination or truncation apart."""
        return (self.worst <= 1.0 and self.reward_mismatches == 0
                and self.terminated_mismatches == 0 and not self.truncated_differs.any())


def compare(case: Case, env_params: Any, values: np.ndarray, times: np.ndarray,
            actions: np.ndarray, ours: Outcome, theirs: Outcome) -> Comparison:
    """`Comparison` of jaxpg's steps against Gymnasium's from the same states and actions.

    In float32 each value's tolerance is `float32_tolerances` and a termination may differ where
    Gymnasium's new state lies within the step's own error (and 2 float32 spacings) of a
    threshold; in float64 the tolerance is 1e-12 and every termination must agree.

    Args:
      case: the task.
      env_params: scalar params of both.
      values: `[N, K]` the states stepped from.
      times: `[N]` steps taken.
      actions: `[N]` actions.
      ours: jaxpg's `Outcome` (`step_jaxpg`), its dtype deciding the tolerance.
      theirs: Gymnasium's `Outcome` (`step_gymnasium`).

    Returns:
      `Comparison`.
    """
    difference = differences(case, ours, theirs)
    if ours.values.dtype == np.float64:
        tolerance = np.full(values.shape, FLOAT64_TOLERANCE)
        excused = np.zeros(len(values), bool)
    else:
        tolerance = float32_tolerances(case, env_params, values, times, actions, theirs.values)
        spacing = np.spacing(np.abs(theirs.values).astype(np.float32))
        excused = case.near(theirs.values, env_params, difference + 2 * spacing)
    return Comparison(
        value_errors=difference / np.maximum(np.abs(theirs.values), case.scale),
        tolerance=tolerance,
        reward_errors=(np.abs(ours.reward - theirs.reward)
                       / np.maximum(np.abs(theirs.reward), 1.0)),
        flipped=ours.terminated != theirs.terminated,
        excused=excused,
        truncated_differs=ours.truncated != theirs.truncated,
        terminated=theirs.terminated,
        truncated=theirs.truncated,
    )


# ---------------------------------------------------------------- resets


def reset_jaxpg(module: ModuleType, seed: int, n: int) -> np.ndarray:
    """jaxpg's resets of the module's first preset from n keys split from `seed`.

    Returns:
      `[n, K]` float64 states.
    """
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    _, state = jax.jit(jax.vmap(module.reset, in_axes=(0, None)))(
        keys, next(iter(module.PRESETS.values())))
    return np.asarray(state.to_array(), np.float64)


def reset_gymnasium(case: Case, n: int) -> np.ndarray:
    """Gymnasium's resets of the case's preset, `reset(seed=i)` for i in [0, n).

    Returns:
      `[n, K]` float64 states.
    """
    gym_env = make_gymnasium(case, next(iter(case.variants.values())))
    states = np.empty((n, len(case.low)))
    for seed in range(n):
        gym_env.reset(seed=seed)
        states[seed] = np.asarray(gym_env.unwrapped.state, np.float64)  # type: ignore[attr-defined]
    return states


class ResetComparison(NamedTuple):
    """Two samples of resets compared value by value."""

    constant: np.ndarray  # [K] bool: Gymnasium's value never changes (the cars' velocity)
    mean_sigmas: np.ndarray  # [K] |mean difference| / its standard error under Gymnasium's range
    p_value: np.ndarray  # [K] the two-sample Kolmogorov-Smirnov p-value (1 where constant)
    equal_constants: bool  # jaxpg's values equal Gymnasium's where those never change

    @property
    def ok(self) -> bool:
        """Means within `RESET_SIGMAS` standard errors, p-values >= `RESET_P_VALUE`."""
        return (self.equal_constants and bool((self.mean_sigmas < RESET_SIGMAS).all())
                and bool((self.p_value > RESET_P_VALUE).all()))


def compare_resets(ours: np.ndarray, theirs: np.ndarray) -> ResetComparison:
    """Whether jaxpg's resets are distributed as Gymnasium's.

    The mean of n uniforms has standard deviation ptp / sqrt(12 n), so the difference of the two
    means ptp / sqrt(12) * sqrt(1/n + 1/m); the KS p-value of the same distribution is uniform, of
    another range or a skew ~0.

    Args:
      ours: `[n, K]` jaxpg's reset states.
      theirs: `[m, K]` Gymnasium's.

    Returns:
      `ResetComparison`.
    """
    spread = np.ptp(theirs, axis=0)
    constant = spread == 0
    standard_error = (np.where(constant, 1.0, spread)
                      * math.sqrt((1 / len(ours) + 1 / len(theirs)) / 12))
    mean_sigmas = np.where(constant, 0.0,
                           np.abs(ours.mean(axis=0) - theirs.mean(axis=0)) / standard_error)
    p_value = np.array([1.0 if fixed else scipy.stats.ks_2samp(mine, gyms).pvalue
                        for fixed, mine, gyms in zip(constant, ours.T, theirs.T, strict=True)])
    equal_constants = bool((ours[:, constant] == theirs[:1, constant]).all())
    return ResetComparison(constant, mean_sigmas, p_value, equal_constants)


# ---------------------------------------------------------------- the report


@dataclasses.dataclass(frozen=True)
class VariantParity:
    """One variant's re-synced steps, summarised."""

    name: str  # a key of the case's `variants`
    comparison: Comparison


@dataclasses.dataclass(frozen=True)
class Report:
    """Conformance of one task: every variant's steps and the resets."""

    env: str  # the Gymnasium id
    dtype: str  # jaxpg's float dtype
    variants: tuple[VariantParity, ...]
    resets: ResetComparison
    reset_draws: int  # resets drawn on each side

    @property
    def ok(self) -> bool:
        """Whether every variant and the resets hold."""
        return self.resets.ok and all(v.comparison.ok for v in self.variants)

    def format(self) -> str:
        """A text table, one row per variant, the resets, and a verdict."""
        floor = FLOAT32_TOLERANCE if self.dtype == "float32" else FLOAT64_TOLERANCE
        rows = [[v.name, len(c.flipped), int(c.terminated.sum()), int(c.truncated.sum()),
                 f"{c.value_errors.max(initial=0.0):.2e}", f"{c.worst:.3f}",
                 int((c.tolerance > floor).any(axis=1).sum()), c.reward_mismatches,
                 c.terminated_mismatches, int(c.truncated_differs.sum()), c.near_threshold,
                 "yes" if c.ok else "NO"]
                for v in self.variants for c in (v.comparison,)]
        resets = self.resets
        return format_table(
            [f"jaxpg {self.env} ({self.dtype}) vs Gymnasium (float64), re-synced on drawn "
             "states (ranges' ends, step limits and thresholds included):",
             f"max relative error (above each value's scale) over its tolerance must be <= 1 "
             f"(tolerance {floor:g}; 'ill' states: the step's own float32 sensitivity allows "
             "more); mismatches of reward / terminated / truncated must be 0",
             "(near: terminated differed where Gymnasium's state is within the float32 step's "
             "error of a threshold; not a failure).",
             f"Resets: {self.reset_draws} draws each; least KS p-value "
             f"{resets.p_value.min():.3g} (>= {RESET_P_VALUE:g}), mean apart by at most "
             f"{resets.mean_sigmas.max():.2f} standard errors (< {RESET_SIGMAS:g}), constant "
             f"values {'equal' if resets.equal_constants else 'DIFFER'}: "
             + ("yes" if resets.ok else "NO")],
            [("variant", -10), ("states", 7), ("term", 6), ("trunc", 6), ("max error", 9),
             ("/tol", 6), ("ill", 5), ("reward", 6), ("term", 4), ("trunc", 5), ("near", 4),
             ("ok", 3)],
            rows, self.ok)


def format_table(notes: Sequence[str], columns: Sequence[tuple[str, int]],
                 rows: Sequence[Sequence[Any]], ok: bool) -> str:
    """A conformance report: its notes, a table and the verdict line.

    Args:
      notes: lines above the table.
      columns: (name, width) of each column; a negative width aligns it left.
      rows: each row's cells, one per column.
      ok: the verdict.

    Returns:
      The text, ending "conformance: OK" or "conformance: FAILED".
    """
    def line(cells: Sequence[Any]) -> str:
        return " ".join(f"{str(cell):{'<' if width < 0 else '>'}{abs(width)}}"
                        for cell, (_, width) in zip(cells, columns, strict=True))

    header = line([name for name, _ in columns])
    return "\n".join([*notes, "", header, "-" * len(header), *map(line, rows), "",
                      "conformance: " + ("OK" if ok else "FAILED")])


def check(env: str, states: int = 10_000, seed: int = 0, reset_draws: int = 4000) -> Report:
    """Compares every variant of one task with Gymnasium, re-synced, and its resets.

    Args:
      env: a key of `CASES` (a Gymnasium id).
      states: N, the states drawn and stepped per variant.
      seed: seeds the draw (a numpy generator) and jaxpg's reset keys.
      reset_draws: resets drawn on each side.

    Returns:
      `Report` in JAX's default float dtype; `report.ok` is False where anything disagrees.

    Raises:
      ValueError: one line naming the argument, for an unknown `env` or a count out of range.
    """
    if env not in CASES:
        raise ValueError(f"env: allowed {', '.join(CASES)}; got {env!r}")
    check_int("states", states, 1, MAX_STATES)
    check_int("seed", seed, 0, 2**32)
    check_int("reset_draws", reset_draws, 2)
    case = CASES[env]
    variants = []
    for name, env_params in case.variants.items():
        values, times, actions = draw(case, env_params, np.random.default_rng(seed), states)
        theirs = step_gymnasium(case, make_gymnasium(case, env_params), values, times, actions)
        ours = step_jaxpg(case, env_params, values, times, actions)
        variants.append(VariantParity(name, compare(case, env_params, values, times, actions,
                                                    ours, theirs)))
    resets = compare_resets(reset_jaxpg(case.module, seed, reset_draws),
                            reset_gymnasium(case, reset_draws))
    return Report(env, np.dtype(jnp.result_type(float)).name, tuple(variants), resets,
                  reset_draws)
