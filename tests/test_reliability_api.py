"""The Python API refuses values that would answer wrongly without a word, in one line naming the
argument, before anything compiles."""

import numpy as np
import pytest
from conftest import xla_compiles

from jaxpg import (
    TrainConfig,
    envs,
    evaluate,
    evaluation,
    policies,
    programs,
    report,
    results,
    sweep,
    train,
)


@pytest.mark.parametrize("value, match", [
    (np.nan, "must be finite"),  # a NaN state never falls: every episode would last 200 steps
    (1e39, r"must be at most 3\.403e\+38 in magnitude"),  # infinite in float32
])
def test_initial_states_that_the_episodes_cannot_start_from_are_refused(value, match):
    states = [[0.0, 0.0, 0.01, 0.0], [0.0, 0.0, 0.0, value]]
    with xla_compiles() as compiled, pytest.raises(ValueError, match=f"^init_states: {match}"):
        evaluate(policies.basic_policy, episodes=2, init_states=states)
    assert not compiled


@pytest.mark.parametrize("trainer", [train, lambda config, **kw: sweep(config, [0, 1], **kw)])
def test_an_on_iteration_that_is_no_function_is_refused(trainer):
    programs._program.cache_clear()  # as a new process: a program compiled before would hide it
    with xla_compiles() as compiled, pytest.raises(
            ValueError, match="^on_iteration: must be a function .* or None, got int$"):
        trainer(TrainConfig(iterations=1), on_iteration=5)
    assert not compiled


@pytest.mark.parametrize("env, field, value, match", [
    ("Acrobot-v1", "link_mass_1", 1e39, r"must be at most 3\.403e\+38 in magnitude"),  # inf in f32
    ("MountainCar-v0", "force", 1e39, r"must be at most 3\.403e\+38 in magnitude"),
    ("Pendulum-v1", "dt", 1e-300, r"must be at least 1\.175e-38"),  # 0 in float32: a frozen pole
    ("MountainCarContinuous-v0", "power", 1e-300, r"must be at least 1\.175e-38"),
])
def test_physics_that_float32_cannot_hold_are_refused_on_every_task(env, field, value, match):
    with xla_compiles() as compiled, pytest.raises(ValueError, match=f"^{field}: {match}"):
        TrainConfig(env=envs.MODULES[env].make_params(env, **{field: value}))
    assert not compiled


@pytest.mark.parametrize("call, match", [
    (lambda: report.compare(["unread"], confidence="0.9"), "^confidence: must be a number"),
    (lambda: report.compare("unread"), "^sweeps: expected a list of sweep folders"),
    (lambda: results.save_sweep(None, "unwritten"), "^result: expected what jaxpg.sweep returns"),
    (lambda: evaluation.robustness(policies.basic_policy, network="mlp"),
     "^network: expected the policy's flax module"),
])
def test_arguments_of_the_wrong_kind_are_named_in_one_line(call, match, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=match):
        call()
    assert not list(tmp_path.iterdir())  # nothing read or written
