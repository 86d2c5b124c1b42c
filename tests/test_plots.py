"""Plots: each writes a valid PNG of the documented size (a heatmap's sized to its grid), its
written values rounded and apart, and bad input is refused."""

import itertools

import imageio.v3 as iio
import numpy as np
import pytest
from matplotlib.transforms import Bbox

from jaxpg import plots
from jaxpg.iteration import Metrics

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _metrics(shape):
    mean = np.linspace(10, 200, num=shape[-1]) * np.ones(shape)
    return Metrics(mean, mean - 5, mean + 5, mean, -mean / 100, np.ones(shape))


def _assert_png(path, width, height):
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    image = iio.imread(path)
    assert image.shape[:2] == (height, width)
    assert image.dtype == np.uint8
    assert image.min() < 128 < image.max()  # something drawn on a light background
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary file left


@pytest.fixture
def drawn(monkeypatch):
    """The figures the plots write, in order, kept for a test to read their artists."""
    figures = []
    save = plots._save

    def save_and_keep(fig, path):
        figures.append(fig)
        return save(fig, path)

    monkeypatch.setattr(plots, "_save", save_and_keep)
    return figures


def _assert_png_of(fig, path):
    """`_assert_png` at the size of `fig`, whose size follows what it shows."""
    width, height = (fig.get_size_inches() * plots.DPI).astype(int)  # Agg truncates to pixels
    _assert_png(path, width, height)


def _inside(box, outer):
    """Whether the bounding box `box` lies within `outer`."""
    return bool(np.all(box.min >= outer.min) and np.all(box.max <= outer.max))


def _assert_apart(fig):
    """Each heatmap cell's text lies within its cell, and no two texts of the heatmap (cells, row
    and column labels) come within 2 pixels of each other or leave the figure."""
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()
    for text in ax.texts:
        j, i = text.get_position()
        corners = ax.transData.transform([(j - 0.5, i - 0.5), (j + 0.5, i + 0.5)])
        assert _inside(text.get_window_extent(renderer),
                       Bbox([corners.min(axis=0), corners.max(axis=0)]))
    texts = [*ax.texts, *ax.get_xticklabels(), *ax.get_yticklabels()]
    boxes = [text.get_window_extent(renderer) for text in texts if text.get_text()]
    assert all(_inside(box, fig.bbox) for box in boxes)
    for a, b in itertools.combinations(boxes, 2):
        assert not a.padded(1).overlaps(b.padded(1))


def _assert_filled(fig):
    """The drawing spans `fig` (no blank band along an edge, as where a grid of square cells left
    45 % of an 8 x 4 heatmap's figure empty), and the heatmap's grid covers a fifth of it at least
    (its labels may take the rest, or a 1 x 12 grid was a strip 6 % of the figure)."""
    drawing = fig.get_tightbbox(fig.canvas.get_renderer()).size / fig.get_size_inches()
    assert np.all(drawing > 0.95)
    assert np.prod(fig.axes[0].get_position().size) > 1 / 5


def test_learning_curve(tmp_path):
    path = plots.learning_curve(_metrics((30,)), tmp_path / "curve.png", title="seed 0")
    _assert_png(path, 800, 450)
    with pytest.raises(ValueError, match="metrics"):
        plots.learning_curve(_metrics((4, 30)), tmp_path / "many.png")


def test_sweep_curves(tmp_path):
    grid, iterations = 3, 25
    median = np.linspace(10, 200, iterations) * np.arange(1, grid + 1)[:, None] / grid
    solved = np.clip(np.linspace(-0.5, 1, iterations) * np.ones((grid, 1)), 0, 1)
    labels = [f"lr={lr}, discount=0.95" for lr in (0.001, 0.01, 0.1)]
    path = plots.sweep_curves(
        median, median - 10, median + 10, solved, labels, 195.0, tmp_path / "sweep.png"
    )
    _assert_png(path, 800, 700)
    with pytest.raises(ValueError, match="labels"):
        plots.sweep_curves(median, median, median, solved, labels[:2], 195.0, tmp_path / "x.png")
    with pytest.raises(ValueError, match="q75"):
        plots.sweep_curves(median, median, median[:, :3], solved, labels, 195.0, tmp_path / "x.png")


def test_throughput_chart(tmp_path):
    rows = [
        {"impl": impl, "n": n, "steps_per_s": rate * n}
        for impl, rate in (("jaxpg", 1e5), ("gymnasium", 1e4))
        for n in (1024, 1, 32)  # unsorted on purpose
    ]
    path = plots.throughput_chart(rows, tmp_path / "throughput.png", "CartPole steps per second")
    _assert_png(path, 800, 450)
    with pytest.raises(ValueError, match=r"rows\[0\]"):
        plots.throughput_chart([{"impl": "x", "n": 0, "steps_per_s": 1.0}], tmp_path / "x.png", "t")
    with pytest.raises(ValueError, match=r"rows\[1\]"):
        plots.throughput_chart([rows[0], {"impl": "x"}], tmp_path / "x.png", "t")


