"""Work that cannot fit in memory or compile, and a coordinator that does not answer, end in one
line with exit status 2, before anything compiles or hangs."""

import socket
import subprocess
import sys

import numpy as np
import pytest
from conftest import xla_compiles

from jaxpg import budget, cartpole, evaluate, policies, robustness
from jaxpg.animation import render_episode

# Far beyond any machine: 10**12 episodes of 200 steps are 8 * 10**15 bytes at 40 bytes a step.
HUGE = 10**12


def _run(*args):
    return subprocess.run([sys.executable, "-m", "jaxpg.cli", *args], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize("args, starts", [
    (["evaluate", "--episodes", str(HUGE)], "jaxpg evaluate: error: episodes: playing "
                                            f"{HUGE} episodes of at most 200 steps"),
    (["render", "--max-steps", str(HUGE)], "jaxpg render: error: max_steps: drawing an episode "
                                           f"of at most {HUGE} steps"),
    (["train", "--hidden", "10000", "--iterations", "1", "--no-cache"],
     f"jaxpg train: error: hidden: at most {budget.MAX_UNITS} units per layer"),
    (["sweep", "--coordinator", "127.0.0.1:9", "--num-processes", "2", "--process-id", "1",
      "--coordinator-timeout", "1"],
     "jaxpg sweep: error: coordinator: nothing answered at 127.0.0.1:9 within 1 s"),
])
def test_the_command_line_refuses_in_one_line(args, starts, tmp_path):
    finished = _run(*args, "--out", str(tmp_path / ("x.gif" if args[0] == "render" else "out")))
    assert finished.returncode == 2
    assert finished.stderr.startswith(starts) and finished.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists() and not (tmp_path / "x.gif").exists()


@pytest.mark.parametrize("play", [
    lambda: evaluate(policies.basic_policy, episodes=HUGE),
    lambda: evaluate(policies.basic_policy, episodes=np.int64(HUGE), max_steps=np.int64(HUGE)),
    lambda: robustness(policies.basic_policy, {"length": [0.5, 1.0]}, episodes=HUGE),
])
def test_evaluation_refuses_before_anything_compiles(play):
    with xla_compiles() as compiled, pytest.raises(ValueError, match="^episodes: playing "):
        play()
    assert not compiled


def test_render_refuses_before_anything_compiles():
    long_env = cartpole.V1.replace(max_steps=HUGE)
    with xla_compiles() as compiled, pytest.raises(ValueError, match="^max_steps: drawing "):
        render_episode(policies.basic_policy, env_params=long_env, max_steps=10**6)
    assert not compiled


def test_process_0_whose_peers_never_join_ends_in_one_line(tmp_path):
    """JAX's own wait would end in a C++ abort; the command's ends at --coordinator-timeout."""
    with socket.socket() as probe:  # a port nothing listens on once closed
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    finished = _run("sweep", "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
                    "--process-id", "0", "--coordinator-timeout", "2", "--out", str(tmp_path))
    assert finished.returncode == 2 and finished.stderr.count("\n") == 1, finished.stderr
    assert finished.stderr.startswith(
        f"jaxpg sweep: error: coordinator: the 2 processes did not all join at 127.0.0.1:{port} "
        f"within 2 s")


def test_held_out_episodes_beyond_memory_are_refused_before_training():
    from jaxpg import TrainConfig, sweep

    with xla_compiles() as compiled, pytest.raises(ValueError, match="^eval_episodes: playing "):
        sweep(TrainConfig(), seeds=range(1024), eval_episodes=2**20 - 1)
    assert not compiled


def test_episodes_beyond_a_chunk_play_in_chunks_of_one_program_within_memory(monkeypatch):
    """12 episodes of 100 steps at 500 steps a chunk: 3 chunks of 4 (at most 500 // 100 = 5)."""
    from jaxpg import evaluation

    states = evaluation.gymnasium_reset_states(12, seed=3)
    # The basic policy ignores its uniforms: from the same states, the same returns in any chunks.
    whole = evaluate(policies.basic_policy, episodes=12, max_steps=100, init_states=states)
    monkeypatch.setattr(evaluation, "STEPS_AT_ONCE", 500)
    # Room for a chunk, 4 * 100 * 40 bytes and 12 returns at 16 bytes, not for 12 * 100 * 40.
    monkeypatch.setattr(budget, "machine_memory", lambda: int(20000 / budget.USABLE_SHARE))
    done = []
    with xla_compiles() as compiled:
        chunked = evaluate(policies.basic_policy, episodes=12, max_steps=100, init_states=states,
                           on_chunk=done.append)
    assert done == [4, 8, 12]
    assert [name for name in compiled if "_jaxpg_returns" in name] == ["jit(_jaxpg_returns)"]
    np.testing.assert_array_equal(chunked.returns, whole.returns)
    drawn = evaluate(policies.basic_policy, episodes=12, max_steps=100).returns
    assert len({tuple(drawn[start:start + 4]) for start in (0, 4, 8)}) == 3  # each its own resets
    with pytest.raises(ValueError, match="^episodes: playing 13 episodes of at most 100 steps, 5 "):
        monkeypatch.setattr(budget, "machine_memory", lambda: int(12000 / budget.USABLE_SHARE))
        evaluate(policies.basic_policy, episodes=13, max_steps=100)


@pytest.mark.parametrize("quiet", [False, True])
def test_the_command_shows_the_chunks_done_unless_quiet(monkeypatch, capsys, quiet):
    from jaxpg import cli, evaluation

    monkeypatch.setattr(evaluation, "STEPS_AT_ONCE", 100)
    args = ["evaluate", "--episodes", "12", "--max-steps", "20", *(["--quiet"] * quiet)]
    assert cli.run_command(args) == 0
    shown = [line.split(" [")[0] for line in capsys.readouterr().err.splitlines()]
    assert shown == ([] if quiet else ["episodes: 4/12", "episodes: 8/12", "episodes: 12/12"])


def test_robustness_plays_the_chunks_of_evaluate(monkeypatch):
    from jaxpg import evaluation

    monkeypatch.setattr(evaluation, "STEPS_AT_ONCE", 500)  # chunks of 4 episodes of 100 steps
    done = []
    played = robustness(policies.basic_policy, {"length": [0.5, 1.0]}, episodes=12,
                        max_steps=100, on_chunk=done.append)
    assert done == [4, 8, 12]
    for p, length in enumerate([0.5, 1.0]):
        alone = evaluate(policies.basic_policy, episodes=12, max_steps=100,
                         env=cartpole.V1.replace(length=length))
        np.testing.assert_array_equal(played.returns[0, 0, p], alone.returns)
