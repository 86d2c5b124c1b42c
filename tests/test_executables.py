"""Training programs compiled ahead of their calls, and kept on disk whole: reused by a later
process without tracing or compiling."""

import functools
import json
import logging
import os
import pathlib
import pickle
import stat
import subprocess
import sys
import tempfile

import chex
import jax
import numpy as np
import pytest
from conftest import xla_compiles
from jax.experimental.compilation_cache import compilation_cache

from jaxpg import executables, iteration, policies, programs, reinforce, schedule
from jaxpg.train_config import TrainConfig

CONFIG = TrainConfig(iterations=3, episodes=3, max_steps=20)


def _inputs(seeds):
    """(keys, hyperparams) of `seeds` under CONFIG's settings."""
    hyperparams = CONFIG.hyperparams.per_run(len(seeds))
    return reinforce.run_keys(seeds), hyperparams


def _train(seeds, place=lambda leaf: leaf):
    part = jax.tree.map(place, _inputs(seeds))
    (result,) = schedule.train_blocks(programs.compiled_program(CONFIG), CONFIG.iterations, [part])
    return result


def _new_process():
    """Forgets every program this process holds, as a new process would start."""
    programs._program.cache_clear()


@pytest.fixture
def store(tmp_path):
    executables.keep_programs(tmp_path)
    _new_process()
    yield tmp_path
    executables.stop_keeping_programs()
    _new_process()


def _not_again(*args, **kwargs):
    raise AssertionError("traced or compiled, though the program was kept")


def test_a_kept_program_is_loaded_and_trains_exactly_the_same(store, monkeypatch):
    expected = _train([0, 1])  # store is on: compiled and written
    # Two runs train alone (`schedule.ALONE_PER_CORE`).
    assert sorted(p.name.split("-")[0] for p in store.iterdir()) == ["init", "iterate_alone"]
    _new_process()
    monkeypatch.setattr(jax.stages.Lowered, "compile", _not_again)
    monkeypatch.setattr(policies, "init_network", _not_again)  # traced by init
    monkeypatch.setattr(programs, "iterate", _not_again)  # traced by iterate
    chex.assert_trees_all_equal(_train([0, 1]), expected)
    executables.stop_keeping_programs()
    _new_process()
    monkeypatch.undo()
    chex.assert_trees_all_equal(_train([0, 1]), expected)  # the plain jitted program


def test_other_shapes_and_settings_get_programs_of_their_own(store):
    _train([0])
    _train(range(schedule.ALONE_PER_CORE * schedule.usable_cores() + 1))  # in blocks
    assert len(list(store.iterdir())) == 4  # init and iterate, for a run alone and for a block


def test_a_damaged_file_is_compiled_again_and_replaced(store):
    expected = _train([3])
    for path in store.iterdir():
        path.write_bytes(b"not a program")
    _new_process()
    chex.assert_trees_all_equal(_train([3]), expected)
    assert all(path.stat().st_size > 1000 for path in store.iterdir())


def test_nothing_is_kept_beside_jaxs_persistent_cache(store, tmp_path_factory):
    previous = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", str(tmp_path_factory.mktemp("xla")))
    try:
        _train([4])
    finally:
        jax.config.update("jax_compilation_cache_dir", previous)
        compilation_cache.reset_cache()
    assert list(store.iterdir()) == []


def test_a_program_from_jaxs_cache_is_not_kept(store, monkeypatch):
    """Whatever JAX's cache supplies (here: a compile that reports a hit) is used, never written."""
    compile_now = jax.stages.Lowered.compile

    def from_jaxs_cache(lowered, *args, **kwargs):
        jax.monitoring.record_event("/jax/compilation_cache/cache_hits")
        return compile_now(lowered, *args, **kwargs)

    monkeypatch.setattr(jax.stages.Lowered, "compile", from_jaxs_cache)
    _train([5])
    assert list(store.iterdir()) == []


@pytest.mark.parametrize("kept", [False, True])
@pytest.mark.parametrize("placed", [False, True], ids=["numpy", "committed"])
def test_each_program_is_compiled_once_ahead_of_its_calls(kept, placed, tmp_path):
    """`schedule.train_blocks` prepares its programs for the arrays its calls pass: numpy ones, or
    jax arrays committed to a device (as a sweep places them), whose state stays committed there."""
    if kept:
        executables.keep_programs(tmp_path)
    _new_process()
    place = functools.partial(jax.device_put, device=jax.devices()[0]) if placed else np.asarray
    try:
        with xla_compiles() as compiled:
            result = _train([6, 7], place)
    finally:
        executables.stop_keeping_programs()
        _new_process()
    # (Besides them, taking a block of committed arrays compiles a slice.)
    assert [compiled.count(name) for name in ["jit(_iterate_stacked)", "jit(init_runs)"]] == [1, 1]
    chex.assert_trees_all_equal(result, _train([6, 7]))


