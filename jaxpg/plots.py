"""Learning curves, sweep summaries, throughput charts and comparisons, written as image files.

matplotlib is imported inside each function, so that importing jaxpg stays light. Figures are
drawn with `matplotlib.figure.Figure` and its Agg canvas, never through pyplot: no global state and
no display is touched. Each file is replaced atomically; its format follows the suffix (PNG for
`.png`).
"""

import pathlib
import textwrap
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import numpy.typing as npt

from jaxpg import atomic_files
from jaxpg.atomic_files import StrPath
from jaxpg.types import HostArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.figure import Figure
    from matplotlib.legend import Legend
    from matplotlib.text import Text

    from jaxpg.iteration import Metrics

FIGSIZE = (8.0, 4.5)  # inches
DPI = 100  # so an 800 x 450 pixel image, or 800 x 700 for two panels (a heatmap, or a panel per
# setting, is as large as what it shows)
_TWO_PANEL_FIGSIZE = (8.0, 7.0)

_BAND_ALPHA = 0.15  # light enough that the bands of several settings show through one another
_ONE_PANEL_SETTINGS = 4  # up to this many settings share a panel of bands; more get a panel each
_PANEL_HEIGHT = 1.9  # inches, each row of such panels
_PANELS_TOP = 0.9  # inches, for the legend and the shared axis label

_CELL_FONT = 10.0  # points, of the text in a heatmap's cells, unless the grid outgrows _MAX_GRID
_MIN_CELL_FONT = 6.0  # points
_CELL_PADDING = np.array([0.3, 0.18])  # inches, width and height, around a cell's text
_MIN_CELL = np.array([0.6, 0.4])  # inches
_MIN_GRID = np.array([1.6, 1.4])  # inches, so that one row or column still has room for the colour
_MAX_GRID = np.array([16.0, 12.0])  # inches
_COLORBAR_WIDTH = 0.15  # inches
_HEADING_MARGIN = 0.1  # inches, either side of a heatmap's title
_LABEL_GAP = 0.1  # inches, at least between two column labels side by side
_FIT_STEPS = 3  # resizings of a figure until the layout gives the grid its size (within 0.01")
_SIGNIFICANT = 3  # digits written of a return heatmap's largest value
_PROBABILITY_DECIMALS = 2


def load_in_background() -> None:
    """Starts importing matplotlib on a thread of its own, for a command that draws once it has
    trained: the import (about half a second) then runs beside the training rather than after it.

    A figure's function imports matplotlib itself, and waits for this import where it is still
    running.
    """
    threading.Thread(target=_import_matplotlib, name="matplotlib-import", daemon=True).start()


def _import_matplotlib() -> None:
    """Imports what `_figure` uses."""
    from matplotlib import figure  # noqa: F401
    from matplotlib.backends import backend_agg  # noqa: F401


def _figure(figsize: tuple[float, float]) -> "Figure":
    """A figure of `figsize` inches at `DPI` on an Agg canvas, laid out by matplotlib's constrained
    layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)  # a renderer to measure text with, and the PNG writer
    return fig


def _renderer(fig: "Figure") -> "RendererAgg":
    """The renderer of `fig`'s Agg canvas (`_figure`), to measure its artists with."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    return cast(FigureCanvasAgg, fig.canvas).get_renderer()


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


def _colours(count: int) -> list[tuple[float, float, float, float]]:
    """`count` distinct colours of the qualitative colour map tab10 (repeating after 10)."""
    from matplotlib import colormaps

    palette = colormaps["tab10"]
    return [palette(g % palette.N) for g in range(count)]


def _band(ax: "Axes", x: HostArray, estimate: HostArray, low: HostArray, high: HostArray,
          colour: Any, label: str | None) -> None:
    """One setting's line `[X]` against `x` `[X]`, drawn over its band from `low` to `high`."""
    ax.fill_between(x, low, high, color=colour, alpha=_BAND_ALPHA, linewidth=0)
    ax.plot(x, estimate, color=colour, linewidth=2, label=label)


