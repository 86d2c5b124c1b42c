"""A sweep's folder: its runs' files and the comparison of its settings, written in one step.

`save_sweep` writes what `jaxpg sweep --out DIR` writes: `metrics.npz` (every metric `[G, S, I]`,
the seeds, the grid's values and any held-out returns), `runs.csv` (a row per run),
`summary.json` (the config, the grid and statistics across seeds), `sweep.png`,
`policies.msgpack` (`checkpoint.save_sweep`) and, with two seeds or more, the comparison report
(`report.write`). The folder holds one result: it is replaced whole (`atomic_files.staged`).
"""

import os
import pathlib
from typing import Any

import numpy as np

from jaxpg import atomic_files, checkpoint, plots, report
from jaxpg.reinforce import first_nonfinite
from jaxpg.sweeps import SweepResult
from jaxpg.train_config import TrainConfig


def held_out(result: SweepResult) -> dict[str, np.ndarray]:
    """A sweep's held-out returns by name, `[G, S, N]`: none where it played none.

    Args:
      result: the sweep's result.

    Returns:
      {"eval_returns", "eval_greedy_returns"} where the sweep played held-out episodes, else {}.
    """
    if result.eval_returns is None or result.eval_greedy_returns is None:
        return {}  # (played together: both or neither)
    return {"eval_returns": result.eval_returns,
            "eval_greedy_returns": result.eval_greedy_returns}


class ReportRefused(ValueError):
    """A sweep's folder was written, but `report.compare` refused its scores (a diverged run's)."""


def save_sweep(result: SweepResult, out: str | os.PathLike[str],
               seconds: float | None = None) -> dict[str, Any] | None:
    """Writes a sweep's folder, as `jaxpg sweep --out` does, replacing `out` whole in one step.

    Args:
      result: what `jaxpg.sweep` returns, with its config.
      out: the output folder (created if missing; `atomic_files.check_out_dir`).
      seconds: optional: how long the sweep took, recorded in summary.json (null without it).

    Returns:
      The comparison of the settings (`report.compare`), or None for fewer than 2 seeds.

    Raises:
      ValueError: for a result without its config or an `out` that cannot hold results, before
        anything is written.
      ReportRefused: a ValueError, for a comparison that `report.compare` refuses (a diverged
        run's scores), after the folder is in place without the report.
    """
    if not isinstance(result, SweepResult):
        raise ValueError(f"result: expected what jaxpg.sweep returns, a SweepResult, got "
                         f"{type(result).__name__}")
    if result.config is None:
        raise ValueError("result: a SweepResult without its config; give what jaxpg.sweep returns")
    out = atomic_files.check_out_dir(out)
    comparison: dict[str, Any] | ValueError | None = None
    with atomic_files.staged(out) as stage:
        _write_runs(result, result.config, stage, seconds)
        # From the sweep's own files, into the same folder: one step puts both in place. A
        # failing report never costs the runs: it is raised after.
        if result.seeds.size >= 2:
            try:
                comparison = report.write([stage], stage, within=os.fspath(out))
            except ValueError as error:
                comparison = error
    if isinstance(comparison, ValueError):
        raise ReportRefused(str(comparison))
    return comparison


def _write_runs(result: SweepResult, config: TrainConfig, folder: pathlib.Path,
                seconds: float | None) -> None:
    """Writes the sweep's metrics.npz, runs.csv, summary.json, sweep.png and policies.msgpack
    into the existing `folder`."""
    s, grid = result.summary, result.grid
    num_settings, num_seeds = s.final_return.shape
    # (numpy's stubs let `**` arguments fill `allow_pickle`, a bool, which these never name.)
    np.savez_compressed(
        folder / "metrics.npz", seeds=result.seeds,
        **{name: [g[name] for g in grid] for name in grid[0]},  # type: ignore[arg-type]
        **result.metrics.columns(), **held_out(result))  # type: ignore[arg-type]
    atomic_files.write_csv(folder / "runs.csv", {
        **{name: np.repeat([g[name] for g in grid], num_seeds) for name in grid[0]},
        "seed": np.tile(result.seeds, num_settings),
        "last_10_mean_return": s.final_return.ravel(),
        "first_solved_iteration": s.first_solved.ravel(),
        "first_nonfinite_iteration": first_nonfinite(result.metrics).ravel(),
        **{f"{name}_mean": returns.mean(axis=-1).ravel()
           for name, returns in held_out(result).items()},
    })
    atomic_files.write_json(folder / "summary.json", {
        "format": report.SWEEP_FORMAT,
        "config": checkpoint.config_to_dict(config), "seeds": num_seeds, "seconds": seconds,
        "grid": grid, "fraction_solved": s.fraction_solved,
        "median_last_10_mean_return": np.median(s.final_return, axis=1),
        "median": s.median, "q25": s.q25, "q75": s.q75, "solved_by": s.solved_by,
    })
    plots.sweep_curves(s.median, s.q25, s.q75, s.solved_by, list(map(report.setting_label, grid)),
                       config.solved_return, folder / "sweep.png")
    checkpoint.save_sweep(folder / checkpoint.SWEEP_FILENAME, result, config)
