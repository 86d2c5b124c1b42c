"""The parity harness: passes on jaxpg as it is, fails on a wrong constant."""

import dataclasses

import jax
import numpy as np
import pytest
from flax import struct

from jaxpg import cartpole, cli, conformance
from jaxpg.envs import mountain_car, parity
from jaxpg.train_config import PHYSICS


@struct.dataclass
class Phys2dParams(cartpole.CartPoleParams):
    """Gymnasium's phys2d CartPole's mistake: masspole + length (0.6) instead of their product."""

    @property
    def polemass_length(self):
        return self.masspole + self.length


def test_default_run_is_ok():
    report = conformance.compare_with_gymnasium()
    assert report.ok, report.format()
    assert [v.name for v in report.variants] == list(conformance.VARIANTS)
    for variant in report.variants:
        # The episodes reach every ending: a fall and the step limit.
        assert variant.stats.terminated > 0 and variant.stats.truncated > 0, variant
        assert max(variant.stats.max_error) <= 1e-6
    v0, v1 = report.variants[:2]
    assert v0.stats.steps < v1.stats.steps  # v0 truncates at 200, v1 at 500
    assert report.format().endswith("conformance: OK")


def test_three_physics_settings_play_identical_episodes():
    """Every physical field set apart from its default, and 100 episodes of the basic policy with
    identical returns in jaxpg and in Gymnasium's CartPoleEnv with the same attributes."""
    physics = {name: value for name, value in conformance.VARIANTS.items()
               if set(value) & set(PHYSICS)}
    assert len(physics) == 3 and set().union(*physics.values()) == set(PHYSICS)
    assert all(getattr(cartpole.V1, field) != value
               for setting in physics.values() for field, value in setting.items())
    report = conformance.compare_with_gymnasium(variants=list(physics))
    assert report.ok, report.format()
    for variant in report.variants:
        assert variant.episodes == variant.equal_returns == 100
        assert f"{variant.name} " in report.format() and "100/100" in report.format()
    in_jaxpg, in_gymnasium = conformance.episode_returns(
        cartpole.V1.replace(**physics["long-heavy-pole"]), 100, 0)
    np.testing.assert_array_equal(in_jaxpg, in_gymnasium)
    assert len(np.unique(in_jaxpg)) > 10  # episodes of many lengths, not one


def test_float64_run_is_ok():
    with jax.enable_x64(True):
        report = conformance.compare_with_gymnasium(episodes=20, variants=["v1", "semi-implicit"])
    assert report.dtype == "float64" and report.tolerance == 1e-12
    assert report.ok, report.format()


def test_wrong_polemass_length_is_flagged():
    report = conformance.compare_with_gymnasium(episodes=10, env_params=Phys2dParams(),
                                                variants="v1")
    assert not report.ok
    (variant,) = report.variants
    # polemass_length enters temp and xacc: 0.6 instead of 0.05 changes the accelerations by far
    # more than 1e-6 at the first step of every episode.
    assert variant.stats.max_error[1] > 1e-3  # x_dot
    assert variant.first_divergence == 1
    assert variant.equal_returns < variant.episodes
    assert report.format().endswith("conformance: FAILED")


@pytest.mark.parametrize("kwargs, match", [
    ({"episodes": 0}, "episodes"),
    ({"seed": -1}, "seed"),
    ({"variants": ["v2"]}, "variants"),
    ({"variants": []}, "variants"),
    ({"env_params": "CartPole-v1"}, "env_params"),
])
def test_bad_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=f"^{match}:"):
        conformance.compare_with_gymnasium(**kwargs)


# ---------------------------------------------------------------- the command, every task


CLI_STATES = 200  # a few seconds per task; the tests of jaxpg.envs.parity step 10^4


def run_cli(capsys, *argv):
    """`jaxpg conformance ARGV` in this process: (status, stdout, stderr)."""
    status = cli.run_command(["conformance", *argv])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.mark.parametrize("env", list(parity.CASES))
