"""A comparison report of sweep folders: how each setting scores, and how sure the ranking is.

It reads folders as `jaxpg sweep --out DIR` writes them (`summary.json`, `metrics.npz`). Every
setting of every folder is a unit of the comparison; the folders must share one configuration but
for the grid fields (learning rate, discount) and their seeds, and are never merged otherwise. Each
run's score is its held-out evaluation return where every folder has them (`eval_returns`,
`[G, S, N]`, averaged over the N episodes), otherwise its training mean return over the last
`SOLVED_WINDOW` iterations; the report says which.
"""

import contextlib
import functools
import json
import os
import pathlib
import sys
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, TypedDict

import numpy as np

from jaxpg import atomic_files, plots, safe_read, stats
from jaxpg.sweeps import SOLVED_WINDOW
from jaxpg.train_config import HYPERPARAMETERS
from jaxpg.validation import check_finite

# summary.json's "format": the folders this version writes and reads.
SWEEP_FORMAT = "jaxpg-sweep-1"
COMPARISON_FORMAT = "jaxpg-comparison-1"  # comparison.json's "format"
COMPARISON_FILE = "comparison.json"
PLOT_FILES = ("aggregate_intervals.png", "performance_profiles.png", "iqm_curves.png",
              "improvement.png")
_AGGREGATES = ("iqm", "mean", "median", "optimality_gap")
# Bounds on what a sweep folder's files may hold: summary.json's [G, I] statistics of 100 settings x
# 10,000 iterations take about 110 MB; one array of metrics.npz of 1,000 seeds x 100 settings x
# 10,000 iterations of float32, 4e9 bytes.
_MAX_SUMMARY_BYTES = 2**28
_MAX_ARRAY_BYTES = 2**32
# The words for the JSON values that a message does not quote.
_JSON_TYPES = {dict: "an object", list: "an array", bool: "a boolean", type(None): "null"}
# Iterations a curve's band is computed at, evenly spaced with the first and last: the bootstrap's
# cost grows with them, and a plot needs no more.
_CURVE_POINTS = 50


class Sweep(NamedTuple):
    """The runs of one sweep folder, as the report needs them."""

    folder: str  # as the user named it
    config: dict[str, Any]  # summary.json's config
    settings: list[dict[str, float]]  # G dicts {"learning_rate": ..., "discount": ...}
    scores: np.ndarray  # [G, S] one score per run
    curves: np.ndarray  # [G, S, I] each run's mean return per iteration
    score: str  # what the scores are, in words


class _Unit(NamedTuple):
    """One setting of one folder: what the comparison compares."""

    label: str  # the setting in words, after its folder where there are several
    folder: str  # as the user named it
    setting: dict[str, float]  # {"learning_rate": ..., "discount": ...}
    scores: np.ndarray  # [S]
    curves: np.ndarray  # [S, I]


class _Interval(TypedDict):
    """How every interval of a comparison is computed: the arguments of the `stats` functions."""

    confidence: float  # the coverage, in (0, 1)
    reps: int  # bootstrap resamples
    seed: int  # seeds every bootstrap


def setting_label(setting: dict[str, float]) -> str:
    """A grid setting in words, e.g. "lr=0.01, discount=0.95, length=1".

    Args:
      setting: a grid setting, as `sweeps.expand_grid` gives it.

    Returns:
      The learning rate and discount, the entropy coefficient where it is not 0, and the physics
      the grid names.
    """
    words = [f"lr={setting['learning_rate']:g}", f"discount={setting['discount']:g}"]
    words += [f"{name}={value:g}" for name, value in setting.items()
              if name not in ("learning_rate", "discount") and (
                  name != "entropy_coef" or value)]
    return ", ".join(words)


# --- Reading ------------------------------------------------------------------------------------


