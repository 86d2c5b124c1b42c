"""The README's study from Python runs as written, at 4 seeds of 3 iterations.

The block is executed with "SEEDS = 64" replaced by "SEEDS = 4" and "ITERATIONS = 150" by
"ITERATIONS = 3", in a temporary working directory: the same code, at a test's cost.
"""

import re

from test_readme import README, _python_block

from jaxpg import report

SECTION = "A study from Python"
SMALLER = {"SEEDS = 64": "SEEDS = 4", "ITERATIONS = 150": "ITERATIONS = 3"}


def test_the_block_is_at_most_30_lines_of_code():
    code = [line for line in _python_block(SECTION).splitlines() if line.strip()]
    assert len(code) <= 30


def test_the_study_writes_three_folders_and_compares_the_settings(tmp_path, monkeypatch, capsys):
    code = _python_block(SECTION)
    for full, small in SMALLER.items():
        assert code.count(full) == 1, full
        code = code.replace(full, small)
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(code, str(README), "exec"), namespace)
    comparison = namespace["comparison"]
    assert [s["runs"] for s in comparison["settings"]] == [4, 4, 4]
    assert comparison["folders"] == ["sweeps[0]", "sweeps[1]", "sweeps[2]"]
    assert comparison["score"].startswith("held-out evaluation return")
    labels = [s["label"] for s in comparison["settings"]]
    assert "entropy_coef=0.01" in labels[1] and re.search(r"entropy_coef=0(,|$)", labels[0])
    assert "loss=PPO" in labels[2] and "loss=reinforce" in labels[0]
    for name in ("reinforce", "entropy", "ppo"):
        folder = tmp_path / "runs/study" / name
        written = {p.name for p in folder.iterdir()}
        assert {"metrics.npz", "runs.csv", "summary.json", "sweep.png", "policies.msgpack",
                report.COMPARISON_FILE} <= written
        loaded = report.load_sweep(folder)
        assert loaded.scores.shape == (1, 4)
    assert {p.name for p in (tmp_path / "runs/study/report").iterdir()} == {
        report.COMPARISON_FILE, *report.PLOT_FILES}
    printed = capsys.readouterr().out
    # A line per setting: its name and the IQM of its 4 policies at each of the 3 lengths.
    assert len(re.findall(r"^(reinforce|entropy|ppo) \[", printed, re.MULTILINE)) == 3
    assert labels[2] in printed