def _banded_lines(x: HostArray, estimate: HostArray, low: HostArray, high: HostArray,
                  labels: Sequence[str], xlabel: str, ylabel: str,
                  solved_return: float | None = None) -> tuple["Figure", "Axes"]:
    """Each setting's line in its band, on one panel or, for many settings, on a panel each.

    Up to `_ONE_PANEL_SETTINGS` settings share a panel (`_one_panel`); more get a panel each
    (`_panel_each`). The legend is above the panels, where it covers no line (`_legend_above`).

    Args:
      x: `[X]` where the lines are evaluated.
      estimate: `[G, X]` each setting's line.
      low: `[G, X]` the bottom of each setting's band.
      high: `[G, X]` its top.
      labels: G names of the settings.
      xlabel: what `x` is.
      ylabel: what the lines are.
      solved_return: optional return that counts as solved, drawn as a dashed line on each panel.

    Returns:
      The figure and its first panel (the panels share their axes).
    """
    draw = _one_panel if len(labels) <= _ONE_PANEL_SETTINGS else _panel_each
    fig, panels = draw(x, estimate, low, high, labels, xlabel, ylabel)
    for ax in panels:
        if solved_return is not None:
            ax.axhline(solved_return, color="black", linestyle="--", linewidth=1,
                       label=f"solved ({solved_return:g})")
        ax.grid(alpha=0.3)
    handles, names = panels[0].get_legend_handles_labels()
    _legend_above(fig, dict(zip(names, handles)))  # each name once
    return fig, panels[0]


def _legend_above(fig: "Figure", entries: Mapping[str, Any]) -> None:
    """A legend of `entries` `{name: handle}` above `fig`'s panels, in two columns where they fit
    across the figure, else in one (long names, e.g. with their folders)."""
    def legend(ncols: int) -> "Legend":
        return fig.legend(list(entries.values()), list(entries), loc="outside upper center",
                          ncols=ncols, fontsize="small", frameon=False)

    two_columns = legend(2)
    if two_columns.get_window_extent(_renderer(fig)).width > fig.bbox.width:
        two_columns.remove()
        legend(1)


