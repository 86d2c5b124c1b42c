"""The comparison report: `jaxpg sweep` writes it, `jaxpg compare` compares folders, bad folders
are refused in one line."""

import dataclasses
import json
import os
import shutil
import zipfile

import numpy as np
import pytest

from jaxpg import TrainConfig, atomic_files, checkpoint, cli, report, save_sweep, stats, sweep

SMALL = ["--iterations", "3", "--episodes", "3", "--max-steps", "20", "--quiet", "--no-cache"]
REPORT_FILES = {report.COMPARISON_FILE, *report.PLOT_FILES}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """Two sweep folders of one config (4 seeds x 2 settings, 3 seeds x 2), one of 1 seed and one
    of 12 iterations."""
    root = tmp_path_factory.mktemp("sweeps")
    for name, args in (("a", ["--seeds", "4", "--lr", "0.01,0.02"]),
                       ("b", ["--seeds", "3", "--lr", "0.05", "--discount", "0.9,0.99"]),
                       ("one", ["--seeds", "1"]),
                       ("long", ["--seeds", "4", "--iterations", "12"])):
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
    """Rewrites metrics.npz with what the report reads from it, and `arrays` (which replace
    those of the same names)."""
    with np.load(folder / "metrics.npz") as npz:
        contents = {name: npz[name]
                    for name in ("seeds", "learning_rate", "discount", "mean_return")}
    np.savez(folder / "metrics.npz", **{**contents, **arrays})


def _npy(shape, descr="<f4", data=b""):
    """An .npy file written by hand: version 1.0's header declaring `shape` of `descr`, padded
    to 64 bytes as numpy pads it, then `data`."""
    header = repr({"descr": descr, "fortran_order": False, "shape": shape}).encode()
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + data


def _write_npz(folder, **members):
    """Writes metrics.npz as a zip archive of the given `.npy` members' bytes."""
    with zipfile.ZipFile(folder / "metrics.npz", "w") as archive:
        for name, data in members.items():
            archive.writestr(f"{name}.npy", data)


def _flip_a_bit_of_mean_return(folder):
    """Flips the lowest bit of the last byte of mean_return's data, stored uncompressed."""
    _add_to_npz(folder)
    with np.load(folder / "metrics.npz") as npz:
        stored = npz["mean_return"].tobytes()
    data = bytearray((folder / "metrics.npz").read_bytes())
    data[data.index(stored) + len(stored) - 1] ^= 1
    (folder / "metrics.npz").write_bytes(data)


def _nested(depth):
    return "[" * depth + "]" * depth


