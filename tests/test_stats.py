"""Statistics: aggregates exact against numpy, intervals against scipy's bootstrap, P(improvement)
against Mann-Whitney U, hand-checked values on fixed arrays, and bad input refused in one line."""

import numpy as np
import pytest
import scipy.stats

from jaxpg import stats

RNG = np.random.default_rng(12345)
SAMPLES = {
    "normal": RNG.normal(100.0, 20.0, size=256),
    "heavy tails": RNG.standard_cauchy(size=300),
    # Integer returns, each value held by about two runs. (With fewer distinct values a median's
    # bootstrap distribution jumps by more than 2 % of the range, and a bound may fall on either
    # side of a jump in two bootstraps of 2,000 resamples.)
    "ties": RNG.integers(0, 100, size=200).astype(float),
    "few runs": RNG.exponential(50.0, size=12),
}
HEAVY = np.array([1.0, 2, 3, 4, 5, 6, 7, 1e6])


def _middle_half(x):
    """The IQM spelled out: sort, cut floor(n / 4) at each end, average the rest."""
    x = np.sort(np.ravel(x))
    cut = x.size // 4
    return x[cut : x.size - cut].mean()


# --- Aggregates ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SAMPLES)
def test_aggregates_equal_numpy(name):
    x = SAMPLES[name]
    np.testing.assert_allclose(stats.iqm(x), _middle_half(x), rtol=1e-12)
    assert stats.iqm(x) == scipy.stats.trim_mean(x, 0.25)
    assert stats.mean(x) == np.mean(x)
    assert stats.median(x) == np.median(x)


def test_aggregates_of_tasks_take_all_scores_and_axis_0_takes_each_task():
    x = SAMPLES["normal"].reshape(64, 4)
    np.testing.assert_allclose(stats.iqm(x), _middle_half(x), rtol=1e-12)
    np.testing.assert_allclose(stats.iqm(x, axis=0), [_middle_half(c) for c in x.T], rtol=1e-12)
    assert stats.median(x) == np.median(x)
    np.testing.assert_array_equal(stats.mean(x, axis=0), x.mean(axis=0))


def test_hand_checked_aggregates_under_heavy_tails():
    # Sorted 1..7, 1e6: the IQM cuts 8 // 4 = 2 at each end and averages 3, 4, 5, 6 = 4.5;
    # the median is (4 + 5) / 2 = 4.5; the mean is (28 + 1e6) / 8 = 125003.5.
    assert stats.iqm(HEAVY) == 4.5
    assert stats.median(HEAVY) == 4.5
    assert stats.mean(HEAVY) == 125003.5


def test_optimality_gap():
    # min(scores, 195) = 100, 195, 195, 150; their mean is 640 / 4 = 160; 195 - 160 = 35.
    assert stats.optimality_gap([100.0, 200.0, 300.0, 150.0], 195.0) == 35.0
    assert stats.optimality_gap([500.0, 195.0], 195.0) == 0.0
    with pytest.raises(ValueError, match="^target"):
        stats.optimality_gap([1.0], float("nan"))


# --- Bootstrap confidence intervals ---------------------------------------------------------------


@pytest.mark.parametrize("name", SAMPLES)
@pytest.mark.parametrize("statistic, reduce", [
    ("iqm", lambda a, axis: scipy.stats.trim_mean(a, 0.25, axis=axis)),
    ("mean", np.mean),
    ("median", np.median),
])
def test_interval_matches_scipy_bootstrap(name, statistic, reduce):
    x = SAMPLES[name]
    low, high = stats.bootstrap_ci(x, statistic, confidence=0.9)
    reference = scipy.stats.bootstrap((x,), reduce, confidence_level=0.9, n_resamples=2000,
                                      method="percentile", rng=np.random.default_rng(7))
    tolerance = 0.02 * np.ptp(x)
    assert abs(low - reference.confidence_interval.low) <= tolerance
    assert abs(high - reference.confidence_interval.high) <= tolerance
    assert low <= high


def test_interval_is_seeded_and_a_function_serves_as_statistic():
    x = SAMPLES["normal"]
    assert stats.bootstrap_ci(x, seed=3) == stats.bootstrap_ci(x, seed=3)
    assert stats.bootstrap_ci(x, seed=3) != stats.bootstrap_ci(x, seed=4)
    assert stats.bootstrap_ci(x, np.mean) == stats.bootstrap_ci(x, "mean")


def test_interval_of_equal_scores_is_a_point():
    assert stats.bootstrap_ci(np.full(10, 7.0)) == (7.0, 7.0)


