"""The README's examples run as written."""

import pathlib
import re

README = pathlib.Path(__file__).parent.parent / "README.md"


def _python_block(section):
    """The first ```python block under the README heading `section`."""
    text = README.read_text()
    body = text[text.index(f"## {section}\n"):]
    return re.search(r"```python\n(.*?)```", body, re.DOTALL)[1]


def test_your_own_policy_and_loss_runs_and_learns(capsys):
    namespace = {}
    exec(compile(_python_block("Your own policy and loss"), str(README), "exec"), namespace)
    results = namespace["results"]
    assert results.metrics.extra["clipped"].shape == (2, 16, 150)
    assert results.summary.final_return.mean() > 100  # it learned (a random policy scores ~22)
    assert len(capsys.readouterr().out.splitlines()) == 2