LABELS = [f"lr={lr}, discount=0.95" for lr in (0.001, 0.01, 0.1)]


def test_aggregate_intervals(tmp_path):
    estimate = np.array([20.0, 150.0, 90.0])
    triple = (estimate, estimate - 10, estimate + 15)
    path = plots.aggregate_intervals(LABELS, {"IQM": triple, "mean": triple},
                                     tmp_path / "intervals.png")
    _assert_png(path, 800, 450)
    with pytest.raises(ValueError, match=r"^estimates\['IQM'\]\[2\]"):
        plots.aggregate_intervals(LABELS, {"IQM": (estimate, estimate, estimate[:2])},
                                  tmp_path / "x.png")
    with pytest.raises(ValueError, match="^labels"):
        plots.aggregate_intervals(LABELS[:2], {"IQM": triple}, tmp_path / "x.png")
    with pytest.raises(ValueError, match="^estimates"):
        plots.aggregate_intervals(LABELS, {}, tmp_path / "x.png")


def test_performance_profiles(tmp_path):
    taus = np.linspace(0, 500, 101)
    fraction = np.clip(1 - taus / np.array([[100.0], [300.0], [500.0]]), 0, 1)
    path = plots.performance_profiles(taus, fraction, fraction * 0.9, np.minimum(fraction * 1.1, 1),
                                      LABELS, tmp_path / "profiles.png")
    _assert_png(path, 800, 450)
    with pytest.raises(ValueError, match="^taus"):
        plots.performance_profiles(taus[:5], fraction, fraction, fraction, LABELS,
                                   tmp_path / "x.png")
    with pytest.raises(ValueError, match="^high"):
        plots.performance_profiles(taus, fraction, fraction, fraction[:2], LABELS,
                                   tmp_path / "x.png")


def test_iqm_curves(tmp_path):
    iterations = np.arange(1, 150, 6)
    iqm = np.linspace(10, 200, 25) * np.array([[0.3], [0.6], [1.0]])
    path = plots.iqm_curves(iterations, iqm, iqm - 10, iqm + 10, LABELS, tmp_path / "curves.png",
                            solved_return=195.0)
    _assert_png(path, 800, 450)
    with pytest.raises(ValueError, match="^iqm"):
        plots.iqm_curves(iterations, iqm[0], iqm[0], iqm[0], ["one"], tmp_path / "x.png")
    with pytest.raises(ValueError, match="^labels"):
        plots.iqm_curves(iterations, iqm, iqm, iqm, LABELS[:1], tmp_path / "x.png")
    with pytest.raises(ValueError, match="^iterations"):
        plots.iqm_curves(iterations[:3], iqm, iqm, iqm, LABELS, tmp_path / "x.png")


@pytest.mark.parametrize("settings, panels", [(3, 1), (5, 5), (8, 8)])
def test_iqm_curves_give_each_setting_its_colour_and_keep_the_legend_off_the_lines(
        tmp_path, drawn, settings, panels):
    iterations = np.arange(1, 150, 6)
    iqm = np.linspace(10, 200, 25) * np.linspace(0.3, 1, settings)[:, None]
    labels = [f"/home/user/experiments/cartpole/sweep-a: lr={lr:g}, discount=0.95"
              for lr in np.geomspace(1e-3, 0.1, settings)]  # as a comparison of folders labels
    plots.iqm_curves(iterations, iqm, iqm - 10, iqm + 10, labels, tmp_path / "curves.png",
                     solved_return=195.0)
    fig = drawn[-1]
    assert len(fig.axes) == panels
    bands = [band for ax in fig.axes for band in ax.collections]
    assert len(bands) == len({tuple(band.get_facecolor()[0]) for band in bands}) == settings
    legend = fig.legends[0]
    if panels == 1:
        assert [text.get_text() for text in legend.get_texts()] == [*labels, "solved (195)"]
    else:
        assert [" ".join(ax.get_title().split()) for ax in fig.axes] == labels  # maybe wrapped
    renderer = fig.canvas.get_renderer()
    boxes = [legend.get_window_extent(renderer), *(ax.title.get_window_extent(renderer)
                                                   for ax in fig.axes if ax.get_title())]
    assert all(_inside(box, fig.bbox) for box in boxes)
    for a, b in itertools.combinations(boxes, 2):
        assert not a.overlaps(b)
    assert not any(boxes[0].overlaps(ax.get_window_extent(renderer)) for ax in fig.axes)


def test_improvement_heatmap(tmp_path, drawn):
    probability = np.array([[0.5, 0.1, 0.3], [0.9, 0.5, 0.7], [0.7, 0.3, 0.5]])
    path = plots.improvement_heatmap(probability, LABELS, tmp_path / "improvement.png")
    _assert_png_of(drawn[-1], path)
    assert [text.get_text() for text in drawn[-1].axes[0].texts] == [
        f"{p:.2f}" for p in probability.flat]
    with pytest.raises(ValueError, match="^probability"):
        plots.improvement_heatmap(probability[:, :2], LABELS, tmp_path / "x.png")
    with pytest.raises(ValueError, match="^high"):
        plots.improvement_heatmap(probability, LABELS, tmp_path / "x.png", low=probability)
    with pytest.raises(ValueError, match="^low"):
        plots.improvement_heatmap(probability, LABELS, tmp_path / "x.png", low=probability[:2],
                                  high=probability)


