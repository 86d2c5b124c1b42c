"""jaxpg's classic-control environments (`jaxpg.envs`) against Gymnasium's, which run beside them.

Steps are compared re-synced by the library's harness (`jaxpg.envs.parity`) on 10^4 states per
variant: Gymnasium's environment is set to each state and stepped once, and jaxpg's pure step,
vmapped, takes the same steps from the same states.
"""

import dataclasses
import functools
import math
from typing import Any

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from gymnasium.envs.classic_control import acrobot as gym_acrobot

from jaxpg.envs import MODULES, acrobot, continuous_mountain_car, mountain_car, parity, pendulum

N_STATES = 10_000
PI = math.pi
CASES = parity.CASES
VARIANTS = [(name, variant) for name, case in CASES.items() for variant in case.variants]


@functools.cache
def gymnasium_steps(name: str, variant: str) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray,
                                                      parity.Outcome]:
    """The variant's env_params, N states, times and actions, and Gymnasium's steps from them."""
    case = CASES[name]
    env_params = case.variants[variant]
    values, times, actions = parity.draw(case, env_params, np.random.default_rng(0), N_STATES)
    outcome = parity.step_gymnasium(case, parity.make_gymnasium(case, env_params), values, times,
                                    actions)
    return env_params, values, times, actions, outcome


# ---------------------------------------------------------------- re-synced steps


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "float64"])
@pytest.mark.parametrize("name, variant", VARIANTS)
def test_steps_match_gymnasium(name, variant, x64):
    case = CASES[name]
    env_params, values, times, actions, gym_outcome = gymnasium_steps(name, variant)
    with jax.enable_x64(x64):
        ours = parity.step_jaxpg(case, env_params, values, times, actions)
        compared = parity.compare(case, env_params, values, times, actions, ours, gym_outcome)
    assert ours.values.dtype == (np.float64 if x64 else np.float32)
    tolerance, flipped = compared.tolerance, compared.flipped
    if x64:
        assert (tolerance == 1e-12).all() and not compared.excused.any()
    else:
        assert tolerance.min() == 1e-5
        # Only Acrobot's step is ill-conditioned, on 8% of these states at the most (their
        # velocities drawn up to the bounds).
        relaxed = (tolerance > 1e-5).any(axis=1)
        assert relaxed.mean() < 0.1 and (name == acrobot.NAME or not relaxed.any())
    # Only float32 may decide a threshold otherwise (`compared.excused`): where Gymnasium's new
    # state lies within the step's own error (and 2 float32 spacings) of it. A handful of the
    # states aimed at the threshold do.
    value_errors = compared.value_errors
    assert (value_errors <= tolerance).all(), (value_errors / tolerance).max(axis=0)
    assert not (flipped & ~compared.excused).any(), np.flatnonzero(flipped & ~compared.excused)[:5]
    assert flipped.sum() <= N_STATES // 200  # up to 7 measured, of 1667 aimed states
    reward_errors = compared.reward_errors
    assert reward_errors[~flipped].max() <= tolerance.min(), reward_errors.max()
    np.testing.assert_array_equal(ours.truncated, gym_outcome.truncated)
    assert compared.ok and compared.worst <= 1.0 and compared.reward_mismatches == 0
    assert compared.terminated_mismatches == 0 and not compared.truncated_differs.any()
    # The set covers both ends: truncations, and terminations where an episode can end.
    assert 0.05 < gym_outcome.truncated.mean() < 0.5
    if name != pendulum.NAME:
        assert 0.01 < gym_outcome.terminated.mean() < 0.99


