"""Statistics that tell settings apart: IQM, bootstrap confidence intervals, P(improvement).

The methods are those of Agarwal et al., "Deep Reinforcement Learning at the Edge of the
Statistical Precipice" (NeurIPS 2021), as their rliable library computes them, written here with
numpy and scipy alone.

Scores are `[R]` (one score per run) or `[R, T]` (runs by tasks, e.g. physics settings). With tasks,
an aggregate is taken over all `R * T` scores together, and the bootstrap resamples runs in one of
two ways, chosen by `paired`:

- `paired=False`, the default: each task draws its own runs (rliable's stratified bootstrap). It
  holds where each task's runs are independent of the other tasks' (each task trained its own).
- `paired=True`: a resample draws run indices once and takes those whole rows in every task and
  in every table compared (`improvement_ci`'s x and y, `improvement_matrix`'s settings): row r is
  one run (one seed) throughout. Use it where the same runs play every task, as a `robustness`
  table's policies play every physics setting: a policy's scores rise and fall together over the
  settings, and resampling each setting on its own, as if they were independent, narrows the
  interval several times over. It holds for independent tasks too, at about the stratified
  width, but needs the same runs in every table.

Scores must be finite, and no larger in magnitude than float64's largest number over 8 times the
scores an aggregate takes together (about 2e301 for a million), so that no statistic here
overflows; larger ones are refused.

`iqm_curve` always resamples whole runs (their curves). Every bootstrap is seeded, so a report is
reproducible, and vectorised: the resamples are drawn and reduced as one array, in chunks that
bound the memory.

Intervals are percentile intervals: the `(1 - confidence) / 2` and `(1 + confidence) / 2`
quantiles of the statistic over the resamples (linear interpolation, as `np.percentile`).
"""

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, cast

import numpy as np
import numpy.typing as npt
import scipy.stats

from jaxpg.validation import check_bool, check_finite, check_int, check_number, shown

# Resampled scores held at once (float64, plus as many int64 indices): 32 MiB each.
_CHUNK_SCORES = 2**22
PROFILE_POINTS = 101  # performance_profile's default thresholds

# An aggregate of scores: a float over all of them (`axis=None`), an array over one axis.
Aggregate = np.ndarray | float
# What `bootstrap_ci` reduces each resample with: a name of `STATISTICS`, or a function
# `f(scores, axis)` as `np.mean`.
Statistic = str | Callable[..., Aggregate]


# --- Aggregates ----------------------------------------------------------------------------------


def iqm(scores: np.ndarray, axis: int | None = None) -> Aggregate:
    """The interquartile mean: the mean of the scores left once the lowest and highest 25 % are cut.

    As `scipy.stats.trim_mean(scores, 0.25, axis)`: `floor(0.25 * n)` scores are cut at each end,
    so for n not divisible by 4 slightly more than the middle half is kept.

    Args:
      scores: `[R]` or `[R, T]` scores.
      axis: None for the aggregate over all scores; an axis to reduce only that one (0: per task).

    Returns:
      A float for `axis=None`, otherwise the array without `axis`.
    """
    return scipy.stats.trim_mean(_check_scores(scores, axis=axis), 0.25, axis=axis)


def mean(scores: np.ndarray, axis: int | None = None) -> Aggregate:
    """The mean score.

    Args:
      scores: `[R]` or `[R, T]` scores.
      axis: None for the aggregate over all scores; an axis to reduce only that one.

    Returns:
      A float for `axis=None`, otherwise the array without `axis`.
    """
    return np.mean(_check_scores(scores, axis=axis), axis=axis)


def median(scores: np.ndarray, axis: int | None = None) -> Aggregate:
    """The median score; its arguments and result are those of `mean`."""
    return np.median(_check_scores(scores, axis=axis), axis=axis)


