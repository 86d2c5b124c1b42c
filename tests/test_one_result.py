"""One output folder holds one command's result, and Ctrl-C at any moment ends a command with
status 130 and one line, its output folder left as it was."""

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
    assert [p.name for p in tmp_path.iterdir() if "staging" in p.name] == []


def _interrupted(args, delay, tmp_path):
    """Runs `python -m jaxpg.cli ARGS`, sends SIGINT after `delay` seconds: (status, seconds from
    the signal to the end, stderr)."""
    process = subprocess.Popen([sys.executable, "-m", "jaxpg.cli", *args], cwd=tmp_path,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(delay)
        process.send_signal(signal.SIGINT)
        start = time.perf_counter()
        status = process.wait(timeout=20)
        seconds = time.perf_counter() - start
    finally:
        process.kill()
    return status, seconds, process.stderr.read()


# At 0.2 s the process is importing the package `jaxpg` (JAX with it), before `jaxpg.cli` runs.
_IN_PACKAGE_IMPORT = pytest.mark.xfail(
    strict=True, reason="jaxpg/__init__.py imports JAX before the command can catch Ctrl-C")


@pytest.mark.parametrize("delay", [pytest.param(0.2, marks=_IN_PACKAGE_IMPORT), 2.5, 4.0])
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


def test_ctrl_c_ends_a_render_of_a_long_episode(tmp_path):
    """The basic policy balances for long: the compiled episode runs until the signal ends it."""
    status, seconds, stderr = _interrupted(
        ["render", "--max-steps", "10000000", "--out", str(tmp_path / "long.gif")], 4.0, tmp_path)
    assert status == 130 and seconds < 3 and "Traceback" not in stderr, stderr
    assert not (tmp_path / "long.gif").exists()


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
