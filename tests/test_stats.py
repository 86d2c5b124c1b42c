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


def _runs_with_tasks(rng, runs, tasks, run_sd, noise_sd):
    """`[runs, tasks]` scores in which each run adds its own N(0, run_sd) to every task, as a
    policy of a robustness table plays every physics setting, plus N(0, noise_sd) per score."""
    return rng.normal(0.0, run_sd, (runs, 1)) + rng.normal(0.0, noise_sd, (runs, tasks))


def _whole_rows_by_hand(statistic, tables, confidence=0.95, reps=2000, seed=7):
    """The paired bootstrap spelled out: each resample draws the run indices once and takes those
    rows of every table; the percentile interval of `statistic(*resampled_tables)`."""
    rng = np.random.default_rng(seed)
    runs = tables[0].shape[0]
    values = []
    for _ in range(reps):
        rows = rng.integers(0, runs, runs)
        values.append(statistic(*(table[rows] for table in tables)))
    tail = 100 * (1 - confidence) / 2
    return np.percentile(values, [tail, 100 - tail])


def _width(interval):
    return interval[1] - interval[0]


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
    # Two Monte Carlo estimates of one interval: they agree to a part of its width (and of the
    # data's range).
    reference_low, reference_high = reference.confidence_interval
    tolerance = min(0.15 * (reference_high - reference_low), 0.02 * np.ptp(x))
    assert abs(low - reference_low) <= tolerance
    assert abs(high - reference_high) <= tolerance
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


# --- Paired (whole-run) bootstrap ---------------------------------------------------------------


PAIRED = _runs_with_tasks(np.random.default_rng(8), 48, 6, run_sd=20.0, noise_sd=5.0)
PAIRED_OTHER = _runs_with_tasks(np.random.default_rng(9), 48, 6, run_sd=20.0, noise_sd=5.0) + 3


@pytest.mark.parametrize("statistic", ["iqm", "mean", "median"])
def test_paired_interval_matches_whole_rows_resampled_by_hand(statistic):
    reduce = stats.STATISTICS[statistic]
    low, high = stats.bootstrap_ci(PAIRED, statistic, paired=True)
    reference = _whole_rows_by_hand(lambda table: reduce(table), [PAIRED])
    tolerance = 0.02 * np.ptp(PAIRED)
    assert abs(low - reference[0]) <= tolerance and abs(high - reference[1]) <= tolerance


def test_paired_improvement_interval_matches_the_same_rows_of_x_and_y_resampled_by_hand():
    low, high = stats.improvement_ci(PAIRED, PAIRED_OTHER, paired=True)
    reference = _whole_rows_by_hand(stats.probability_of_improvement, [PAIRED, PAIRED_OTHER])
    # P(improvement) ranges over [0, 1]: 2 % of it is 0.02.
    assert abs(low - reference[0]) <= 0.02 and abs(high - reference[1]) <= 0.02
    assert low < stats.probability_of_improvement(PAIRED, PAIRED_OTHER) < high


def test_paired_draws_whole_rows():
    # The mean of whole resampled rows is the mean of their row means, draw for draw.
    np.testing.assert_allclose(stats.bootstrap_ci(PAIRED, "mean", paired=True),
                               stats.bootstrap_ci(PAIRED.mean(axis=1), "mean"), rtol=1e-12)
    # One task has nothing to pair: both ways draw alike.
    one = SAMPLES["normal"]
    assert stats.bootstrap_ci(one, paired=True) == stats.bootstrap_ci(one)
    # Two copies of a column: the fraction above each tau is the single column's, resample by
    # resample, when both copies take the same rows; not when each draws its own.
    runs = SAMPLES["normal"][:64]
    twice = np.stack([runs, runs], axis=1)
    alone, paired = stats.performance_profile(runs), stats.performance_profile(twice, paired=True)
    np.testing.assert_array_equal(paired.low, alone.low)
    np.testing.assert_array_equal(paired.high, alone.high)
    assert not np.array_equal(stats.performance_profile(twice).low, alone.low)