def test_stratified_interval_resamples_runs_within_each_task():
    # Task 0 scores 0 in every run and task 1 scores 10: a resample within tasks always holds
    # 8 zeros and 8 tens, whose mean is 5. Pooling the 16 scores would let it vary.
    x = np.stack([np.zeros(8), np.full(8, 10.0)], axis=1)
    assert stats.bootstrap_ci(x, "mean") == (5.0, 5.0)
    # One task is the unstratified case, draw for draw.
    one = SAMPLES["normal"]
    assert stats.bootstrap_ci(one[:, None], "iqm") == stats.bootstrap_ci(one, "iqm")


# --- Probability of improvement -----------------------------------------------------------------


@pytest.mark.parametrize("x, y", [
    (SAMPLES["normal"], SAMPLES["normal"][:100] + 5),
    (SAMPLES["ties"], SAMPLES["ties"][::-1][:40] + 1),
    (SAMPLES["heavy tails"], SAMPLES["few runs"]),
])
def test_probability_of_improvement_is_mann_whitney_u_over_pairs(x, y):
    expected = scipy.stats.mannwhitneyu(x, y).statistic / (x.size * y.size)
    assert stats.probability_of_improvement(x, y) == pytest.approx(expected, rel=1e-12)


def test_hand_checked_probabilities_with_ties():
    # x = 3 beats y = 2 and 1 (2 each, twice: 4); x = 2 ties y = 2 (0.5) and beats 1 (1):
    # 5.5 of 3 * 2 = 6 pairs.
    assert stats.probability_of_improvement([3.0, 3.0, 2.0], [2.0, 1.0]) == 5.5 / 6
    # x = 1 loses twice (0); the two x = 2 tie both y = 2 (4 * 0.5 = 2); x = 3 wins twice (2):
    # 4 / 8.
    assert stats.probability_of_improvement([1.0, 2.0, 2.0, 3.0], [2.0, 2.0]) == 0.5
    # Equal scores tie every pair, and so does the interval.
    assert stats.probability_of_improvement(np.full(10, 5.0), np.full(7, 5.0)) == 0.5
    assert stats.improvement_ci(np.full(10, 5.0), np.full(7, 5.0)) == (0.5, 0.5)
    # HEAVY above every score of 0 but for none: the size of 1e6 counts no more than 8's would.
    assert stats.probability_of_improvement(HEAVY, np.zeros(3)) == 1.0


def test_probability_of_improvement_over_tasks_averages_the_tasks():
    x, y = SAMPLES["normal"][:60].reshape(20, 3), SAMPLES["normal"][60:105].reshape(15, 3)
    per_task = [scipy.stats.mannwhitneyu(x[:, t], y[:, t]).statistic / (20 * 15) for t in range(3)]
    assert stats.probability_of_improvement(x, y) == pytest.approx(np.mean(per_task), rel=1e-12)


def test_improvement_interval_holds_the_estimate_and_a_clear_difference_excludes_one_half():
    x, y = SAMPLES["normal"], SAMPLES["normal"][::2] - 30
    low, high = stats.improvement_ci(x, y)
    assert 0.5 < low <= stats.probability_of_improvement(x, y) <= high <= 1


