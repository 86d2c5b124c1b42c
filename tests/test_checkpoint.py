"""Checkpoints: round trips, the documented format, bad files, and atomic writes."""

import dataclasses
import json
import os
import pathlib
import signal
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import SMALL_CONFIG
from flax import serialization

import jaxpg
from jaxpg import atomic_files, cartpole, checkpoint, policies
from jaxpg.iteration import Metrics
from jaxpg.train_config import TrainConfig

CONFIG = TrainConfig(
    iterations=3,
    hidden=(4, 3),
    activation="tanh",
    optimizer="sgd",
    env=cartpole.make_params(masspole=0.2, integrator="semi-implicit", sutton_barto_reward=True),
    learning_rate=0.05,
    discount=0.9,
)


def _params(config, seed=0):
    return policies.init_network(jax.random.PRNGKey(seed), config.network)


def _metrics(iterations=3):
    values = jnp.arange(iterations, dtype=jnp.float32)
    return Metrics(values, values - 1, values + 1, values * 2, -values, values / 2)


def _assert_trees_equal(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(x, y)


def test_round_trip_keeps_params_config_metrics_and_version(tmp_path):
    params, metrics = _params(CONFIG), _metrics()
    path = checkpoint.save(tmp_path / "run" / "policy.msgpack", params, CONFIG, metrics)
    loaded = checkpoint.load(path)
    assert loaded.config == CONFIG
    assert isinstance(loaded.config.env, cartpole.CartPoleParams)
    assert loaded.version == jaxpg.__version__
    _assert_trees_equal(loaded.policy_params, params)
    _assert_trees_equal(loaded.metrics, metrics)
    # The loaded network acts as the saved one.
    obs = jnp.array([[0.01, -0.02, 0.03, 0.04]])
    np.testing.assert_array_equal(
        CONFIG.network.apply(loaded.policy_params, obs), CONFIG.network.apply(params, obs)
    )


def test_preset_env_no_metrics_and_directories(tmp_path):
    config = TrainConfig(env="CartPole-v0")
    path = checkpoint.save(tmp_path, _params(config), config)  # a directory: DIR/policy.msgpack
    assert path == tmp_path / checkpoint.FILENAME
    loaded = checkpoint.load(tmp_path)
    assert loaded.config == config and loaded.config.env == "CartPole-v0"
    assert loaded.metrics is None


def test_file_holds_the_documented_fields(tmp_path):
    path = checkpoint.save(tmp_path / "p.msgpack", _params(CONFIG), CONFIG, _metrics())
    payload = serialization.msgpack_restore(path.read_bytes())
    assert set(payload) == {
        "format", "format_version", "jaxpg_version", "config", "policy_params", "metrics"
    }
    assert payload["format"] == "jaxpg-checkpoint" and payload["format_version"] == 1
    assert payload["config"]["hidden"] == [4, 3]
    assert payload["config"]["env"]["masspole"] == pytest.approx(0.2)
    assert payload["config"]["env"]["integrator"] == "semi-implicit"
    assert payload["policy_params"]["params"]["Dense_0"]["kernel"].shape == (4, 4)
    assert payload["metrics"]["mean_return"].tolist() == [0.0, 1.0, 2.0]


def test_save_rejects_params_of_another_network(tmp_path):
    with pytest.raises(ValueError, match="policy_params"):
        checkpoint.save(tmp_path / "p.msgpack", _params(TrainConfig()), CONFIG)
    with pytest.raises(ValueError, match="config"):
        checkpoint.save(tmp_path / "p.msgpack", _params(CONFIG), dataclasses.asdict(CONFIG))
    assert list(tmp_path.iterdir()) == []


def _payload(**changes):
    payload = {
        "format": checkpoint.FORMAT,
        "format_version": checkpoint.FORMAT_VERSION,
        "jaxpg_version": jaxpg.__version__,
        "config": checkpoint.config_to_dict(CONFIG),
        "policy_params": jax.tree.map(np.asarray, _params(CONFIG)),
        "metrics": None,
    }
    return serialization.msgpack_serialize({**payload, **changes})


@pytest.mark.parametrize(
    "content, problem",
    [
        (lambda: _payload()[:-100], "unreadable"),  # truncated
        (lambda: np.random.default_rng(0).bytes(256), "not a jaxpg checkpoint"),
        (lambda: json.dumps({"format": "jaxpg-checkpoint"}).encode(), "not a jaxpg checkpoint"),
        (lambda: serialization.msgpack_serialize({"weights": [1, 2]}), "format marker"),
        (lambda: _payload(format_version=checkpoint.FORMAT_VERSION + 1), "newer"),
        (lambda: _payload(config={**checkpoint.config_to_dict(CONFIG), "hidden": [7]}), "fit"),
        (lambda: _payload(config={"colour": "red"}), "damaged"),
    ],
    ids=["truncated", "random", "json", "foreign-msgpack", "newer", "mismatch", "bad-config"],
)
def test_bad_files_raise_a_value_error_naming_the_path(tmp_path, content, problem):
    path = tmp_path / "policy.msgpack"
    path.write_bytes(content())
    with pytest.raises(ValueError, match=problem) as error:
        checkpoint.load(path)
    assert str(path) in str(error.value)


def _with_kernel(values):
    """CONFIG's parameters with the first layer's kernel replaced by `values`."""
    params = jax.tree.map(np.asarray, _params(CONFIG))
    kernel = params["params"]["Dense_0"]["kernel"]
    params["params"]["Dense_0"]["kernel"] = np.broadcast_to(values, kernel.shape)
    return params


@pytest.mark.parametrize(
    "changes, problem",
    [
        ({"policy_params": _with_kernel(np.complex64(1 + 2j))},
         "kernel: expected float32 or float64"),
        ({"policy_params": _with_kernel(np.int8(3))}, "kernel: expected float32 or float64"),
        ({"metrics": {**_metrics()._asdict(), "loss": "small"}},
         "metrics.loss: expected float32 or float64 values, got str"),
        ({"format_version": True}, "bad format_version True"),
        ({"format_version": 1.0}, "bad format_version 1.0"),
    ],
    ids=["complex64", "int8", "text-metric", "bool-version", "float-version"],
)
def test_contents_of_the_wrong_type_raise_one_line_naming_the_path_and_field(
        tmp_path, changes, problem):
    path = tmp_path / "policy.msgpack"
    path.write_bytes(_payload(**changes))
    with pytest.raises(ValueError, match=problem) as error:
        checkpoint.load(path)
    assert str(path) in str(error.value) and "\n" not in str(error.value)


def test_weights_and_metrics_of_a_diverged_run_load(tmp_path):
    metrics = _metrics()._replace(loss=np.array([1.0, np.nan, np.inf], np.float32))
    params = _with_kernel(np.float32(np.nan))
    path = tmp_path / "policy.msgpack"
    path.write_bytes(_payload(policy_params=params,
                              metrics=jax.tree.map(np.asarray, metrics._asdict())))
    loaded = checkpoint.load(path)
    np.testing.assert_array_equal(loaded.metrics.loss, metrics.loss)
    jax.tree.map(np.testing.assert_array_equal, loaded.policy_params, params)


def test_a_sweeps_runs_in_one_file(tmp_path, small_sweep):
    path = checkpoint.save_sweep(tmp_path, small_sweep, SMALL_CONFIG)
    assert path == tmp_path / "policies.msgpack"
    payload = serialization.msgpack_restore(path.read_bytes())
    assert payload["format_version"] == 2 and payload["runs"]["seeds"] == [0, 1, 2, 3, 4]
    assert payload["policy_params"]["params"]["Dense_0"]["kernel"].shape == (2, 5, 4, 5)
    loaded = checkpoint.load(tmp_path)  # the folder `jaxpg sweep` writes
    assert loaded.grid == small_sweep.grid and loaded.config == SMALL_CONFIG
    np.testing.assert_array_equal(loaded.seeds, small_sweep.seeds)
    _assert_trees_equal(loaded.policy_params, small_sweep.policy_params)
    _assert_trees_equal(loaded.metrics, small_sweep.metrics)
    run = checkpoint.select_run(loaded, 1, 3)  # seed 3 at the second learning rate
    _assert_trees_equal(run.policy_params,
                        jax.tree.map(lambda leaf: leaf[1, 3], small_sweep.policy_params))
    assert run.config == dataclasses.replace(SMALL_CONFIG, learning_rate=0.02)
    assert run.metrics.mean_return.shape == (3,) and run.grid is None


def test_a_sweeps_run_takes_its_physics_and_bad_runs_are_refused(tmp_path):
    grid = [{"learning_rate": 0.01, "discount": 0.95, "entropy_coef": 0.0, "length": 1.0}]
    params = jax.tree.map(lambda leaf: np.stack([[leaf, leaf]]), _params(CONFIG))  # [1, 2, ...]
    path = checkpoint.save(tmp_path / "p.msgpack", params, CONFIG,
                           runs={"grid": grid, "seeds": [4, 7]})
    run = checkpoint.select_run(checkpoint.load(path), 0, 1)
    assert run.config.env == CONFIG.env.replace(length=1.0)
    for g, s in [(1, 0), (0, 2), (-1, 0)]:
        with pytest.raises(ValueError, match=r"^run: expected g in \[0, 1\) and s in \[0, 2\)"):
            checkpoint.select_run(checkpoint.load(path), g, s)
    with pytest.raises(ValueError, match="^run: the checkpoint holds one run"):
        checkpoint.select_run(checkpoint.load(checkpoint.save(tmp_path, _params(CONFIG), CONFIG)),
                              0, 0)
    with pytest.raises(ValueError, match="policy_params: parameters do not fit"):
        checkpoint.save(tmp_path / "q.msgpack", params, CONFIG, runs={"grid": grid, "seeds": [4]})
    path.write_bytes(_payload(format_version=2, policy_params=params,
                              runs={"grid": grid * 2, "seeds": [4, 7]}))
    with pytest.raises(ValueError, match="damaged.*do not fit"):
        checkpoint.load(path)


def test_missing_file_raises_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="policy.msgpack"):
        checkpoint.load(tmp_path)