def test_paired_draws_the_same_rows_of_every_setting():
    # A setting against itself: the same rows on both sides tie every resample at exactly 1/2;
    # independent rows do not.
    assert stats.improvement_ci(PAIRED, PAIRED, paired=True) == (0.5, 0.5)
    assert _width(stats.improvement_ci(PAIRED, PAIRED)) > 0.05
    # A setting 5 above another, run by run: every paired resample's IQMs differ by exactly 5, so
    # the interval is a point and 2 seeds would tell them apart.
    estimate = stats.seeds_needed([PAIRED, PAIRED + 5.0], paired=True)
    assert estimate.low == pytest.approx(5.0, rel=1e-12)
    assert estimate.high == pytest.approx(5.0, rel=1e-12)
    assert estimate.seeds == 2
    unpaired = stats.seeds_needed([PAIRED, PAIRED + 5.0])
    assert unpaired.high - unpaired.low > 5 and unpaired.seeds > 2
    matrix = stats.improvement_matrix([PAIRED, PAIRED_OTHER, PAIRED + 1.0], reps=500, paired=True)
    assert (matrix.low[0, 1], matrix.high[0, 1]) == stats.improvement_ci(
        PAIRED, PAIRED_OTHER, reps=500, paired=True)
    assert (matrix.low[0, 2], matrix.high[0, 2]) != stats.improvement_ci(
        PAIRED, PAIRED + 1.0, reps=500)


def test_paired_and_stratified_widths_on_independent_and_on_paired_tasks():
    rng = np.random.default_rng(10)
    x, y = rng.normal(100.0, 20.0, (256, 4)), rng.normal(100.0, 20.0, (256, 4))
    # Independent tasks: either way is right, so the widths agree (over 30 such tables the
    # ratios lay in [0.89, 1.17]).
    for paired, stratified in [
        (stats.bootstrap_ci(x, paired=True), stats.bootstrap_ci(x)),
        (stats.improvement_ci(x, y, paired=True), stats.improvement_ci(x, y)),
    ]:
        assert 0.8 < _width(paired) / _width(stratified) < 1.25
    # The same runs in 8 tasks, run effect sd 1, noise sd 0.3: the mean's variance is
    # (1 + 0.3^2 / 8) / R resampling runs, and (1 + 0.3^2) / (8 R) as if the tasks were
    # independent; the widths' ratio is sqrt(8 * 1.01125 / 1.09) = 2.7.
    table = _runs_with_tasks(rng, 64, 8, run_sd=1.0, noise_sd=0.3)
    ratio = _width(stats.bootstrap_ci(table, "mean", paired=True)) / _width(
        stats.bootstrap_ci(table, "mean"))
    assert 2.2 < ratio < 3.2


def _coverage(paired, studies=200, reps=1000):
    """How often the 95 % interval of P(X > Y) holds 1/2 over simulated studies of two equal
    settings with the same seeds: each run's own effect (sd 1) plays every task, and a seed's
    effect (sd 0.5) both settings, plus noise (sd 0.3) per score; 32 runs by 4 tasks."""
    rng = np.random.default_rng(11)
    covered = 0
    for study in range(studies):
        seed_effect = rng.normal(0.0, 0.5, (32, 1))
        x, y = (seed_effect + _runs_with_tasks(rng, 32, 4, 1.0, 0.3) for _ in range(2))
        low, high = stats.improvement_ci(x, y, reps=reps, seed=study, paired=paired)
        covered += low <= 0.5 <= high
    return covered / studies


def test_paired_improvement_interval_covers_equal_settings():
    # Over 1,500 such studies the paired intervals held 1/2 in 94.9 %.
    assert _coverage(paired=True) >= 0.93


