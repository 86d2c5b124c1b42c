"""A comparison report of sweeps: how each setting scores, and how sure the ranking is.

It compares `SweepResult`s and folders as `jaxpg sweep --out DIR` writes them (`summary.json`,
`metrics.npz`). Every setting of every sweep is a unit of the comparison, named by the config
fields and grid values in which the units differ (a loss, a policy, an optimizer, physics,
hyperparameters); sweeps are never merged. They must share the iteration count, the solved return
and the kind of score: each run's score is its held-out evaluation return where every sweep has
them (`eval_returns`, `[G, S, N]`, averaged over the N episodes), otherwise its training mean
return over the last `SOLVED_WINDOW` iterations; the report says which.
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

from jaxpg import atomic_files, checkpoint, plots, safe_read, stats
from jaxpg.envs import cartpole
from jaxpg.sweeps import SOLVED_WINDOW, SweepResult
from jaxpg.validation import check_finite, check_int, check_number, check_representable

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
# What `compare` takes: a sweep folder or a `SweepResult`.
Source = str | os.PathLike[str] | SweepResult
# Iterations a curve's band is computed at, evenly spaced with the first and last: the bootstrap's
# cost grows with them, and a plot needs no more.
_CURVE_POINTS = 50


class Sweep(NamedTuple):
    """The runs of one sweep, as the report needs them."""

    folder: str  # as the user named it; "sweeps[i]" for the i-th source, a `SweepResult`
    config: dict[str, Any]  # summary.json's config (`checkpoint.config_to_dict`)
    settings: list[dict[str, float]]  # G dicts {"learning_rate": ..., "discount": ...}
    scores: np.ndarray  # [G, S] one score per run
    curves: np.ndarray  # [G, S, I] each run's mean return per iteration
    score: str  # what the scores are, in words


class _Unit(NamedTuple):
    """One setting of one folder: what the comparison compares."""

    label: str  # what sets it apart from the others, in words (`_labels`)
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


def load_sweep(folder: str | os.PathLike[str]) -> Sweep:
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
        numbers (a learning rate and a discount each), mean returns `[G, S, I]` and, optionally,
        held-out returns `[G, S, N]`, each finite and within float32's range.
    """
    path = pathlib.Path(folder)
    if not path.is_dir():
        raise ValueError(f"{folder}: no such folder")
    if not any(path.iterdir()):
        raise ValueError(f"{folder}: empty; expected a folder written by jaxpg sweep --out")
    summary = _read_summary(path, folder)
    settings = _read_grid(summary.get("grid"), path / "summary.json")
    arrays = _read_metrics(path, folder)
    return _scored(os.fspath(folder), summary["config"], settings, arrays["mean_return"],
                   arrays.get("eval_returns"), f"{path / 'metrics.npz'}: ")


def from_result(result: SweepResult, name: str) -> Sweep:
    """A `SweepResult`'s runs, as the report needs them.

    Args:
      result: the result of `jaxpg.sweep`, which carries its config.
      name: what messages and the report call it, such as "sweeps[0]".

    Returns:
      `Sweep` with `[G, S]` scores and `[G, S, I]` curves.

    Raises:
      ValueError: naming `name`, for a result without its config, or with mean returns or
        held-out returns that are empty, misshapen, not finite or beyond float32's range.
    """
    if result.config is None:
        raise ValueError(f"{name}: a SweepResult without its config; give what jaxpg.sweep "
                         f"returns")
    curves = _returns(f"{name}: mean_return", result.metrics.mean_return)
    held_out = (None if result.eval_returns is None
                else _returns(f"{name}: eval_returns", result.eval_returns))
    settings = [{key: float(value) for key, value in setting.items()} for setting in result.grid]
    return _scored(name, checkpoint.config_to_dict(result.config), settings, curves, held_out,
                   f"{name}: ")