def test_a_wrong_constant_is_flagged():
    # jaxpg pushes with force 0.0011 where Gymnasium keeps its 0.001: the velocity moves by 1e-4
    # a step, 1.4e-3 of its scale 0.07, and where a car nears the goal its termination moves.
    case = dataclasses.replace(CASES[mountain_car.NAME], configure=parity.set_attributes({}))
    env_params = mountain_car.V0.replace(force=0.0011)
    values, times, actions = parity.draw(case, env_params, np.random.default_rng(0), 600)
    theirs = parity.step_gymnasium(case, parity.make_gymnasium(case, env_params), values, times,
                                   actions)
    ours = parity.step_jaxpg(case, env_params, values, times, actions)
    compared = parity.compare(case, env_params, values, times, actions, ours, theirs)
    assert not compared.ok and compared.worst > 100  # 1.4e-3 / 1e-5
    right = parity.step_jaxpg(case, mountain_car.V0, values, times, actions)
    assert parity.compare(case, mountain_car.V0, values, times, actions, right, theirs).ok


# ---------------------------------------------------------------- resets


@pytest.mark.parametrize("name", list(CASES))
def test_resets_are_distributed_as_gymnasiums(name):
    n = 4000
    compared = parity.compare_resets(parity.reset_jaxpg(CASES[name].module, 0, n),
                                     parity.reset_gymnasium(CASES[name], n))
    # A value Gymnasium always starts at (the mountain cars' velocity) is jaxpg's too.
    assert compared.constant.any() == ("MountainCar" in name) and compared.equal_constants
    # A uniform's mean has standard deviation ptp / sqrt(12 n): within 5 of them.
    assert (compared.mean_sigmas < 5).all(), compared.mean_sigmas
    # The same distribution: with fixed keys and seeds the p-value is deterministic, and
    # another range or a skew gives p ~ 0.
    assert (compared.p_value > 1e-3).all(), compared.p_value
    assert compared.ok


def test_reset_comparison_can_fail():
    # Gymnasium's resets against themselves shifted by a tenth of their range, or widened.
    theirs = parity.reset_gymnasium(CASES[pendulum.NAME], 4000)
    shifted = parity.compare_resets(theirs + [0.2 * PI, 0.0], theirs)
    widened = parity.compare_resets(theirs * [1.0, 1.2], theirs)
    assert not shifted.ok and shifted.p_value[0] < 1e-3 and shifted.p_value[1] == 1.0
    assert not widened.ok and widened.p_value[1] < 1e-3
    car = parity.reset_gymnasium(CASES[mountain_car.NAME], 100)
    assert not parity.compare_resets(car + [0.0, 1e-9], car).ok  # a constant velocity moved


@pytest.mark.parametrize("name, low, high", [
    (acrobot.NAME, [-0.1] * 4, [0.1] * 4),
    (mountain_car.NAME, [-0.6, 0.0], [-0.4, 0.0]),
    (pendulum.NAME, [-PI, -1.0], [PI, 1.0]),
    (continuous_mountain_car.NAME, [-0.6, 0.0], [-0.4, 0.0]),
])
def test_resets_fill_gymnasiums_ranges(name, low, high):
    module = CASES[name].module
    obs, state = jax.vmap(module.reset, in_axes=(0, None))(
        jax.random.split(jax.random.PRNGKey(1), 8), module.PRESETS[name])
    assert obs.shape == (8, module.OBS_SIZE) and (np.asarray(state.time) == 0).all()
    values = parity.reset_jaxpg(module, 1, 10_000)
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
    gym_env = parity.make_gymnasium(CASES[acrobot.NAME], acrobot.V1).unwrapped
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


def test_torque_noise_may_be_a_numpy_number():
    """A numpy float is a number (it was refused as not one); it steps as the Python float."""
    state = acrobot.AcrobotState.from_array(np.array([0.1, -0.2, 0.3, 0.4]), key=jnp.uint32([1, 2]))
    for numpy_noise, noise in [(np.float32(0.25), 0.25), (np.int64(0), 0)]:
        params = acrobot.make_params(torque_noise_max=numpy_noise)
        assert params.torque_noise_max == noise
        jax.tree.map(np.testing.assert_array_equal, acrobot.step(state, 2, params),
                     acrobot.step(state, 2, acrobot.make_params(torque_noise_max=noise)))