def optimality_gap(scores: np.ndarray, target: float, axis: int | None = None) -> Aggregate:
    """The mean shortfall from `target`: `target - mean(min(scores, target))`.

    Scores above the target count as the target, so going beyond it earns nothing; 0 means every
    run reached it.

    Args:
      scores: `[R]` or `[R, T]` scores.
      target: the score that counts as solved, e.g. `TrainConfig.solved_return`.
      axis: None for the aggregate over all scores; an axis to reduce only that one.

    Returns:
      A float for `axis=None`, otherwise the array without `axis`.

    Raises:
      ValueError: for a `target` that is not one finite number (`check_number`), or scores that
        are empty or not finite.
    """
    target = check_number("target", target)
    return target - np.mean(np.minimum(_check_scores(scores, axis=axis), target), axis=axis)


STATISTICS: dict[str, Callable[..., Aggregate]] = {"iqm": iqm, "mean": mean, "median": median}


# --- Confidence intervals ------------------------------------------------------------------------


def bootstrap_ci(
    scores: np.ndarray,
    statistic: Statistic = "iqm",
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
    paired: bool = False,
) -> tuple[float, float]:
    """A percentile bootstrap confidence interval of an aggregate of the scores.

    Args:
      scores: `[R]` scores, or `[R, T]`: the statistic is then taken over all `R * T` resampled
        scores together.
      statistic: "iqm", "mean", "median", or a function `f(scores, axis)` reducing `axis` of a
        float array as `np.mean` does; it is called once per chunk of resamples with a
        `[B, R * T]` array and `axis=-1`, and returns `[B]`.
      confidence: the interval's coverage, in (0, 1).
      reps: how many resamples.
      seed: seeds the resampling, so the same call gives the same interval.
      paired: False (the default) draws each task's runs on its own (stratified), for tasks whose
        runs are independent; True draws whole rows, for `[R, T]` scores whose row r is one run in
        every task (a `robustness` table). `[R]` scores are resampled alike either way.

    Returns:
      (low, high) floats.

    Raises:
      ValueError: for scores that are empty or not finite, fewer than 2 runs, a `confidence`
        outside (0, 1), a `reps` below 1, a negative `seed`, an unknown `statistic` or a
        `paired` that is not a bool.
    """
    reduce = _statistic(statistic)
    scores = _check_interval_args(scores, confidence, reps)
    replicates = _replicates(scores, _aggregate(reduce), reps, _rng(seed),
                             check_bool("paired", paired))
    return _interval(replicates, confidence)