def _scored(folder: str, config: dict[str, Any], settings: list[dict[str, float]],
            curves: np.ndarray, held_out: np.ndarray | None, where: str) -> Sweep:
    """The `Sweep` of finite `[G, S, I]` mean returns and optional `[G, S, N]` held-out returns,
    scored; a ValueError starting with `where` names the array unless it is so shaped, G being
    the number of `settings`, and not empty."""
    if curves.ndim != 3 or curves.shape[0] != len(settings) or not curves.size:
        raise ValueError(f"{where}mean_return of shape {list(curves.shape)}, expected [G, S, I] "
                         f"with G = {len(settings)} (the grid's settings) and S, I > 0")
    if held_out is None:
        window = min(SOLVED_WINDOW, curves.shape[-1])
        scores = curves[..., -window:].mean(axis=-1)
        score = f"training return: each run's mean return over its last {window} iterations"
    elif held_out.ndim == 3 and held_out.shape[:2] == curves.shape[:2] and held_out.size:
        scores = held_out.mean(axis=-1)
        score = (f"held-out evaluation return: each run's mean return over its "
                 f"{held_out.shape[-1]} evaluation episodes")
    else:
        raise ValueError(f"{where}eval_returns of shape {list(held_out.shape)}, expected "
                         f"[G, S, N] with [G, S] = {list(curves.shape[:2])} and N > 0")
    return Sweep(folder, config, settings, scores, curves, score)


def _missing(folder: str | os.PathLike[str], name: str) -> ValueError:
    """The error for a sweep folder without its file `name`."""
    return ValueError(f"{folder}: no {name}; expected a folder written by jaxpg sweep --out")


def _read_summary(path: pathlib.Path, folder: str | os.PathLike[str]) -> dict[str, Any]:
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
    try:
        checkpoint.check_config_dict(summary["config"])
    except ValueError as error:
        raise ValueError(f"{file}: damaged config ({error})") from None
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