# Each case damages a copy of sweep "a" (2 settings x 4 seeds x 3 iterations): (file, edit,
# what the message says after the file's path).
DAMAGED = {
    "truncated npz": ("metrics.npz", lambda f: (f / "metrics.npz").write_bytes(
        (f / "metrics.npz").read_bytes()[:300]), "damaged .npz archive (BadZipFile"),
    "not a zip": ("metrics.npz", lambda f: (f / "metrics.npz").write_bytes(b"PK" + bytes(500)),
                  "damaged .npz archive"),
    # 2**37 float32 values: 512 GiB, which loading would allocate before reading a byte.
    "512 GiB header": ("metrics.npz", lambda f: _write_npz(f, mean_return=_npy((2**37,))),
                       "mean_return.npy: its header declares shape (137438953472,) of float32, "
                       "549755813888 bytes, more than the 4294967296 allowed"),
    # 2 * 4 * 2**20 float32 values declared (32 MiB), 4 bytes held.
    "header beyond data": ("metrics.npz", lambda f: _write_npz(
        f, mean_return=_npy((2, 4, 2**20), data=bytes(4))),
        "mean_return.npy: its header declares 33554432 bytes of data, the archive holds 4"),
    "flipped bit": ("metrics.npz", _flip_a_bit_of_mean_return,
                    "damaged .npz archive (BadZipFile: Bad CRC-32 for file 'mean_return.npy')"),
    "no npy header": ("metrics.npz", lambda f: _write_npz(f, mean_return=b"{}" * 40),
                      "mean_return.npy: no .npy header"),
    "objects": ("metrics.npz", lambda f: _write_npz(f, mean_return=_npy((2,), "|O", bytes(16))),
                "mean_return.npy: expected an array of numbers, got shape (2,) of object"),
    "no mean_return": ("metrics.npz", lambda f: _write_npz(f, seeds=_npy((0,))),
                       "no mean_return; run the sweep again"),
    "other settings": ("metrics.npz", lambda f: _add_to_npz(f, mean_return=np.ones((3, 4, 3))),
                       "mean_return of shape [3, 4, 3], expected [G, S, I] with G = 2"),
    "no iterations": ("metrics.npz", lambda f: _add_to_npz(f, mean_return=np.ones((2, 4, 0))),
                      "mean_return of shape [2, 4, 0], expected [G, S, I]"),
    "NaN return": ("metrics.npz", lambda f: _add_to_npz(f, mean_return=np.full((2, 4, 3), np.nan)),
                   "mean_return: must be finite, got NaN or infinity"),
    "no grid": ("summary.json", lambda f: _edit_summary(f, lambda s: s.pop("grid")),
                "grid must be a non-empty array of settings, got null"),
    "grid of another type": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s.update(grid={"learning_rate": [0.01]})),
        "grid must be a non-empty array of settings, got an object"),
    "setting without discount": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["grid"][1].pop("discount")),
        "grid[1] must be an object with a learning_rate and a discount"),
    "setting of another type": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["grid"].__setitem__(0, [0.01, 0.95])),
        "grid[0] must be an object with a learning_rate and a discount"),
    "text learning rate": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["grid"][0].update(learning_rate="0.01")),
        "grid[0].learning_rate: must be a finite number, got '0.01'"),
    "list discount": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["grid"][1].update(discount=[0.9])),
        "grid[1].discount: must be a finite number, got an array"),
    "huge integer": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["grid"][1].update(discount=10**400)),
        "grid[1].discount: must be a finite number, got 1000000000000000000000000000000000000000"),
    "no solved_return": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["config"].pop("solved_return")),
        "config.solved_return: must be a finite number, got null"),
    # The config is read as a TrainConfig would take it: a report labels runs by it.
    "NaN learning rate": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["config"].update(learning_rate=float("nan"))),
        "damaged config (learning_rate: must be finite, got NaN or infinity)"),
    "iterations as words": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["config"].update(iterations="lots")),
        "damaged config (iterations: must be a positive integer, got 'lots')"),
    "unknown environment": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["config"].update(env=["x", "x", "x"])), "damaged config (env: expected"),
    "unknown field": ("summary.json", lambda f: _edit_summary(
        f, lambda s: s["config"].update(frob=1)), "damaged config (unknown config field(s) frob)"),
    "nested 100000 deep": ("summary.json", lambda f: (f / "summary.json").write_text(
        _nested(100_000)), "not valid JSON (nested too deeply)"),
    "not UTF-8": ("summary.json", lambda f: (f / "summary.json").write_bytes(b'{"\xff": 1}'),
                  "not valid JSON"),
    "not JSON": ("summary.json", lambda f: (f / "summary.json").write_text("{"),
                 "not valid JSON (Expecting property name"),
    "a folder": ("summary.json", lambda f: ((f / "summary.json").unlink(),
                                            (f / "summary.json").mkdir()),
                 "not a regular file (a folder)"),
}


@pytest.mark.parametrize("case", DAMAGED)
def test_damaged_files_are_one_line_errors_naming_the_file(sweeps, tmp_path, case):
    name, damage, message = DAMAGED[case]
    folder = _copy(sweeps, tmp_path)
    damage(folder)
    with pytest.raises(ValueError) as error:
        report.load_sweep(folder)
    assert str(error.value).startswith(f"{folder / name}: {message}")
    assert "\n" not in str(error.value)


def test_files_over_their_bounds_are_refused_before_they_are_read(sweeps, tmp_path, monkeypatch):
    folder = _copy(sweeps, tmp_path)
    size = (folder / "summary.json").stat().st_size
    monkeypatch.setattr(report, "_MAX_SUMMARY_BYTES", size - 1)
    with pytest.raises(ValueError, match=f"summary.json: {size} bytes, more than the {size - 1}"):
        report.load_sweep(folder)
    monkeypatch.undo()
    # A zip bomb: 2 x 4 x 2**20 zeros (32 MiB) compress to about 32 KiB.
    np.savez_compressed(folder / "metrics.npz", mean_return=np.zeros((2, 4, 2**20), np.float32))
    assert (folder / "metrics.npz").stat().st_size < 2**20
    monkeypatch.setattr(report, "_MAX_ARRAY_BYTES", 2**20)
    with pytest.raises(ValueError, match="mean_return.npy: its header declares shape "
                                         r"\(2, 4, 1048576\) of float32, 33554432 bytes"):
        report.load_sweep(folder)


