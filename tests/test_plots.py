"""Plots: each writes a valid PNG of the documented size, and bad input is refused."""

import imageio.v3 as iio
import numpy as np
import pytest

from jaxpg import plots
from jaxpg.reinforce import Metrics

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