def test_a_call_waits_for_the_program_being_compiled_ahead():
    _new_process()
    program = programs.compiled_program(CONFIG)
    keys, hyperparams = _inputs([8])
    with xla_compiles() as compiled:
        future = program.init.prepare(keys, hyperparams)
        state = program.init(keys, hyperparams)
    assert compiled == ["jit(init_runs)"]
    assert future.done()
    chex.assert_trees_all_equal(state, program.init._jitted(keys, hyperparams))


def test_a_failed_compile_is_tried_again_at_the_next_call(store, monkeypatch):
    compile_now, failures = jax.stages.Lowered.compile, []

    def fail_once(lowered, *args, **kwargs):
        if not failures:
            failures.append(lowered)
            raise RuntimeError("out of memory, once")
        return compile_now(lowered, *args, **kwargs)

    monkeypatch.setattr(jax.stages.Lowered, "compile", fail_once)
    program, args = programs.compiled_program(CONFIG), _inputs([9])
    program.init.prepare(*args)
    with pytest.raises(RuntimeError, match="once"):
        program.init(*args)
    chex.assert_trees_all_equal(program.init(*args), program.init._jitted(*args))
    assert [p.name.split("-")[0] for p in store.iterdir()] == ["init"]


def test_python_numbers_among_the_arguments_call_the_jitted_function():
    _new_process()
    program, args = programs.compiled_program(CONFIG), _inputs([10])
    schedule.train_blocks(program, CONFIG.iterations, [args])  # its programs are prepared
    state = program.init(*args)
    state_copy = jax.tree.map(np.array, state)  # the call donates its state
    _, metrics = program.iterate(state, args[1], 2)
    fields = len(iteration.Metrics._fields) - 1 + len(program.extra)  # `extra` holds the loss's
    assert np.asarray(metrics).shape[:2] == (programs.ITERATIONS_PER_CALL, fields)
    _, typed = program.iterate(jax.device_put(state_copy), args[1], np.int32(2))
    np.testing.assert_array_equal(np.asarray(metrics)[:2], np.asarray(typed)[:2])  # as np.int32(2)


class _Planted:
    """A pickle that, unpickled, writes the file `marker`."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return pathlib.Path.write_text, (self.marker, "the cache ran code")


def test_a_pickle_planted_in_every_file_never_runs(store, tmp_path_factory):
    expected = _train([11])
    marker = tmp_path_factory.mktemp("planted") / "ran"
    planted = pickle.dumps(_Planted(marker))
    files = sorted(store.iterdir())
    for path in files:
        path.write_bytes(planted)
    _new_process()
    chex.assert_trees_all_equal(_train([11]), expected)
    assert not marker.exists()
    assert sorted(store.iterdir()) == files and all(p.read_bytes() != planted for p in files)


def test_a_file_of_another_program_is_warned_about_once_compiled_again_and_replaced(
        store, caplog, monkeypatch):
    expected = _train([12])
    init, iterate = sorted(store.iterdir())
    swapped = {init: iterate.read_bytes(), iterate: init.read_bytes()}
    for path, data in swapped.items():
        path.write_bytes(data)
    assert _replaced_after_one_warning_each(store, [12], expected, caplog, monkeypatch) == [
        "it holds another program"] * 2


def _replaced_after_one_warning_each(store, seeds, expected, caplog, monkeypatch):
    """Trains `seeds` as a new process twice: the first warns about each file of `store` once and
    trains `expected`; the second loads the files it replaced, compiling nothing.

    Returns:
      Each warning's reason, in the order of the files' names.
    """
    files = sorted(store.iterdir())
    _new_process()
    with caplog.at_level(logging.WARNING, logger=executables.__name__):
        chex.assert_trees_all_equal(_train(seeds), expected)
    messages = sorted(r.getMessage() for r in caplog.records)
    assert [m.split(" (")[0] for m in messages] == [f"could not load {p}" for p in files]
    _new_process()  # replaced: loaded now, not compiled
    monkeypatch.setattr(jax.stages.Lowered, "compile", _not_again)
    chex.assert_trees_all_equal(_train(seeds), expected)
    monkeypatch.undo()
    return [m.split(" (", 1)[1].rsplit(")", 1)[0] for m in messages]


def _swapped(indices):
    """Swaps the first two of `indices`; of one leaf (init's keys), takes the next leaf instead."""
    indices[:2] = indices[1::-1] if len(indices) >= 2 else [indices[0] + 1]


@pytest.mark.parametrize("edit", [
    lambda header: header["arguments"].pop(),  # once: "Execution supplied 2 arguments"
    lambda header: _swapped(header["arguments"]),  # once: another policy trained, silently
    lambda header: header.update(outputs={"tuple": [header["outputs"]]}),
], ids=["an-argument-dropped", "arguments-swapped", "outputs-nested"])
def test_an_edited_header_is_warned_about_once_compiled_again_and_replaced(
        store, caplog, monkeypatch, edit):
    """The header decides which arrays the executable runs on and what its outputs are: it is
    under the file's digest, as the payload is."""
    expected = _train([15])
    for path in store.iterdir():
        marker, digest, header, payload = path.read_bytes().split(b"\n", 3)
        described = json.loads(header)
        edit(described)
        path.write_bytes(b"\n".join([marker, digest, json.dumps(described).encode(), payload]))
    assert _replaced_after_one_warning_each(store, [15], expected, caplog, monkeypatch) == [
        "its contents do not match their digest"] * 2


def test_a_folder_in_a_files_place_is_warned_about_once_and_replaced(store, caplog, monkeypatch):
    expected = _train([16])
    for path in store.iterdir():
        path.unlink()
        (path / "inside").mkdir(parents=True)
    reasons = _replaced_after_one_warning_each(store, [16], expected, caplog, monkeypatch)
    assert len(reasons) == 2 and all("Is a directory" in reason for reason in reasons)
    assert all(path.is_file() for path in store.iterdir())


def test_cache_directories_are_created_for_the_user_alone(tmp_path):
    directory = tmp_path / "cache" / "jaxpg" / "programs"
    executables.keep_programs(directory)
    _new_process()
    try:
        _train([13])
    finally:
        executables.stop_keeping_programs()
        _new_process()
    assert len(list(directory.iterdir())) == 2
    for folder in (tmp_path / "cache", tmp_path / "cache" / "jaxpg", directory):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700


def test_a_directory_that_others_can_write_is_not_used(tmp_path, caplog):
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o777)
    shared.chmod(0o777)  # (mkdir's mode is masked by the umask)
    with caplog.at_level(logging.WARNING, logger=executables.__name__):
        executables.keep_programs(shared)
    assert [r.getMessage() for r in caplog.records] == [
        f"keeping no compiled programs in {shared}: others can write it"]
    _new_process()
    _train([14])
    assert list(shared.iterdir()) == []


