"""Numbers that the computation's float cannot hold: refused in one line before anything compiles,
by the Python API and by the command line (exit status 2, no traceback)."""

import re
import subprocess
import sys

import jax
import numpy as np
import pytest

from jaxpg import cartpole

SMALL = ["--iterations", "1", "--episodes", "1", "--max-steps", "5", "--quiet", "--no-cache"]
# float32's largest number, 3.403e38, and its smallest normal one, 1.175e-38.
TOO_LARGE = r"must be at most 3\.403e\+38 in magnitude \(the largest float32\)"
TOO_SMALL = r"must be at least 1\.175e-38 \(the smallest normal float32\)"


@pytest.mark.parametrize("fields, match", [
    ({"length": 1e308}, f"length: {TOO_LARGE}, got 1e\\+308"),
    ({"gravity": -1e39}, f"gravity: {TOO_LARGE}, got -1e\\+39"),
    ({"tau": 1e-300}, f"tau: {TOO_SMALL}, got 1e-300"),  # 0 in float32: the cart never moves
    ({"force_mag": 1e-40}, f"force_mag: {TOO_SMALL}, got 1e-40"),  # subnormal in float32
    # total_mass and polemass_length, which step derives.
    ({"masspole": 2e38, "masscart": 2e38}, f"masspole \\+ masscart: {TOO_LARGE}, got 4e\\+38"),
    ({"masspole": 1e-20, "length": 1e-20}, f"masspole \\* length: {TOO_SMALL}, got 1e-40"),
    # reset draws in [low, high) by scaling the width.
    ({"reset_low": -3e38, "reset_high": 3e38}, f"reset_high - reset_low: {TOO_LARGE}"),
    # Apart in float64, one number in float32.
    ({"reset_high": -0.05 + 1e-12}, "reset_low: must be below reset_high in float32"),
])
def test_physics_that_float32_cannot_hold_are_refused(fields, match):
    with pytest.raises(ValueError, match=f"^{match}"):
        cartpole.make_params(**fields)


def test_float64_physics_hold_what_float32_cannot():
    with jax.enable_x64(True):
        assert cartpole.make_params(tau=1e-300, length=1e300).tau == 1e-300


def test_a_quantity_derived_from_a_traced_field_is_left_to_the_caller():
    """A traced masspole is unknown while tracing: masspole * length is not checked then."""
    shape = jax.eval_shape(lambda masspole: cartpole.step(
        cartpole.CartPoleState.from_array(np.zeros(4, np.float32)), 1,
        cartpole.CartPoleParams(masspole=masspole, length=1e30)),
        jax.ShapeDtypeStruct((), np.float32))
    assert shape[0].shape == (4,)


def _jaxpg(*args):
    return subprocess.run([sys.executable, "-m", "jaxpg.cli", *args], capture_output=True,
                          text=True)


TRAIN = ["train", *SMALL]
SWEEP = ["sweep", "--seeds", "2", *SMALL]


@pytest.mark.parametrize("args, match", [
    ([*TRAIN, "--length", "1e308"], f"length: {TOO_LARGE}, got 1e\\+308"),
    ([*TRAIN, "--tau", "1e-300"], f"tau: {TOO_SMALL}, got 1e-300"),
    ([*TRAIN, "--discount", "1e-300"], f"discount: {TOO_SMALL}, got 1e-300"),
    ([*TRAIN, "--lr", "1e300"], f"learning_rate: {TOO_LARGE}, got 1e\\+300"),
    ([*TRAIN, "--length", "0.3:1e39"], f"length: {TOO_LARGE}, got 1e\\+39"),
    ([*SWEEP, "--length", "0.5,1e39"], f"length: {TOO_LARGE}, got 1e\\+39"),
    ([*SWEEP, "--masspole", "1e30", "--length", "1e10"],
     f"masspole \\* length: {TOO_LARGE}, got 1e\\+40"),
    (["evaluate", "--episodes", "2", "--tau", "1e-300"], f"tau: {TOO_SMALL}, got 1e-300"),
])
def test_the_command_line_refuses_them_in_one_line_with_status_2(tmp_path, args, match):
    out = tmp_path / "out"
    done = _jaxpg(*args, "--out", str(out))
    assert done.returncode == 2, done.stderr
    assert re.fullmatch(f"jaxpg {args[0]}: error: {match}\n", done.stderr), done.stderr
    assert not out.exists()