def load_sweep(folder: str | pathlib.Path) -> Sweep:
    """Reads a folder written by `jaxpg sweep --out`.

    Its files are read only where they are regular files, within `_MAX_SUMMARY_BYTES` (summary.json)
    and `_MAX_ARRAY_BYTES` (each array of metrics.npz, judged by its header before it is read).

    Args:
      folder: the folder.

    Returns:
      `Sweep` with `[G, S]` scores and `[G, S, I]` curves.

    Raises:
      ValueError: naming the folder or its file, for a missing or empty folder, one written by
        another version of jaxpg or by something else, or a file that is no regular file, is
        larger than its bound, damaged, or holds other than a sweep's: a grid of G settings of
        numbers (a learning rate and a discount each), finite mean returns `[G, S, I]` and,
        optionally, held-out returns `[G, S, N]`.
    """
    path = pathlib.Path(folder)
    if not path.is_dir():
        raise ValueError(f"{folder}: no such folder")
    if not any(path.iterdir()):
        raise ValueError(f"{folder}: empty; expected a folder written by jaxpg sweep --out")
    summary = _read_summary(path, folder)
    settings = _read_grid(summary.get("grid"), path / "summary.json")
    arrays = _read_metrics(path, folder)
    npz = path / "metrics.npz"
    curves, held_out = arrays["mean_return"], arrays.get("eval_returns")
    if curves.ndim != 3 or curves.shape[0] != len(settings) or not curves.size:
        raise ValueError(f"{npz}: mean_return of shape {list(curves.shape)}, expected [G, S, I] "
                         f"with G = {len(settings)} (summary.json's grid) and S, I > 0")
    if held_out is None:
        window = min(SOLVED_WINDOW, curves.shape[-1])
        scores = curves[..., -window:].mean(axis=-1)
        score = f"training return: each run's mean return over its last {window} iterations"
    elif held_out.ndim == 3 and held_out.shape[:2] == curves.shape[:2] and held_out.size:
        scores = held_out.mean(axis=-1)
        score = (f"held-out evaluation return: each run's mean return over its "
                 f"{held_out.shape[-1]} evaluation episodes")
    else:
        raise ValueError(f"{npz}: eval_returns of shape {list(held_out.shape)}, expected "
                         f"[G, S, N] with [G, S] = {list(curves.shape[:2])} and N > 0")
    return Sweep(str(folder), summary["config"], settings, scores, curves, score)


def _missing(folder: str | pathlib.Path, name: str) -> ValueError:
    """The error for a sweep folder without its file `name`."""
    return ValueError(f"{folder}: no {name}; expected a folder written by jaxpg sweep --out")


def _read_summary(path: pathlib.Path, folder: str | pathlib.Path) -> dict[str, Any]:
    """`path`'s summary.json (`safe_read.read_json`).

    A ValueError names `folder` or the file unless it holds this version's format marker and a
    config with a solved_return.
    """
    file = path / "summary.json"
    try:
        summary = safe_read.read_json(file, _MAX_SUMMARY_BYTES)
    except FileNotFoundError:
        raise _missing(folder, "summary.json") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("config"), dict):
        raise ValueError(f"{folder}: summary.json holds no sweep config; run the sweep again")
    if summary.get("format") != SWEEP_FORMAT:
        found = ("no format marker" if "format" not in summary
                 else f"format {_json_value(summary['format'])}")
        raise ValueError(f"{folder}: written by another version of jaxpg ({found}, this version "
                         f"reads {SWEEP_FORMAT!r}); run the sweep again")
    _number(summary["config"].get("solved_return"), f"{file}: config.solved_return")
    return summary


def _read_grid(grid: object, file: pathlib.Path) -> list[dict[str, float]]:
    """summary.json's grid as G settings `{name: value}`; a ValueError naming `file` and the
    entry unless each is an object of numbers with a learning_rate and a discount."""
    if not isinstance(grid, list) or not grid:
        raise ValueError(f"{file}: grid must be a non-empty array of settings, got "
                         f"{_json_value(grid)}")
    for g, setting in enumerate(grid):
        if not isinstance(setting, dict) or not {"learning_rate", "discount"} <= setting.keys():
            raise ValueError(f"{file}: grid[{g}] must be an object with a learning_rate and a "
                             f"discount")
    return [{name: _number(value, f"{file}: grid[{g}].{name}") for name, value in setting.items()}
            for g, setting in enumerate(grid)]


def _number(value: object, where: str) -> float:
    """A JSON value as a float; a ValueError naming `where` unless it is a finite number."""
    if (isinstance(value, bool) or not isinstance(value, int | float)
            or not abs(value) <= sys.float_info.max):  # (an int compares exactly; NaN false)
        raise ValueError(f"{where}: must be a finite number, got {_json_value(value)}")
    return float(value)


def _json_value(value: object) -> str:
    """A JSON value for a message: quoted, cut at 40 characters, where it is a string or a
    number; else its type in words (an array or object may be long or deeply nested)."""
    return _JSON_TYPES.get(type(value)) or f"{value!r:.40}"


