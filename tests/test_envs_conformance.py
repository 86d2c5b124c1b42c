"""jaxpg's classic-control environments (`jaxpg.envs`) against Gymnasium's, which run beside them.

Steps are compared re-synced: Gymnasium's environment is set to each of 10^4 states and stepped
once, and jaxpg's pure step, vmapped, takes the same steps from the same states. The states are
float32 numbers (as Gymnasium's Acrobot and MountainCarContinuous hold them), so that float32 and
float64 start from the same values; Gymnasium computes in float64 either way.
"""

import dataclasses
import functools
import math
from collections.abc import Callable
from types import ModuleType
from typing import Any, NamedTuple

import chex
import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from gymnasium.envs.classic_control import acrobot as gym_acrobot

from jaxpg.envs import MODULES, acrobot, continuous_mountain_car, mountain_car, pendulum

N_STATES = 10_000
EDGE = 0.1  # the share of values drawn at an end of their range instead of inside it


class Outcome(NamedTuple):
    """N steps' results as numpy arrays: new states `[N, K]`, rewards, terminated, truncated."""

    values: np.ndarray
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray


@dataclasses.dataclass(frozen=True)
class Case:
    """How one environment is drawn, stepped in Gymnasium and compared.

    Attributes:
      module: the jaxpg module.
      state: its state class.
      low: `[K]` the low end of each state value's range (drawn uniform, or at an end).
      high: `[K]` the high end.
      actions: `n -> actions [n]` drawn with a numpy generator.
      scale: `[K]` each value's magnitude below which its errors count absolutely.
      angles: the state values compared modulo a turn (Gymnasium wraps them).
      configure: `(Gymnasium's env, env_params) -> None` sets the env's physics to `env_params`.
      near: `(Gymnasium's new values, env_params, window [N, K]) -> [N] bool`: the steps whose
        values lie within `window` of a threshold of the termination, where a float32 step
        within that distance of Gymnasium's may decide otherwise.
      aim: optional: (value index, target field) of the states moved to land near a threshold.
      variants: named `env_params`, the first the preset.
    """

    module: ModuleType
    state: type
    low: tuple[float, ...]
    high: tuple[float, ...]
    actions: Callable[[np.random.Generator, int], np.ndarray]
    scale: tuple[float, ...]
    angles: tuple[int, ...]
    configure: Callable[[Any, Any], None]
    near: Callable[[np.ndarray, Any, np.ndarray], np.ndarray]
    variants: dict[str, Any]
    aim: tuple[int, str] | None = None

    def gym_action(self, action: Any) -> Any:
        """An action as Gymnasium takes it: an int, or a float64 `[1]` (see `pendulum`)."""
        if hasattr(self.module, "NUM_ACTIONS"):
            return int(action)
        return np.array([action], np.float64)


def set_attributes(names: dict[str, str]) -> Callable[[Any, Any], None]:
    """`configure` for an env whose attribute `names[field]` is the field of the params."""
    def configure(env: Any, env_params: Any) -> None:
        for field, attribute in names.items():
            setattr(env, attribute, float(getattr(env_params, field)))
    return configure


def configure_acrobot(env: Any, env_params: acrobot.AcrobotParams) -> None:
    set_attributes({name: name.upper() for name in (
        "link_length_1", "link_mass_1", "link_mass_2", "link_com_pos_1", "link_com_pos_2",
        "link_moi", "max_vel_1", "max_vel_2")} | {"dt": "dt"})(env, env_params)
    env.AVAIL_TORQUE = [-float(env_params.torque), 0.0, float(env_params.torque)]
    env.book_or_nips = env_params.book_or_nips
    assert env_params.gravity == 9.8  # Gymnasium's `_dsdt` has it as a number