def _read_metrics(path: pathlib.Path, folder: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """`path`'s metrics.npz: float64 mean_return and, where it holds them, eval_returns
    (`safe_read.read_arrays`), checked (`_returns`); a ValueError naming `folder` or the file
    otherwise."""
    npz = path / "metrics.npz"
    try:
        arrays = safe_read.read_arrays(npz, ("mean_return", "eval_returns"), _MAX_ARRAY_BYTES)
    except FileNotFoundError:
        raise _missing(folder, "metrics.npz") from None
    if "mean_return" not in arrays:
        raise ValueError(f"{npz}: no mean_return; run the sweep again")
    return {name: _returns(f"{npz}: {name}", values) for name, values in arrays.items()}


def _returns(name: str, values: object) -> np.ndarray:
    """Returns as float64; a ValueError naming `name` unless each is finite and within float32's
    range, as training computes them: sums and differences of many such cannot overflow."""
    checked = check_finite(name, values)
    check_representable(name, checked, np.float32)
    return checked.astype(np.float64)


def _load(sweeps: Sequence[Source]) -> list[Sweep]:
    """Every source's `Sweep` (`load_sweep`, `from_result`), once each.

    Raises:
      ValueError: for no source, one given twice (a folder as `X` and `X/`, or through a link;
        one `SweepResult`), or one that is neither a folder's path (an empty one is not) nor a
        `SweepResult`.
    """
    if isinstance(sweeps, str | os.PathLike | SweepResult):  # one, not a list of them
        raise ValueError(f"sweeps: expected a list of sweep folders or SweepResults, got one "
                         f"{type(sweeps).__name__}; give [{type(sweeps).__name__}]")
    if not sweeps:
        raise ValueError("sweeps: give at least one sweep folder or SweepResult")
    seen: dict[int | str, str] = {}
    loaded = []
    for i, source in enumerate(sweeps):
        key: int | str
        if isinstance(source, SweepResult):
            name, key = f"sweeps[{i}]", id(source)
        elif isinstance(source, str | os.PathLike):
            name, key = os.fspath(source), os.path.realpath(source)
            if not name:  # (not the working directory)
                raise ValueError(f"sweeps[{i}]: must be a sweep folder or a SweepResult, got an "
                                 f"empty path")
        else:
            raise ValueError(f"sweeps[{i}]: must be a sweep folder or a SweepResult, got "
                             f"{type(source).__name__}")
        if key in seen:
            raise ValueError(f"sweeps: a sweep is given more than once ({seen[key]} and {name} "
                             f"are the same {'result' if isinstance(key, int) else 'folder'})")
        seen[key] = name
        loaded.append(from_result(source, name) if isinstance(source, SweepResult)
                      else load_sweep(source))
    return loaded


def check_comparable(sweeps: Sequence[Sweep]) -> None:
    """Raises a ValueError naming what differs unless the sweeps' settings may be compared.

    Their configs may differ in anything but the solved return (the target every setting is
    measured against); their metrics must be of one length, and their scores of one kind.

    Args:
      sweeps: one or more sweeps, as `load_sweep` or `from_result` read them.
    """
    first = sweeps[0]
    for other in sweeps[1:]:
        pair = f"sweeps: {first.folder} and {other.folder}"
        if other.config["solved_return"] != first.config["solved_return"]:
            raise ValueError(f"{pair} differ in solved_return ({first.config['solved_return']} "
                             f"against {other.config['solved_return']}); compare sweeps of one "
                             f"target")
        if other.curves.shape[-1] != first.curves.shape[-1]:
            raise ValueError(f"{pair} hold metrics of different lengths "
                             f"({first.curves.shape[-1]} against {other.curves.shape[-1]} "
                             f"iterations); compare sweeps of one length")
        if other.score != first.score:
            raise ValueError(f"{pair} score their runs differently ({first.score}; "
                             f"{other.score}); compare like with like")


# --- Comparing ----------------------------------------------------------------------------------


# Bootstrap resamples per interval, at most: a comparison's time grows in proportion to them (its
# memory does not: `stats` draws them in chunks of `stats._CHUNK_SCORES` scores).
MAX_REPS = 100_000
# The least resamples: a 95 % interval's ends are their 2.5 % and 97.5 % quantiles, which fewer
# than 50 leave without one resample in a tail.
MIN_REPS = 50


def compare(sweeps: Sequence[Source], confidence: float = 0.95, reps: int = 2000,
            seed: int = 0) -> dict[str, Any]:
    """The comparison of every setting of the sweeps with every other.

    Args:
      sweeps: `SweepResult`s and folders written by `jaxpg sweep --out` (or `save_sweep`), in
        any mix; their configs may differ (`check_comparable`).
      confidence: the coverage of every interval, in (0, 1).
      reps: bootstrap resamples per interval, in [`MIN_REPS`, `MAX_REPS`].
      seed: seeds every bootstrap, so the report is reproducible.

    Returns:
      A dict, as `comparison.json` holds it: "settings" (G entries: label, folder, grid values,
      runs, and each aggregate of `_AGGREGATES` as {"estimate", "low", "high"}),
      "probability_of_improvement" (`[G, G]` "probability", "low", "high": row over column),
      "seeds_needed" (None for one setting), "iqm_curves" (`[G, I']` at I' <= `_CURVE_POINTS`
      iterations), "performance_profiles" (`[G, P]`), and what was compared and how. A
      `SweepResult` is called "sweeps[i]" where a folder is called by its path.

    Raises:
      ValueError: for no sweep or a repeated one, a folder that `load_sweep` refuses or a result
        that `from_result` refuses, sweeps that may not be compared (`check_comparable`), a
        setting of fewer than 2 runs, a `reps` out of range, or an interval argument that `stats`
        refuses.
    """
    reps = check_int("reps", reps, MIN_REPS, MAX_REPS + 1)  # before any folder is read
    confidence = check_number("confidence", confidence)  # its range: `stats`
    loaded = _load(sweeps)
    check_comparable(loaded)
    units = _units(loaded)
    scores = [unit.scores for unit in units]
    labels = [unit.label for unit in units]
    solved_return = float(loaded[0].config["solved_return"])
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
        "folders": [sweep.folder for sweep in loaded],
        "score": loaded[0].score,
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
    """Every setting of every sweep, labelled by what sets it apart (`_labels`), after its sweep
    where only the sweeps tell settings apart."""
    runs = [(sweep, g) for sweep in sweeps for g in range(len(sweep.settings))]
    labels = _labels([_values(sweep.config, sweep.settings[g]) for sweep, g in runs],
                     [sweep.settings[g] for sweep, g in runs])
    if len(set(labels)) < len(labels):
        labels = [f"{sweep.folder}: {label}" for (sweep, _), label in zip(runs, labels)]
    units = []
    for (sweep, g), label in zip(runs, labels):
        if sweep.scores[g].size < 2:
            raise ValueError(f"{sweep.folder}: {label} has {sweep.scores[g].size} run; a "
                             f"comparison needs at least 2 seeds per setting")
        units.append(_Unit(label, sweep.folder, sweep.settings[g], sweep.scores[g],
                           sweep.curves[g]))
    return units


def _values(config: dict[str, Any], setting: dict[str, float]) -> dict[str, Any]:
    """What one setting of a sweep trains with: its config's fields, the environment's physics
    as fields of their own, and the grid's values in place of the config's."""
    env = config.get("env")
    if isinstance(env, str) and env in cartpole.PRESETS:
        preset = cartpole.PRESETS[env]
        env = {name: getattr(preset, name) for name in cartpole.CartPoleParams.__dataclass_fields__}
    physics = env if isinstance(env, dict) else {"env": env}
    rest = {name: value for name, value in config.items() if name != "env"}
    return {**setting, **physics, **rest, **setting}  # (the grid's fields first)


def _labels(values: Sequence[dict[str, Any]], settings: Sequence[dict[str, float]]) -> list[str]:
    """Each setting named by the fields whose values differ among `values` (one dict per
    setting, `_values`); where none differ, by its grid values (`setting_label` of `settings`)."""
    names = list(dict.fromkeys(name for value in values for name in value))
    differ = [name for name in names if any(v.get(name) != values[0].get(name) for v in values)]
    if not differ:
        return [setting_label(setting) for setting in settings]
    return [", ".join(f"{_SHORT.get(name, name)}={_text(v.get(name))}" for name in differ)
            for v in values]


_SHORT = {"learning_rate": "lr"}  # names that labels shorten


def _text(value: Any) -> str:
    """A config value in a label: a number as "%g", a user's object by its class or function's
    name, a list or dict by its items, anything else as `str` gives it."""
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, dict) and "object" in value:
        return str(value["object"]).rpartition(".")[2]
    if isinstance(value, list):
        return "(" + ", ".join(map(_text, value)) + ")"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_text(v)}" for k, v in value.items()) + "}"
    return str(value)


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


def write(sweeps: Sequence[Source], out: str | os.PathLike[str], confidence: float = 0.95,
          reps: int = 2000, seed: int = 0, within: str | None = None) -> dict[str, Any]:
    """Compares the sweeps and writes `comparison.json` and the plots of `PLOT_FILES` into `out`.

    Args:
      sweeps: `SweepResult`s and folders written by `jaxpg sweep --out`, as `compare` takes them.
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
      ValueError: as `compare`, and for an `out` that is not a folder that can be written or
        that is (or holds) a folder compared.
    """
    if within is None:
        out = atomic_files.check_out_dir(out)
        _check_not_compared(out, sweeps)
    try:
        comparison = compare(sweeps, confidence, reps, seed)
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


def _check_not_compared(out: str | os.PathLike[str], sweeps: Sequence[Source]) -> None:
    """Raises a ValueError naming `out` where it is, or holds, a folder being compared: writing
    `out` replaces it whole."""
    for source in sweeps:
        if isinstance(source, str | os.PathLike):
            atomic_files.check_not_replacing(out, source, "a folder compared", "the report")


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