def _one_panel(x: HostArray, estimate: HostArray, low: HostArray, high: HostArray,
               labels: Sequence[str], xlabel: str, ylabel: str) -> tuple["Figure", list["Axes"]]:
    """Every setting's line `[G, X]` in its band on one panel, each in a colour of its own, as
    `_banded_lines` takes them; returns the figure and its panel."""
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    for g, (label, colour) in enumerate(zip(labels, _colours(len(labels)))):
        _band(ax, x, estimate[g], low[g], high[g], colour, label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    return fig, [ax]


def _panel_each(x: HostArray, estimate: HostArray, low: HostArray, high: HostArray,
                labels: Sequence[str], xlabel: str, ylabel: str) -> tuple["Figure", list["Axes"]]:
    """Each setting's line `[G, X]` in its band on a panel of its own, two panels across, titled
    by the setting, over the other settings' lines in grey, as `_banded_lines` takes them; returns
    the figure and its panels."""
    rows = -(-len(labels) // 2)
    fig = _figure((FIGSIZE[0], _PANELS_TOP + _PANEL_HEIGHT * rows))
    grid = fig.subplots(rows, 2, sharex=True, sharey=True, squeeze=False).ravel()
    panels = list(grid[:len(labels)])
    for g, (ax, label, colour) in enumerate(zip(panels, labels, _colours(len(labels)))):
        ax.plot(x, np.delete(estimate, g, axis=0).T, color="0.75", linewidth=1,
                label="the other settings")
        _band(ax, x, estimate[g], low[g], high[g], colour, None)
        ax.set_title(label, fontsize="small", color=colour)
    for ax in grid[len(labels):]:  # the last slot, for an odd number of settings
        ax.remove()
        panels[-2].xaxis.set_tick_params(labelbottom=True)  # now the last of its column
    fig.supxlabel(xlabel, fontsize="medium")
    fig.supylabel(ylabel, fontsize="medium")
    _wrap_titles(fig, panels)
    return fig, panels


def _wrap_titles(fig: "Figure", panels: Sequence["Axes"]) -> None:
    """Breaks each panel's title that is wider than its panel into lines that fit it."""
    fig.draw_without_rendering()
    renderer = _renderer(fig)
    for ax in panels:
        title = ax.title.get_text()
        fits = ax.get_window_extent(renderer).width / ax.title.get_window_extent(renderer).width
        if fits < 1:  # (a line of 0.95 as many characters, as some are wider than others)
            ax.title.set_text(textwrap.fill(title, int(0.95 * fits * len(title))))


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

    Up to `_ONE_PANEL_SETTINGS` settings share a panel; more get a panel each (`_banded_lines`).

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
    fig, ax = _banded_lines(taus, fraction, low, high, labels, f"{xlabel} (tau)",
                            "fraction of runs with score > tau")
    ax.set_ylim(-0.02, 1.02)
    return _save(fig, path)


def iqm_curves(iterations: npt.ArrayLike, iqm: npt.ArrayLike, low: npt.ArrayLike,
               high: npt.ArrayLike, labels: Sequence[str], path: StrPath,
               solved_return: float | None = None) -> pathlib.Path:
    """Plots the IQM over runs per iteration, with its confidence band, for each setting.

    Up to `_ONE_PANEL_SETTINGS` settings share a panel; more get a panel each (`_banded_lines`).

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
    fig, ax = _banded_lines(iterations, iqm, low, high, labels, "iteration",
                            "IQM of the mean return (CI band)", solved_return)
    # (The default locator is a MaxNLocator, whose `set_params` takes `integer`.)
    ax.xaxis.get_major_locator().set_params(integer=True)  # type: ignore[call-arg]
    return _save(fig, path)


def improvement_heatmap(probability: npt.ArrayLike, labels: Sequence[str], path: StrPath,
                        low: npt.ArrayLike | None = None, high: npt.ArrayLike | None = None
                        ) -> pathlib.Path:
    """Plots P(row's setting scores above column's) for every pair of settings, values written in.

    Each cell holds P to two decimals and, given `low` and `high`, its interval below it. The rows
    are numbered after their labels and the columns by those numbers, so that long labels are
    written once.

    Args:
      probability: `[G, G]` probabilities of improvement, e.g. `stats.improvement_matrix(...)[0]`.
      labels: G names of the settings.
      path: the image file to write.
      low: optional `[G, G]` lower bounds of the probabilities' intervals, given with `high`.
      high: optional `[G, G]` upper bounds.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for arrays of other shapes, labels that do not match them, or only one of `low`
        and `high`.
    """
    if (low is None) != (high is None):
        raise ValueError(f"{'low' if low is None else 'high'}: give low and high together, or "
                         f"neither")
    bounds: dict[str, npt.ArrayLike] = (
        {} if low is None or high is None else {"low": low, "high": high})
    probability, *interval = _check_alike(list(labels), "GG", probability=probability, **bounds)
    if probability.shape[1] != len(labels):
        raise ValueError(f"probability: expected shape [G, G], got {probability.shape}")
    texts = _written(probability, _PROBABILITY_DECIMALS)
    title = "probability of improvement"
    if interval:
        bounds_texts = (_written(bound, _PROBABILITY_DECIMALS) for bound in interval)
        texts = np.vectorize("{}\n[{}, {}]".format, otypes=[object])(texts, *bounds_texts)
        title += " [confidence interval]"
    numbers = range(1, len(labels) + 1)
    # Dark text on the light middle of the colour map, white on its dark ends.
    fig = _written_heatmap(
        probability, texts, [f"{label} ({g})" for g, label in zip(numbers, labels)],
        [str(g) for g in numbers], "P(row > column)", lambda value: 0.2 < value < 0.8,
        title=title, xlabel="setting (numbered as the rows)", cmap="RdBu", vmin=0, vmax=1)
    return _save(fig, path)


def return_heatmap(values: npt.ArrayLike, row_labels: Sequence[str], column_labels: Sequence[str],
                   path: StrPath, max_return: float, xlabel: str | None = None,
                   title: str | None = None) -> pathlib.Path:
    """Plots a return per cell of a table of settings, e.g. the median per physics setting.

    Each cell holds its value rounded to `_SIGNIFICANT` digits of the table's largest one (so
    198.135 is written 198 in a table of returns up to 200), without the decimals that are zero in
    every cell.

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
    # Dark text on the light upper part of the colour map, white on its dark lower part.
    fig = _written_heatmap(values, _written(values, _decimals(values, _SIGNIFICANT)), row_labels,
                           column_labels, "return", lambda value: value > 0.6 * max_return,
                           title=title, xlabel=xlabel, cmap="viridis", vmin=0, vmax=max_return)
    return _save(fig, path)


# --- Heatmaps with their values written in ------------------------------------------------------


def _decimals(values: HostArray, significant: int) -> int:
    """The decimals that write the largest finite |value| with `significant` digits (at least 0),
    fewer where every value ends in zeros there (so 11 and 30, not 11.0 and 30.0)."""
    finite = values[np.isfinite(values)]
    largest = np.max(np.abs(finite), initial=0.0)
    most = 0 if largest == 0 else max(0, significant - 1 - int(np.floor(np.log10(largest))))
    rounded = np.round(finite, most)
    return next(d for d in range(most + 1) if np.array_equal(np.round(finite, d), rounded))


def _written(values: HostArray, decimals: int) -> npt.NDArray[np.str_]:
    """`values` `[...]` written with `decimals` decimals, as strings of the same shape ("0", never
    "-0")."""
    return np.char.mod(f"%.{decimals}f", np.round(values, decimals) + 0.0)


def _written_heatmap(values: HostArray, texts: npt.NDArray[Any], row_labels: Sequence[str],
                     column_labels: Sequence[str], colorbar_label: str,
                     light: Callable[[float], bool], title: str | None, xlabel: str | None,
                     **colours: Any) -> "Figure":
    """A figure of `values` as coloured cells with `texts` written in, sized to the grid.

    Each cell is as large as the widest and the tallest text needs at `_CELL_FONT` points (and at
    least `_MIN_CELL`); where that grid would outgrow `_MAX_GRID`, the cells and the text shrink
    together, the text to `_MIN_CELL_FONT` at least. The figure is as large as the grid and its
    labels, colour bar and title need.

    Args:
      values: `[R, C]` what the cells' colours show.
      texts: `[R, C]` what is written in each cell, in black where `light(value)` or the cell is
        NaN (and left blank), else in white.
      row_labels: R names of the rows.
      column_labels: C names of the columns, turned where they are wider than a column.
      colorbar_label: what the colours are.
      light: whether a value's colour is light.
      title: optional title.
      xlabel: optional name of the columns.
      **colours: `imshow`'s colour arguments (cmap, vmin, vmax).

    Returns:
      The figure.
    """
    fig = _figure(FIGSIZE)
    ax = fig.add_subplot()
    image = ax.imshow(values, aspect="auto", **colours)
    written = [ax.text(j, i, str(texts[i, j]), ha="center", va="center", fontsize=_CELL_FONT,
                       color="black" if light(value) or np.isnan(value) else "white")
               for (i, j), value in np.ndenumerate(values)]
    grid, font = _grid_size(fig, written, values.shape)
    for text in written:
        text.set_fontsize(font)
    fig.colorbar(image, ax=ax, label=colorbar_label, aspect=grid[1] / _COLORBAR_WIDTH)
    ax.set_xticks(np.arange(len(column_labels)), column_labels, fontsize="small")
    ax.set_yticks(np.arange(len(row_labels)), row_labels, fontsize="small")
    ax.set_xlabel(xlabel or "")
    heading = fig.suptitle(title or "")
    _fit(fig, ax, grid, heading)
    return fig


def _grid_size(fig: "Figure", texts: Sequence["Text"], shape: tuple[int, ...]
               ) -> tuple[HostArray, float]:
    """The size of a heatmap `shape` `[R, C]` whose cells hold `texts` drawn at `_CELL_FONT`.

    Args:
      fig: the figure the texts are drawn on.
      texts: the cells' texts, at `_CELL_FONT` points.
      shape: the grid's rows and columns.

    Returns:
      The grid's `[2]` width and height in inches, and the font size in points that fits the
      texts into its cells.
    """
    renderer = _renderer(fig)
    extents = [text.get_window_extent(renderer) for text in texts]
    text_size = np.max([(extent.width, extent.height) for extent in extents], axis=0) / fig.dpi
    cells = np.array(shape[::-1])  # columns across, rows down
    needed = (text_size + _CELL_PADDING) * cells
    scale = min(1.0, *(_MAX_GRID / needed))
    grid = np.clip(np.maximum(needed * scale, _MIN_CELL * cells), _MIN_GRID, _MAX_GRID)
    return grid, max(_MIN_CELL_FONT, _CELL_FONT * scale)


def _fit(fig: "Figure", ax: "Axes", size: HostArray, heading: "Text") -> None:
    """Resizes `fig` so that its constrained layout makes `ax` `size` `[2]` inches (width,
    height), or wider where `heading` needs, its column labels turned where one and `_LABEL_GAP`
    are wider than a column."""
    renderer = _renderer(fig)
    least_width = heading.get_window_extent(renderer).width / fig.dpi + 2 * _HEADING_MARGIN
    fig.draw_without_rendering()
    widest = max(label.get_window_extent(renderer).width for label in ax.get_xticklabels())
    if widest / fig.dpi + _LABEL_GAP > size[0] / len(ax.get_xticks()):
        ax.tick_params(axis="x", labelrotation=30)
        for label in ax.get_xticklabels():
            label.set(ha="right", rotation_mode="anchor")
    for _ in range(_FIT_STEPS):
        figure_size = fig.get_size_inches()
        width, height = figure_size + size - ax.get_position().size * figure_size
        fig.set_size_inches(max(width, least_width), height)
        fig.draw_without_rendering()