def test_stratified_improvement_interval_misses_equal_settings_on_paired_tasks():
    # Treating one run's tasks as independent narrows the interval: over 1,500 studies it held
    # 1/2 in 74 % only.
    assert _coverage(paired=False, reps=500) < 0.85


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
    (lambda: stats.bootstrap_ci([1.0, 2.0], paired="runs"), "paired: must be True or False"),
    (lambda: stats.improvement_ci(np.ones((4, 3)), np.ones((5, 3)), paired=True),
     r"y: paired with x, expected its shape \(4, 3\)"),
    (lambda: stats.improvement_ci(np.ones(4), np.ones(5), paired=True), "y: paired with x"),
    (lambda: stats.improvement_ci(np.ones((0, 3)), np.ones((0, 3)), paired=True), "x: empty"),
    (lambda: stats.improvement_ci(np.ones((4, 3)), np.full((4, 3), np.nan), paired=True),
     "y: must be finite"),
    (lambda: stats.improvement_matrix([np.ones(4), np.ones(4), np.ones(3)], paired=True),
     r"scores\[2\]: paired with scores\[0\]"),
    (lambda: stats.seeds_needed([np.ones(4), np.ones(6)], paired=True),
     r"scores\[1\]: paired with scores\[0\]"),
    (lambda: stats.performance_profile([1.0, 2.0], paired=1), "paired"),
    (lambda: stats.improvement_ci([1.0, 2.0], [1e308, 0.0]), "y: magnitudes must be at most"),
    (lambda: stats.seeds_needed([[1.0, 2.0], [-1e308, 1.0]]), r"scores\[1\]: magnitudes"),
    # Not numbers, or not one array: numpy's own messages, which named no argument.
    (lambda: stats.iqm(["1", "2"]), "scores: must be a number"),
    (lambda: stats.mean([1j, 2.0]), "scores: must be a number"),
    (lambda: stats.median([True, False]), "scores: must be a number"),
    (lambda: stats.iqm([[1.0, 2.0], [3.0]]), "scores: must be numbers in rows of one length"),
    (lambda: stats.performance_profile([1.0, 2.0], taus=[1.0, [2.0]]),
     "taus: must be numbers in rows of one length"),
    (lambda: stats.iqm(np.ones((4, 2)), axis=1.0), r"axis: must be an integer in \[-2, 2\)"),
    (lambda: stats.mean(np.ones((4, 2)), axis=True), "axis: must be an integer"),
    (lambda: stats.median(np.ones(4), axis=2), "axis: must be an integer"),
    (lambda: stats.optimality_gap([1.0], "195"), "target: must be a number"),
    (lambda: stats.optimality_gap([1.0], True), "target: must be a number"),
    (lambda: stats.optimality_gap([1.0], None), "target: must be a number"),
    (lambda: stats.bootstrap_ci([1.0, 2.0], ["iqm"]), "statistic: expected 'iqm'"),
    (lambda: stats.bootstrap_ci([1.0, 2.0], lambda s, axis: s), "statistic: expected a function "
     r"f\(scores, axis\) giving one number per row"),
    (lambda: stats.performance_profile([1.0, 2.0], taus=[np.nan, 1.0]), "taus: must be finite"),
    (lambda: stats.performance_profile([1.0, 2.0], taus=["a"]), "taus: must be a number"),
    (lambda: stats.iqm_curve(np.ones((4, 2)), iterations=["a", "b"]), "iterations: must be a"),
    # Settings of other tasks: P(improvement) names the setting, seeds_needed compared them.
    (lambda: stats.improvement_matrix([np.ones((3, 2)), np.ones((3, 3))]),
     r"scores\[1\]: expected the tasks of scores\[0\], \(2,\), got shape \(3, 3\)"),
    (lambda: stats.seeds_needed([np.ones((3, 2)), np.ones((3, 3))]),
     r"scores\[1\]: expected the tasks of scores\[0\]"),
])
def test_bad_input_is_one_line_naming_the_argument(call, word):
    with pytest.raises(ValueError, match=f"^{word}") as error:
        call()
    assert "\n" not in str(error.value)


# The bound of 4 scores: float64's largest over 8 * 4, 1.7977e308 / 32 = 5.618e306.
BOUND_OF_4 = np.finfo(np.float64).max / 32


@pytest.mark.parametrize("statistic", ["iqm", "mean", "median"])
def test_scores_at_the_bound_give_finite_intervals_and_larger_ones_are_refused(statistic):
    """Values near float64's largest would sum to infinity: a statistic of them was NaN."""
    at_bound = BOUND_OF_4 * np.array([1.0, -1.0, 1.0, -1.0])
    assert np.all(np.isfinite(stats.bootstrap_ci(at_bound, statistic, reps=200)))
    assert np.all(np.isfinite(stats.bootstrap_ci(np.abs(at_bound), statistic, reps=200)))
    beyond = np.nextafter(BOUND_OF_4, np.inf) * np.array([1.0, -1.0, 1.0, -1.0])
    with pytest.raises(ValueError, match=r"^scores: magnitudes must be at most 5\.618e\+306 for 4 "
                       r"scores, so that the statistics' sums cannot overflow, got 5\.6177"):
        stats.bootstrap_ci(beyond, statistic, reps=200)
    with pytest.raises(ValueError, match=r"^scores: .* got 1e\+308$"):
        stats.bootstrap_ci([1e308, -1e308, 1e308, -1e308], statistic)


def test_an_aggregate_along_an_axis_bounds_the_scores_it_takes_together():
    scores = np.full((4, 2), BOUND_OF_4)  # 4 scores per task, 8 in all
    # 4 * BOUND_OF_4 / 4: scaled by powers of 2, exact.
    np.testing.assert_array_equal(stats.mean(scores, axis=0), [BOUND_OF_4, BOUND_OF_4])
    with pytest.raises(ValueError, match="^scores: magnitudes must be at most 2.809e\\+306 for 8 "):
        stats.mean(scores)  # 1.7977e308 / 64 = 2.809e306
