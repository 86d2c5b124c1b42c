"""Hostile files in place of the ones `jaxpg compare` and `jaxpg evaluate` read: a FIFO, which an
ordinary open would wait on for a writer forever, and /dev/zero, which an ordinary read would read
without end. Each command runs in its own process under a time limit, so that a regression fails
the test instead of hanging it, and must exit 2 with one line naming the file. A checkpoint of
NaN weights evaluates, with one line of warning. A FIFO where a file is to be written stays (a
rename would have replaced it, /dev/null as well), and returns too large to sum are refused."""

import json
import os
import stat
import subprocess
import sys
import warnings

import jax
import numpy as np
import pytest

from jaxpg import TrainConfig, checkpoint, policies, report

TIME_LIMIT = 120  # seconds: a few for the command, the rest for a loaded machine


def _sweep_folder(folder):
    """A folder as `jaxpg sweep --out` writes it, as far as `jaxpg compare` reads it: 2 settings
    of 3 seeds, 4 iterations."""
    folder.mkdir()
    grid = [{"learning_rate": rate, "discount": 0.95} for rate in (0.01, 0.02)]
    summary = {"format": report.SWEEP_FORMAT, "grid": grid,
               "config": checkpoint.config_to_dict(TrainConfig(iterations=4))}
    (folder / "summary.json").write_text(json.dumps(summary))
    np.savez(folder / "metrics.npz", mean_return=np.arange(24.0).reshape(2, 3, 4))
    return folder


def _hostile(path, kind):
    """Puts a FIFO, or a link to /dev/zero, at `path`."""
    path.unlink(missing_ok=True)
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to("/dev/zero")


def _run(*args):
    """The `jaxpg` command's exit status and stderr's lines, within `TIME_LIMIT`."""
    done = subprocess.run([sys.executable, "-m", "jaxpg.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=TIME_LIMIT)
    return done.returncode, done.stderr.strip().splitlines()


@pytest.mark.parametrize("name", ["summary.json", "metrics.npz"])
@pytest.mark.parametrize("kind, what", [("fifo", "a FIFO"), ("zero", "a character device")])
def test_compare_refuses_what_is_no_regular_file(tmp_path, name, kind, what):
    folder = _sweep_folder(tmp_path / "sweep")
    _hostile(folder / name, kind)
    status, lines = _run("compare", folder, "--out", tmp_path / "out")
    assert status == 2 and len(lines) == 1
    assert lines[0] == f"jaxpg compare: error: {folder / name}: not a regular file ({what})"
    assert not (tmp_path / "out").exists()


def test_the_folder_before_the_damage_compares(tmp_path):
    """The folder the other tests damage is one `jaxpg compare` reads."""
    folder = _sweep_folder(tmp_path / "sweep")
    assert report.compare([folder], reps=50)["settings"][1]["runs"] == 3


@pytest.mark.parametrize("kind, what", [("fifo", "a FIFO"), ("zero", "a character device")])
def test_evaluate_refuses_a_checkpoint_that_is_no_regular_file(tmp_path, kind, what):
    path = tmp_path / checkpoint.FILENAME
    _hostile(path, kind)
    status, lines = _run("evaluate", "--policy", tmp_path)
    assert status == 2 and len(lines) == 1
    assert lines[0] == f"jaxpg evaluate: error: {path}: not a regular file ({what})"


def test_evaluate_warns_in_one_line_of_a_checkpoint_of_nan_weights(tmp_path):
    config = TrainConfig(hidden=(4,))
    params = policies.init_network(jax.random.PRNGKey(0), config.network)
    path = checkpoint.save(tmp_path, jax.tree.map(lambda leaf: leaf * np.nan, params), config)
    status, lines = _run("evaluate", "--policy", tmp_path, "--episodes", "2")
    assert status == 0
    assert [line for line in lines if str(path) in line] == [
        f"jaxpg: warning: {path}: the weights hold NaN or infinity (training diverged); such a "
        f"policy's actions mean nothing"]


def test_a_file_is_not_written_over_a_fifo(tmp_path):
    config = TrainConfig(hidden=(4,))
    params = policies.init_network(jax.random.PRNGKey(0), config.network)
    fifo, gif = tmp_path / checkpoint.FILENAME, tmp_path / "episode.gif"
    os.mkfifo(fifo)
    os.mkfifo(gif)
    with pytest.raises(ValueError, match=f"^path: {fifo} is a FIFO, not a regular file; "):
        checkpoint.save(fifo, params, config)
    status, lines = _run("render", "--out", gif, "--max-steps", "3")
    assert status == 2 and lines == [f"jaxpg render: error: out: {gif} is a FIFO, not a regular "
                                     f"file; give a file's path (it is created if missing)"]
    assert all(stat.S_ISFIFO(path.stat().st_mode) for path in tmp_path.iterdir())


@pytest.mark.parametrize("files", [("policies.msgpack", "summary.json"),
                                   ("policy.msgpack", "metrics.json")])
def test_a_checkpoint_is_not_saved_into_a_folder_of_results(tmp_path, files):
    """Into a sweep's folder it would have made a folder of two results (which `evaluate
    --policy` then read as the single policy); into a train folder, replaced the policy that the
    folder's metrics describe."""
    config = TrainConfig(hidden=(4,))
    params = policies.init_network(jax.random.PRNGKey(0), config.network)
    folder = tmp_path / "results"
    folder.mkdir()
    for name in files:
        (folder / name).write_text("kept")
    for path in (folder, folder / "mine.msgpack"):
        with pytest.raises(ValueError, match=f"^path: .* lies inside {folder}, a folder of jaxpg's "
                                             "results"):
            checkpoint.save(path, params, config)
    assert sorted(p.name for p in folder.iterdir()) == sorted(files)
    assert all((folder / name).read_text() == "kept" for name in files)


def test_compare_refuses_returns_too_large_to_sum(tmp_path):
    """1e308 is finite, but the mean of two overflows: refused as beyond float32, as training's."""
    folder = _sweep_folder(tmp_path / "sweep")
    np.savez(folder / "metrics.npz", mean_return=np.full((2, 3, 4), 1e308))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (no overflow on the way)
        with pytest.raises(ValueError, match=f"^{folder / 'metrics.npz'}: mean_return: must be at "
                                             r"most 3\.403e\+38 in magnitude"):
            report.compare([folder], reps=50)