# --- Probability of improvement -----------------------------------------------------------------


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y): how likely a run of setting x scores above a run of setting y, ties counting half.

    That is the Mann-Whitney U statistic of x over the number of pairs, `U / (n m)`. With tasks,
    the probability of each task is averaged over the tasks (as rliable does).

    Args:
      x: `[n]` or `[n, T]` scores of one setting.
      y: `[m]` or `[m, T]` scores of the other, with the same tasks.

    Returns:
      A float in [0, 1]; 0.5 for settings that cannot be told apart.
    """
    x_codes, y_codes, distinct = _codes(*_check_pair(x, y))
    return float(_improvement(x_codes[None], y_codes[None], distinct)[0])


def improvement_ci(
    x: np.ndarray,
    y: np.ndarray,
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
    paired: bool = False,
) -> tuple[float, float]:
    """A percentile bootstrap confidence interval of `probability_of_improvement(x, y)`.

    Args:
      x: `[n]` or `[n, T]` scores of one setting, n >= 2.
      y: `[m]` or `[m, T]` scores of the other, with the same tasks, m >= 2.
      confidence: the interval's coverage, in (0, 1).
      reps: how many resamples.
      seed: seeds the resampling.
      paired: False (the default) resamples the runs of x and of y independently, within each
        task (stratified); True draws run indices once per resample and takes those whole rows of
        x and of y, for x and y of one shape whose runs play every task (`robustness` tables).
        Row r of x and of y may be one seed (then drawn together, as it should be) or two
        independent runs.

    Returns:
      (low, high) floats.

    Raises:
      ValueError: as `bootstrap_ci`'s, naming x or y, for x and y with other tasks, and with
        `paired`, for x and y of other shapes.
    """
    x, y = _check_pair(x, y)
    _check_interval_args(x, confidence, reps, name="x")
    _check_interval_args(y, confidence, reps, name="y")
    rng_x, rng_y = _generators(seed, paired, {"x": x, "y": y})
    # Resampling the scores' codes resamples the scores; P(X > Y) needs only their order.
    x_codes, y_codes, distinct = _codes(x, y)
    replicates = np.concatenate([
        _improvement(_resample(x_codes, rng_x, count, paired),
                     _resample(y_codes, rng_y, count, paired), distinct)
        for count in _chunk_counts(reps, x.size + y.size)
    ])
    return _interval(replicates, confidence)


class ImprovementMatrix(NamedTuple):
    """P(row's setting > column's setting) for every pair, with confidence intervals, `[G, G]`."""

    probability: np.ndarray  # [G, G]; the diagonal is 0.5, a setting against itself
    low: np.ndarray  # [G, G] lower bounds; 0.5 on the diagonal
    high: np.ndarray  # [G, G] upper bounds; 0.5 on the diagonal


def improvement_matrix(
    scores: Sequence[np.ndarray],
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
    paired: bool = False,
) -> ImprovementMatrix:
    """`probability_of_improvement` and `improvement_ci` of every setting over every other.

    Each pair is computed once: P(y > x) is 1 - P(x > y) with ties counting half, and the
    interval of (y, x) is (1 - high, 1 - low) of (x, y).

    Args:
      scores: G arrays of `[n_g]` or `[n_g, T]` scores, one per setting (the runs may differ
        unless `paired`).
      confidence: the intervals' coverage, in (0, 1).
      reps: resamples per pair.
      seed: seeds the resampling of every pair.
      paired: False (the default) resamples each setting's runs independently, within each task;
        True draws the same whole rows of every setting, as `improvement_ci(paired=True)`, for
        settings of one shape whose row r is one run (one seed) throughout.

    Returns:
      `ImprovementMatrix` of `[G, G]` arrays.
    """
    scores = _check_settings(scores)
    if check_bool("paired", paired):
        _check_same_runs({f"scores[{g}]": s for g, s in enumerate(scores)})
    size = len(scores)
    probability, low, high = (np.full((size, size), 0.5) for _ in range(3))
    for i in range(size):
        for j in range(i + 1, size):
            probability[i, j] = probability_of_improvement(scores[i], scores[j])
            low[i, j], high[i, j] = improvement_ci(
                scores[i], scores[j], confidence, reps, seed, paired)
            probability[j, i], low[j, i], high[j, i] = (
                1 - probability[i, j], 1 - high[i, j], 1 - low[i, j])
    return ImprovementMatrix(probability, low, high)


# --- Profiles and curves -------------------------------------------------------------------------


class Band(NamedTuple):
    """A curve with a pointwise confidence band."""

    x: np.ndarray  # [P] where the curve is evaluated: score thresholds or iterations
    estimate: np.ndarray  # [P]
    low: np.ndarray  # [P]
    high: np.ndarray  # [P]


def performance_profile(
    scores: np.ndarray,
    taus: np.ndarray | None = None,
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
    paired: bool = False,
) -> Band:
    """The fraction of runs scoring above tau, for each tau, with bootstrap confidence bands.

    Args:
      scores: `[R]` or `[R, T]` scores, R >= 2; with tasks, the fraction of all `R * T` scores.
      taus: `[P]` thresholds; by default 101 evenly spaced from the lowest score to the highest.
      confidence: the bands' coverage, in (0, 1).
      reps: how many resamples.
      seed: seeds the resampling.
      paired: False (the default) draws each task's runs on its own (stratified), for tasks whose
        runs are independent; True draws whole rows, for `[R, T]` scores whose row r is one run in
        every task (a `robustness` table). `[R]` scores are resampled alike either way.

    Returns:
      `Band` over the `[P]` taus: the fraction of scores strictly above each, and its interval.
    """
    scores = _check_interval_args(scores, confidence, reps)
    if taus is None:
        taus = np.linspace(scores.min(), scores.max(), PROFILE_POINTS)
    taus = check_finite("taus", taus).astype(np.float64)
    if taus.ndim != 1 or taus.size == 0:
        raise ValueError(f"taus: expected a non-empty [P] array, got shape {taus.shape}")

    def above(flat: np.ndarray) -> np.ndarray:
        """The fraction of each row of `[..., N]` scores above each tau: `[..., P]`."""
        # One threshold at a time keeps memory at one [B, R * T] comparison.
        return np.stack([(flat > tau).mean(axis=-1) for tau in taus], axis=-1)

    replicates = _replicates(scores, lambda sample: above(_flat(sample)), reps, _rng(seed),
                             check_bool("paired", paired))
    return Band(taus, above(scores.ravel()), *_interval(replicates, confidence))


def iqm_curve(
    scores: np.ndarray,
    iterations: np.ndarray | None = None,
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
) -> Band:
    """The IQM over runs at each iteration, with bootstrap confidence bands: sample efficiency.

    A run's whole curve is resampled as one (runs are the independent units, iterations are not).

    Args:
      scores: `[R, I]` a score per run and iteration, e.g. the mean return of each iteration,
        R >= 2.
      iterations: `[I]` the iteration numbers of the columns, for `Band.x`; by default 1 to I.
      confidence: the bands' coverage, in (0, 1).
      reps: how many resamples.
      seed: seeds the resampling.

    Returns:
      `Band` over the I iterations.
    """
    scores = _check_interval_args(scores, confidence, reps)
    if scores.ndim != 2:
        raise ValueError(f"scores: expected [runs, iterations], got shape {scores.shape}")
    iterations = (np.arange(1, scores.shape[1] + 1) if iterations is None
                  else check_finite("iterations", iterations))
    if iterations.shape != scores.shape[1:]:
        raise ValueError(f"iterations: expected shape {scores.shape[1:]} (a number per column of "
                         f"scores), got {iterations.shape}")
    replicates = _replicates(scores, _iqm_over_runs, reps, _rng(seed), whole_rows=True)
    per_iteration = cast(np.ndarray, iqm(scores, axis=0))  # an axis given: an array
    return Band(iterations, per_iteration, *_interval(replicates, confidence))


def _iqm_over_runs(sample: np.ndarray) -> np.ndarray:
    """The IQM over axis 1 of `[B, R, I]` resamples: `[B, I]`, as `trim_mean(sample, 0.25, 1)`."""
    runs = sample.shape[1]
    cut = runs // 4
    # A full sort: faster here than np.partition with two kth (docs/performance.md).
    return np.sort(sample, axis=1)[:, cut : runs - cut].mean(axis=1)


# --- How many seeds -------------------------------------------------------------------------------


class SeedsEstimate(NamedTuple):
    """How many seeds would tell the two best settings apart (`seeds_needed`)."""

    best: int  # index of the setting with the highest IQM
    second: int  # index of the runner-up
    difference: float  # IQM(best) - IQM(second), >= 0
    low: float  # lower bound of the difference's confidence interval with the runs at hand
    high: float  # its upper bound
    seeds: int | None  # seeds per setting for the interval to exclude 0; None: the IQMs are equal


def seeds_needed(
    scores: Sequence[np.ndarray],
    confidence: float = 0.95,
    reps: int = 2000,
    seed: int = 0,
    paired: bool = False,
) -> SeedsEstimate:
    """Estimates the seeds per setting at which the two best settings' IQMs would differ clearly.

    Method: the two settings of highest IQM are resampled (independently, or at the same run
    indices where `paired`), and d = IQM(best) - IQM(second) is bootstrapped. Assuming the spread
    of a setting's IQM over resamples shrinks as 1/sqrt(runs), with n' runs each the bootstrap
    difference would be `d + (sqrt(n_best) e_best - sqrt(n_second) e_second) / sqrt(n')`, where e
    are the resamples' deviations from their IQM. Its lower percentile bound is
    `d + q / sqrt(n')`, with q the same percentile of the numerator, so it exceeds 0 from
    `n' = floor((q / d)^2) + 1` on. With equal runs n this is `n (w / d)^2` for w the current
    interval's lower half-width: the interval scaled by sqrt(n / n'). It is a guide, not a
    promise: a new sweep gives another d.

    Args:
      scores: G >= 2 arrays of `[n_g]` or `[n_g, T]` scores, one per setting, n_g >= 2.
      confidence: the interval's coverage, in (0, 1).
      reps: how many resamples.
      seed: seeds the resampling.
      paired: False (the default) resamples each setting's runs independently, within each task;
        True draws the same whole rows of both settings, as `improvement_ci(paired=True)`, for
        settings of one shape whose row r is one run (one seed) throughout.

    Returns:
      `SeedsEstimate`; `seeds` is at least 2, or None when the two IQMs are equal.
    """
    scores = _check_settings(scores)
    if len(scores) < 2:
        raise ValueError(f"scores: expected at least 2 settings to compare, got {len(scores)}")
    for g, setting in enumerate(scores):
        _check_interval_args(setting, confidence, reps, name=f"scores[{g}]")
    estimates = np.array([iqm(s) for s in scores])
    second, best = np.argsort(estimates, kind="stable")[-2:]
    difference = float(estimates[best] - estimates[second])
    rngs = _generators(seed, paired, {f"scores[{g}]": s for g, s in enumerate(scores)})
    # How far each resample's IQM falls from the setting's IQM: [reps] per setting.
    deviations = [_replicates(scores[g], _aggregate(iqm), reps, rng, paired) - estimates[g]
                  for g, rng in zip((best, second), rngs)]
    low, high = _interval(difference + deviations[0] - deviations[1], confidence)
    per_run = sum(sign * math.sqrt(scores[g].shape[0]) * deviation
                  for sign, g, deviation in zip((1, -1), (best, second), deviations))
    q = _interval(per_run, confidence)[0]
    needed = None
    if difference > 0:
        needed = 2 if q >= 0 else max(2, math.floor((q / difference) ** 2) + 1)
    return SeedsEstimate(int(best), int(second), difference, low, high, needed)


# --- Resampling ---------------------------------------------------------------------------------


def _chunk_counts(reps: int, scores_per_resample: int) -> list[int]:
    """Splits `reps` resamples into chunks of at most `_CHUNK_SCORES` scores (at least 1 each)."""
    per_chunk = max(1, _CHUNK_SCORES // scores_per_resample)
    return [min(per_chunk, reps - start) for start in range(0, reps, per_chunk)]


def _resample(
    scores: np.ndarray, rng: np.random.Generator, count: int, whole_rows: bool = False
) -> np.ndarray:
    """`count` resamples of the runs (rows) of `[R]` or `[R, T]` scores: `[count, R]` or
    `[count, R, T]`.

    By default each column (task) draws its own runs; with `whole_rows`, a drawn run brings its
    whole row (its scores in every task, or its curve over iterations).
    """
    runs = scores.shape[0]
    if whole_rows or scores.ndim == 1:
        return scores[rng.integers(0, runs, (count, runs))]
    tasks = scores.shape[1]
    return scores[rng.integers(0, runs, (count, runs, tasks)), np.arange(tasks)]


def _replicates(
    scores: np.ndarray,
    reduce: Callable[[np.ndarray], np.ndarray],
    reps: int,
    rng: np.random.Generator,
    whole_rows: bool = False,
) -> np.ndarray:
    """`reduce` of `reps` resamples of `scores`, concatenated over chunks: `[reps, ...]`."""
    return np.concatenate([
        reduce(_resample(scores, rng, count, whole_rows))
        for count in _chunk_counts(reps, scores.size)
    ])


def _aggregate(reduce: Callable[..., Any]) -> Callable[[np.ndarray], np.ndarray]:
    """`reduce(scores, axis)` over all scores of each resample, `[B, R]` or `[B, R, T]` -> `[B]`."""
    return lambda sample: reduce(_flat(sample), axis=-1)


def _flat(sample: np.ndarray) -> np.ndarray:
    """`[B, R]` or `[B, R, T]` resamples as `[B, R * T]`: an aggregate takes all scores together."""
    return sample.reshape(sample.shape[0], -1)


def _codes(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Each task's scores of x and y as the ranks of their values among the task's distinct values.

    Returns:
      (`[n, T]` and `[m, T]` integer codes, `[T]` how many distinct values each task has).
    """
    x, y = x.reshape(x.shape[0], -1), y.reshape(y.shape[0], -1)
    x_codes, y_codes = np.empty(x.shape, np.int64), np.empty(y.shape, np.int64)
    distinct = []
    for t in range(x.shape[1]):
        values, codes = np.unique(np.concatenate([x[:, t], y[:, t]]), return_inverse=True)
        x_codes[:, t], y_codes[:, t] = codes[: x.shape[0]], codes[x.shape[0] :]
        distinct.append(values.size)
    return x_codes, y_codes, distinct


