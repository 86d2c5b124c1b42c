"""Result folders replaced whole (also when killed), one writer per folder, temporary files,
JSON."""

import json
import os
import pathlib
import stat
import subprocess
import sys

import numpy as np
import pytest
from conftest import claimed_by_another_process

from jaxpg import atomic_files

OLD = {"a.txt": "old a", "b.txt": "old b", "c.txt": "old c"}
NEW = {"a.txt": "new a", "b.txt": "new b", "c.txt": "new c"}


def _files(folder):
    return {p.name: p.read_text() for p in folder.iterdir()} if folder.exists() else None


def _write(out, files):
    with atomic_files.staged(out) as stage:
        for name, text in files.items():
            (stage / name).write_text(text)


# Writes NEW into the folder argv[1] through `staged`, killed (SIGKILL, which no cleanup
# survives) just before the argv[2]-th call of os.rename or atomic_files._exchange; argv[3] == "1"
# makes the system lack the exchange, as one without renameat2 does.
_KILLED_WRITE = f"""
import os, signal, sys
from jaxpg import atomic_files

out, kill_at, exchange = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "0"
calls = []

def killed_before(function):
    def wrapper(*args, **kwargs):
        calls.append(function)
        if len(calls) == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)
        return function(*args, **kwargs)
    return wrapper

os.rename = killed_before(os.rename)
atomic_files._exchange = killed_before(atomic_files._exchange if exchange else lambda a, b: False)
with atomic_files.staged(out) as stage:
    for name, text in {NEW!r}.items():
        (stage / name).write_text(text)
"""


def _killed_write(out, kill_at, exchange):
    process = subprocess.run([sys.executable, "-c", _KILLED_WRITE, str(out), str(kill_at),
                              "0" if exchange else "1"], capture_output=True, text=True)
    assert process.returncode in (0, -9), process.stderr
    return process.returncode == -9


@pytest.mark.parametrize("exchange", [True, False], ids=["exchange", "two-renames"])
def test_a_kill_at_any_step_leaves_the_earlier_folder_or_the_new_one_whole(tmp_path, exchange):
    """With the exchange, the folder is the earlier one or the new one at every moment; with two
    renames, a kill between them leaves it aside, and the next run's claim puts it back."""
    if exchange and atomic_files._renameat2() is None:
        pytest.skip("no renameat2 here")
    seen = set()
    for kill_at in range(1, 10):
        out = tmp_path / f"run{kill_at}"
        _write(out, OLD)
        killed = _killed_write(out, kill_at, exchange)
        if exchange:
            assert _files(out) in (OLD, NEW)
        atomic_files.claim(out)
        found = _files(out)
        assert found in (OLD, NEW)
        seen.add("new" if found == NEW else "old")
        atomic_files._release(atomic_files._real(out))
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(f".run{kill_at}.")] == [
            f".run{kill_at}.lock"]  # no staging folder, nothing aside
        if not killed:
            break
    assert not killed and seen == {"old", "new"}


def test_the_later_files_replace_the_earlier_folder_whole(tmp_path):
    out = tmp_path / "run"
    _write(out, OLD)
    _write(out, {"a.txt": "new a", "d.txt": "new d"})
    assert _files(out) == {"a.txt": "new a", "d.txt": "new d"}


def test_a_failed_write_leaves_the_folder_and_releases_it(tmp_path):
    out = tmp_path / "run"
    _write(out, OLD)
    with pytest.raises(RuntimeError):
        with atomic_files.staged(out) as stage:
            (stage / "a.txt").write_text("half")
            raise RuntimeError("disk full")
    assert _files(out) == OLD
    _write(out, NEW)  # released: the next write goes ahead
    assert _files(out) == NEW
    assert sorted(p.name for p in tmp_path.iterdir()) == [".run.lock", "run"]


def test_a_second_process_is_refused_the_folder_another_holds(tmp_path):
    out = tmp_path / "run"
    with claimed_by_another_process(out):
        with pytest.raises(ValueError, match="out: another jaxpg process is writing to"):
            atomic_files.claim(out)
    _write(out, NEW)  # the lock went with the process
    assert _files(out) == NEW


def test_what_killed_runs_left_is_removed_by_the_next_claim(tmp_path):
    out = tmp_path / "run"
    _write(out, OLD)
    (out / ".staging-0123456789ab").mkdir()  # inside the folder, as jaxpg 0.1.0 staged
    (out / ".staging-0123456789ab" / "a.txt").write_text("partial")
    staging = tmp_path / atomic_files.temporary_name("run", "staging-abcdef012345")
    staging.mkdir()
    (tmp_path / "other").mkdir()  # not the folder's: stays
    _write(out, NEW)
    assert _files(out) == NEW
    assert sorted(p.name for p in tmp_path.iterdir()) == [".run.lock", "other", "run"]


@pytest.mark.parametrize("make, problem", [
    (lambda tmp: "", "out: expected a directory, got an empty path"),
    (lambda tmp: tmp.parent, "holds the working directory"),
    (lambda tmp: tmp / "project", "holds directories (src)"),
])
def test_folders_that_are_not_jaxpgs_to_replace_are_refused(tmp_path, monkeypatch, make, problem):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "project" / "src").mkdir(parents=True)
    with pytest.raises(ValueError, match=problem.replace("(", r"\(").replace(")", r"\)")):
        atomic_files.claim(make(tmp_path))


