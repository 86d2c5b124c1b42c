"""Learning curves, sweep summaries, throughput charts and comparisons, written as image files.

matplotlib is imported inside each function, so that importing jaxpg stays light. Figures are
drawn with `matplotlib.figure.Figure` and its Agg canvas, never through pyplot: no global state and
no display is touched. Each file is replaced atomically; its format follows the suffix (PNG for
`.png`).
"""

import pathlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from jaxpg import atomic_files
from jaxpg.atomic_files import StrPath
from jaxpg.types import HostArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from jaxpg.iteration import Metrics

FIGSIZE = (8.0, 4.5)  # inches
DPI = 100  # so an 800 x 450 pixel image, or 800 x 700 for two panels
_TWO_PANEL_FIGSIZE = (8.0, 7.0)


def _figure(figsize: tuple[float, float]) -> "Figure":
    """A figure of `figsize` inches at `DPI`, laid out by matplotlib's constrained layout."""
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=DPI, layout="constrained")


def _save(fig: "Figure", path: StrPath) -> pathlib.Path:
    """Writes `fig` to `path` atomically and returns the path."""
    with atomic_files.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI)
    return pathlib.Path(path)


def learning_curve(metrics: "Metrics", path: StrPath, title: str | None = None) -> pathlib.Path:
    """Plots one run's mean return per iteration, with the band from its min to max return.

    Args:
      metrics: `iteration.Metrics` of one run, `[I]` leaves.
      path: the image file to write.
      title: optional figure title.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: unless the metrics are one run's, `[I]`.
    """
    mean = np.asarray(metrics.mean_return)
    low, high = np.asarray(metrics.min_return), np.asarray(metrics.max_return)
    if mean.ndim != 1 or low.shape != mean.shape or high.shape != mean.shape:
        raise ValueError(
            f"metrics: expected one run's Metrics with [I] leaves, got mean_return of shape "
            f"{mean.shape} (for several runs, pass one run's slice or use sweep_curves)"
        )
    iterations = np.arange(1, mean.size + 1)
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    ax.fill_between(iterations, low, high, alpha=0.25, label="min to max return")
    ax.plot(iterations, mean, label="mean return")
    ax.set_xlabel("iteration")
    ax.set_ylabel("return per episode")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left")
    if title:
        ax.set_title(title)
    return _save(fig, path)


def sweep_curves(median: npt.ArrayLike, q25: npt.ArrayLike, q75: npt.ArrayLike,
                 solved_fraction: npt.ArrayLike, labels: Iterable[str], solved_return: float,
                 path: StrPath) -> pathlib.Path:
    """Plots a sweep: median return with its interquartile band, and the fraction of seeds solved.

    Args:
      median: `[G, I]` median over seeds of the mean return, per grid point and iteration.
      q25: `[G, I]` 25th percentile.
      q75: `[G, I]` 75th percentile.
      solved_fraction: `[G, I]` fraction of seeds that have reached `solved_return` by then.
      labels: G names of the grid points, e.g. "lr=0.01, discount=0.95".
      solved_return: the return that counts as solved, drawn as a dashed line.
      path: the image file to write.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for arrays of other shapes, or not G labels.
    """
    median, q25, q75, solved_fraction = (
        np.asarray(a, dtype=float) for a in (median, q25, q75, solved_fraction)
    )
    if median.ndim != 2:
        raise ValueError(f"median: expected shape [G, I], got {median.shape}")
    for name, array in (("q25", q25), ("q75", q75), ("solved_fraction", solved_fraction)):
        if array.shape != median.shape:
            raise ValueError(
                f"{name}: expected shape {median.shape} (as median), got {array.shape}"
            )
    labels = list(labels)
    if len(labels) != median.shape[0]:
        raise ValueError(f"labels: expected {median.shape[0]} labels, got {len(labels)}")
    iterations = np.arange(1, median.shape[1] + 1)
    fig = _figure(_TWO_PANEL_FIGSIZE)
    returns_ax, solved_ax = fig.subplots(2, 1, sharex=True)
    for g, label in enumerate(labels):
        (line,) = returns_ax.plot(iterations, median[g], label=label)
        returns_ax.fill_between(iterations, q25[g], q75[g], color=line.get_color(), alpha=0.2)
        solved_ax.plot(iterations, solved_fraction[g], color=line.get_color())
    returns_ax.axhline(solved_return, color="black", linestyle="--", linewidth=1,
                       label=f"solved ({solved_return:g})")
    returns_ax.set_ylabel("median return (IQR band)")
    returns_ax.grid(alpha=0.3)
    returns_ax.legend(loc="upper left", fontsize="small")
    solved_ax.set_ylim(-0.02, 1.02)
    solved_ax.set_xlabel("iteration")
    solved_ax.set_ylabel("fraction of seeds solved")
    solved_ax.grid(alpha=0.3)
    return _save(fig, path)