def test_failed_write_leaves_the_previous_checkpoint_and_no_temporary_file(tmp_path, monkeypatch):
    path = checkpoint.save(tmp_path / "policy.msgpack", _params(CONFIG), CONFIG)

    def write_half_then_fail(self, data):
        with open(self, "wb") as f:
            f.write(data[: len(data) // 2])
        raise OSError("No space left on device")

    monkeypatch.setattr(pathlib.Path, "write_bytes", write_half_then_fail)
    newer = dataclasses.replace(CONFIG, learning_rate=0.5)
    with pytest.raises(OSError, match="No space"):
        checkpoint.save(path, _params(CONFIG, seed=1), newer)
    assert checkpoint.load(path).config == CONFIG
    assert [p.name for p in tmp_path.iterdir()] == ["policy.msgpack"]


_KILLED_SAVE = """
import os, sys, time
from jaxpg import checkpoint

def stall(fd):  # the new file is written but not yet flushed or renamed
    print("writing", flush=True)
    time.sleep(120)

path = sys.argv[1]
old = checkpoint.load(path)
os.fsync = stall
config = old.config.__class__(**{**old.config.__dict__, "learning_rate": 0.5})
checkpoint.save(path, old.policy_params, config)
"""


def test_killed_save_leaves_the_previous_checkpoint(tmp_path):
    path = checkpoint.save(tmp_path / "policy.msgpack", _params(CONFIG), CONFIG)
    process = subprocess.Popen(
        [sys.executable, "-c", _KILLED_SAVE, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )
    try:
        assert process.stdout.readline().strip() == "writing"
        temporary = [p for p in tmp_path.iterdir() if p.name != "policy.msgpack"]
        assert len(temporary) == 1  # the new checkpoint, complete but not yet in place
        assert checkpoint.load(temporary[0]).config.learning_rate == 0.5
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    assert process.returncode == -signal.SIGKILL
    assert checkpoint.load(path).config == CONFIG


def test_atomic_write_replaces_content_with_ordinary_permissions(tmp_path):
    path = tmp_path / "notes.txt"
    atomic_files.atomic_write(path, "first")
    atomic_files.atomic_write(path, b"second")
    assert path.read_text() == "second"
    ordinary = tmp_path / "ordinary.txt"
    ordinary.write_text("x")
    assert path.stat().st_mode == ordinary.stat().st_mode  # the umask's, not mkstemp's 0600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "ordinary.txt"]
