"""The declared lower bounds of the runtime dependencies are what CI's lower-bound smoke
installs."""

import importlib.util
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
CI = ROOT / ".ci"


def _load_checker():
    spec = importlib.util.spec_from_file_location("lower_bounds", CI / "lower_bounds.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


lower_bounds = _load_checker()

PYPROJECT = """
[project]
dependencies = [
    "jax>=0.8.1",
    "numpy>=2.0",  # a comment
    "ml_dtypes>=0.5,<0.7",
]
"""
PINS = "# a comment\njax==0.8.1\nnumpy==2.0.0\nml-dtypes==0.5.0\n"


def test_pyproject_and_the_pins_agree():
    assert lower_bounds.disagreements(
        (ROOT / "pyproject.toml").read_text(), (CI / "lower-bounds.txt").read_text()) == []


def test_every_runtime_dependency_is_pinned_at_its_lower_bound():
    bounds, problems = lower_bounds.declared((ROOT / "pyproject.toml").read_text())
    pins, pin_problems = lower_bounds.pinned((CI / "lower-bounds.txt").read_text())
    assert problems == [] and pin_problems == []
    assert {"jax", "jaxlib", "gymnasium", "optax", "flax", "numpy"} <= bounds.keys() == pins.keys()


def test_the_checker_agrees_on_equal_bounds_in_either_spelling():
    assert lower_bounds.disagreements(PYPROJECT, PINS) == []


@pytest.mark.parametrize("pyproject, pins, found", [
    (PYPROJECT.replace("jax>=0.8.1", "jax>=0.7"), PINS,
     "jax: pyproject.toml declares >=0.7, lower-bounds.txt pins 0.8.1"),
    (PYPROJECT, PINS.replace("numpy==2.0.0\n", ""),
     "numpy: pyproject.toml declares >=2.0, lower-bounds.txt has no pin"),
    (PYPROJECT, PINS + "scipy==1.13.0\n",
     "scipy: lower-bounds.txt pins 1.13.0, not a runtime dependency"),
    (PYPROJECT.replace('"jax>=0.8.1"', '"jax"'), PINS, "'jax' needs exactly one '>=' lower bound"),
    (PYPROJECT, PINS.replace("jax==0.8.1", "jax>=0.8.1"), "'jax>=0.8.1' is not 'name==version'"),
])
def test_the_checker_reports_each_disagreement(pyproject, pins, found):
    problems = lower_bounds.disagreements(pyproject, pins)
    assert any(found in problem for problem in problems), problems


def test_the_smoke_installs_the_pins_and_runs_every_stable_command():
    smoke = (CI / "smoke").read_text()
    assert 'python3 "$repo/.ci/lower_bounds.py"\n' in smoke
    # Not editable: the distribution as pip builds it (every package in it).
    assert re.search(r'pip install .*-c "\$repo/\.ci/lower-bounds\.txt" "\$work/src"\n', smoke)
    assert 'python "$repo/.ci/lower_bounds.py" --installed\n' in smoke
    for command in ("train", "sweep", "evaluate", "conformance"):
        assert re.search(rf"^jaxpg {command} ", smoke, re.MULTILINE), command
    assert 'check_env(gymnasium.make("jaxpg/CartPole-v1"' in smoke


def test_ci_runs_the_smoke_then_the_whole_suite_last():
    lines = [line for line in (CI / "run").read_text().splitlines()
             if line.strip() and not line.startswith("#")]
    assert "bash .ci/smoke || smoke=$?" in lines
    assert lines.index("bash .ci/smoke || smoke=$?") < lines.index("python -m pytest -q -n auto")
    assert lines[-2:] == ["python -m pytest -q -n auto", 'exit "$smoke"']