def near_acrobot(values: np.ndarray, env_params: Any, window: np.ndarray) -> np.ndarray:
    # The height -cos(t1) - cos(t1 + t2) moves by at most 2 |d t1| + |d t2| for changes d.
    height = -np.cos(values[:, 0]) - np.cos(values[:, 0] + values[:, 1])
    return np.abs(height - 1.0) <= 3 * window[:, :2].max(axis=1)


def near_goal(values: np.ndarray, env_params: Any, window: np.ndarray) -> np.ndarray:
    (position, velocity), (position_window, velocity_window) = values.T, window.T
    goal, goal_velocity = float(env_params.goal_position), float(env_params.goal_velocity)
    return ((np.abs(position - goal) <= position_window)
            | ((position >= goal - position_window)
               & (np.abs(velocity - goal_velocity) <= velocity_window)))


def never(values: np.ndarray, env_params: Any, window: np.ndarray) -> np.ndarray:
    return np.zeros(len(values), bool)


def discrete(num: int) -> Callable[[np.random.Generator, int], np.ndarray]:
    return lambda rng, n: rng.integers(0, num, n)


def continuous(limit: float, beyond: float) -> Callable[[np.random.Generator, int], np.ndarray]:
    """Actions uniform in [-beyond, beyond] (past the clip at `limit`), some exactly at +-limit."""
    def draw(rng: np.random.Generator, n: int) -> np.ndarray:
        actions = rng.uniform(-beyond, beyond, n)
        at_limit = rng.random(n) < EDGE
        return np.where(at_limit, rng.choice([-limit, limit], n), actions)
    return draw