def _improvement(x_codes: np.ndarray, y_codes: np.ndarray, distinct: Sequence[int]) -> np.ndarray:
    """P(X > Y) of `[B, n, T]` against `[B, m, T]` codes (`_codes`), averaged over tasks: `[B]`.

    Counting, not comparing pairs: with h_x and h_y how many of a resample's x and y hold each
    code, U = sum over codes k of h_x[k] (#{y below k} + h_y[k] / 2), in O(B (n + m + K)).
    """
    n, m = x_codes.shape[1], y_codes.shape[1]
    u = 0.0
    for t, size in enumerate(distinct):
        h_x, h_y = _histograms(x_codes[..., t], size), _histograms(y_codes[..., t], size)
        below = np.cumsum(h_y, axis=1) - h_y
        u = u + (h_x * (below + h_y / 2)).sum(axis=1)
    return u / (len(distinct) * n * m)


def _histograms(codes: np.ndarray, size: int) -> np.ndarray:
    """How often each code 0..size-1 occurs in each row of `[B, n]` codes: `[B, size]`."""
    rows = codes.shape[0]
    offsets = size * np.arange(rows)[:, None]
    return np.bincount((codes + offsets).ravel(), minlength=rows * size).reshape(rows, size)


def _interval(replicates: np.ndarray, confidence: float) -> tuple[Any, Any]:
    """The percentile interval over the first axis of `replicates`: (low, high), floats for
    `[reps]` replicates, `[...]` arrays for `[reps, ...]`."""
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(replicates, [tail, 100 - tail], axis=0)
    return (float(low), float(high)) if np.ndim(low) == 0 else (low, high)