def test_sweep_writes_its_report(sweeps):
    folder = sweeps / "a"
    assert REPORT_FILES <= {p.name for p in folder.iterdir()}
    assert _strict_json(folder / "summary.json")["format"] == report.SWEEP_FORMAT
    comparison = _strict_json(folder / report.COMPARISON_FILE)
    assert [s["label"] for s in comparison["settings"]] == ["lr=0.01", "lr=0.02"]  # what differs
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
    assert comparison["seeds_needed"]["best"] in {"lr=0.01", "lr=0.02"}


def test_scores_are_the_means_of_the_last_ten_iterations_of_a_longer_sweep(sweeps):
    comparison = report.compare([sweeps / "long"])
    with np.load(sweeps / "long" / "metrics.npz") as npz:
        curves = npz["mean_return"].astype(np.float64)
    assert curves.shape[-1] == 12
    scores = curves[..., -10:].mean(axis=-1)
    assert not np.allclose(scores, curves.mean(axis=-1))  # the window is not every iteration
    assert "last 10 iterations" in comparison["score"]
    (setting,) = comparison["settings"]
    assert setting["iqm"]["estimate"] == stats.iqm(scores[0])


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
    assert labels[0] == "lr=0.01, discount=0.95"  # the learning rates and discounts differ
    assert labels[3] == "lr=0.05, discount=0.99"
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
    ("other target", "differ in solved_return (195.0 against 100.0); compare sweeps of one"),
    ("one seed", "has 1 run; a comparison needs at least 2 seeds per setting"),
    ("twice", "sweeps: a sweep is given more than once"),
    ("final separator", "are the same folder"),
    ("linked", "are the same folder"),
    ("other length", "hold metrics of different lengths (3 against 5 iterations)"),
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
    elif case == "other target":
        _edit_summary(copy, lambda summary: summary["config"].update(solved_return=100.0))
    elif case == "other length":  # a config of 3 iterations, metrics of 5
        _add_to_npz(copy, mean_return=np.ones((2, 4, 5)))
    elif case == "linked":
        (tmp_path / "link").symlink_to(sweeps / "a")
    folders = {"one seed": [sweeps / "one"], "twice": [sweeps / "a", sweeps / "a"],
               "final separator": [sweeps / "a", f"{sweeps / 'a'}{os.sep}"],
               "linked": [sweeps / "a", tmp_path / "link"]}.get(case, [sweeps / "a", copy])
    assert cli.run_command(["compare", *map(str, folders), "--out", str(tmp_path / "out")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("jaxpg compare: error:")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, word", [
    (["--confidence", "1.5"], "confidence"),
    (["--reps", "0"], "reps"),
    (["--reps", "1"], "reps"),  # an interval of one resample: its estimate outside it
])
def test_bad_options_exit_2_with_one_line(sweeps, tmp_path, capsys, args, word):
    out = tmp_path / "out"
    assert cli.run_command(["compare", str(sweeps / "a"), "--out", str(out), *args]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and word in lines[0]


def test_folders_of_other_configs_are_compared_and_named_by_what_differs(sweeps, tmp_path):
    folder = _copy(sweeps, tmp_path)
    _edit_summary(folder, lambda summary: summary["config"].update(max_steps=10, loss="baseline"))
    labels = [s["label"] for s in report.compare([sweeps / "a", folder], reps=50)["settings"]]
    assert labels == [f"lr={lr}, max_steps={steps}, loss={loss}"
                      for steps, loss in ((20, "reinforce"), (10, "baseline"))
                      for lr in (0.01, 0.02)]


def test_settings_alike_but_for_their_folders_are_named_after_them(sweeps, tmp_path):
    folder = _copy(sweeps, tmp_path)
    labels = [s["label"] for s in report.compare([sweeps / "a", folder], reps=50)["settings"]]
    assert labels[0] == f"{sweeps / 'a'}: lr=0.01" and labels[3] == f"{folder}: lr=0.02"


# --- SweepResults and save_sweep ----------------------------------------------------------------


@pytest.fixture(scope="module")
def result():
    """A sweep of 3 seeds x 2 learning rates, with 4 held-out episodes per run."""
    config = TrainConfig(iterations=3, episodes=3, max_steps=20)
    return sweep(config, seeds=range(3), grid={"learning_rate": [0.01, 0.02]},
                 show_progress=False, eval_episodes=4)


def test_save_sweep_writes_the_folder_that_jaxpg_sweep_writes(sweeps, result, tmp_path):
    out = tmp_path / "saved"
    out.mkdir()
    (out / "earlier.txt").write_text("an earlier result")
    comparison = save_sweep(result, out)
    assert {p.name for p in out.iterdir()} == {p.name for p in (sweeps / "a").iterdir()}
    assert _strict_json(out / report.COMPARISON_FILE)["settings"] == json.loads(
        json.dumps(atomic_files.to_json(comparison)))["settings"]  # (as JSON holds it, "out")
    loaded = report.load_sweep(out)
    np.testing.assert_array_equal(loaded.scores, result.eval_returns.mean(axis=-1))
    assert loaded.config == checkpoint.config_to_dict(result.config)
    assert checkpoint.load(out).policy_params.keys() == result.policy_params.keys()


def test_a_result_and_its_folder_compare_alike(result, tmp_path):
    save_sweep(result, tmp_path / "saved")
    from_result, from_folder = (report.compare([source], reps=50)
                                for source in (result, tmp_path / "saved"))
    assert from_result["folders"] == ["sweeps[0]"]
    assert from_result["settings"] == [{**setting, "folder": "sweeps[0]"}
                                       for setting in from_folder["settings"]]


def test_results_of_other_losses_are_named_by_their_loss(result):
    other = result._replace(config=dataclasses.replace(result.config, loss="reward-to-go"))
    labels = [s["label"] for s in report.compare([result, other], reps=50)["settings"]]
    assert labels == ["lr=0.01, loss=reinforce", "lr=0.02, loss=reinforce",
                      "lr=0.01, loss=reward-to-go", "lr=0.02, loss=reward-to-go"]


def _with_mean_return(result, values):
    return result._replace(metrics=result.metrics._replace(mean_return=values))


@pytest.mark.parametrize("edit, message", [
    (lambda r: [r, r], "sweeps: a sweep is given more than once (sweeps[0] and sweeps[1] are the "
                       "same result)"),
    (lambda r: [r, 3], "sweeps[1]: must be a sweep folder or a SweepResult, got int"),
    (lambda r: [], "sweeps: give at least one sweep folder or SweepResult"),
    (lambda r: [r._replace(config=None)], "sweeps[0]: a SweepResult without its config"),
    (lambda r: [_with_mean_return(r, np.full((2, 3, 3), np.nan))],
     "sweeps[0]: mean_return: must be finite, got NaN"),
    (lambda r: [_with_mean_return(r, np.zeros((2, 0, 3)))],
     "sweeps[0]: mean_return of shape [2, 0, 3], expected [G, S, I]"),
    (lambda r: [r._replace(eval_returns=np.zeros((2, 2, 4)))],
     "sweeps[0]: eval_returns of shape [2, 2, 4], expected [G, S, N] with [G, S] = [2, 3]"),
    (lambda r: [r, _with_mean_return(r._replace(eval_returns=None), np.zeros((2, 3, 3)))],
     "score their runs differently"),
    (lambda r: [r, _with_mean_return(r, np.zeros((2, 3, 5)))],
     "sweeps: sweeps[0] and sweeps[1] hold metrics of different lengths (3 against 5"),
])
def test_bad_results_are_one_line_errors(result, edit, message):
    with pytest.raises(ValueError) as raised:
        report.compare(edit(result), reps=50)
    assert message in str(raised.value) and "\n" not in str(raised.value)


def test_save_sweep_refuses_a_result_without_config_and_writes_nothing(result, tmp_path):
    with pytest.raises(ValueError, match="result: a SweepResult without its config"):
        save_sweep(result._replace(config=None), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_a_report_into_a_folder_compared_is_refused_and_the_folder_kept(sweeps, tmp_path, capsys):
    folder = _copy(sweeps, tmp_path)
    before = sorted((path.name, path.read_bytes()) for path in folder.iterdir())
    assert cli.run_command(["compare", str(sweeps / "a"), str(folder), "--out", str(folder)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "a folder compared, which writing the report" in lines[0], lines
    assert sorted((path.name, path.read_bytes()) for path in folder.iterdir()) == before