def _read_metrics(path: pathlib.Path, folder: str | pathlib.Path) -> dict[str, np.ndarray]:
    """`path`'s metrics.npz: finite float64 mean_return and, where it holds them, eval_returns
    (`safe_read.read_arrays`); a ValueError naming `folder` or the file otherwise."""
    npz = path / "metrics.npz"
    try:
        arrays = safe_read.read_arrays(npz, ("mean_return", "eval_returns"), _MAX_ARRAY_BYTES)
    except FileNotFoundError:
        raise _missing(folder, "metrics.npz") from None
    if "mean_return" not in arrays:
        raise ValueError(f"{npz}: no mean_return; run the sweep again")
    return {name: check_finite(f"{npz}: {name}", values).astype(np.float64)
            for name, values in arrays.items()}


def _check_distinct(folders: Sequence[str | pathlib.Path]) -> None:
    """Raises a ValueError naming two of `folders` that are one folder (`X` and `X/`, links)."""
    seen: dict[str, str | pathlib.Path] = {}
    for folder in folders:
        real = os.path.realpath(folder)
        if real in seen:
            raise ValueError(f"folders: a folder is given more than once ({seen[real]} and "
                             f"{folder} are the same folder)")
        seen[real] = folder


def check_comparable(sweeps: Sequence[Sweep]) -> None:
    """Raises a ValueError naming what differs unless the sweeps may be compared setting by setting.

    Their configs must be equal but for the grid fields, their metrics of one length, and their
    scores of one kind.

    Args:
      sweeps: one or more sweeps, as `load_sweep` reads them.
    """
    first = sweeps[0]
    for other in sweeps[1:]:
        keys = sorted((set(first.config) | set(other.config)) - set(HYPERPARAMETERS))
        differ = [f"{key} ({first.config.get(key)} against {other.config.get(key)})"
                  for key in keys if first.config.get(key) != other.config.get(key)]
        if differ:
            raise ValueError(f"folders: {first.folder} and {other.folder} differ in "
                             f"{', '.join(differ)}; only learning rates, discounts and seeds may "
                             f"differ")
        if other.curves.shape[-1] != first.curves.shape[-1]:
            raise ValueError(f"folders: {first.folder} and {other.folder} hold metrics of "
                             f"different lengths ({first.curves.shape[-1]} against "
                             f"{other.curves.shape[-1]} iterations); compare sweeps of one length")
        if other.score != first.score:
            raise ValueError(f"folders: {first.folder} and {other.folder} score their runs "
                             f"differently ({first.score}; {other.score}); compare like with like")


# --- Comparing ----------------------------------------------------------------------------------


def compare(folders: Sequence[str | pathlib.Path], confidence: float = 0.95, reps: int = 2000,
            seed: int = 0) -> dict[str, Any]:
    """The comparison of every setting of the sweep folders with every other.

    Args:
      folders: folders written by `jaxpg sweep --out`, of one config.
      confidence: the coverage of every interval, in (0, 1).
      reps: bootstrap resamples per interval.
      seed: seeds every bootstrap, so the report is reproducible.

    Returns:
      A dict, as `comparison.json` holds it: "settings" (G entries: label, folder, grid values,
      runs, and each aggregate of `_AGGREGATES` as {"estimate", "low", "high"}),
      "probability_of_improvement" (`[G, G]` "probability", "low", "high": row over column),
      "seeds_needed" (None for one setting), "iqm_curves" (`[G, I']` at I' <= `_CURVE_POINTS`
      iterations), "performance_profiles" (`[G, P]`), and what was compared and how.

    Raises:
      ValueError: for no folder or a repeated one, a folder that `load_sweep` refuses, folders
        that may not be compared (`check_comparable`), a setting of fewer than 2 runs, or an
        interval argument that `stats` refuses.
    """
    if not folders:
        raise ValueError("folders: give at least one sweep folder")
    _check_distinct(folders)
    sweeps = [load_sweep(folder) for folder in folders]
    check_comparable(sweeps)
    units = _units(sweeps)
    scores = [unit.scores for unit in units]
    labels = [unit.label for unit in units]
    solved_return = float(sweeps[0].config["solved_return"])
    interval = _Interval(confidence=confidence, reps=reps, seed=seed)
    gap = functools.partial(stats.optimality_gap, target=solved_return)
    statistics: dict[str, Callable[..., stats.Aggregate]] = dict(
        zip(_AGGREGATES, (stats.iqm, stats.mean, stats.median, gap)))
    settings = [
        {"label": unit.label, "folder": unit.folder, **unit.setting, "runs": unit.scores.size,
         **{name: _estimate(f(unit.scores), stats.bootstrap_ci(unit.scores, f, **interval))
            for name, f in statistics.items()}}
        for unit in units
    ]
    taus = np.linspace(min(map(np.min, scores)), max(map(np.max, scores)), stats.PROFILE_POINTS)
    return {
        "format": COMPARISON_FORMAT,
        "folders": [sweep.folder for sweep in sweeps],
        "score": sweeps[0].score,
        "solved_return": solved_return,
        **interval,
        "settings": settings,
        "probability_of_improvement": stats.improvement_matrix(scores, **interval)._asdict(),
        "seeds_needed": _seeds_needed(scores, labels, interval),
        "iqm_curves": _curves([unit.curves for unit in units], interval),
        "performance_profiles": _bands(
            [stats.performance_profile(x, taus, **interval) for x in scores], "tau"),
    }


