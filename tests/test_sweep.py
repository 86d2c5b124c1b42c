"""Sweeps: seed i of a sweep is `train(seed=i)` exactly; summary statistics; bad input."""

import chex
import jax
import numpy as np
import pytest

from jaxpg import TrainConfig, train
from jaxpg.sweep import summarize, sweep


@pytest.fixture(scope="module")
def book_sweep():
    return sweep(TrainConfig(), seeds=range(64), show_progress=False)


def test_sixty_four_seeds_learn(book_sweep):
    assert book_sweep.metrics.mean_return.shape == (1, 64, 150)
    assert np.median(book_sweep.summary.final_return) >= 175


@pytest.mark.parametrize("seed", [0, 37, 63])
def test_seed_in_sweep_equals_seed_alone(book_sweep, seed):
    alone = train(TrainConfig(), seed=seed, show_progress=False)
    chex.assert_trees_all_equal(jax.tree.map(lambda a: a[0, seed], book_sweep.metrics), alone.metrics)
    chex.assert_trees_all_equal(jax.tree.map(lambda a: a[0, seed], book_sweep.policy_params),
                                alone.policy_params)


def test_grid_runs_every_setting_and_matches_train():
    config = TrainConfig(iterations=20)
    grid = {"learning_rate": [0.003, 0.01], "discount": [0.9, 0.99]}
    swept = sweep(config, seeds=[5, 6], grid=grid, show_progress=False)
    assert [(g["learning_rate"], g["discount"]) for g in swept.grid] == [
        (0.003, 0.9), (0.003, 0.99), (0.01, 0.9), (0.01, 0.99)]
    assert swept.metrics.loss.shape == (4, 2, 20)
    alone = train(TrainConfig(iterations=20, learning_rate=0.01, discount=0.9), seed=6,
                  show_progress=False)
    chex.assert_trees_all_equal(jax.tree.map(lambda a: a[2, 1], swept.metrics), alone.metrics)


def test_summary_statistics():
    # Two seeds, 12 iterations: seed 0 reaches 200 from iteration 2 on, seed 1 stays at 10.
    mean_return = np.array([[[0, 0] + [200] * 10, [10] * 12]], dtype=float)
    s = summarize(mean_return, solved_return=195)
    np.testing.assert_array_equal(s.median[0], np.median(mean_return[0], axis=0))
    np.testing.assert_array_equal(s.final_return, [[200, 10]])
    np.testing.assert_array_equal(s.fraction_solved, [0.5])
    # The trailing 10-iteration mean first reaches 195 at iteration 11 (iterations 2..11 all 200).
    np.testing.assert_array_equal(s.first_solved, [[11, -1]])
    np.testing.assert_array_equal(s.solved_by[0, 10:], [0, 0.5])


@pytest.mark.parametrize("kwargs, match", [
    (dict(seeds=[]), "seeds"),
    (dict(seeds=[1, 1]), "seeds"),
    (dict(seeds=[-1]), "seeds"),
    (dict(grid={"lr": [0.1]}), "grid"),
    (dict(grid={"discount": [0.0]}), "discount"),
    (dict(grid={"learning_rate": [-1.0]}), "learning_rate"),
])
def test_bad_sweeps_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sweep(TrainConfig(iterations=1), **kwargs)