# --- Checks -------------------------------------------------------------------------------------


def _check_scores(scores: npt.ArrayLike, name: str = "scores", axis: int | None = None
                  ) -> np.ndarray:
    """`scores` as a float64 `[R]` or `[R, T]` array; a ValueError unless an array of finite
    numbers (`check_finite`: not bools, strings or rows of other lengths), non-empty, and of
    magnitudes at most `_max_score` of the scores that one aggregate takes together: all of them,
    or those along `axis`, an integer naming one of their axes."""
    scores = check_finite(name, scores).astype(np.float64)
    if scores.ndim not in (1, 2):
        raise ValueError(f"{name}: expected [runs] or [runs, tasks], got shape {scores.shape}")
    if scores.size == 0:
        raise ValueError(f"{name}: empty, expected at least one score")
    count = scores.size if axis is None else scores.shape[
        check_int("axis", axis, -scores.ndim, scores.ndim)]
    largest, limit = np.abs(scores).max(), _max_score(count)
    if largest > limit:
        raise ValueError(f"{name}: magnitudes must be at most {limit:.4g} for {count} scores, "
                         f"so that the statistics' sums cannot overflow, got {float(largest)!r}")
    return scores


def _max_score(count: int) -> float:
    """The largest magnitude of `count` scores whose statistics cannot overflow float64.

    The statistics here sum at most `count` scores, take differences of two such means,
    interpolate between them, and (`seeds_needed`) scale such a difference by the square root of
    the runs: with every score at most `float64 max / (8 count)`, none of these exceeds half of
    float64's largest number. A function given as `statistic` is on its own.

    Args:
      count: how many scores, `R * T`.

    Returns:
      The bound: about 2.2e307 for one score, 2.2e301 for a million.
    """
    return float(np.finfo(np.float64).max / (8 * count))


