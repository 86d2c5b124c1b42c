"""One output folder holds one command's result, and Ctrl-C at any moment ends a command with
status 130 and one line, its output folder left as it was."""

import importlib.metadata
import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest

from jaxpg import cli

SMALL = ["--iterations", "3", "--episodes", "3", "--max-steps", "20", "--quiet", "--no-cache"]


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()} if folder.exists() else None


@pytest.mark.parametrize("first, second", [
    (["sweep", "--seeds", "8"], ["sweep", "--seeds", "1", "--lr", "0.03", "--iterations", "20"]),
    (["sweep", "--seeds", "2"], ["train"]),
    (["train"], ["sweep", "--seeds", "2"]),
])
def test_a_folder_holds_the_second_result_alone(tmp_path, first, second):
    """The second command's files, and only those, whatever the first left there."""
    out, fresh = tmp_path / "out", tmp_path / "fresh"
    assert cli.run_command([first[0], *SMALL, *first[1:], "--out", str(out)]) == 0
    assert cli.run_command([second[0], *SMALL, *second[1:], "--out", str(out)]) == 0
    assert cli.run_command([second[0], *SMALL, *second[1:], "--out", str(fresh)]) == 0
    assert _listing(out) == _listing(fresh)
    for name in _listing(out):  # the same bytes, but for the time taken and the folder's name
        ours, theirs = (_comparable(folder / name) for folder in (out, fresh))
        assert ours == theirs, name
    assert [p.name for p in tmp_path.iterdir() if "staging" in p.name] == []


def _comparable(path):
    """A result file's bytes; a JSON file's contents, without the seconds taken or the names of
    folders."""
    if path.suffix != ".json":
        return path.read_bytes()
    contents = json.loads(path.read_text())
    contents.pop("seconds", None)
    contents.pop("folders", None)
    for setting in contents.get("settings", []):
        if isinstance(setting, dict):
            setting.pop("folder", None)
    return contents


def _cpu_seconds(pid):
    """The CPU time, user and system, that process `pid` has used so far (Linux's /proc)."""
    fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def _wait_for(process, seconds):
    """Returns once `process` has run for `seconds`, of CPU time where /proc tells it.

    A loaded machine delays a process's progress, not its CPU time: a given CPU time finds it
    at the same point of its work (Python's start-up alone takes ~0.04 s).
    """
    if not pathlib.Path(f"/proc/{process.pid}/stat").exists():
        time.sleep(seconds)
        return
    while process.poll() is None and _cpu_seconds(process.pid) < seconds:
        time.sleep(0.005)


