"""The `jaxpg` command end to end: outputs, exit statuses, one-line errors, no lost results."""

import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
import warnings

import jax
import numpy as np
import pytest
from conftest import claimed_by_another_process, xla_compiles
from jax.experimental.compilation_cache import compilation_cache

from jaxpg import (
    TrainConfig,
    atomic_files,
    cartpole,
    checkpoint,
    cli,
    executables,
    policies,
    xla_options,
)
from jaxpg.evaluation import evaluate, robustness

SMALL = ["--iterations", "3", "--episodes", "2", "--max-steps", "20", "--quiet", "--no-cache"]


def _run(*args):
    return subprocess.run([sys.executable, "-m", "jaxpg.cli", *args], capture_output=True,
                          text=True)


def test_train_writes_results_that_evaluate_loads(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.run_command(["train", *SMALL, "--seed", "3", "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {
        "policy.msgpack", "metrics.json", "metrics.csv", "learning_curve.png"}
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["metrics"]["mean_return"]) == 3 and metrics["seed"] == 3
    assert (out / "metrics.csv").read_text().splitlines()[0].startswith("iteration,mean_return")
    assert checkpoint.load(out).config.max_steps == 20
    capsys.readouterr()
    assert cli.run_command(["evaluate", "--policy", str(out), "--episodes", "5",
                            "--backend", "gymnasium"]) == 0
    assert "mean" in capsys.readouterr().out


def test_a_second_train_loads_the_programs_the_first_kept(tmp_path):
    """With the cache on (the default), the programs are kept whole and a second process reuses
    them."""
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    args = [a for a in SMALL if a != "--no-cache"]
    store = tmp_path / "cache/jaxpg/programs"
    files = []
    for name in ("first", "second"):
        subprocess.run([sys.executable, "-m", "jaxpg.cli", "train", *args, "--out",
                        str(tmp_path / name)], env=env, check=True, capture_output=True)
        files.append({p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in store.iterdir()})
    assert sorted(n.split("-")[0] for n in files[0]) == ["init", "iterate_alone"]  # a run alone's
    assert files[1] == files[0]  # loaded, neither compiled nor written again
    first, second = (json.loads((tmp_path / n / "metrics.json").read_text())["metrics"]
                     for n in ("first", "second"))
    assert first == second


def test_sweep_writes_summary_and_picture(tmp_path):
    out = tmp_path / "sweep"
    assert cli.run_command(["sweep", *SMALL, "--seeds", "3", "--lr", "0.01,0.02",
                            "--memory-budget", "1G", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["grid"]) == 2 and len(summary["fraction_solved"]) == 2
    with np.load(out / "metrics.npz") as npz:
        assert npz["mean_return"].shape == (2, 3, 3)
    assert len((out / "runs.csv").read_text().splitlines()) == 1 + 2 * 3
    assert (out / "sweep.png").stat().st_size > 0


@pytest.mark.parametrize("args, word", [
    (["train", "--iterations", "0"], "iterations"),
    (["train", "--episodes", "-2"], "episodes"),
    (["train", "--discount", "1.5"], "discount"),
    (["train", "--lr", "0"], "learning_rate"),
    (["train", "--optimizer", "nope"], "optimizer"),
    (["train", "--activation", "nope"], "activation"),
    (["train", "--env", "CartPole-v7"], "env"),
    (["train", "--hidden", "x"], "hidden"),
    (["train", "--loss", "a2c"], "--loss"),
    (["train", "--entropy-coef", "-1"], "entropy_coef"),
    (["train", "--entropy-coef", "-1e-3"], "entropy_coef"),  # a value, not an unknown flag
    (["train", "--masspole", "-.5"], "masspole"),
    (["sweep", "--entropy-coef", "0,inf"], "entropy_coef"),
    (["sweep", "--seeds", "0"], "seeds"),
    (["sweep", "--discount", "0.9,2"], "discount"),
    (["sweep", "--memory-budget", "2X"], "--memory-budget"),
    (["sweep", "--coordinator", "localhost:1234"], "coordinator"),
    (["sweep", "--coordinator", "localhost:99999", "--num-processes", "2", "--process-id", "0"],
     "coordinator: expected HOST:PORT with PORT in [1, 65535]"),
    # Digits that int() reads but JAX's server cannot bind (it crashed the process).
    (["sweep", "--coordinator", "localhost:\u0661\u0662\u0663\u0664", "--num-processes", "1",
      "--process-id", "0"], "coordinator: expected HOST:PORT with PORT in [1, 65535]"),
    (["evaluate", "--backend", "mujoco"], "backend"),
    (["evaluate", "--policy", "/nonexistent/dir"], "policy"),
    (["evaluate", "--env", "CartPole-v7"], "env"),
    (["render", "--max-steps", "0"], "max_steps"),
    (["frobnicate"], "invalid choice"),
])
def test_bad_input_exits_2_with_one_line(args, word):
    result = _run(*args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and word in lines[0] and "Traceback" not in result.stderr


@pytest.mark.parametrize("args, runs", [
    (["train"], 1),
    (["reproduce"], 1),
    (["sweep", "--seeds", "3", "--lr", "0.01,0.02", "--discount", "0.9,0.95,0.99"], 18),
    (["sweep", "--seeds", "1"], 1),
    (["sweep", "--coordinator", "h:1", "--num-processes", "2", "--process-id", "0"], None),
    (["evaluate"], None),
])
def test_the_command_sizes_xlas_threads_by_the_runs_it_trains_at_once(args, runs):
    """`main` hands this count to `xla_options.configure_xla`: one thread for XLA for one run."""
    assert cli._runs_at_once(cli.build_parser().parse_args(args)) == runs


def test_the_command_configures_xla_for_its_runs_before_it_runs(monkeypatch):
    calls = []
    monkeypatch.setattr(xla_options, "configure_xla",
                        lambda runs: calls.append(("configure", runs)))
    monkeypatch.setattr(cli, "_execute", lambda args: calls.append(("execute", args.command)) or 0)
    with pytest.raises(SystemExit) as exit_:
        cli.main(["train", "--seed", "1"])
    assert exit_.value.code == 0 and calls == [("configure", 1), ("execute", "train")]


def test_out_that_is_a_file_is_refused(tmp_path):
    target = tmp_path / "file"
    target.write_text("keep me")
    result = _run("train", *SMALL, "--out", str(target))
    assert result.returncode == 2 and "out" in result.stderr
    assert target.read_text() == "keep me"


def test_failed_run_keeps_earlier_results(tmp_path, monkeypatch):
    out = tmp_path / "run"
    assert cli.run_command(["train", *SMALL, "--out", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken_plot(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr("jaxpg.plots.learning_curve", broken_plot)
    with pytest.raises(RuntimeError):
        cli.run_command(["train", *SMALL, "--seed", "9", "--out", str(out)])
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_evaluate_basic_policy_prints_statistics(capsys):
    assert cli.run_command(["evaluate", "--episodes", "20", "--max-steps", "50"]) == 0
    out = capsys.readouterr().out
    expected = evaluate(policies.basic_policy, episodes=20, max_steps=50)
    assert (f"mean {expected.mean:.3f}  std {expected.std:.3f}  min {expected.min:g}  "
            f"max {expected.max:g}") in out


@pytest.mark.parametrize("env, limit", [("CartPole-v1", 500), ("CartPole-v0", 200)])
def test_evaluate_says_the_steps_the_time_limit_plays(env, limit, capsys):
    """A --max-steps beyond the environment's time limit plays to the limit, and says so."""
    assert cli.run_command(["evaluate", "--env", env, "--episodes", "3", "--max-steps",
                            "100000"]) == 0
    assert f"over 3 episodes of at most {limit} steps" in capsys.readouterr().out


def test_render_writes_a_gif(tmp_path):
    path = tmp_path / "cart.gif"
    assert cli.run_command(["render", "--out", str(path), "--max-steps", "10"]) == 0
    assert path.read_bytes()[:6] in (b"GIF87a", b"GIF89a")


def _result(folder):
    """What tells two `jaxpg train` results apart: all but the seconds it took."""
    metrics = json.loads((folder / "metrics.json").read_text())
    return (metrics["seed"], metrics["metrics"], (folder / "metrics.csv").read_text(),
            (folder / checkpoint.FILENAME).read_bytes(), sorted(p.name for p in folder.iterdir()))


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace")
def test_a_train_killed_at_any_rename_leaves_the_earlier_result_or_the_new_one(tmp_path):
    """A reproduction: strace kills the run as it enters its Nth rename (or the
    exchange), for every N until one run ends; the folder holds one run's results each time.
    The runs find their programs kept by the first two (so each is seconds, not a compile)."""
    out, reference = tmp_path / "run", tmp_path / "reference"
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    args = ["train", *(a for a in SMALL if a != "--no-cache")]
    for seed, folder in ((0, out), (1, reference)):
        subprocess.run([sys.executable, "-m", "jaxpg.cli", *args, "--seed", str(seed), "--out",
                        str(folder)], env=env, check=True, capture_output=True)
    old, new = _result(out), _result(reference)
    for syscall, when in [("renameat2", 1), *(("rename", n) for n in range(1, 10))]:
        killed = subprocess.run(
            ["strace", "-f", "-qq", "-o", os.devnull, "-e", f"trace={syscall}",
             "-e", f"inject={syscall}:signal=KILL:when={when}", sys.executable, "-m", "jaxpg.cli",
             *args, "--seed", "1", "--out", str(out)], env=env, capture_output=True, text=True)
        if "ptrace" in killed.stderr:
            pytest.skip(f"strace cannot trace here: {killed.stderr.strip()}")
        assert _result(out) in (old, new), (syscall, when)
        if syscall == "rename" and killed.returncode == 0:
            break
    assert _result(out) == new


@pytest.mark.parametrize("command", [
    ["train", *SMALL],
    ["evaluate", "--episodes", "5", "--max-steps", "20", "--length", "0.5,1.0"],
])
def test_a_second_run_into_the_same_out_is_refused_with_one_line(tmp_path, command):
    """Before any work: nothing is trained or played, nothing printed."""
    out = tmp_path / "run"
    with claimed_by_another_process(out):
        result = _run(*command, "--out", str(out))
    assert result.returncode == 2 and not out.exists() and not result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"out: another jaxpg process is writing to {out}" in lines[0]


@pytest.mark.parametrize("args, word", [
    (["train", *SMALL, "--out", ""], "out: "),
    (["sweep", *SMALL, "--seeds", "2", "--out", ""], "out: "),
    (["evaluate", "--policy", ""], "policy: "),
    (["render", "--policy", "", "--out", "cart.gif"], "policy: "),
])
def test_an_empty_path_is_refused_with_one_line(tmp_path, monkeypatch, capsys, args, word):
    checkpoint.save(tmp_path, policies.init_network(jax.random.PRNGKey(0), TrainConfig().network),
                    TrainConfig())  # what an empty path would have read: the working directory's
    monkeypatch.chdir(tmp_path)
    assert cli.run_command(args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and word in lines[0] and "empty path" in lines[0]
    assert [p.name for p in tmp_path.iterdir()] == [checkpoint.FILENAME]


@pytest.mark.parametrize("value", ["", "relative/cache"])
def test_an_empty_or_relative_xdg_cache_home_is_ignored(tmp_path, monkeypatch, value):
    """The XDG base directory specification: such values are ignored, for ~/.cache."""
    monkeypatch.setenv("XDG_CACHE_HOME", value)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    previous = jax.config.jax_compilation_cache_dir
    try:
        cli._enable_compilation_cache(False, whole_programs=True)
        assert executables._directory == tmp_path / "home/.cache/jaxpg/programs"
        cli._enable_compilation_cache(False)
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "home/.cache/jaxpg/xla")
    finally:
        executables.stop_keeping_programs()
        jax.config.update("jax_compilation_cache_dir", previous)
        compilation_cache.reset_cache()
    for folder in ("home/.cache", "home/.cache/jaxpg", "home/.cache/jaxpg/xla"):
        assert stat.S_IMODE((tmp_path / folder).stat().st_mode) == 0o700
    assert sorted(p.name for p in tmp_path.iterdir()) == ["home"]


def test_render_writes_a_file_of_a_long_name(tmp_path):
    path = tmp_path / ("c" * 236 + ".gif")  # 240 bytes: the temporary name must be cut to fit
    assert cli.run_command(["render", "--out", str(path), "--max-steps", "10"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_train_and_sweep_take_a_loss_an_entropy_bonus_and_a_linear_policy(tmp_path):
    out = tmp_path / "run"
    args = ["--loss", "baseline", "--entropy-coef", "0.01", "--hidden", ""]
    assert cli.run_command(["train", *SMALL, *args, "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    assert len(metrics["value_loss"]) == len(metrics["entropy"]) == 3
    assert (out / "metrics.csv").read_text().splitlines()[0].endswith("entropy,value_loss")
    loaded = checkpoint.load(out)
    assert (loaded.config.loss, loaded.config.hidden) == ("baseline", ())
    assert set(loaded.critic_params["params"]) == {"weights", "bias"}  # kept to warm-start it
    sweep_out = tmp_path / "sweep"
    assert cli.run_command(["sweep", *SMALL, "--seeds", "2", "--loss", "reward-to-go",
                     "--entropy-coef", "0,0.01", "--eval-episodes", "4",
                     "--out", str(sweep_out)]) == 0
    with np.load(sweep_out / "metrics.npz") as saved:
        assert saved["entropy"].shape == (2, 2, 3)
        assert saved["eval_returns"].shape == saved["eval_greedy_returns"].shape == (2, 2, 4)
        np.testing.assert_array_equal(saved["entropy_coef"], [0, 0.01])
    assert (sweep_out / "runs.csv").read_text().splitlines()[0].endswith(
        "eval_returns_mean,eval_greedy_returns_mean")


@pytest.fixture(scope="module")
def sweep_folder(tmp_path_factory):
    """A sweep of two seeds at two learning rates, as `jaxpg sweep` writes it."""
    out = tmp_path_factory.mktemp("cli") / "sweep"
    assert cli.run_command(["sweep", *SMALL, "--seeds", "2", "--lr", "0.01,0.02",
                            "--out", str(out)]) == 0
    return out


def test_a_sweeps_policies_are_evaluated_in_many_physics_settings(sweep_folder, tmp_path, capsys):
    loaded = checkpoint.load(sweep_folder)  # policies.msgpack: every run's parameters
    assert [setting["learning_rate"] for setting in loaded.grid] == [0.01, 0.02]
    assert loaded.policy_params["params"]["Dense_0"]["kernel"].shape == (2, 2, 4, 5)
    out = tmp_path / "robust"
    capsys.readouterr()
    assert cli.run_command(["evaluate", "--policy", str(sweep_folder), "--length", "0.25,0.5,1,2",
                     "--masspole", "0.1,0.5", "--episodes", "5", "--max-steps", "30",
                     "--out", str(out)]) == 0
    assert "masspole=0.5, length=2: " in capsys.readouterr().out
    assert {p.name for p in out.iterdir()} == {"robustness.json", "robustness.csv",
                                               "robustness.png"}
    saved = json.loads((out / "robustness.json").read_text())
    expected = robustness(loaded.policy_params, {"masspole": [0.1, 0.5],
                                                 "length": [0.25, 0.5, 1.0, 2.0]},
                          episodes=5, max_steps=30)
    assert saved["settings"] == expected.settings
    np.testing.assert_array_equal(saved["median"], expected.median)  # [G, S, P]
    np.testing.assert_array_equal(saved["median_per_setting"], np.median(expected.pooled, axis=1))
    rows = (out / "robustness.csv").read_text().splitlines()
    assert rows[0] == "g,s,masspole,length,mean,median,std,min,max" and len(rows) == 1 + 2 * 2 * 8


def test_one_run_of_a_sweep_is_evaluated_and_rendered(sweep_folder, tmp_path, capsys):
    params = checkpoint.load(sweep_folder).policy_params
    alone = evaluate(policies.network_policy(policies.PolicyNetwork(),
                                             jax.tree.map(lambda leaf: leaf[1, 0], params)),
                     episodes=5, max_steps=30, env=cartpole.V1.replace(length=2.0),
                     backend="gymnasium")
    capsys.readouterr()
    assert cli.run_command(["evaluate", "--policy", str(sweep_folder), "--run", "1,0",
                            "--length", "2", "--episodes", "5", "--max-steps", "30",
                            "--backend", "gymnasium"]) == 0
    assert f"mean {alone.mean:.3f}  std {alone.std:.3f}" in capsys.readouterr().out
    assert cli.run_command(["evaluate", "--policy", str(sweep_folder), "--episodes", "5"]) == 0
    assert "default physics: " in capsys.readouterr().out  # every run, in the default physics
    gif = tmp_path / "run.gif"
    assert cli.run_command(["render", "--policy", str(sweep_folder), "--run", "0,1",
                            "--out", str(gif), "--max-steps", "10"]) == 0
    assert gif.read_bytes()[:6] in (b"GIF87a", b"GIF89a")


@pytest.mark.parametrize("args, word", [
    (["--length", "0,1"], "length: must be positive"),
    (["--masspole", "-0.1"], "masspole: must be positive"),
    (["--masscart", "0"], "masscart: must be positive"),
    (["--tau", "0"], "tau: must be positive"),
    (["--gravity", "nan"], "gravity: must be finite"),
    (["--length", "1,1"], "length: the grid repeats"),
    (["--length", ""], "--length"),
    (["--length", "0.5:2"], "--length"),
    (["--run", "2,0"], "run: expected g in [0, 2)"),
    (["--run", "x"], "--run"),
    (["--policy", "basic", "--run", "0,0"], "run: only for a sweep"),
    (["--backend", "gymnasium", "--length", "1,2"], "backend"),
    (["--episodes", "0"], "episodes"),
    (["--lenght", "1"], "unrecognized arguments"),
])
def test_bad_evaluate_input_exits_2_with_one_line_and_writes_nothing(sweep_folder, tmp_path,
                                                                      capsys, args, word):
    out = tmp_path / "out"
    try:
        status = cli.run_command(["evaluate", "--policy", str(sweep_folder), "--out", str(out),
                                  *args])
    except SystemExit as exit_:  # argparse's own errors
        status = exit_.code
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and word in lines[0], lines
    assert not out.exists()


def test_a_command_that_fails_after_claiming_its_folder_releases_it(sweep_folder, tmp_path):
    """`run_command` in a process that goes on: a command refused once it held its output folder
    leaves the folder to other processes."""
    out = tmp_path / "out"
    assert cli.run_command(["evaluate", "--policy", str(sweep_folder), "--out", str(out),
                            "--episodes", "0"]) == 2
    assert (tmp_path / atomic_files.temporary_name("out", "lock")).exists()  # it was claimed
    with claimed_by_another_process(out):
        pass


_HUGE_BUDGET = "9" * 400 + "T"  # a float of it is infinite


@pytest.mark.parametrize("args, word", [
    (["train", "--episodes", "1000000000"], "memory: training 1 run for 150 iterations of "
                                             "1000000000 episodes"),
    (["train", "--max-steps", "2147483647"], "max_steps: at most 500, the environment's "),
    (["train", "--iterations", "1000000000"], "memory: "),
    (["train", "--hidden", "100000000"], "hidden: at most 4000 units per layer"),
    (["train", "--hidden", ",".join(["4000"] * 64)], "memory: "),  # about 30 GiB
    (["sweep", "--seeds", "4294967296"], "seeds: training 4294967296 seeds x 1 settings"),
    (["sweep", "--seeds", "8589934592"], "seeds: must be a non-empty sequence"),
    (["sweep", "--memory-budget", _HUGE_BUDGET], "memory_budget: "),
    (["train", "--solved-return", "nan"], "solved_return: must be finite"),
    (["train", "--optimizer", "lbfgs"], "optimizer: cannot train with 'lbfgs'"),
    (["sweep", "--lr", "0.01,0.01"], "learning_rate: the grid repeats a value"),
    (["sweep", "--eval-physics", "base"], "eval_physics: 'base' chooses the physics of held-out"),
    (["sweep", "--coordinator-timeout", "0"], "coordinator_timeout: must be an integer in [1, "),
    (["train", "--out", "/proc/x"], "out: cannot write in /proc"),
    (["reproduce", "--seed=-1"], "seed: must be an integer"),
    (["render", "--out", "cartpole.txt"], "out: must end with .gif or .mp4"),
    (["render", "--out", "/proc/cartpole.gif"], "out: cannot write in /proc"),
])
def test_bad_input_is_refused_in_one_line_before_any_work(tmp_path, monkeypatch, capsys, args,
                                                          word):
    """Within a second, before anything is traced, compiled, allocated, written or printed; the
    memory line says what was asked, what it needs and what the machine has."""
    monkeypatch.chdir(tmp_path)
    start = time.perf_counter()
    with xla_compiles() as compiled:
        status = cli.run_command([*args, "--quiet"] if args[0] in ("train", "sweep") else args)
    seconds = time.perf_counter() - start
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and word in lines[0], lines
    assert "memory" not in word or "this machine has" in lines[0]
    assert not compiled and not captured.out and not list(tmp_path.iterdir())
    assert seconds < 1


@pytest.mark.parametrize("command, signals", [("train", 1), ("sweep", 3)])
def test_ctrl_c_stops_training_at_once_and_keeps_the_earlier_result(tmp_path, command, signals):
    """SIGINT, once or several times, ends the command within about a second (at the workers'
    next program call) with status 130 and one line; the earlier result stays as it was."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.json").write_text("earlier")
    seeds = ["--seeds", "8"] if command == "sweep" else []
    process = subprocess.Popen(
        [sys.executable, "-m", "jaxpg.cli", command, *seeds, "--iterations", "100000",
         "--episodes", "5", "--max-steps", "50", "--no-cache", "--out", str(out)],
        stderr=subprocess.PIPE, text=True)
    try:
        assert process.stderr.readline().startswith("Iteration: 10000/100000")  # training
        start = time.perf_counter()
        for _ in range(signals):
            process.send_signal(signal.SIGINT)
            time.sleep(0.05)
        status = process.wait(timeout=30)
        seconds = time.perf_counter() - start
    finally:
        process.kill()
    rest = process.stderr.read()
    assert status == 130 and rest == f"jaxpg {command}: interrupted\n" and seconds < 2, rest
    assert [p.name for p in out.iterdir()] == ["metrics.json"]
    assert (out / "metrics.json").read_text() == "earlier"
    assert [p.name for p in tmp_path.iterdir() if "staging" in p.name] == []


def test_the_last_10_mean_of_a_seed_is_the_same_in_a_sweep_and_alone(tmp_path):
    args = ["--iterations", "12", "--episodes", "3", "--max-steps", "20", "--quiet", "--no-cache"]
    assert cli.run_command(["train", *args, "--seed", "3", "--out", str(tmp_path / "alone")]) == 0
    assert cli.run_command(["sweep", *args, "--seeds", "4", "--out", str(tmp_path / "sweep")]) == 0
    alone = json.loads((tmp_path / "alone/metrics.json").read_text())["last_10_mean_return"]
    rows = (tmp_path / "sweep/runs.csv").read_text().splitlines()
    column = rows[0].split(",").index("last_10_mean_return")
    assert rows[1 + 3].split(",")[column] == repr(alone)  # seed 3: the same number, to the bit


def test_divergence_is_reported_with_its_first_iteration(tmp_path):
    args = [*SMALL, "--lr", "1e30", "--optimizer", "sgd"]
    with pytest.warns(RuntimeWarning, match="diverged: .* from iteration 1 on"):
        assert cli.run_command(["train", *args, "--out", str(tmp_path / "run")]) == 0
    assert json.loads((tmp_path / "run/metrics.json").read_text())[
        "first_nonfinite_iteration"] == 1
    with pytest.warns(RuntimeWarning, match="diverged"):
        assert cli.run_command(["sweep", *args, "--seeds", "2",
                                "--out", str(tmp_path / "sweep")]) == 0
    rows = [row.split(",") for row in (tmp_path / "sweep/runs.csv").read_text().splitlines()]
    column = rows[0].index("first_nonfinite_iteration")
    assert [row[column] for row in rows[1:]] == ["1", "-1"]  # seed 1's stayed finite


def test_a_sweep_whose_scores_the_report_refuses_keeps_its_runs_and_succeeds(tmp_path, capsys):
    """Every run diverges: the runs are written, and the report is missing, in one line."""
    args = ["--env", "MountainCarContinuous-v0", "--seeds", "2", "--lr", "100", "--iterations",
            "30", "--episodes", "4", "--max-steps", "100", "--quiet", "--no-cache"]
    with pytest.warns(RuntimeWarning, match="diverged"):
        assert cli.run_command(["sweep", *args, "--out", str(tmp_path / "sweep")]) == 0
    assert "no comparison report: " in capsys.readouterr().out
    assert {p.name for p in (tmp_path / "sweep").iterdir()} == {
        "metrics.npz", "runs.csv", "summary.json", "sweep.png", "policies.msgpack"}


def test_the_command_warns_in_one_line_and_once_of_an_unreadable_compilation_cache(capsys):
    """JAX warns of every entry of a damaged cache (21 for `reproduce`, two lines each)."""
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = cli._show_warning
        for name in ("jit_add", "jit_scan", "jit_where"):
            warnings.warn(f"Error reading persistent compilation cache entry for '{name}': "
                          f"error: Error -3 while decompressing data: incorrect header check",
                          stacklevel=1)
        warnings.warn("something else", RuntimeWarning, stacklevel=1)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2 and "unreadable entries" in lines[0] and "'jit_add'" in lines[0]
    assert lines[1] == "jaxpg: warning: something else"


def test_a_cache_home_that_is_a_file_means_training_with_one_warning(tmp_path):
    """matplotlib, whose cache is there too, keeps a temporary one without its two lines."""
    (tmp_path / "cache").write_text("a file")
    environment = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    environment.pop("MPLCONFIGDIR", None)
    common = [sys.executable, "-m", "jaxpg.cli", "train", *SMALL[:-1]]  # (--no-cache aside)
    finished = subprocess.run([*common, "--out", str(tmp_path / "out")], env=environment,
                              capture_output=True, text=True)
    assert finished.returncode == 0
    assert finished.stderr.splitlines() == [
        f"keeping no compiled programs in {tmp_path}/cache/jaxpg/programs: it cannot be used "
        f"(Not a directory)"]
    assert (tmp_path / "out" / checkpoint.FILENAME).is_file()


def test_jaxs_cache_where_the_cache_home_is_a_file_is_left_off_with_one_warning(
        tmp_path, monkeypatch, capsys):
    """JAX would warn of each of its entries as unreadable (`reproduce`'s 21), as if damaged."""
    (tmp_path / "cache").write_text("a file")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    previous = jax.config.jax_compilation_cache_dir
    cli._enable_compilation_cache(False)
    assert jax.config.jax_compilation_cache_dir == previous
    assert capsys.readouterr().err == (f"jaxpg: warning: keeping no compiled programs in "
                                       f"{tmp_path}/cache/jaxpg/xla: it cannot be used "
                                       f"(Not a directory)\n")


@pytest.mark.parametrize("policy, out", [("", ""), ("policies.msgpack", ""), ("", "..")])
def test_evaluate_refuses_an_out_that_holds_the_policies_evaluated(sweep_folder, capsys, policy,
                                                                    out):
    """Writing the results there would replace the sweep, its policies included."""
    before = {p.name: p.read_bytes() for p in sweep_folder.iterdir()}
    status = cli.run_command(["evaluate", "--policy", str(sweep_folder / policy), "--episodes",
                              "3", "--max-steps", "10", "--out", str(sweep_folder / out)])
    lines = capsys.readouterr().err.splitlines()
    assert status == 2 and len(lines) == 1 and "the policies evaluated, which writing" in lines[0]
    assert {p.name: p.read_bytes() for p in sweep_folder.iterdir()} == before


@pytest.mark.parametrize(("text", "size"), [
    ("2G", 2 * 2**30), ("512MB", 512 * 2**20), ("1.5GiB", 3 * 2**29), ("1000000", 10**6)])
def test_memory_sizes_are_read_exactly(text, size):
    assert cli._bytes(text) == size


@pytest.mark.parametrize("text", ["1000000.9", "0", "0.5", "2X", ""])
def test_memory_sizes_that_are_no_whole_positive_number_of_bytes_are_refused(text, capsys):
    with pytest.raises(SystemExit) as exit_:  # (the parser's own refusal)
        cli.run_command(["sweep", "--memory-budget", text])
    assert exit_.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()[-1:]
    assert line.endswith(f"expected a positive whole number of bytes such as 2G, 512M or "
                         f"1000000, got {text!r}")
