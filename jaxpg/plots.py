"""Learning curves, sweep summaries and throughput charts, written as image files.

matplotlib is imported inside each function, so that importing jaxpg stays light. Figures are
drawn with `matplotlib.figure.Figure` and its Agg canvas, never through pyplot: no global state and
no display is touched. Each file is replaced atomically; its format follows the suffix (PNG for
`.png`).
"""

import pathlib

import numpy as np

from jaxpg import results

FIGSIZE = (8.0, 4.5)  # inches
DPI = 100  # so an 800 x 450 pixel image, or 800 x 700 for two panels
_TWO_PANEL_FIGSIZE = (8.0, 7.0)


def _figure(figsize):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=DPI, layout="constrained")


def _save(fig, path):
    """Writes `fig` to `path` atomically and returns the path."""
    with results.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI)
    return pathlib.Path(path)


def learning_curve(metrics, path, title=None):
    """Plots one run's mean return per iteration, with the band from its min to max return.

    Args:
      metrics: `reinforce.Metrics` of one run, `[I]` leaves.
      path: the image file to write.
      title: optional figure title.

    Returns:
      The `pathlib.Path` written.
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


def sweep_curves(median, q25, q75, solved_fraction, labels, solved_return, path):
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


def throughput_chart(rows, path, title, xlabel="N (environments or seeds)"):
    """Plots throughput against N on log-log axes, one line per implementation.

    Args:
      rows: dicts {"impl": str, "n": int, "steps_per_s": float}, in any order.
      path: the image file to write.
      title: figure title.
      xlabel: what N counts.

    Returns:
      The `pathlib.Path` written.
    """
    by_impl = {}
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