def _units(sweeps: Sequence[Sweep]) -> list[_Unit]:
    """Every setting of every sweep, labelled with its folder where there are several."""
    units = []
    for sweep in sweeps:
        for setting, scores, curves in zip(sweep.settings, sweep.scores, sweep.curves):
            label = setting_label(setting)
            if len(sweeps) > 1:
                label = f"{sweep.folder}: {label}"
            if scores.size < 2:
                raise ValueError(f"{sweep.folder}: {label} has {scores.size} run; a comparison "
                                 f"needs at least 2 seeds per setting")
            units.append(_Unit(label, sweep.folder, setting, scores, curves))
    return units


def _estimate(estimate: stats.Aggregate, interval: tuple[float, float]) -> dict[str, float]:
    """An aggregate over all scores (a float) and its interval, as `comparison.json` holds them."""
    return {"estimate": float(estimate), "low": interval[0], "high": interval[1]}


def _seeds_needed(scores: Sequence[np.ndarray], labels: Sequence[str],
                  interval: _Interval) -> dict[str, Any] | None:
    """`stats.seeds_needed` with the settings named by their labels; None for one setting."""
    if len(scores) < 2:
        return None
    estimate = stats.seeds_needed(scores, **interval)
    return {**estimate._asdict(), "best": labels[estimate.best], "second": labels[estimate.second]}


def _curves(curves: Sequence[np.ndarray], interval: _Interval) -> dict[str, np.ndarray]:
    """The IQM curves with bands of every setting's `[S, I]` curves, at up to `_CURVE_POINTS`
    iterations."""
    columns = np.unique(np.linspace(0, curves[0].shape[1] - 1, _CURVE_POINTS).round().astype(int))
    bands = [stats.iqm_curve(c[:, columns], columns + 1, **interval) for c in curves]
    return _bands(bands, "iteration")


def _bands(bands: Sequence[stats.Band], x_name: str) -> dict[str, np.ndarray]:
    """`stats.Band`s of every setting as one `{x_name: [P], "estimate": [G, P], ...}`."""
    return {x_name: bands[0].x, **{field: np.stack([getattr(b, field) for b in bands])
                                   for field in ("estimate", "low", "high")}}


# --- Writing ------------------------------------------------------------------------------------


def write(folders: Sequence[str | pathlib.Path], out: str | pathlib.Path, confidence: float = 0.95,
          reps: int = 2000, seed: int = 0, within: str | None = None) -> dict[str, Any]:
    """Compares the folders and writes `comparison.json` and the plots of `PLOT_FILES` into `out`.

    Args:
      folders: folders written by `jaxpg sweep --out`, of one config.
      out: the output folder (created if missing), replaced whole (`atomic_files.staged`).
      confidence: the coverage of every interval, in (0, 1).
      reps: bootstrap resamples per interval.
      seed: seeds every bootstrap.
      within: optional: the output folder that `out`, a staging folder of the caller's, is to
        replace. The report is then written into `out` beside its files, and names `within`
        wherever it would name `out` (as `jaxpg sweep` reports on its own folder).

    Returns:
      The comparison, as `compare` returns it.

    Raises:
      ValueError: as `compare`, and for an `out` that is not a folder that can be written.
    """
    if within is None:
        out = atomic_files.check_out_dir(out)
    try:
        comparison = compare(folders, confidence, reps, seed)
    except ValueError as error:
        if within is None:
            raise
        raise ValueError(str(error).replace(os.fspath(out), within)) from None
    if within is not None:
        comparison = _renamed(comparison, os.fspath(out), within)
    with (contextlib.nullcontext(pathlib.Path(out)) if within is not None
          else atomic_files.staged(out)) as stage:
        _write_comparison(comparison, stage)
    return comparison