def test_torque_noise_adds_a_uniform_torque():
    # With noise m, action 2 pushes with 1 + noise: the step equals a noiseless one whose torque
    # is 1 + noise, and each state carries its next key.
    n, noise_max = 2000, 0.5
    noisy = acrobot.V1.replace(torque_noise_max=noise_max)
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    start = acrobot.AcrobotState.from_array(np.tile([0.3, -0.2, 1.0, -2.0], (n, 1)), key=keys)
    action = jnp.full(n, 2)
    _, stepped, *_ = parity.batched_step(acrobot, noisy)(start, action, noisy)
    next_keys, noise = acrobot.torque_noise(keys, noise_max, jnp.float32)
    torques = acrobot.V1.replace(torque=1.0 + noise)
    _, plain, *_ = parity.batched_step(acrobot, torques)(start, action, torques)
    chex.assert_trees_all_close(stepped.to_array(), plain.to_array(), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(stepped.key, next_keys)
    assert not np.array_equal(stepped.key, keys)
    assert scipy.stats.kstest(np.asarray(noise), "uniform",
                              args=(-noise_max, 2 * noise_max)).pvalue > 1e-3
    _, quiet, *_ = parity.batched_step(acrobot, acrobot.V1)(start, action, acrobot.V1)
    np.testing.assert_array_equal(quiet.key, keys)  # no noise draws nothing


# ---------------------------------------------------------------- the interface


@pytest.mark.parametrize("name", list(CASES))
def test_a_sweep_vmaps_over_physics(name):
    # Three settings of gravity, which every step reads, in one vmapped step equal three steps,
    # one per setting; and the settings step the same states apart.
    case = CASES[name]
    env_params = case.variants["preset"]
    field = "gravity"
    settings = [getattr(env_params, field) * scale for scale in (0.8, 1.0, 1.25)]
    values, times, actions = parity.draw(case, env_params, np.random.default_rng(1), 3)
    together = parity.step_jaxpg(case, env_params.replace(**{field: np.array(settings)}), values,
                                 times, actions)
    for i, setting in enumerate(settings):
        alone = parity.step_jaxpg(case, env_params.replace(**{field: setting}), values[i:i + 1],
                                  times[i:i + 1], actions[i:i + 1])
        chex.assert_trees_all_close(tuple(leaf[i] for leaf in together),
                                    tuple(leaf[0] for leaf in alone), rtol=1e-6, atol=1e-7)
    one_state = parity.step_jaxpg(case, env_params.replace(**{field: np.array(settings)}),
                                  values[:1].repeat(3, 0), times[:1].repeat(3, 0),
                                  actions[:1].repeat(3, 0))
    moved = one_state[0]  # the states after the step
    assert len({row.tobytes() for row in moved}) == 3, moved  # each setting steps otherwise


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


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32, jnp.uint8, np.int8, bool])
@pytest.mark.parametrize("module, state", [(acrobot, ACROBOT_STATE), (mountain_car, CAR_STATE)])
def test_an_action_of_any_integer_dtype_pushes_as_the_int(module, state, dtype):
    """An unsigned 0 less 1 wrapped round to 255: action 0 pushed the other way, 255 times."""
    env_params = module.PRESETS[module.NAME]
    for action in range(2 if dtype is bool else 3):
        expected = module.step(state, action, env_params)
        got = module.step(state, dtype(action), env_params)
        np.testing.assert_array_equal(got[0], expected[0])
        stepped = jax.jit(module.step)(state, jnp.asarray(action, dtype), env_params)
        np.testing.assert_array_equal(stepped[0], jax.jit(module.step)(state, action,
                                                                       env_params)[0])


@pytest.mark.parametrize("make, match", [
    (lambda: acrobot.make_params("Acrobot-v0"), "env"),
    (lambda: acrobot.make_params(dt=0.0), "dt"),
    (lambda: acrobot.make_params(link_moi=-1.0), "link_moi"),
    (lambda: acrobot.make_params(book_or_nips="paper"), "book_or_nips"),
    (lambda: acrobot.make_params(torque_noise_max=-0.1), "torque_noise_max"),
    (lambda: acrobot.make_params(torque_noise_max=True), "torque_noise_max"),  # was noise 1
    (lambda: acrobot.make_params(torque_noise_max=np.bool_(True)), "torque_noise_max"),
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
