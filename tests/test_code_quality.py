"""The package passes its linter (ruff) and its type checker (mypy), as configured in pyproject."""

import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _run(*args):
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True)


@pytest.mark.parametrize("args", [("ruff", "check", "jaxpg", "tests", "benchmarks"), ("mypy",)],
                         ids=["ruff", "mypy"])
def test_the_code_passes(args):
    result = _run(*args)
    assert result.returncode == 0, result.stdout + result.stderr