def test_long_names_get_temporary_names_that_fit(tmp_path):
    name = "r" * 240 + ".gif"
    atomic_files.atomic_write(tmp_path / name, b"GIF89a")
    assert [p.name for p in tmp_path.iterdir()] == [name]
    _write(tmp_path / ("o" * 250), NEW)
    assert _files(tmp_path / ("o" * 250)) == NEW
    assert all(len(p.name.encode()) <= 255 for p in tmp_path.iterdir())
    # Cut at a character, not inside one (each is 3 bytes in UTF-8).
    assert len(atomic_files.temporary_name("é" * 200, "lock").encode()) <= atomic_files.NAME_MAX


def test_a_folder_whose_name_is_not_utf8_holds_results(tmp_path):
    out = tmp_path / os.fsdecode(b"run-\xff\xfe")  # bytes a shell can pass, not UTF-8
    atomic_files.claim(out)
    _write(out, NEW)
    assert _files(out) == NEW
    assert sorted(os.listdir(os.fsencode(tmp_path))) == [b".run-\xff\xfe.lock", b"run-\xff\xfe"]
    long = os.fsdecode(b"\xff" * 300)  # each undecodable byte is one character of one byte
    room = atomic_files.NAME_MAX - len(".") - len(".lock")
    expected = b"." + b"\xff" * room + b".lock"
    assert os.fsencode(atomic_files.temporary_name(long, "lock")) == expected


@pytest.mark.parametrize(("path", "message"), [
    ("r" * 256, r"^out: the name r{40}\.\.\. is 256 bytes long; a file name holds at most 255$"),
    ("ok/" + "é" * 128, r"^out: the name é{40}\.\.\. is 256 bytes long"),
    ("\ud800", r"^out: '.*' holds characters that no file name can hold$"),
])
def test_names_no_file_system_takes_are_refused_naming_out(tmp_path, path, message):
    with pytest.raises(ValueError, match=message):
        atomic_files.claim(tmp_path / path)
    assert list(tmp_path.iterdir()) == []  # nothing created


def test_only_temporary_files_that_no_process_writes_are_removed(tmp_path):
    stale = tmp_path / ".p-1.xla.0123456789ab.tmp.xla"
    stale.write_bytes(b"half a program")
    kept = tmp_path / "p-1.xla"
    kept.write_bytes(b"a program")
    with atomic_files.atomic_path(tmp_path / "p-2.xla") as writing:
        writing.write_bytes(b"being written")
        atomic_files.remove_stale_temporaries(tmp_path)
        assert writing.exists() and not stale.exists() and kept.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p-1.xla", "p-2.xla"]


def test_private_directories_are_created_for_the_user_alone(tmp_path):
    path = atomic_files.private_directory(tmp_path / "cache" / "jaxpg" / "programs")
    for folder in (tmp_path / "cache", tmp_path / "cache" / "jaxpg", path):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700


def test_json_is_strict_with_non_finite_numbers_as_null(tmp_path):
    path = tmp_path / "metrics.json"
    atomic_files.write_json(path, {"loss": np.array([1.5, np.nan, np.inf, -np.inf], np.float32),
                              "final": float("nan"), "seed": 3})

    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")

    assert json.loads(path.read_text(), parse_constant=refuse) == {
        "loss": [1.5, None, None, None], "final": None, "seed": 3}


def test_a_folder_reached_through_a_link_is_replaced_where_it_is(tmp_path):
    target = tmp_path / "disk" / "run"
    _write(target, OLD)
    link = tmp_path / "run"
    os.symlink(target, link)
    _write(link, NEW)
    assert link.is_symlink() and pathlib.Path(os.readlink(link)) == target
    assert _files(target) == NEW


@pytest.mark.parametrize("folder", ["/proc/run", "/proc/x/y"])
def test_a_folder_that_cannot_be_written_is_refused_when_claimed(folder):
    with pytest.raises(ValueError, match="^out: cannot write in /proc"):
        atomic_files.claim(folder)
    with pytest.raises(ValueError, match="^path: cannot write in /proc"):
        atomic_files.check_writable("/proc", "path")


def test_a_file_that_cannot_be_created_is_named_by_its_folder_not_a_temporary_name():
    with pytest.raises(FileNotFoundError) as raised:
        atomic_files.atomic_write("/proc/x.json", "{}")
    assert (raised.value.errno, raised.value.filename) == (2, "/proc")
    assert str(raised.value) == "[Errno 2] No such file or directory: '/proc'"


@pytest.mark.parametrize("files", atomic_files.RESULT_FILES)
def test_no_result_is_written_inside_another(tmp_path, files):
    for name in files:
        (tmp_path / name).write_text("a result")
    for inside in (tmp_path / "sub", tmp_path / "a" / "b"):
        with pytest.raises(ValueError, match=f"^out: .* lies inside {tmp_path}, a folder of "
                                             "jaxpg's results"):
            atomic_files.claim(inside)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(files)  # nothing created
    atomic_files.check_out_dir(tmp_path)  # the folder itself: written again, replaced whole


def test_a_folder_holding_one_file_of_a_kind_of_results_is_no_results_folder(tmp_path):
    (tmp_path / "metrics.json").write_text("a project's own")  # not beside a policy
    atomic_files.check_out_dir(tmp_path / "runs")
