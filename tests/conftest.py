"""Fixtures and helpers shared by the tests."""

from jaxpg import xla_options

# The tests run under the XLA setting that `train` and `sweep` give a process whose JAX has not
# started (`xla_options.configure_unstarted`): set here, before any test starts JAX, rather than by
# whichever test trains first.
xla_options.configure_xla()

import contextlib
import os
import pathlib
import subprocess
import sys

import jax
import numpy as np
import pytest

from jaxpg import TrainConfig
from jaxpg.sweeps import sweep

# Ten short runs: five seeds by two learning rates. The device tests run the same sweep as
# `jaxpg sweep --iterations 3 --episodes 3 --max-steps 20 --seeds 5 --lr 0.01,0.02`.
SMALL_CONFIG = TrainConfig(iterations=3, episodes=3, max_steps=20)
SMALL_SEEDS = range(5)
SMALL_GRID = {"learning_rate": [0.01, 0.02]}


@pytest.fixture(scope="session")
def small_sweep():
    """The small sweep in one chunk on one device, the reference for chunked and sharded runs."""
    return sweep(SMALL_CONFIG, SMALL_SEEDS, SMALL_GRID, show_progress=True)


_HOLD = """
import sys, time
from jaxpg import atomic_files
atomic_files.claim(sys.argv[1])
print("held", flush=True)
time.sleep(120)
"""


@contextlib.contextmanager
def claimed_by_another_process(out):
    """Inside the block, another process holds the output folder `out` (`atomic_files.claim`)."""
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(out)], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        yield
    finally:
        holder.kill()
        holder.wait()


@contextlib.contextmanager
def xla_compiles():
    """The names of the programs XLA compiles inside the block, one entry per compile."""
    names = []

    def listen(event, duration, fun_name=None, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            names.append(fun_name)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def check_alone(*args):
    """`benchmarks/check_alone.py` with `args`, under its own XLA setting (that of the `jaxpg`
    command): the finished process, its output captured."""
    script = pathlib.Path(__file__).resolve().parents[1] / "benchmarks" / "check_alone.py"
    return subprocess.run([sys.executable, str(script), *args],
                          env={**os.environ, "XLA_FLAGS": ""}, capture_output=True, text=True)


def assert_trained_alike(actual, expected):
    """Two trees of training results are equal bit for bit, but for gradient norms (leaves whose
    path names `grad_norm`), equal to one unit in the last place: a statistic nothing is computed
    from, whose multiplications and additions LLVM can fuse into one rounding in one program's
    layout and not in another's (seen with the runs split over two CPU devices).
    `benchmarks/check_alone.py` compares every bit of runs alone and side by side.
    """
    expected_leaves, structure = jax.tree_util.tree_flatten_with_path(expected)
    actual_leaves = jax.tree.leaves(actual)
    assert jax.tree.structure(actual) == structure
    for (path, want), got in zip(expected_leaves, actual_leaves):
        name = jax.tree_util.keystr(path)
        if "grad_norm" in name:
            np.testing.assert_array_max_ulp(np.asarray(got), np.asarray(want), maxulp=1)
        else:
            np.testing.assert_array_equal(np.asarray(got), np.asarray(want), err_msg=name)