def throughput_chart(rows: Iterable[Mapping[str, Any]], path: StrPath, title: str,
                     xlabel: str = "N (environments or seeds)") -> pathlib.Path:
    """Plots throughput against N on log-log axes, one line per implementation.

    Args:
      rows: dicts {"impl": str, "n": int, "steps_per_s": float}, in any order.
      path: the image file to write.
      title: figure title.
      xlabel: what N counts.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for no row, or a row without those keys or with values that are not positive.
    """
    by_impl: dict[str, list[tuple[float, float]]] = {}
    for i, row in enumerate(rows):
        try:
            impl, n, rate = str(row["impl"]), float(row["n"]), float(row["steps_per_s"])
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(
                f"rows[{i}]: expected {{'impl': str, 'n': int, 'steps_per_s': float}}, got {row!r}"
            ) from e
        if not (n > 0 and rate > 0):
            raise ValueError(
                f"rows[{i}]: n and steps_per_s must be positive for a log scale, got {row!r}"
            )
        by_impl.setdefault(impl, []).append((n, rate))
    if not by_impl:
        raise ValueError("rows: nothing to plot")
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    for impl, points in by_impl.items():
        n, rate = np.array(sorted(points)).T
        ax.plot(n, rate, marker="o", label=impl)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("steps per second")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    return _save(fig, path)


# --- Comparing settings (`jaxpg.stats`) --------------------------------------------------------


def _check_alike(labels: Sequence[str], dims: str, **arrays: npt.ArrayLike) -> list[HostArray]:
    """The arrays as floats, all of the first one's shape, with one label per row of it.

    Args:
      labels: the settings' names, one per row.
      dims: the names of the dimensions expected, e.g. "GI" for `[G, I]`.
      **arrays: the arrays by the names of their arguments, the first one setting the shape.

    Returns:
      The arrays as float numpy arrays, in order.

    Raises:
      ValueError: naming the first array of another shape (or the first one, when it has not
        `len(dims)` axes or is empty), or `labels` when there is not one per row.
    """
    (first_name, first), *others = arrays.items()
    first = np.asarray(first, dtype=float)
    if first.ndim != len(dims) or first.size == 0:
        raise ValueError(f"{first_name}: expected shape [{', '.join(dims)}], got {first.shape}")
    checked = [first]
    for name, array in others:
        array = np.asarray(array, dtype=float)
        if array.shape != first.shape:
            raise ValueError(f"{name}: expected shape {first.shape} (as {first_name}), "
                             f"got {array.shape}")
        checked.append(array)
    if len(labels) != first.shape[0]:
        raise ValueError(f"labels: expected {first.shape[0]} labels, got {len(labels)}")
    return checked


def _banded_lines(ax: "Axes", x: HostArray, estimate: HostArray, low: HostArray, high: HostArray,
                  labels: Sequence[str]) -> None:
    """One line per setting `[G, X]` against `x` `[X]`, in a band from `low` to `high`."""
    for g, label in enumerate(labels):
        (line,) = ax.plot(x, estimate[g], label=label)
        ax.fill_between(x, low[g], high[g], color=line.get_color(), alpha=0.2)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize="small")


