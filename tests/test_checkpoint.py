"""Checkpoints: round trips, the documented format, bad files, and atomic writes."""

import dataclasses
import functools
import hashlib
import json
import os
import pathlib
import re
import signal
import subprocess
import sys
import warnings

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from conftest import SMALL_CONFIG
from flax import serialization

import jaxpg
from jaxpg import atomic_files, cartpole, checkpoint, losses, policies, sweep, train
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


def test_metrics_of_other_iterations_than_the_configs_are_refused(tmp_path):
    metrics = _metrics()
    for other in (dataclasses.replace(CONFIG, iterations=CONFIG.iterations + 1),
                  dataclasses.replace(CONFIG, iterations=1)):
        with pytest.raises(ValueError, match=rf"^metrics: expected {other.iterations} iterations "
                                             rf"\(config's\) in every field, got 3$"):
            checkpoint.save(tmp_path, _params(other), other, metrics)
    assert not list(tmp_path.iterdir())


def test_preset_env_no_metrics_and_directories(tmp_path):
    config = TrainConfig(env="CartPole-v0")
    path = checkpoint.save(tmp_path, _params(config), config)  # a directory: DIR/policy.msgpack
    assert path == tmp_path / checkpoint.FILENAME
    loaded = checkpoint.load(tmp_path)
    assert loaded.config == config and loaded.config.env == "CartPole-v0"
    assert loaded.metrics is None


def test_a_final_separator_names_a_folder_to_create(tmp_path):
    path = checkpoint.save(f"{tmp_path}/missing/dir{os.sep}", _params(CONFIG), CONFIG)
    assert path == tmp_path / "missing" / "dir" / checkpoint.FILENAME
    assert checkpoint.load(tmp_path / "missing" / "dir").config == CONFIG
    assert checkpoint.save(f"{tmp_path}/missing/file", _params(CONFIG), CONFIG).is_file()


def _content(path):
    """The map of a checkpoint's content, and the file's own map."""
    payload = serialization.msgpack_restore(path.read_bytes())
    return serialization.msgpack_restore(payload["content"]), payload


def test_file_holds_the_documented_fields(tmp_path):
    path = checkpoint.save(tmp_path / "p.msgpack", _params(CONFIG), CONFIG, _metrics())
    payload, outer = _content(path)
    assert set(outer) == {"format", "format_version", "sha256", "content"}
    assert outer["format"] == "jaxpg-checkpoint" and outer["format_version"] == 3
    assert outer["sha256"] == hashlib.sha256(outer["content"]).hexdigest()
    assert set(payload) == {"jaxpg_version", "config", "policy_params", "metrics", "critic_params"}
    assert payload["critic_params"] is None  # (CONFIG's loss has no critic)
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


_OUTER = ("format", "format_version", "sha256", "content")  # the file's own map's fields


def _payload(version=checkpoint.FORMAT_VERSION, **changes):
    """A checkpoint file of CONFIG's parameters in format `version`, the fields of `changes`
    (those of `_OUTER` in the file's map, the others in its content) replaced."""
    fields = {
        "jaxpg_version": jaxpg.__version__,
        "config": checkpoint.config_to_dict(CONFIG),
        "policy_params": jax.tree.map(np.asarray, _params(CONFIG)),
        "metrics": None,
        **{name: value for name, value in changes.items() if name not in _OUTER},
    }
    outer = {"format": checkpoint.FORMAT, "format_version": version}
    if version < 3:  # earlier versions: the fields beside the format, unchecked
        outer.update(fields)
    else:
        content = serialization.msgpack_serialize(fields)
        outer.update(sha256=hashlib.sha256(content).hexdigest(), content=content)
    return serialization.msgpack_serialize(
        {**outer, **{name: value for name, value in changes.items() if name in _OUTER}})