def test_temporary_files_that_killed_processes_left_are_removed(tmp_path):
    left = tmp_path / ".init-0123.xla.0123456789ab.tmp.xla"
    left.write_bytes(b"half a program")
    executables.keep_programs(tmp_path)
    executables.stop_keeping_programs()
    assert list(tmp_path.iterdir()) == []


def _train_command(tmp_path, cache_home):
    """Runs `jaxpg train` in a new process with XDG_CACHE_HOME=`cache_home` and HOME in
    `tmp_path`, in an empty working directory, which it must leave empty.

    Returns:
      The lines of its standard error that are not matplotlib's (it warns about its own cache).
    """
    work, home = tmp_path / "work", tmp_path / "home"
    work.mkdir()
    home.mkdir()
    env = {**os.environ, "XDG_CACHE_HOME": cache_home, "HOME": str(home)}
    done = subprocess.run(
        [sys.executable, "-m", "jaxpg.cli", "train", "--iterations", "2", "--episodes", "2",
         "--max-steps", "10", "--quiet", "--out", str(tmp_path / "out")],
        cwd=work, env=env, capture_output=True, text=True, check=True)
    assert list(work.iterdir()) == []
    assert (tmp_path / "out" / "policy.msgpack").is_file()
    return [line for line in done.stderr.splitlines() if "matplotlib" not in line.lower()]


def _read_only_directory(tmp_path):
    """A directory in which this process cannot create a file: one made read-only, or /sys where
    permissions do not bind the process (root)."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    for candidate in (folder, pathlib.Path("/sys")):
        try:
            with tempfile.TemporaryFile(dir=candidate):
                pass
        except OSError:
            return candidate
    pytest.skip("every directory can be written here")


@pytest.mark.parametrize("kind", ["a file", "read-only"])
def test_a_cache_home_that_cannot_be_used_means_training_without_kept_programs(tmp_path, kind):
    if kind == "a file":
        cache = tmp_path / "cache"
        cache.write_text("not a folder")
    else:
        cache = _read_only_directory(tmp_path)
    [warning] = _train_command(tmp_path, str(cache))
    assert warning.startswith(
        f"keeping no compiled programs in {cache / 'jaxpg' / 'programs'}: it cannot be ")


def test_a_relative_cache_home_is_ignored_and_nothing_is_created_in_the_working_directory(
        tmp_path):
    """As the XDG base directory specification says: ~/.cache is used, matplotlib's cache too."""
    assert _train_command(tmp_path, "relative/cache") == []
    kept = tmp_path / "home" / ".cache" / "jaxpg" / "programs"
    assert sorted(p.name.split("-")[0] for p in kept.iterdir()) == ["init", "iterate_alone"]
    assert (tmp_path / "home" / ".cache" / "matplotlib").is_dir()


def test_the_source_digest_covers_the_environments_modules(monkeypatch):
    """A kept program is found by a digest of jaxpg's code: an edit to an environment's module,
    in a subpackage, changes it (and the program is compiled again)."""
    read_bytes = pathlib.Path.read_bytes
    before = executables._source_digest.__wrapped__()
    monkeypatch.setattr(pathlib.Path, "read_bytes", lambda path: read_bytes(path) + (
        b"# edited" if path.parent.name == "envs" and path.name == "cartpole.py" else b""))
    assert executables._source_digest.__wrapped__() != before