PI = math.pi
CASES = {
    "acrobot": Case(
        acrobot, acrobot.AcrobotState, (-PI, -PI, -4 * PI, -9 * PI), (PI, PI, 4 * PI, 9 * PI),
        discrete(3),
        scale=(PI, PI, 4 * PI, 9 * PI), angles=(0, 1), configure=configure_acrobot,
        near=near_acrobot,
        variants={"preset": acrobot.V1, "nips": acrobot.V1.replace(book_or_nips="nips"),
                  "physics": acrobot.V1.replace(
                      link_mass_2=2.0, link_length_1=1.5, link_com_pos_1=0.7, link_moi=0.8,
                      dt=0.1, max_vel_1=3 * PI, torque=2.0, max_steps=300)}),
    "mountain_car": Case(
        mountain_car, mountain_car.MountainCarState, (-1.2, -0.07), (0.6, 0.07), discrete(3),
        scale=(1.2, 0.07), angles=(),
        configure=set_attributes({name: name for name in (
            "min_position", "max_position", "max_speed", "goal_position", "goal_velocity",
            "force", "gravity")}),
        near=near_goal, aim=(0, "goal_position"),
        variants={"preset": mountain_car.V0, "physics": mountain_car.V0.replace(
            force=0.0015, gravity=0.003, max_speed=0.05, goal_position=0.4,
            goal_velocity=0.01, max_steps=100)}),
    "pendulum": Case(
        pendulum, pendulum.PendulumState, (-4 * PI, -8.0), (4 * PI, 8.0), continuous(2.0, 3.0),
        scale=(PI, 8.0),
        angles=(), configure=set_attributes({
            "max_speed": "max_speed", "max_torque": "max_torque", "dt": "dt", "gravity": "g",
            "mass": "m", "length": "l"}),
        near=never,
        variants={"preset": pendulum.V1, "physics": pendulum.V1.replace(
            gravity=9.81, mass=1.3, length=0.8, dt=0.04, max_speed=6.0, max_torque=1.5,
            max_steps=300)}),
    "continuous_mountain_car": Case(
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
VARIANTS = [(name, variant) for name, case in CASES.items() for variant in case.variants]


# ---------------------------------------------------------------- both sides of a step


def make_gymnasium(case: Case, env_params: Any) -> gymnasium.Env:
    """`gymnasium.make` of the case's id, its physics and TimeLimit those of `env_params`."""
    gym_env = gymnasium.make(case.module.NAME, max_episode_steps=int(env_params.max_steps),
                             disable_env_checker=True)
    gym_env.reset(seed=0)  # the wrappers refuse a step before the first reset
    case.configure(gym_env.unwrapped, env_params)
    return gym_env


def step_gymnasium(case: Case, gym_env: gymnasium.Env, values: np.ndarray, times: np.ndarray,
                   actions: np.ndarray) -> Outcome:
    """Gymnasium's step from each of N states, its step count set in its TimeLimit."""
    out = Outcome(np.empty(values.shape), np.empty(len(values)), np.empty(len(values), bool),
                  np.empty(len(values), bool))
    for i, (state, time, action) in enumerate(zip(values, times, actions, strict=True)):
        gym_env.unwrapped.state = np.array(state, np.float64)
        gym_env._elapsed_steps = int(time)
        _, out.reward[i], out.terminated[i], out.truncated[i], _ = gym_env.step(
            case.gym_action(action))
        out.values[i] = np.asarray(gym_env.unwrapped.state, np.float64)
    return out


def batched_step(module: ModuleType, env_params: Any) -> Callable[..., Any]:
    """The module's step, jitted and vmapped over states, actions and the numbers of
    `env_params` that are arrays."""
    params_axes = jax.tree.map(lambda leaf: 0 if np.ndim(leaf) else None, env_params)
    return jax.jit(jax.vmap(module.step, in_axes=(0, 0, params_axes)))


def step_jaxpg(case: Case, env_params: Any, values: np.ndarray, times: np.ndarray,
               actions: np.ndarray) -> Outcome:
    """jaxpg's vmapped step from the same N states, in JAX's default float dtype.

    The numbers of `env_params` that are arrays `[N]` are vmapped over with the states.
    """
    state = case.state.from_array(np.asarray(values, jnp.result_type(float)), times)
    _, state, reward, terminated, truncated = batched_step(case.module, env_params)(
        state, jnp.asarray(actions), env_params)
    return Outcome(*(np.asarray(leaf) for leaf in (state.to_array(), reward, terminated,
                                                   truncated)))


def draw(case: Case, env_params: Any, rng: np.random.Generator, n: int
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """N float32 states, inside their ranges and at their ends, times and actions.

    Times are uniform in [0, 1.2 max_steps), so that the step limit falls inside. With `aim`,
    a sixth of the states are moved (by Gymnasium's own steps) to land within +-2e-6 of the
    threshold, some 30 float32 spacings there.
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


@functools.cache
def gymnasium_steps(name: str, variant: str) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray,
                                                      Outcome]:
    """The variant's env_params, N states, times and actions, and Gymnasium's steps from them."""
    case = CASES[name]
    env_params = case.variants[variant]
    values, times, actions = draw(case, env_params, np.random.default_rng(0), N_STATES)
    outcome = step_gymnasium(case, make_gymnasium(case, env_params), values, times, actions)
    return env_params, values, times, actions, outcome


def differences(case: Case, got: Outcome, want: Outcome) -> np.ndarray:
    """`[N, K]` |got - want| of each value, angles compared modulo a turn."""
    diff = got.values - want.values
    for i in case.angles:
        diff[:, i] = np.remainder(diff[:, i] + PI, 2 * PI) - PI
    return np.abs(diff)


def float32_tolerances(case: Case, env_params: Any, values: np.ndarray, times: np.ndarray,
                       actions: np.ndarray, new_values: np.ndarray) -> np.ndarray:
    """`[N, K]` per step and value: 1e-5, or ten times what float32-sized changes of the state
    can change the result by, where that is more (the step is ill-conditioned there).

    The change is the first-order one, each value moved by half a float32 spacing (2^-24
    relative) in the worst direction: sum_j |d new_i / d x_j| |x_j| 2^-24, relative as the
    errors are. The Jacobian is the float64 step's (equal to Gymnasium's to 1e-12, above). Only
    Acrobot needs it: its Runge-Kutta step over 0.2 s from its fastest states multiplies input
    changes up to ~1000-fold (Gymnasium itself, its float64 state moved by 2^-24, moves its
    result by up to 6e-5 there), and no float32 arithmetic holds 1e-5; float32 errors measured
    up to 3 times this first-order change.
    """
    def new(value, time, action):
        return case.module.step(case.state.from_array(value, time), action, env_params)[
            1].to_array()

    with jax.enable_x64(True):
        jacobians = np.asarray(jax.jit(jax.vmap(jax.jacfwd(new)))(values, times, actions))
    change = (np.abs(jacobians) @ np.abs(values)[..., None])[..., 0] * 2.0**-24
    return np.maximum(1e-5, 10 * change / np.maximum(np.abs(new_values), case.scale))


# ---------------------------------------------------------------- re-synced steps


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "float64"])
@pytest.mark.parametrize("name, variant", VARIANTS)
def test_steps_match_gymnasium(name, variant, x64):
    case = CASES[name]
    env_params, values, times, actions, gym_outcome = gymnasium_steps(name, variant)
    with jax.enable_x64(x64):
        ours = step_jaxpg(case, env_params, values, times, actions)
    assert ours.values.dtype == (np.float64 if x64 else np.float32)
    difference = differences(case, ours, gym_outcome)
    if x64:
        tolerance, excused = np.full(values.shape, 1e-12), np.zeros(N_STATES, bool)
    else:
        tolerance = float32_tolerances(case, env_params, values, times, actions,
                                       gym_outcome.values)
        # Only Acrobot's step is ill-conditioned, on 8% of these states at the most (their
        # velocities drawn up to the bounds).
        relaxed = (tolerance > 1e-5).any(axis=1)
        assert relaxed.mean() < 0.1 and (name == "acrobot" or not relaxed.any())
        # Only float32 may decide a threshold otherwise: where Gymnasium's new state lies
        # within the step's own error (and 2 float32 spacings) of it. A handful of the states
        # aimed at the threshold do.
        spacing = np.spacing(np.abs(gym_outcome.values).astype(np.float32))
        excused = case.near(gym_outcome.values, env_params, difference + 2 * spacing)
    value_errors = difference / np.maximum(np.abs(gym_outcome.values), case.scale)
    assert (value_errors <= tolerance).all(), (value_errors / tolerance).max(axis=0)
    reward_errors = (np.abs(ours.reward - gym_outcome.reward)
                     / np.maximum(np.abs(gym_outcome.reward), 1.0))
    flipped = ours.terminated != gym_outcome.terminated
    assert not (flipped & ~excused).any(), np.flatnonzero(flipped & ~excused)[:5]
    assert flipped.sum() <= N_STATES // 200  # up to 7 measured, of 1667 aimed states
    assert reward_errors[~flipped].max() <= tolerance.min(), reward_errors.max()
    np.testing.assert_array_equal(ours.truncated, gym_outcome.truncated)
    # The set covers both ends: truncations, and terminations where an episode can end.
    assert 0.05 < gym_outcome.truncated.mean() < 0.5
    if name != "pendulum":
        assert 0.01 < gym_outcome.terminated.mean() < 0.99


# ---------------------------------------------------------------- resets


def reset_jaxpg(module: ModuleType, seed: int, n: int) -> np.ndarray:
    """`[n, K]` float64 values of jaxpg's resets, from n keys."""
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    obs, state = jax.jit(jax.vmap(module.reset, in_axes=(0, None)))(
        keys, next(iter(module.PRESETS.values())))
    assert obs.shape == (n, module.OBS_SIZE) and (np.asarray(state.time) == 0).all()
    return np.asarray(state.to_array(), np.float64)


@pytest.mark.parametrize("name", list(CASES))
def test_resets_are_distributed_as_gymnasiums(name):
    case = CASES[name]
    n = 4000
    ours = reset_jaxpg(case.module, 0, n)
    gym_env = make_gymnasium(case, case.variants["preset"])
    theirs = np.empty_like(ours)
    for seed in range(n):
        gym_env.reset(seed=seed)
        theirs[seed] = np.asarray(gym_env.unwrapped.state, np.float64)
    for component, (mine, gyms) in enumerate(zip(ours.T, theirs.T)):
        if np.ptp(gyms) == 0:  # a value Gymnasium always starts at: the mountain cars' velocity
            np.testing.assert_array_equal(mine, gyms[0])
            continue
        # A uniform's mean has standard deviation ptp / sqrt(12 n): within 5 of them.
        assert abs(mine.mean() - gyms.mean()) < 5 * np.ptp(gyms) / math.sqrt(12 * n), component
        # The same distribution: with fixed keys and seeds the p-value is deterministic, and
        # another range or a skew gives p ~ 0.
        assert scipy.stats.ks_2samp(mine, gyms).pvalue > 1e-3, component


@pytest.mark.parametrize("name, low, high", [
    ("acrobot", [-0.1] * 4, [0.1] * 4),
    ("mountain_car", [-0.6, 0.0], [-0.4, 0.0]),
    ("pendulum", [-PI, -1.0], [PI, 1.0]),
    ("continuous_mountain_car", [-0.6, 0.0], [-0.4, 0.0]),
])
def test_resets_fill_gymnasiums_ranges(name, low, high):
    values = reset_jaxpg(CASES[name].module, 1, 10_000)
    # Uniform in [low, high) of float32 numbers: float32(0.1) is 0.10000000149, float32(pi)
    # 3.14159274. Acrobot rounds as Gymnasium's reset does, so its values reach float32(0.1).
    low, high = np.float32(low).astype(np.float64), np.float32(high).astype(np.float64)
    assert (low <= values.min(axis=0)).all() and (values.max(axis=0) <= high).all()
    # 10^4 uniform draws come within 1e-3 of either end of the range (p ~ e^-10 otherwise).
    np.testing.assert_allclose(values.min(axis=0), low, atol=1e-3 * (high - low).max())
    np.testing.assert_allclose(values.max(axis=0), high, atol=1e-3 * (high - low).max())


# ---------------------------------------------------------------- Acrobot unsynced

UNSYNCED_STEPS = 1000
UNSYNCED_RUNS = 32


def test_acrobot_float64_follows_gymnasium_unsynced_for_an_episode_in_most_runs():
    # Each run starts from a reset state and takes the same random actions in both, each on its
    # own state (no TimeLimit: a run is one chain of steps). Their last bits differ from the
    # first step (see `acrobot`), and chaos grows the difference: over 80 runs of 4000 steps
    # the first step where they part (np.allclose at 1e-5, as `check_environments_match`)
    # had a median near 1000 and a least of 373, 95% of them past 500; here 11 of the 32 part
    # within 1000 steps, the first at step 496. Asserted with a margin that whatever bits XLA's
    # fusion gives cannot break by chance: most runs hold a whole episode (500 steps; at 95%
    # per run, fewer than 16 of 32 has probability ~1e-15) and none parts within 100 steps.
    rng = np.random.default_rng(3)
    starts = rng.uniform(-0.1, 0.1, (UNSYNCED_RUNS, 4)).astype(np.float32).astype(np.float64)
    actions = rng.integers(0, 3, (UNSYNCED_STEPS, UNSYNCED_RUNS))
    gym_env = make_gymnasium(CASES["acrobot"], acrobot.V1).unwrapped
    theirs = np.empty((UNSYNCED_STEPS, UNSYNCED_RUNS, 6))
    for run, start in enumerate(starts):
        gym_env.state = start.copy()
        for t in range(UNSYNCED_STEPS):
            gym_env.step(int(actions[t, run]))
            s = gym_env.state
            theirs[t, run] = [np.cos(s[0]), np.sin(s[0]), np.cos(s[1]), np.sin(s[1]), s[2], s[3]]

    def one_step(state, action):
        obs, state, *_ = jax.vmap(acrobot.step, in_axes=(0, 0, None))(state, action, acrobot.V1)
        return state, obs

    with jax.enable_x64(True):
        _, ours = jax.jit(lambda s, a: jax.lax.scan(one_step, s, a))(
            acrobot.AcrobotState.from_array(starts), jnp.asarray(actions))
        ours = np.asarray(ours)
    apart = ~np.isclose(ours, theirs, rtol=1e-5, atol=1e-5).all(axis=-1)
    first_apart = np.where(apart.any(axis=0), apart.argmax(axis=0), UNSYNCED_STEPS)
    assert (first_apart >= 500).mean() >= 0.5, np.sort(first_apart)
    assert first_apart.min() >= 100, np.sort(first_apart)
    # The comparison can fail: chaos parts about half the runs within 1000 steps.
    assert (first_apart < UNSYNCED_STEPS).any(), np.sort(first_apart)


# ---------------------------------------------------------------- Acrobot's pieces


def test_wrap_is_gymnasiums_loop():
    # Gymnasium's loop to the last bit wherever it takes at most WRAP_TURNS turns: |x| <= 13 pi.
    rng = np.random.default_rng(0)
    turns = 2 * acrobot.WRAP_TURNS + 1
    x = np.concatenate([rng.uniform(-turns * PI, turns * PI, 4000),
                        np.arange(-turns, turns + 1) * PI,  # odd multiples land on the ends
                        np.nextafter(np.arange(-turns, turns + 1) * PI, np.inf)])
    want = np.array([gym_acrobot.wrap(value, -PI, PI) for value in x])
    with jax.enable_x64(True):
        got = np.asarray(jax.jit(acrobot.wrap, static_argnums=(1, 2))(x, -PI, PI))
        far = np.asarray(acrobot.wrap(jnp.array([40 * PI + 1.0, -1e4]), -PI, PI))
    np.testing.assert_array_equal(got, want)
    # Beyond, only a state far outside the velocity bounds reaches: still in range, turns apart.
    assert (np.abs(far) <= PI).all()
    np.testing.assert_allclose(np.remainder(far - [40 * PI + 1.0, -1e4] + PI, 2 * PI) - PI, 0,
                               atol=1e-9)


def test_torque_noise_adds_a_uniform_torque():
    # With noise m, action 2 pushes with 1 + noise: the step equals a noiseless one whose torque
    # is 1 + noise, and each state carries its next key.
    n, noise_max = 2000, 0.5
    noisy = acrobot.V1.replace(torque_noise_max=noise_max)
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    start = acrobot.AcrobotState.from_array(np.tile([0.3, -0.2, 1.0, -2.0], (n, 1)), key=keys)
    action = jnp.full(n, 2)
    _, stepped, *_ = batched_step(acrobot, noisy)(start, action, noisy)
    next_keys, noise = acrobot.torque_noise(keys, noise_max, jnp.float32)
    torques = acrobot.V1.replace(torque=1.0 + noise)
    _, plain, *_ = batched_step(acrobot, torques)(start, action, torques)
    chex.assert_trees_all_close(stepped.to_array(), plain.to_array(), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(stepped.key, next_keys)
    assert not np.array_equal(stepped.key, keys)
    assert scipy.stats.kstest(np.asarray(noise), "uniform",
                              args=(-noise_max, 2 * noise_max)).pvalue > 1e-3
    _, quiet, *_ = batched_step(acrobot, acrobot.V1)(start, action, acrobot.V1)
    np.testing.assert_array_equal(quiet.key, keys)  # no noise draws nothing


# ---------------------------------------------------------------- the interface


@pytest.mark.parametrize("name", list(CASES))
def test_a_sweep_vmaps_over_physics(name):
    # Three settings of one field in one vmapped step equal three steps, one per setting.
    case = CASES[name]
    env_params = case.variants["preset"]
    field = dataclasses.fields(env_params)[0].name
    settings = [getattr(env_params, field) * scale for scale in (0.8, 1.0, 1.25)]
    values, times, actions = draw(case, env_params, np.random.default_rng(1), 3)
    together = step_jaxpg(case, env_params.replace(**{field: np.array(settings)}), values, times,
                          actions)
    for i, setting in enumerate(settings):
        alone = step_jaxpg(case, env_params.replace(**{field: setting}), values[i:i + 1],
                           times[i:i + 1], actions[i:i + 1])
        chex.assert_trees_all_close(tuple(leaf[i] for leaf in together),
                                    tuple(leaf[0] for leaf in alone), rtol=1e-6, atol=1e-7)


def test_every_module_has_the_interface():
    for name, module in MODULES.items():  # CartPole's two presets share its module
        assert name in module.PRESETS and module.NAME in module.PRESETS and module.OBS_SIZE >= 2
        discrete = hasattr(module, "NUM_ACTIONS")
        assert discrete != hasattr(module, "ACTION_LOW") == hasattr(module, "ACTION_HIGH")
        for function in ("make_params", "check_params", "reset", "step", "observe"):
            assert callable(getattr(module, function)), (name, function)
        assert module.make_params(name) == module.PRESETS[name]
        assert module.make_params() == module.PRESETS[module.NAME]


ACROBOT_STATE = acrobot.AcrobotState.from_array(np.zeros(4))
CAR_STATE = mountain_car.MountainCarState.from_array(np.array([-0.5, 0.0]))
PENDULUM_STATE = pendulum.PendulumState.from_array(np.zeros(2))


@pytest.mark.parametrize("make, match", [
    (lambda: acrobot.make_params("Acrobot-v0"), "env"),
    (lambda: acrobot.make_params(dt=0.0), "dt"),
    (lambda: acrobot.make_params(link_moi=-1.0), "link_moi"),
    (lambda: acrobot.make_params(book_or_nips="paper"), "book_or_nips"),
    (lambda: acrobot.make_params(torque_noise_max=-0.1), "torque_noise_max"),
    (lambda: acrobot.make_params(reset_low=0.2), "reset_low"),
    (lambda: acrobot.check_params(mountain_car.V0), "env_params"),
    (lambda: mountain_car.make_params(min_position=1.0), "min_position"),
    (lambda: mountain_car.make_params(force=np.nan), "force"),
    (lambda: mountain_car.make_params(max_steps=0), "max_steps"),
    (lambda: mountain_car.make_params(max_steps=2.5), "max_steps"),
    (lambda: mountain_car.make_params(max_steps=2**40), "max_steps"),  # steps count in int32
    (lambda: mountain_car.make_params(gravityy=1.0), "env_params"),
    (lambda: pendulum.make_params(length=0.0), "length"),
    (lambda: pendulum.make_params(gravity=np.inf), "gravity"),
    (lambda: continuous_mountain_car.make_params(min_action=2.0), "min_action"),
    (lambda: continuous_mountain_car.make_params(power="0.1"), "power"),
    (lambda: acrobot.AcrobotState.from_array(np.zeros(3)), "state"),
    (lambda: pendulum.PendulumState.from_array(np.zeros((5, 4))), "state"),
    (lambda: acrobot.step(ACROBOT_STATE, 3, acrobot.V1), "action"),
    (lambda: mountain_car.step(CAR_STATE, 1.5, mountain_car.V0), "action"),
    (lambda: mountain_car.step(CAR_STATE, jnp.array([0, -1]), mountain_car.V0), "action"),
    (lambda: pendulum.step(PENDULUM_STATE, np.nan, pendulum.V1), "action"),
    (lambda: continuous_mountain_car.step(
        CAR_STATE, 0.5, continuous_mountain_car.V0.replace(max_speed=-1.0)), "max_speed"),
])
def test_bad_input_raises(make, match):
    with pytest.raises(ValueError, match=f"^{match}:"):
        make()
