"""Plots: each writes a valid PNG of the documented size, and bad input is refused."""

import imageio.v3 as iio
import numpy as np
import pytest

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


def test_improvement_heatmap(tmp_path):
    probability = np.array([[0.5, 0.1, 0.3], [0.9, 0.5, 0.7], [0.7, 0.3, 0.5]])
    path = plots.improvement_heatmap(probability, LABELS, tmp_path / "improvement.png")
    _assert_png(path, 800, 450)
    with pytest.raises(ValueError, match="^probability"):
        plots.improvement_heatmap(probability[:, :2], LABELS, tmp_path / "x.png")


def test_return_heatmap(tmp_path):
    median = np.array([[12.0, 30.5, 200.0], [8.0, 21.0, 187.0]])
    labels = ["length=0.5", "length=1"], ["0.1", "0.3", "0.5"]
    path = plots.return_heatmap(median, *labels, tmp_path / "robustness.png", 200,
                                xlabel="masspole", title="median return")
    _assert_png(path, 800, 450)
    with pytest.raises(ValueError, match="^column_labels"):
        plots.return_heatmap(median, labels[0], labels[1][:2], tmp_path / "x.png", 200)
    with pytest.raises(ValueError, match="^labels"):
        plots.return_heatmap(median, labels[0][:1], labels[1], tmp_path / "x.png", 200)
    with pytest.raises(ValueError, match="^values"):
        plots.return_heatmap(median[0], labels[0], labels[1], tmp_path / "x.png", 200)
    with pytest.raises(ValueError, match="^max_return"):
        plots.return_heatmap(median, *labels, tmp_path / "x.png", 0)