def aggregate_intervals(labels: Iterable[str],
                        estimates: Mapping[str, Sequence[npt.ArrayLike]],
                        path: StrPath, xlabel: str = "score") -> pathlib.Path:
    """Plots each setting's aggregates as a point within its confidence interval, a panel for each.

    Args:
      labels: G names of the settings.
      estimates: `{name: (estimate [G], low [G], high [G])}`, e.g. `{"IQM": ..., "mean": ...}`.
      path: the image file to write.
      xlabel: what the scores are.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for no estimate, arrays of other shapes, or labels that do not match them.
    """
    labels = list(labels)
    if not estimates:
        raise ValueError("estimates: nothing to plot")
    checked = {name: _check_alike(labels, "G",
                                  **{f"estimates[{name!r}][{k}]": a for k, a in enumerate(triple)})
               for name, triple in estimates.items()}
    fig = _figure(FIGSIZE)
    axes = np.atleast_1d(fig.subplots(1, len(checked), sharey=True))
    rows = np.arange(len(labels))
    for ax, (name, (estimate, low, high)) in zip(axes, checked.items()):
        ax.hlines(rows, low, high, linewidth=8, alpha=0.4, color=[f"C{g}" for g in rows])
        ax.vlines(estimate, rows - 0.3, rows + 0.3, color="black", linewidth=2)
        ax.set_title(name)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3, axis="x")
    axes[0].set_yticks(rows, labels, fontsize="small")
    axes[0].invert_yaxis()  # the first setting on top
    return _save(fig, path)


def performance_profiles(taus: npt.ArrayLike, fraction: npt.ArrayLike, low: npt.ArrayLike,
                         high: npt.ArrayLike, labels: Sequence[str], path: StrPath,
                         xlabel: str = "score") -> pathlib.Path:
    """Plots the fraction of runs scoring above tau against tau, with a band, for each setting.

    Args:
      taus: `[P]` thresholds.
      fraction: `[G, P]` fraction of a setting's runs scoring above each threshold.
      low: `[G, P]` lower confidence bound.
      high: `[G, P]` upper confidence bound.
      labels: G names of the settings.
      path: the image file to write.
      xlabel: what the scores are.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for arrays of other shapes, or labels that do not match them.
    """
    fraction, low, high = _check_alike(list(labels), "GP", fraction=fraction, low=low, high=high)
    taus = np.asarray(taus, dtype=float)
    if taus.shape != fraction.shape[1:]:
        raise ValueError(f"taus: expected shape {fraction.shape[1:]} (fraction's columns), "
                         f"got {taus.shape}")
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    _banded_lines(ax, taus, fraction, low, high, labels)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel(f"{xlabel} (tau)")
    ax.set_ylabel("fraction of runs with score > tau")
    return _save(fig, path)


def iqm_curves(iterations: npt.ArrayLike, iqm: npt.ArrayLike, low: npt.ArrayLike,
               high: npt.ArrayLike, labels: Sequence[str], path: StrPath,
               solved_return: float | None = None) -> pathlib.Path:
    """Plots the IQM over runs per iteration, with its confidence band, for each setting.

    Args:
      iterations: `[I]` the iterations the IQMs are of.
      iqm: `[G, I]` IQM over a setting's runs of each iteration's mean return.
      low: `[G, I]` lower confidence bound.
      high: `[G, I]` upper confidence bound.
      labels: G names of the settings.
      path: the image file to write.
      solved_return: optional return that counts as solved, drawn as a dashed line.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for arrays of other shapes, or labels that do not match them.
    """
    iqm, low, high = _check_alike(list(labels), "GI", iqm=iqm, low=low, high=high)
    iterations = np.asarray(iterations)
    if iterations.shape != iqm.shape[1:]:
        raise ValueError(f"iterations: expected shape {iqm.shape[1:]} (iqm's columns), "
                         f"got {iterations.shape}")
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    if solved_return is not None:
        ax.axhline(solved_return, color="black", linestyle="--", linewidth=1,
                   label=f"solved ({solved_return:g})")
    _banded_lines(ax, iterations, iqm, low, high, labels)
    # (The default locator is a MaxNLocator, whose `set_params` takes `integer`.)
    ax.xaxis.get_major_locator().set_params(integer=True)  # type: ignore[call-arg]
    ax.set_xlabel("iteration")
    ax.set_ylabel("IQM of the mean return (CI band)")
    return _save(fig, path)