@pytest.mark.parametrize(
    "content, problem",
    [
        (lambda: _payload()[:-100], "unreadable"),  # truncated
        (lambda: np.random.default_rng(0).bytes(256), "not a jaxpg checkpoint"),
        (lambda: json.dumps({"format": "jaxpg-checkpoint"}).encode(), "not a jaxpg checkpoint"),
        (lambda: serialization.msgpack_serialize({"weights": [1, 2]}), "format marker"),
        (lambda: _payload(format_version=checkpoint.FORMAT_VERSION + 1),
         r"format version 4 is newer than this jaxpg reads \(up to 3\); upgrade jaxpg$"),
        (lambda: _payload(config={**checkpoint.config_to_dict(CONFIG), "hidden": [7]}), "fit"),
        (lambda: _payload(config={"colour": "red"}), "damaged"),
        (lambda: serialization.msgpack_serialize([checkpoint.FORMAT]), "no msgpack map"),
        (lambda: _payload(sha256=hashlib.sha256(b"other").hexdigest()), "does not match"),
        (lambda: _payload(sha256=None), "its content or sha256 is missing"),
        # msgpack's own error says nothing here: its name does.
        (lambda: b"\x91" * 100_000 + b"\xc0", r"\(unreadable msgpack, StackError\)$"),
    ],
    ids=["truncated", "random", "json", "foreign-msgpack", "newer", "mismatch", "bad-config",
         "array", "other-checksum", "no-checksum", "nested"],
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
    with pytest.warns(RuntimeWarning, match="the weights hold NaN or infinity") as warned:
        loaded = checkpoint.load(path)
    assert len(warned) == 1 and str(path) in str(warned[0].message)
    np.testing.assert_array_equal(loaded.metrics.loss, metrics.loss)
    jax.tree.map(np.testing.assert_array_equal, loaded.policy_params, params)


def test_a_sweep_with_diverged_runs_warns_how_many(tmp_path):
    params = jax.tree.map(lambda leaf: np.stack([[leaf] * 3] * 2), _params(CONFIG))  # [2, 3, ...]
    params["params"]["Dense_1"]["bias"][1, 0] = np.inf
    params["params"]["Dense_0"]["kernel"][0, 2, 1, 1] = np.nan
    grid = [{"learning_rate": 0.01}, {"learning_rate": 0.02}]
    path = checkpoint.save(tmp_path, params, CONFIG, runs={"grid": grid, "seeds": [0, 1, 2]})
    with pytest.warns(RuntimeWarning, match="the weights of 2 of 6 runs hold NaN"):
        checkpoint.load(path)


def test_finite_weights_load_without_warning(tmp_path):
    path = checkpoint.save(tmp_path, _params(CONFIG), CONFIG)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        checkpoint.load(path)


def test_files_of_the_earlier_versions_load_unchecked(tmp_path):
    path = tmp_path / "policy.msgpack"
    path.write_bytes(_payload(version=1, jaxpg_version="0.1.0"))
    loaded = checkpoint.load(path)
    assert loaded.version == "0.1.0" and loaded.config == CONFIG and loaded.grid is None
    _assert_trees_equal(loaded.policy_params, _params(CONFIG))
    params = jax.tree.map(lambda leaf: np.stack([[leaf, leaf]]), _params(CONFIG))  # [1, 2, ...]
    path.write_bytes(_payload(version=2, policy_params=params,
                              runs={"grid": [{"learning_rate": 0.01}], "seeds": [3, 4]}))
    loaded = checkpoint.load(path)
    assert loaded.grid == [{"learning_rate": 0.01}] and loaded.seeds.tolist() == [3, 4]


def test_every_flipped_bit_is_refused_or_changes_nothing(tmp_path):
    path = checkpoint.save(tmp_path / "policy.msgpack", _params(CONFIG), CONFIG, _metrics())
    data = path.read_bytes()
    original = checkpoint.load(path)
    _, outer = _content(path)
    start = data.index(outer["content"])
    # 24 bits evenly spaced over the whole file, and one bit of every byte of the file's own map
    # (its keys, format, version and checksum), a different bit in each byte.
    around = [k for k in range(len(data)) if not start <= k < start + len(outer["content"])]
    bits = [*np.linspace(0, 8 * len(data) - 1, 24).astype(int), *(8 * k + k % 8 for k in around)]
    refused = []
    for bit in bits:
        flipped = bytearray(data)
        flipped[bit // 8] ^= 1 << (bit % 8)
        path.write_bytes(flipped)
        try:
            loaded = checkpoint.load(path)
        except ValueError as error:
            assert str(error).startswith(f"{path}: ") and "\n" not in str(error)
            refused.append(bit)
            continue
        assert loaded.config == original.config and loaded.version == original.version
        _assert_trees_equal(loaded.policy_params, original.policy_params)
        _assert_trees_equal(loaded.metrics, original.metrics)
    inside = [bit for bit in bits if bit // 8 not in around]
    assert inside and set(inside) <= set(refused)  # the content's: refused by the checksum


class _TanhPolicy(nn.Module):
    """A user's module: one tanh layer of 4 units, then a logit."""

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(1)(nn.tanh(nn.Dense(4)(obs)))[..., 0]


class _ReluPolicy(nn.Module):
    """Another class with the same parameters' shapes as `_TanhPolicy`."""

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(1)(nn.relu(nn.Dense(4)(obs)))[..., 0]


def test_a_module_of_another_class_is_refused_naming_the_one_expected(tmp_path):
    config = TrainConfig(policy=_TanhPolicy())
    path = checkpoint.save(tmp_path, _params(config), config)
    assert checkpoint.load(path, policy=_TanhPolicy()).config == config
    with pytest.raises(ValueError, match=r"^policy: the checkpoint was trained with "
                                         r"\S*_TanhPolicy, got \S*_ReluPolicy$"):
        checkpoint.load(path, policy=_ReluPolicy())


@pytest.mark.parametrize("given, said", [
    ({"policy": _TanhPolicy()}, "policy: the checkpoint was trained with the built-in network, "
                                "not a user's policy; pass no policy"),
    ({"loss": lambda *args: 0.0}, "loss: the checkpoint was trained with 'reinforce', not a "
                                  "user's loss; pass no loss"),
    ({"optimizer": optax.adam}, "optimizer: the checkpoint was trained with 'adam', not a user's "
                                "optimizer; pass no optimizer"),
])
def test_an_object_for_a_field_saved_as_jaxpgs_own_is_refused(tmp_path, given, said):
    """It would be ignored: the checkpoint's built-in network, loss or optimizer is loaded."""
    config = TrainConfig()
    path = checkpoint.save(tmp_path, _params(config), config)
    with pytest.raises(ValueError, match=f"^{re.escape(said)}$"):
        checkpoint.load(path, **given)


def test_an_optimizer_of_functools_partial_is_saved_and_checked_by_its_type(tmp_path):
    config = TrainConfig(optimizer=functools.partial(optax.adam, b1=0.8))
    path = checkpoint.save(tmp_path, _params(config), config)
    assert checkpoint.load(path, optimizer=config.optimizer).config == config
    with pytest.raises(ValueError, match=r"^optimizer: the checkpoint was trained with "
                                         r"functools.partial, got optax\S*\.sgd$"):
        checkpoint.load(path, optimizer=optax.sgd)


@pytest.mark.parametrize(("grid", "seeds", "problem"), [
    ([{"foo": 1.0}], [0], r"grid: unknown field\(s\) foo of CartPole-v1"),
    ([{"learning_rate": 0.01}], [0, 0], "seeds: must be distinct"),
    ([{"learning_rate": 0.01}, {"learning_rate": 0.01}], [0], "grid: the list repeats a setting"),
    ([{"discount": 2.0}], [0], r"discount: must be in \(0, 1\]"),
])
def test_runs_no_sweep_would_train_make_a_damaged_checkpoint(tmp_path, grid, seeds, problem):
    params = jax.tree.map(lambda leaf: np.stack([[leaf] * len(seeds)] * len(grid)),
                          _params(CONFIG))  # [G, S, ...], sealed with its checksum
    path = tmp_path / "policies.msgpack"
    path.write_bytes(_payload(policy_params=params, runs={"grid": grid, "seeds": seeds}))
    with pytest.raises(ValueError, match=f"^{path}: damaged jaxpg checkpoint \\(ValueError: "
                                         f"{problem}"):
        checkpoint.load(path)


@pytest.mark.parametrize("seed", [2**64 - 1, 2**32, -1])
def test_seeds_out_of_range_are_a_one_line_value_error(tmp_path, seed):
    params = jax.tree.map(lambda leaf: np.stack([[leaf]]), _params(CONFIG))  # [1, 1, ...]
    path = tmp_path / "policies.msgpack"
    path.write_bytes(_payload(policy_params=params,
                              runs={"grid": [{"learning_rate": 0.01}], "seeds": [seed]}))
    with pytest.raises(ValueError, match=r"runs.seeds: must be an integer in \[0, 2\*\*32\)"
                       ) as error:
        checkpoint.load(path)
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


def test_no_regular_file_is_refused_without_reading(tmp_path):
    fifo = tmp_path / "policy.msgpack"
    os.mkfifo(fifo)  # opened for reading as a file, it would wait for a writer forever
    with pytest.raises(ValueError, match=r"policy.msgpack: not a regular file \(a FIFO\)"):
        checkpoint.load(tmp_path)
    (tmp_path / "zero.msgpack").symlink_to("/dev/zero")  # as a file, endless
    with pytest.raises(ValueError, match=r"zero.msgpack: not a regular file \(a character"):
        checkpoint.load(tmp_path / "zero.msgpack")


def test_a_sweeps_runs_in_one_file(tmp_path, small_sweep):
    path = checkpoint.save_sweep(tmp_path, small_sweep)  # the result's own config
    assert small_sweep.config == SMALL_CONFIG
    assert path == tmp_path / "policies.msgpack"
    payload, _ = _content(path)
    assert payload["runs"]["seeds"] == [0, 1, 2, 3, 4]
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
    with pytest.raises(ValueError, match="config: the sweep's result carries none"):
        checkpoint.save_sweep(tmp_path, small_sweep._replace(config=None))


def test_a_sweeps_run_takes_its_physics_and_bad_runs_are_refused(tmp_path):
    grid = [{"learning_rate": 0.01, "discount": 0.95, "entropy_coef": 0.0, "length": 1.0}]
    params = jax.tree.map(lambda leaf: np.stack([[leaf, leaf]]), _params(CONFIG))  # [1, 2, ...]
    path = checkpoint.save(tmp_path / "p.msgpack", params, CONFIG,
                           runs={"grid": grid, "seeds": [4, 7]})
    run = checkpoint.select_run(checkpoint.load(path), 0, 1)
    assert run.config.env == CONFIG.env.replace(length=1.0)
    for g, s in [(np.int32(0), np.int64(1)), (np.int64(0), np.array([1])[0])]:  # numpy integers
        picked = checkpoint.select_run(checkpoint.load(path), g, s)
        assert picked.config == run.config
        jax.tree.map(np.testing.assert_array_equal, picked.policy_params, run.policy_params)
    for g, s in [(1, 0), (0, 2), (-1, 0), (0, 1.0), (True, 0), (np.True_, 0), (np.array(0), 0)]:
        with pytest.raises(ValueError, match=r"^run: expected g in \[0, 1\) and s in \[0, 2\), "
                                             r"integers, got g=.*, s=.*$"):
            checkpoint.select_run(checkpoint.load(path), g, s)
    with pytest.raises(ValueError, match="^run: the checkpoint holds one run"):
        checkpoint.select_run(checkpoint.load(checkpoint.save(tmp_path, _params(CONFIG), CONFIG)),
                              0, 0)
    with pytest.raises(ValueError, match="policy_params: parameters do not fit"):
        checkpoint.save(tmp_path / "q.msgpack", params, CONFIG, runs={"grid": grid, "seeds": [4]})
    two = [*grid, {**grid[0], "length": 1.5}]  # two settings, parameters of one
    path.write_bytes(_payload(policy_params=params, runs={"grid": two, "seeds": [4, 7]}))
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


# --- A loss's critic ------------------------------------------------------------------------------

BASELINE = TrainConfig(iterations=2, episodes=3, max_steps=20, loss="baseline")
WITH_CRITIC = dataclasses.replace(CONFIG, loss="baseline")  # CONFIG's network, and a critic


def _critic(config, seed=0):
    return policies.init_network(jax.random.PRNGKey(seed), losses.critic(config.loss))


@pytest.fixture(scope="module")
def baseline_sweep():
    return sweep(BASELINE, seeds=range(2), grid={"learning_rate": [0.01, 0.02]},
                 show_progress=False)


def test_a_sweeps_critic_is_saved_and_each_run_takes_its_own(tmp_path, baseline_sweep):
    checkpoint.save_sweep(tmp_path, baseline_sweep)
    loaded = checkpoint.load(tmp_path)
    _assert_trees_equal(loaded.critic_params, baseline_sweep.critic_params)
    run = checkpoint.select_run(loaded, 1, 0)  # seed 0 at the second learning rate
    _assert_trees_equal(run.critic_params,
                        jax.tree.map(lambda leaf: leaf[1, 0], baseline_sweep.critic_params))


def test_a_loaded_critic_warm_starts_training_as_the_one_saved(tmp_path):
    result = train(BASELINE, seed=0, show_progress=False)
    path = checkpoint.save(tmp_path, result.policy_params, BASELINE, result.metrics,
                           critic_params=result.critic_params)
    loaded = checkpoint.load(path)
    _assert_trees_equal(loaded.critic_params, result.critic_params)
    one = dataclasses.replace(BASELINE, iterations=1)
    warm, direct, fresh = (
        train(one, seed=1, init_params=loaded.policy_params, init_critic_params=critic,
              show_progress=False)
        for critic in (loaded.critic_params, result.critic_params, None))
    _assert_trees_equal(warm.critic_params, direct.critic_params)
    _assert_trees_equal(warm.policy_params, direct.policy_params)
    # Without the saved critic, the critic restarts from its initialisation: other weights.
    assert not all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(warm.critic_params),
                                                        jax.tree.leaves(fresh.critic_params)))


def test_ppos_critic_round_trips(tmp_path):
    config = dataclasses.replace(CONFIG, loss="ppo")
    path = checkpoint.save(tmp_path, _params(config), config, critic_params=_critic(config, 1))
    _assert_trees_equal(checkpoint.load(path).critic_params, _critic(config, 1))


def test_files_without_a_critic_load_without_one(tmp_path):
    path = tmp_path / "policy.msgpack"
    # As files were written before critics were saved: no critic_params field.
    path.write_bytes(_payload(config=checkpoint.config_to_dict(WITH_CRITIC)))
    loaded = checkpoint.load(path)
    assert loaded.critic_params is None and loaded.config == WITH_CRITIC
    saved = checkpoint.save(tmp_path, _params(WITH_CRITIC), WITH_CRITIC)  # saved without one
    assert checkpoint.load(saved).critic_params is None


def test_save_refuses_a_critic_the_loss_has_not_other_shapes_or_a_whole_result(tmp_path):
    with pytest.raises(ValueError, match="^critic_params: the loss 'reinforce' has no critic$"):
        checkpoint.save(tmp_path, _params(CONFIG), CONFIG, critic_params=_critic(WITH_CRITIC))
    with pytest.raises(ValueError, match="^critic_params: parameters do not fit the critic"):
        checkpoint.save(tmp_path, _params(WITH_CRITIC), WITH_CRITIC,
                        critic_params=_params(WITH_CRITIC))
    whole = jaxpg.TrainResult(_params(WITH_CRITIC), None, None, _critic(WITH_CRITIC))
    for field, given in [("policy_params", (whole, None)), ("critic_params", (None, whole))]:
        with pytest.raises(ValueError, match=f"^{field}: expected parameters, got a TrainResult; "
                                             f"pass its .{field}$"):
            checkpoint.save(tmp_path, given[0] or _params(WITH_CRITIC), WITH_CRITIC,
                            critic_params=given[1])
    # Parameters that `load` would refuse: not saved either.
    with pytest.raises(ValueError, match=r"^policy_params\.params\..*: expected float32 or "
                                         r"float64 values, got float16$"):
        checkpoint.save(tmp_path, jax.tree.map(lambda leaf: np.asarray(leaf, np.float16),
                                               _params(CONFIG)), CONFIG)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("config, critic, problem", [
    (CONFIG, lambda: _critic(WITH_CRITIC), "has no critic"),
    (WITH_CRITIC, lambda: {"params": {"w": np.ones(3, np.int8)}},
     "critic_params.params.w: expected float32 or float64"),
    (WITH_CRITIC, lambda: _params(CONFIG), "do not fit the critic"),
], ids=["no-critic", "int8", "policy-shaped"])
def test_files_of_bad_critics_are_one_line_errors_naming_the_path(tmp_path, config, critic,
                                                                  problem):
    path = tmp_path / "policy.msgpack"
    path.write_bytes(_payload(config=checkpoint.config_to_dict(config),
                              critic_params=jax.tree.map(np.asarray, critic())))
    with pytest.raises(ValueError, match=problem) as error:
        checkpoint.load(path)
    assert str(error.value).startswith(f"{path}: damaged") and "\n" not in str(error.value)