def _interrupted(args, delay, tmp_path, command=(sys.executable, "-m", "jaxpg")):
    """Runs `COMMAND ARGS` (by default `python -m jaxpg ARGS`), sends SIGINT once it has run
    for `delay` seconds (`_wait_for`): (status, seconds from the signal to the end, stderr)."""
    process = subprocess.Popen([*command, *args], cwd=tmp_path,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(process, delay)
        process.send_signal(signal.SIGINT)
        start = time.perf_counter()
        status = process.wait(timeout=20)
        seconds = time.perf_counter() - start
    finally:
        process.kill()
    return status, seconds, process.stderr.read()


# At 0.2 s the process is importing JAX; at 2.5 s and 4.0 s it traces, compiles or trains.
@pytest.mark.parametrize("delay", [0.2, 2.5, 4.0])
@pytest.mark.parametrize("earlier", [False, True], ids=["no-folder", "earlier-result"])
def test_ctrl_c_at_any_moment_exits_130_and_leaves_out_as_it_was(tmp_path, delay, earlier):
    out = tmp_path / "out"
    if earlier:
        assert cli.run_command(["train", *SMALL, "--seed", "5", "--out", str(out)]) == 0
    before = _snapshot(out)
    # Long enough that no delay sees it end: 200 iterations take seconds once compiled.
    status, seconds, stderr = _interrupted(
        ["train", *SMALL, "--iterations", "200000", "--out", str(out)], delay, tmp_path)
    assert status == 130 and seconds < 3 and "Traceback" not in stderr, stderr
    assert stderr.strip().splitlines()[-1].endswith("interrupted"), stderr
    assert _snapshot(out) == before


def _installed_command():
    """The `jaxpg` command as its installed script runs it (pyproject.toml's [project.scripts]):
    Python importing its function, then calling it."""
    (entry_point,) = importlib.metadata.entry_points(group="console_scripts", name="jaxpg")
    module, _, function = entry_point.value.partition(":")
    script = f"import sys; from {module} import {function}; sys.exit({function}())"
    return sys.executable, "-c", script


# After Python's start-up the command imports jaxpg, then JAX, then parses, traces and compiles.
@pytest.mark.parametrize("delay", [0.1, 0.3, 0.6, 1.0, 1.5])
def test_ctrl_c_in_the_first_seconds_of_jaxpg_train_leaves_out_untouched(tmp_path, delay):
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text('{"an": "earlier result"}')
    before, inode = _snapshot(out), out.stat().st_ino
    status, seconds, stderr = _interrupted(
        ["train", *SMALL, "--iterations", "200000", "--out", str(out)], delay, tmp_path,
        command=_installed_command())
    assert status == 130 and seconds < 3, stderr
    assert len(stderr.splitlines()) == 1 and stderr.rstrip().endswith("interrupted"), stderr
    assert _snapshot(out) == before and out.stat().st_ino == inode  # (not replaced by a copy)


# The command's entry point, its import of `jaxpg.cli` held up (standing for a slow machine's).
_SLOW_IMPORT = """
import sys, time

class Slow:
    def find_spec(self, name, path, target=None):
        if name == "jaxpg.cli":
            print("importing", flush=True)
            time.sleep(60)
        return None

sys.meta_path.insert(0, Slow())
from jaxpg.__main__ import main
main()
"""


def _interrupted_once_it_says(code, line, *args):
    """Runs `python -c CODE ARGS`, sends SIGINT once it prints `line`: (status, stderr)."""
    process = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline() == line
        process.send_signal(signal.SIGINT)
        status = process.wait(timeout=20)
    finally:
        process.kill()
    return status, process.stderr.read()


def test_ctrl_c_while_the_command_imports_its_modules_exits_130_with_one_line():
    assert _interrupted_once_it_says(_SLOW_IMPORT, "importing\n", "train") == (
        130, "jaxpg: interrupted\n")


# A render whose episode is one compiled loop of 2**31 - 1 steps: it runs until the signal ends it.
# (The basic policy's own episodes end within a hundred steps, too soon to be interrupted.)
_LONG_RENDER = """
import jax
from jaxpg import cli
from jaxpg import animation

def episode(*args, **kwargs):
    long = jax.jit(lambda x: jax.lax.fori_loop(0, 2**31 - 1, lambda i, v: v * 0.5 + 1.0, x))
    return long(jax.numpy.ones(4096)).block_until_ready()  # minutes: 2**31 steps of 4096

animation.render_episode = episode
cli.main(["render", "--max-steps", "10000000", "--out", "long.gif"])
"""


def test_ctrl_c_ends_a_render_of_a_long_episode(tmp_path):
    status, seconds, stderr = _interrupted([], 4.0, tmp_path,
                                           command=(sys.executable, "-c", _LONG_RENDER))
    assert status == 130 and seconds < 3 and "Traceback" not in stderr, stderr
    assert not (tmp_path / "long.gif").exists()


def test_ctrl_c_while_a_finished_command_shuts_down_keeps_its_status(tmp_path):
    """Python's shutdown of the modules JAX loaded takes about 0.5 s after the command's answer;
    Ctrl-C then leaves the answer's status, and ends the process by no signal (status -2)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "jaxpg.cli", "render", "--max-steps", str(10**12), "--out",
         str(tmp_path / "x.gif")], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        answer = process.stderr.readline()
        time.sleep(0.1)
        process.send_signal(signal.SIGINT)
        status = process.wait(timeout=20)
    finally:
        process.kill()
    assert answer.startswith("jaxpg render: error: max_steps: drawing an episode"), answer
    assert status == 2 and process.stderr.read() == ""


# The command's own "interrupted" line is slow to write (a loaded terminal): the watcher that ends
# the command `_GRACE` seconds after Ctrl-C comes meanwhile, and must not say it again.
_SAID_SLOWLY = """
import sys, time
from jaxpg import cli

class Slow:
    def write(self, text):
        sys.__stderr__.write(text)
        sys.__stderr__.flush()
        if "interrupted" in text:
            time.sleep(2 * cli._GRACE)
    def flush(self):
        sys.__stderr__.flush()

def handler(args):
    sys.stdout.write("running\\n")
    sys.stdout.flush()
    sys.stderr = Slow()
    while True:
        time.sleep(0.01)

cli.cmd_conformance = handler  # (the parser takes the name's value when it is built)
cli.main(["conformance"])
"""


def test_the_interrupted_line_is_said_once_when_the_command_says_it_slowly():
    assert _interrupted_once_it_says(_SAID_SLOWLY, "running\n") == (
        130, "jaxpg conformance: interrupted\n")


def test_no_output_folder_replaced_once_cancelled(tmp_path, monkeypatch):
    """After Ctrl-C a block that ends anyway (its KeyboardInterrupt lost) replaces nothing."""
    from jaxpg import atomic_files

    out = tmp_path / "out"
    with atomic_files.staged(out) as stage:
        (stage / "a.txt").write_text("old")
    monkeypatch.setattr(atomic_files, "_cancelled", type(atomic_files._cancelled)())
    atomic_files.cancel()
    with pytest.raises(KeyboardInterrupt):
        with atomic_files.staged(out) as stage:
            (stage / "a.txt").write_text("new")
    assert _snapshot(out) == {"a.txt": b"old"}