def improvement_heatmap(probability: npt.ArrayLike, labels: Sequence[str], path: StrPath
                        ) -> pathlib.Path:
    """Plots P(row's setting scores above column's) for every pair of settings, values written in.

    Args:
      probability: `[G, G]` probabilities of improvement, e.g. `stats.improvement_matrix(...)[0]`.
      labels: G names of the settings.
      path: the image file to write.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for arrays of other shapes, or labels that do not match them.
    """
    (probability,) = _check_alike(list(labels), "GG", probability=probability)
    if probability.shape[1] != len(labels):
        raise ValueError(f"probability: expected shape [G, G], got {probability.shape}")
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    # Dark text on the light middle of the colour map, white on its dark ends.
    _written_heatmap(fig, ax, probability, labels, labels, "P(row > column)", "{:.2f}",
                     lambda value: 0.2 < value < 0.8, cmap="RdBu", vmin=0, vmax=1)
    ax.set_title("probability of improvement")
    return _save(fig, path)


def return_heatmap(values: npt.ArrayLike, row_labels: Sequence[str], column_labels: Sequence[str],
                   path: StrPath, max_return: float, xlabel: str | None = None,
                   title: str | None = None) -> pathlib.Path:
    """Plots a return per cell of a table of settings, e.g. the median per physics setting.

    Args:
      values: `[R, C]` returns, e.g. `Robustness.median` over every policy's episodes, one cell
        per setting (a grid's last field across, the others down).
      row_labels: R names of the rows, e.g. "length=0.5".
      column_labels: C names of the columns, e.g. "0.1".
      path: the image file to write.
      max_return: the top of the colour scale (its bottom is 0), e.g. the episodes' step limit.
      xlabel: what the columns vary, e.g. "masspole".
      title: optional figure title.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for arrays of other shapes, labels that do not match them, or a `max_return`
        not positive.
    """
    (values,) = _check_alike(list(row_labels), "RC", values=values)
    if values.shape[1] != len(column_labels):
        raise ValueError(f"column_labels: expected {values.shape[1]} labels, got "
                         f"{len(column_labels)}")
    if not max_return > 0:
        raise ValueError(f"max_return: must be positive, got {max_return}")
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    # Dark text on the light upper part of the colour map, white on its dark lower part.
    _written_heatmap(fig, ax, values, row_labels, column_labels, "return", "{:g}",
                     lambda value: value > 0.6 * max_return, cmap="viridis", vmin=0,
                     vmax=max_return)
    if xlabel:
        ax.set_xlabel(xlabel)
    if title:
        ax.set_title(title)
    return _save(fig, path)


def _written_heatmap(fig: "Figure", ax: "Axes", values: HostArray, row_labels: Sequence[str],
                     column_labels: Sequence[str], colorbar_label: str, template: str,
                     light: Callable[[float], bool], **colours: Any) -> None:
    """Draws `values` `[R, C]` as an image with a colour bar and labelled rows and columns, each
    value written in its cell (`template`), in black where `light(value)`, else in white."""
    image = ax.imshow(values, **colours)
    fig.colorbar(image, ax=ax, label=colorbar_label)
    for (i, j), value in np.ndenumerate(values):
        ax.text(j, i, template.format(value), ha="center", va="center", fontsize="small",
                color="black" if light(value) else "white")
    ax.set_xticks(np.arange(len(column_labels)), column_labels, rotation=30, ha="right",
                  fontsize="small")
    ax.set_yticks(np.arange(len(row_labels)), row_labels, fontsize="small")