def _check_interval_args(
    scores: npt.ArrayLike, confidence: float, reps: int, name: str = "scores"
) -> np.ndarray:
    """The checked scores; a ValueError for fewer than 2 runs, or a bad confidence or reps."""
    scores = _check_scores(scores, name)
    if scores.shape[0] < 2:
        raise ValueError(
            f"{name}: a confidence interval needs at least 2 runs, got {scores.shape[0]}")
    if not 0 < check_number("confidence", confidence) < 1:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence!r}")
    check_int("reps", reps)
    return scores


def _rng(seed: int) -> np.random.Generator:
    """The generator of a bootstrap; a ValueError unless `seed` is a non-negative integer."""
    return np.random.default_rng(check_int("seed", seed, 0))


def _generators(
    seed: int, paired: bool, tables: dict[str, np.ndarray]
) -> tuple[np.random.Generator, np.random.Generator]:
    """The generators that resample two of `tables` (named by their arguments), one after the other.

    Unpaired, both are one generator. Paired, the tables must have one shape, and the generators
    are two in one state: resampling whole rows of either draws the same run indices.
    """
    if not check_bool("paired", paired):
        rng = _rng(seed)
        return rng, rng
    _check_same_runs(tables)
    return _rng(seed), _rng(seed)


def _check_same_runs(tables: dict[str, np.ndarray]) -> None:
    """A ValueError naming the first table, by its argument, whose shape is not the first's."""
    (first, shape), *others = ((name, table.shape) for name, table in tables.items())
    for name, other in others:
        if other != shape:
            raise ValueError(f"{name}: paired with {first}, expected its shape {shape} (the same "
                             f"runs and tasks), got {other}")