def _renamed(comparison: dict[str, Any], folder: str, name: str) -> dict[str, Any]:
    """`comparison` with the folder `folder` called `name` (its folders and settings' folders)."""
    def rename(given: str) -> str:
        return name if given == folder else given

    return {**comparison, "folders": [rename(f) for f in comparison["folders"]],
            "settings": [{**s, "folder": rename(s["folder"])} for s in comparison["settings"]]}


def _write_comparison(comparison: dict[str, Any], folder: pathlib.Path) -> None:
    """Writes `comparison.json` and the plots of `PLOT_FILES` of `comparison` into `folder`."""
    labels = [setting["label"] for setting in comparison["settings"]]
    aggregates = {name: [np.array([s[key][part] for s in comparison["settings"]])
                         for part in ("estimate", "low", "high")]
                  for name, key in (("IQM", "iqm"), ("mean", "mean"))}
    curves, profiles = comparison["iqm_curves"], comparison["performance_profiles"]
    text = json.dumps(atomic_files.to_json(comparison), indent=2, allow_nan=False)
    (folder / COMPARISON_FILE).write_text(text + "\n")
    plots.aggregate_intervals(labels, aggregates, folder / PLOT_FILES[0], xlabel="return")
    plots.performance_profiles(profiles["tau"], profiles["estimate"], profiles["low"],
                               profiles["high"], labels, folder / PLOT_FILES[1], xlabel="return")
    plots.iqm_curves(curves["iteration"], curves["estimate"], curves["low"], curves["high"],
                     labels, folder / PLOT_FILES[2], solved_return=comparison["solved_return"])
    improvement = comparison["probability_of_improvement"]
    plots.improvement_heatmap(improvement["probability"], labels, folder / PLOT_FILES[3],
                              low=improvement["low"], high=improvement["high"])


def format_report(comparison: dict[str, Any]) -> str:
    """The comparison as text.

    The score used, a table of IQM and mean with intervals, the P(improvement) matrix and how many
    seeds would tell the two best settings apart.

    Args:
      comparison: as `compare` returns it.

    Returns:
      Lines joined by newlines, without a final one.
    """
    settings = comparison["settings"]
    ci = f"{comparison['confidence']:.0%} CI"
    width = max(len("setting"), *(len(s["label"]) for s in settings))
    lines = [f"score: {comparison['score']}",
             f"{'':4}{'setting':<{width}}  {'runs':>5}  {'IQM [' + ci + ']':<24}  mean [{ci}]"]
    for g, s in enumerate(settings, 1):
        lines.append(f"{g:>3} {s['label']:<{width}}  {s['runs']:>5}  "
                     f"{_with_interval(**s['iqm']):<24}  {_with_interval(**s['mean'])}")
    matrix = comparison["probability_of_improvement"]
    lines.append(f"P(row's setting scores above column's) [{ci}]:")
    cells = [[_with_interval(matrix["probability"][i][j], matrix["low"][i][j],
                             matrix["high"][i][j], ".2f")
              if i != j else "-" for j in range(len(settings))] for i in range(len(settings))]
    lines.append(f"{'':4}" + "  ".join(f"{j:<18}" for j in range(1, len(settings) + 1)).rstrip())
    lines += [f"{i:>3} " + "  ".join(f"{cell:<18}" for cell in row).rstrip()
              for i, row in enumerate(cells, 1)]
    lines.append(_seeds_guidance(comparison["seeds_needed"], ci))
    return "\n".join(lines)


def _with_interval(estimate: float, low: float, high: float, spec: str = ".1f") -> str:
    """An estimate and its interval as "estimate [low, high]", each formatted with `spec`."""
    return f"{estimate:{spec}} [{low:{spec}}, {high:{spec}}]"


def _seeds_guidance(needed: dict[str, Any] | None, ci: str) -> str:
    """The line on how many seeds would tell the two best settings apart (`_seeds_needed`)."""
    if needed is None:
        return "seeds: one setting, nothing to compare"
    pair = f"{needed['best']} against {needed['second']}"
    difference = _with_interval(needed["difference"], needed["low"], needed["high"])
    if needed["seeds"] is None:
        return (f"seeds: the two best settings, {pair}, have the same IQM; no number of seeds "
                f"tells them apart")
    verdict = "excludes" if needed["low"] > 0 else "includes"
    return (f"seeds: the two best settings by IQM, {pair}, differ by {difference} ({ci}), which "
            f"{verdict} 0; with about {needed['seeds']} seeds per setting it would exclude 0 (if "
            f"the interval narrows as 1/sqrt(seeds))")