@pytest.mark.parametrize("settings", [2, 8])
def test_improvement_heatmap_writes_each_probability_over_its_interval(tmp_path, drawn, settings):
    rng = np.random.default_rng(settings)
    upper = np.triu(rng.uniform(0, 1, (settings, settings)), 1)
    probability = upper + np.tril(1 - upper.T, -1) + np.eye(settings) / 2  # P(j > i) = 1 - P(i > j)
    low = np.clip(probability - rng.uniform(0, 0.1, probability.shape), 0, 1)
    high = np.clip(probability + 0.05, 0, 1)
    labels = [f"runs/lr-{lr:g}: lr={lr:g}, discount=0.95"
              for lr in np.geomspace(1e-3, 0.1, settings)]
    plots.improvement_heatmap(probability, labels, tmp_path / "improvement.png", low=low, high=high)
    fig = drawn[-1]
    for text, p, lo, hi in zip(fig.axes[0].texts, probability.flat, low.flat, high.flat):
        estimate, interval = text.get_text().split("\n")
        assert estimate == f"{p:.2f}"
        assert interval == f"[{lo:.2f}, {hi:.2f}]"
    _assert_apart(fig)
    _assert_filled(fig)


# 198.135 and 198.185 were written unrounded, into one another, on an 8 x 4 grid; the largest
# value, 198.185, has 3 digits before the point, so 3 significant digits leave no decimal.
@pytest.mark.parametrize("shape", [(8, 4), (2, 2), (1, 12)])
def test_return_heatmap_writes_rounded_values_within_their_cells(tmp_path, drawn, shape):
    values = np.random.default_rng(0).uniform(0, 200, shape)
    values.flat[:2] = 198.135, 198.185
    rows = [f"length={length:g}, masscart=1" for length in np.linspace(0.25, 2, shape[0])]
    columns = [f"{masspole:g}" for masspole in np.linspace(0.05, 1, shape[1])]
    path = plots.return_heatmap(values, rows, columns, tmp_path / "robustness.png", 200,
                                xlabel="masspole", title="median return of 8 policies")
    fig = drawn[-1]
    _assert_png_of(fig, path)
    written = [text.get_text() for text in fig.axes[0].texts]
    assert written == [f"{v:.0f}" for v in values.flat]
    _assert_apart(fig)
    _assert_filled(fig)


def test_return_heatmap_writes_small_returns_with_decimals(tmp_path, drawn):
    values = np.array([[9.87, 0.123], [-1e-4, 5.0]])  # 9.87 has 1 digit before the point: 2 after
    plots.return_heatmap(values, ["a", "b"], ["1", "2"], tmp_path / "robustness.png", 10)
    assert [text.get_text() for text in drawn[-1].axes[0].texts] == [
        "9.87", "0.12", "0.00", "5.00"]


# Up to 30, 3 significant digits are one decimal, written only where some cell needs it.
@pytest.mark.parametrize("values, written", [
    ([[11.0, 18.0], [30.0, 29.0]], ["11", "18", "30", "29"]),
    ([[11.0, 18.0], [30.0, 29.5]], ["11.0", "18.0", "30.0", "29.5"]),
    ([[11.0, 18.0], [30.0, 29.54]], ["11.0", "18.0", "30.0", "29.5"]),
])
def test_return_heatmap_writes_no_decimals_that_are_zero_everywhere(tmp_path, drawn, values,
                                                                     written):
    plots.return_heatmap(values, ["a", "b"], ["1", "2"], tmp_path / "robustness.png", 30)
    assert [text.get_text() for text in drawn[-1].axes[0].texts] == written


def test_return_heatmap(tmp_path, drawn):
    median = np.array([[12.0, 30.5, 200.0], [8.0, 21.0, 187.0]])
    labels = ["length=0.5", "length=1"], ["0.1", "0.3", "0.5"]
    path = plots.return_heatmap(median, *labels, tmp_path / "robustness.png", 200,
                                xlabel="masspole", title="median return")
    _assert_png_of(drawn[-1], path)
    with pytest.raises(ValueError, match="^column_labels"):
        plots.return_heatmap(median, labels[0], labels[1][:2], tmp_path / "x.png", 200)
    with pytest.raises(ValueError, match="^labels"):
        plots.return_heatmap(median, labels[0][:1], labels[1], tmp_path / "x.png", 200)
    with pytest.raises(ValueError, match="^values"):
        plots.return_heatmap(median[0], labels[0], labels[1], tmp_path / "x.png", 200)
    with pytest.raises(ValueError, match="^max_return"):
        plots.return_heatmap(median, *labels, tmp_path / "x.png", 0)