def test_improvement_matrix_is_each_pair_and_its_complement():
    scores = [SAMPLES["normal"], SAMPLES["normal"][:50] + 10, SAMPLES["ties"] * 50]
    matrix = stats.improvement_matrix(scores, reps=500)
    np.testing.assert_array_equal(np.diag(matrix.probability), 0.5)
    np.testing.assert_allclose(matrix.probability + matrix.probability.T, 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(matrix.low + matrix.high.T, 1.0, rtol=0, atol=1e-15)
    assert matrix.probability[0, 2] == stats.probability_of_improvement(scores[0], scores[2])
    assert (matrix.low[0, 2], matrix.high[0, 2]) == stats.improvement_ci(
        scores[0], scores[2], reps=500)


# --- Profiles and curves ----------------------------------------------------------------------


def test_performance_profile():
    # Above 0: all 4 scores; above 2: 3 and 4 (2 of 4); above 4: none.
    band = stats.performance_profile([1.0, 2.0, 3.0, 4.0], taus=[0.0, 2.0, 4.0])
    np.testing.assert_array_equal(band.estimate, [1.0, 0.5, 0.0])
    np.testing.assert_array_equal(band.low[[0, 2]], [1.0, 0.0])  # no resample changes these
    x = SAMPLES["normal"].reshape(128, 2)
    band = stats.performance_profile(x)
    assert band.x.shape == (101,) and band.x[0] == x.min() and band.x[-1] == x.max()
    np.testing.assert_array_equal(band.estimate, [(x > tau).mean() for tau in band.x])
    assert np.all(band.low <= band.high)


def test_iqm_curve_resamples_whole_runs():
    runs = SAMPLES["normal"][:64]
    # Every iteration a copy of the same scores: resampling whole runs gives every iteration the
    # same band; resampling each iteration on its own would not.
    band = stats.iqm_curve(np.stack([runs] * 5, axis=1))
    np.testing.assert_array_equal(band.x, np.arange(1, 6))
    np.testing.assert_array_equal(stats.iqm_curve(runs[:, None], iterations=[150]).x, [150])
    np.testing.assert_allclose(band.estimate, stats.iqm(runs), rtol=1e-12)
    assert np.ptp(band.low) == 0 and np.ptp(band.high) == 0
    assert band.low[0] < band.estimate[0] < band.high[0]
    # One column draws the runs as the stratified bootstrap of one task does.
    one = stats.iqm_curve(runs[:, None])
    np.testing.assert_allclose((one.low[0], one.high[0]), stats.bootstrap_ci(runs[:, None]),
                               rtol=1e-12)


# --- How many seeds -------------------------------------------------------------------------------


def test_seeds_needed_scales_the_interval_by_the_root_of_the_runs():
    runs = SAMPLES["normal"][:32]
    scores = [runs, runs + 5.0, runs - 40.0]
    estimate = stats.seeds_needed(scores)
    assert (estimate.best, estimate.second) == (1, 0)
    assert estimate.difference == pytest.approx(5.0)
    assert estimate.low < 0 < estimate.high  # 32 runs do not tell them apart
    # Equal runs n: the interval's lower half-width w shrinks as sqrt(n / n') and passes 0 when
    # n' > n (w / d)^2.
    half_width = estimate.difference - estimate.low
    assert estimate.seeds == int(32 * (half_width / estimate.difference) ** 2) + 1
    assert estimate.seeds > 32
    clear = stats.seeds_needed([runs, runs + 40.0])
    assert clear.low > 0 and 2 <= clear.seeds < 32


def test_seeds_needed_without_spread_or_without_difference():
    assert stats.seeds_needed([np.full(4, 1.0), np.full(4, 2.0)]).seeds == 2
    equal = stats.seeds_needed([SAMPLES["few runs"], SAMPLES["few runs"]])
    assert equal.difference == 0 and equal.seeds is None


# --- Bad input ------------------------------------------------------------------------------------


@pytest.mark.parametrize("call, word", [
    (lambda: stats.bootstrap_ci([1.0]), "scores: a confidence interval needs at least 2 runs"),
    (lambda: stats.bootstrap_ci([]), "scores: empty"),
    (lambda: stats.iqm(np.zeros((0, 3))), "scores: empty"),
    (lambda: stats.mean(np.zeros((2, 2, 2))), "scores: expected"),
    (lambda: stats.median([1.0, np.nan]), "scores: must be finite"),
    (lambda: stats.bootstrap_ci([1.0, 2.0], "mode"), "statistic"),
    (lambda: stats.bootstrap_ci([1.0, 2.0], confidence=1.0), "confidence"),
    (lambda: stats.bootstrap_ci([1.0, 2.0], confidence=0), "confidence"),
    (lambda: stats.bootstrap_ci([1.0, 2.0], reps=0), "reps"),
    (lambda: stats.bootstrap_ci([1.0, 2.0], seed=-1), "seed"),
    (lambda: stats.probability_of_improvement(np.ones((3, 2)), np.ones((3, 4))),
     "y: expected the tasks"),
    (lambda: stats.improvement_ci([1.0, 2.0], [1.0]),
     "y: a confidence interval needs at least 2 runs"),
    (lambda: stats.improvement_matrix([]), "scores: expected at least one setting"),
    (lambda: stats.performance_profile([1.0, 2.0], taus=[]), "taus"),
    (lambda: stats.iqm_curve([1.0, 2.0]), "scores: expected"),
    (lambda: stats.iqm_curve(np.ones((4, 3)), iterations=[1, 2]), "iterations"),
    (lambda: stats.seeds_needed([[1.0, 2.0]]), "scores: expected at least 2 settings"),
    (lambda: stats.seeds_needed([[1.0, 2.0], [3.0]]), r"scores\[1\]: a confidence interval"),
])
def test_bad_input_is_one_line_naming_the_argument(call, word):
    with pytest.raises(ValueError, match=f"^{word}") as error:
        call()
    assert "\n" not in str(error.value)