def _check_pair(x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """x and y checked (`_check_scores`); a ValueError unless they have the same tasks."""
    x, y = _check_scores(x, "x"), _check_scores(y, "y")
    if x.shape[1:] != y.shape[1:]:
        raise ValueError(f"y: expected the tasks of x, {x.shape[1:]}, got shape {y.shape}")
    return x, y


def _check_settings(scores: Sequence[npt.ArrayLike]) -> list[np.ndarray]:
    """Every setting's scores checked (`_check_scores`); a ValueError for no setting, or for
    one whose tasks are not the first's."""
    checked = [_check_scores(s, f"scores[{g}]") for g, s in enumerate(scores)]
    if not checked:
        raise ValueError("scores: expected at least one setting, got none")
    for g, setting in enumerate(checked[1:], 1):
        if setting.shape[1:] != checked[0].shape[1:]:
            raise ValueError(f"scores[{g}]: expected the tasks of scores[0], "
                             f"{checked[0].shape[1:]}, got shape {setting.shape}")
    return checked


def _statistic(statistic: Statistic) -> Callable[..., Aggregate]:
    """The function that `statistic` names, or `statistic` itself where it is one, checked as it
    reduces each chunk of resamples (`_one_per_resample`)."""
    if callable(statistic):
        return functools.partial(_one_per_resample, statistic)
    if isinstance(statistic, str) and statistic in STATISTICS:
        return STATISTICS[statistic]
    raise ValueError(
        f"statistic: expected 'iqm', 'mean', 'median' or a function, got {shown(statistic)}"
    )


def _one_per_resample(statistic: Callable[..., Aggregate], sample: np.ndarray, axis: int
                      ) -> np.ndarray:
    """`statistic(sample, axis)` of `[B, N]` resamples: a ValueError unless it is `[B]` numbers,
    one per resample, as `np.mean(sample, axis=-1)` gives."""
    reduced = np.asarray(statistic(sample, axis=axis))
    if reduced.shape != sample.shape[:1] or reduced.dtype.kind not in "iuf":
        raise ValueError(f"statistic: expected a function f(scores, axis) giving one number per "
                         f"row of [B, N] scores, as np.mean does: [{sample.shape[0]}] for shape "
                         f"{sample.shape}, got {reduced.dtype} of shape {reduced.shape}")
    return reduced
