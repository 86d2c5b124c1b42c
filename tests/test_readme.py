"""The README's examples run as written."""

import pathlib
import re

import numpy as np

README = pathlib.Path(__file__).parent.parent / "README.md"


def _python_block(section, index=0):
    """The `index`-th ```python block under the README heading `section` (in that section)."""
    text = README.read_text()
    body = text[text.index(f"## {section}\n"):]
    end = body.find("\n## ", 1)  # the next section's heading
    body = body if end < 0 else body[:end]
    return re.findall(r"```python\n(.*?)```", body, re.DOTALL)[index]


def _run(section, index=0):
    """Executes the section's `index`-th block; returns the names it defined."""
    namespace = {}
    exec(compile(_python_block(section, index), str(README), "exec"), namespace)
    return namespace


def test_quick_start_runs():
    namespace = _run("Quick start")
    # From Gymnasium's reset(seed=i) states, the basic policy's mean over 500 episodes is the
    # book's 41.698; jaxpg's own resets give other episodes of the same distribution.
    assert namespace["in_gymnasium"].mean == 41.698
    assert 35 < namespace["in_jaxpg"].mean < 50
    assert namespace["result"].metrics.mean_return.shape == (150,)
    assert namespace["results"].summary.fraction_solved.shape == (2,)  # two learning rates


def test_your_own_policy_and_loss_runs_and_learns(capsys):
    namespace = _run("Your own policy and loss")
    results = namespace["results"]
    assert results.metrics.extra["clipped"].shape == (2, 16, 150)
    assert results.summary.final_return.mean() > 100  # it learned (a random policy scores ~22)
    assert len(capsys.readouterr().out.splitlines()) == 2


def test_ppo_example_solves_cartpole(capsys):
    namespace = _run("Your own policy and loss", 1)
    assert float(capsys.readouterr().out) >= 195
    assert set(namespace) >= {"ppo"}


def test_other_environments_train_and_learn():
    namespace = _run("Other environments")
    results = namespace["results"]
    assert [setting["link_mass_2"] for setting in results.grid] == [1.0, 1.5]
    assert results.metrics.mean_return.shape == (2, 16, 50)
    # A random Acrobot policy rarely swings up within the 500 steps (return about -500).
    assert np.median(results.summary.final_return[0]) > -400
    assert namespace["pendulum"].randomize == (("mass", (0.8, 1.2)),)


def test_sweeps_robustness_and_statistics_run():
    namespace = _run("Sweeps, robustness and statistics")
    assert namespace["table"].returns.shape == (1, 32, 6, 100)  # [G, S, P, episodes]
    assert namespace["lengths"].eval_returns.shape == (2, 32, 100)
    assert namespace["pairs"].summary.final_return.shape == (2, 32)
    assert [setting["length"] for setting in namespace["pairs"].grid] == [1.0, 2.0]
    # A policy trained on lengths drawn from [0.25, 2.0) balances at length 1.0 (setting 2 of
    # 6: the lengths vary slowest) far longer than the ~22 steps of a random policy.
    assert np.median(namespace["table"].returns[0, :, 2]) > 100
