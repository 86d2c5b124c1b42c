"""The comparison report: `jaxpg sweep` writes it, `jaxpg compare` compares folders, bad folders
are refused in one line."""

import json
import shutil

import numpy as np
import pytest

from jaxpg import cli, report, stats

SMALL = ["--iterations", "3", "--episodes", "3", "--max-steps", "20", "--quiet", "--no-cache"]
REPORT_FILES = {report.COMPARISON_FILE, *report.PLOT_FILES}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """Two sweep folders of one config (4 seeds x 2 settings, 3 seeds x 2) and one of 1 seed."""
    root = tmp_path_factory.mktemp("sweeps")
    for name, args in (("a", ["--seeds", "4", "--lr", "0.01,0.02"]),
                       ("b", ["--seeds", "3", "--lr", "0.05", "--discount", "0.9,0.99"]),
                       ("one", ["--seeds", "1"])):
        assert cli.run_command(["sweep", *SMALL, *args, "--out", str(root / name)]) == 0
    return root


def _strict_json(path):
    def refuse(constant):
        raise AssertionError(f"{path} holds {constant}, not strict JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def _copy(sweeps, tmp_path, name="copy"):
    return shutil.copytree(sweeps / "a", tmp_path / name)


def _edit_summary(folder, edit):
    summary = json.loads((folder / "summary.json").read_text())
    edit(summary)
    (folder / "summary.json").write_text(json.dumps(summary))


def _add_to_npz(folder, **arrays):
    """Rewrites metrics.npz with what the report reads from it, and `arrays`."""
    with np.load(folder / "metrics.npz") as npz:
        contents = {name: npz[name]
                    for name in ("seeds", "learning_rate", "discount", "mean_return")}
    np.savez(folder / "metrics.npz", **contents, **arrays)


def test_sweep_writes_its_report(sweeps):
    folder = sweeps / "a"
    assert REPORT_FILES <= {p.name for p in folder.iterdir()}
    assert _strict_json(folder / "summary.json")["format"] == report.SWEEP_FORMAT
    comparison = _strict_json(folder / report.COMPARISON_FILE)
    assert [s["label"] for s in comparison["settings"]] == [
        "lr=0.01, discount=0.95", "lr=0.02, discount=0.95"]
    assert [s["runs"] for s in comparison["settings"]] == [4, 4]
    for name in report.PLOT_FILES:
        assert (folder / name).read_bytes()[:8] == PNG_SIGNATURE
    assert not REPORT_FILES & {p.name for p in (sweeps / "one").iterdir()}  # 1 seed: no intervals


def test_scores_are_the_last_training_iterations_and_the_report_says_so(sweeps):
    comparison = report.compare([sweeps / "a"])
    with np.load(sweeps / "a" / "metrics.npz") as npz:
        scores = npz["mean_return"].astype(np.float64).mean(axis=-1)  # 3 iterations: all of them
        curves = npz["mean_return"].astype(np.float64)
    assert comparison["score"].startswith("training return")
    assert "last 3 iterations" in comparison["score"]
    for setting, x in zip(comparison["settings"], scores):
        assert setting["iqm"]["estimate"] == stats.iqm(x)
        assert (setting["iqm"]["low"], setting["iqm"]["high"]) == stats.bootstrap_ci(x)
        assert setting["optimality_gap"]["estimate"] == stats.optimality_gap(x, 195.0)
    np.testing.assert_array_equal(comparison["iqm_curves"]["estimate"][1],
                                  stats.iqm(curves[1], axis=0))
    matrix = comparison["probability_of_improvement"]
    assert matrix["probability"][1][0] == pytest.approx(
        stats.probability_of_improvement(scores[1], scores[0]))
    assert comparison["seeds_needed"]["best"] in {
        "lr=0.01, discount=0.95", "lr=0.02, discount=0.95"}


def test_held_out_returns_are_the_scores_where_the_sweep_has_them(sweeps, tmp_path):
    folder = _copy(sweeps, tmp_path)
    held_out = np.arange(2 * 4 * 5, dtype=np.float32).reshape(2, 4, 5)  # [G, S, N]
    _add_to_npz(folder, eval_returns=held_out)
    comparison = report.compare([folder])
    assert comparison["score"].startswith("held-out evaluation return")
    assert "5 evaluation" in comparison["score"]
    # Setting 0's scores are the means of rows 0-4, 5-9, 10-14, 15-19: 2, 7, 12, 17; their IQM
    # cuts one at each end: (7 + 12) / 2 = 9.5.
    assert comparison["settings"][0]["iqm"]["estimate"] == 9.5
    with pytest.raises(ValueError, match="score their runs differently"):
        report.compare([sweeps / "a", folder])


def test_compare_prints_a_table_and_the_matrix_and_writes_the_report(sweeps, tmp_path, capsys):
    out = tmp_path / "comparison"
    assert cli.run_command(["compare", str(sweeps / "a"), str(sweeps / "b"), "--out", str(out),
                            "--reps", "500"]) == 0
    assert {p.name for p in out.iterdir()} == REPORT_FILES
    comparison = _strict_json(out / report.COMPARISON_FILE)
    labels = [s["label"] for s in comparison["settings"]]
    assert labels[0] == f"{sweeps / 'a'}: lr=0.01, discount=0.95"
    assert labels[3] == f"{sweeps / 'b'}: lr=0.05, discount=0.99"
    assert np.shape(comparison["probability_of_improvement"]["low"]) == (4, 4)
    assert np.shape(comparison["performance_profiles"]["estimate"]) == (4, 101)
    assert comparison["reps"] == 500
    printed = capsys.readouterr().out
    assert "IQM [95% CI]" in printed and "P(row's setting scores above column's)" in printed
    assert "seeds per setting" in printed
    assert labels[2] in printed


@pytest.mark.parametrize("case, message", [
    ("missing", "no such folder"),
    ("empty", "empty; expected a folder written by jaxpg sweep"),
    ("unmarked", "written by another version of jaxpg (no format marker"),
    ("other format", "written by another version of jaxpg (format 'jaxpg-sweep-0'"),
    ("other config",
     "differ in max_steps (20 against 10); only learning rates, discounts and seeds may differ"),
    ("one seed", "has 1 run; a comparison needs at least 2 seeds per setting"),
    ("twice", "folders: a folder is given more than once"),
])
def test_bad_folders_exit_2_with_one_line(sweeps, tmp_path, capsys, case, message):
    copy = tmp_path / "copy"
    if case == "empty":
        copy.mkdir()
    elif case != "missing":
        _copy(sweeps, tmp_path)
    if case == "unmarked":
        _edit_summary(copy, lambda summary: summary.pop("format"))
    elif case == "other format":
        _edit_summary(copy, lambda summary: summary.update(format="jaxpg-sweep-0"))
    elif case == "other config":
        _edit_summary(copy, lambda summary: summary["config"].update(max_steps=10))
    folders = {"one seed": [sweeps / "one"], "twice": [sweeps / "a", sweeps / "a"]}.get(
        case, [sweeps / "a", copy])
    assert cli.run_command(["compare", *map(str, folders), "--out", str(tmp_path / "out")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("jaxpg compare: error:")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, word", [
    (["--confidence", "1.5"], "confidence"),
    (["--reps", "0"], "reps"),
])
def test_bad_options_exit_2_with_one_line(sweeps, tmp_path, capsys, args, word):
    out = tmp_path / "out"
    assert cli.run_command(["compare", str(sweeps / "a"), "--out", str(out), *args]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and word in lines[0]
