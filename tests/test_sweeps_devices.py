"""Sweeps over several devices and processes train every run exactly as one device does.

The device count is fixed when JAX starts, so each sweep here runs in fresh processes: two CPU
devices in one process (XLA's `--xla_force_host_platform_device_count`), and two processes joined
by `jax.distributed` through the command line.
"""

import os
import socket
import subprocess
import sys

import jax
import numpy as np
from conftest import SMALL_CONFIG, SMALL_GRID, SMALL_SEEDS, assert_trained_alike

from jaxpg import xla_options

TWO_DEVICES = """
import sys
import jax
import numpy as np
from jaxpg import TrainConfig
from jaxpg.sweeps import sweep

assert jax.device_count() == 2, jax.devices()
swept = sweep({config!r}, {seeds!r}, {grid!r})
np.savez(sys.argv[1], *jax.tree.leaves((swept.policy_params, swept.metrics)))
"""


def _leaves(npz_path):
    with np.load(npz_path) as npz:
        return [npz[f"arr_{i}"] for i in range(len(npz.files))]


def test_two_devices_train_as_one(small_sweep, tmp_path):
    script = TWO_DEVICES.format(config=SMALL_CONFIG, seeds=SMALL_SEEDS, grid=SMALL_GRID)
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    out = tmp_path / "two_devices.npz"
    result = subprocess.run([sys.executable, "-c", script, str(out)], env=env, capture_output=True,
                            text=True)
    assert result.returncode == 0, result.stderr
    expected = (small_sweep.policy_params, small_sweep.metrics)
    assert_trained_alike(jax.tree.unflatten(jax.tree.structure(expected), _leaves(out)), expected)
    # One line per iteration for the runs of both devices.
    lines = [line for line in result.stderr.splitlines() if "Iteration:" in line]
    assert [line.split(",")[0] for line in lines] == [f"Iteration: {i}/3" for i in (1, 2, 3)]
    assert all("(mean of 10 runs)" in line for line in lines)


def _free_port():
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_train_as_one_and_process_0_writes(small_sweep, tmp_path):
    common = ["sweep", "--iterations", "3", "--episodes", "3", "--max-steps", "20", "--seeds", "5",
              "--lr", "0.01,0.02", "--no-cache", "--coordinator", f"localhost:{_free_port()}",
              "--num-processes", "2"]
    # XLA's default setting, as in this process: the command's own rounds the gradient norm
    # differently in its last bit (tests/test_xla_options.py).
    env = {**os.environ, "XLA_FLAGS": xla_options.XLA_DEFAULTS}
    processes = [
        subprocess.Popen([sys.executable, "-m", "jaxpg.cli", *common, "--process-id", str(i),
                          "--out", str(tmp_path / f"out{i}")], env=env, stderr=subprocess.PIPE,
                         text=True)
        for i in range(2)
    ]
    errors = [p.communicate(timeout=300)[1] for p in processes]
    assert [p.returncode for p in processes] == [0, 0], errors
    assert not (tmp_path / "out1").exists()
    with np.load(tmp_path / "out0" / "metrics.npz") as npz:
        expected = small_sweep.metrics.columns()
        assert_trained_alike({name: npz[name] for name in expected}, expected)