def test_command_reports_each_task(capsys, env):
    status, out, err = run_cli(capsys, "--env", env, "--states", str(CLI_STATES))
    assert status == 0 and not err, out + err
    assert out.startswith(f"jaxpg {env} (float32) vs Gymnasium") and "constant values equal" in out
    rows = {line.split()[0]: line.split() for line in out.splitlines()
            if line.split() and line.split()[0] in parity.CASES[env].variants}
    assert list(rows) == list(parity.CASES[env].variants)
    for cells in rows.values():
        # states, then mismatches of reward / terminated / truncated 0, ok "yes".
        assert int(cells[1]) == CLI_STATES and cells[-5:-2] == ["0", "0", "0"], cells
        assert cells[-1] == "yes" and float(cells[5]) <= 1.0, cells
    assert out.rstrip().endswith("conformance: OK")


def test_command_fails_on_a_wrong_constant(capsys, monkeypatch):
    # Gymnasium keeps its force 0.001 (nothing configured) where jaxpg pushes with 0.0011.
    name = mountain_car.NAME
    wrong = dataclasses.replace(parity.CASES[name], configure=parity.set_attributes({}),
                                variants={"wrong-force": mountain_car.V0.replace(force=0.0011)})
    monkeypatch.setitem(parity.CASES, name, wrong)
    status, out, _ = run_cli(capsys, "--env", name, "--states", str(CLI_STATES))
    assert status == 1 and out.rstrip().endswith("conformance: FAILED"), out
    (row,) = [line.split() for line in out.splitlines() if line.startswith("wrong-force ")]
    assert float(row[5]) > 100 and row[-1] == "NO", row  # velocity 1.4e-3 of scale, tol 1e-5


def test_command_runs_cartpole_by_default(capsys):
    status, out, _ = run_cli(capsys, "--episodes", "2", "--seed", "1")
    assert status == 0 and out.startswith("jaxpg (float32) vs Gymnasium CartPoleEnv"), out
    assert [line.split()[0] for line in out.splitlines()[8:-2]] == list(conformance.VARIANTS)
    assert out.rstrip().endswith("conformance: OK")


@pytest.mark.parametrize("argv, match", [
    (["--env", "CartPole-v2"], "env: allowed CartPole-v1, "),
    (["--env", "Pendulum-v1", "--episodes", "5"], "episodes: "),
    (["--states", "5"], "states: "),
    (["--env", "Acrobot-v1", "--states", "0"], "states: "),
    (["--env", "Acrobot-v1", "--seed", "-1"], "seed: "),
    (["--env", "Pendulum-v1", "--states", str(10**12)], "states: must be an integer in"),
    (["--episodes", str(10**12)], "episodes: must be an integer in"),
])
def test_command_refuses_bad_arguments_in_one_line(capsys, argv, match):
    status, out, err = run_cli(capsys, *argv)
    assert status == 2 and not out
    assert err.startswith(f"jaxpg conformance: error: {match}") and err.count("\n") == 1, err


def test_an_episode_of_other_returns_counts_only_where_both_parted_still_together(monkeypatch):
    """From an angle that one step takes to within rounding of 0 (theta + tau * theta_dot = 0
    exactly), float32 and float64 put it on different sides, and the basic policy pushes one way
    in jaxpg and the other in Gymnasium, while the states agree within 1e-3 but not within 1e-60.
    Other physics in jaxpg part the states before the actions do: no excuse."""
    params = cartpole.V1
    flipping = np.array([0.0, 0.0, 1.7e-4, -1.7e-4 / params.tau])
    assert conformance._parted_together(params, flipping, 1e-3)
    assert not conformance._parted_together(params, flipping, 1e-60)
    start = np.array([0.01, 0.0, 0.02, 0.0])
    assert not conformance._parted_together(params, start, 1e-3)  # the same to the end
    step = conformance.step_jaxpg
    monkeypatch.setattr(conformance, "step_jaxpg", lambda values, times, actions, env_params: step(
        values, times, actions, env_params.replace(gravity=12.0)))
    assert not conformance._parted_together(params, start, 1e-3)
    monkeypatch.setattr(conformance, "relative_error", lambda ours, theirs: np.zeros(4))
    assert conformance._parted_together(params, start, 1e-3)  # they part, in actions or the end
