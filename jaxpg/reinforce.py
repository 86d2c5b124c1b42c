"""Training one policy: `train`, and what it shares with sweeps on the host.

One iteration plays `episodes` episodes of at most `max_steps` steps with the current policy,
discounts the rewards and takes one optimizer step on the loss (`jaxpg.iteration`). Iterations
of many runs together are one compiled program (`jaxpg.programs`), which the host calls for up to
`programs.ITERATIONS_PER_CALL` iterations at a time (`jaxpg.schedule`), showing progress as they
complete.
"""

import warnings
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from jaxpg import budget, policies, programs, progress, schedule, xla_options
from jaxpg.iteration import Metrics, TrainResult
from jaxpg.train_config import TrainConfig
from jaxpg.types import ArrayLike, HostArray, Params
from jaxpg.validation import check_int


def run_keys(seeds: ArrayLike | Sequence[int]) -> HostArray:
    """One PRNG key per seed, made on the host: `jax.random.PRNGKey(seed)` of each.

    Threefry's key of a 32-bit seed is its high word (0) and the seed itself.

    Args:
      seeds: integers `[R]` in [0, 2**32).

    Returns:
      uint32 `[R, 2]`, a numpy array.
    """
    seeds = np.asarray(seeds, dtype=np.uint32)
    return np.stack([np.zeros_like(seeds), seeds], axis=-1)


# A frozen dataclass: one default instance is safe to share.
def train(config: TrainConfig = TrainConfig(), seed: int = 0,
          init_params: Params | None = None,
          on_iteration: Callable[[int, Metrics], None] | None = None,
          show_progress: bool = True) -> TrainResult:
    """Trains one policy.

    Args:
      config: the `TrainConfig`.
      seed: an integer in [0, 2**32): the run's key is `jax.random.PRNGKey(seed)`.
      init_params: optional policy parameters to start from (a checkpoint's), shaped as the
        policy's own; the optimizer starts afresh.
      on_iteration: optional `(iteration, metrics) -> None`, called on the host as iterations
        complete, in order, with that iteration's `Metrics` (scalar leaves).
      show_progress: print progress lines on stderr.

    Returns:
      `TrainResult`: the final `policy_params` and `Metrics` with `[iterations]` leaves.

    Raises:
      ValueError: for a config that is not a `TrainConfig`, a seed out of range, training that
        needs more memory than the machine's (`budget.check`), or `init_params` not shaped as
        the policy's parameters; each before anything compiles.
    """
    if not isinstance(config, TrainConfig):
        raise ValueError(f"config: expected a TrainConfig, got {type(config).__name__}")
    check_int("seed", seed, 0, 2**32)
    budget.check(config)
    xla_options.configure_unstarted()
    hyperparams = config.hyperparams.per_run()
    program = programs.compiled_program(config, physics_in_runs=hyperparams.env is not None)
    if init_params is not None:
        init_params = check_init_params(config, init_params)
    first_run = None if on_iteration is None else (
        lambda i, metrics: on_iteration(i, jax.tree.map(lambda leaf: leaf[0], metrics)))
    with progress.bar(config.iterations, enabled=show_progress) as shown:
        (result,) = schedule.train_blocks(
            program, config.iterations, [(run_keys([seed]), hyperparams)],
            progress.together(shown, first_run), init_params)
    result = jax.tree.map(lambda leaf: leaf[0], result)
    warn_if_diverged(jax.tree.map(lambda leaf: leaf[None], result.metrics))
    return result


def check_init_params(config: TrainConfig, init_params: Params) -> Params:
    """`init_params` as numpy arrays of the policy's dtypes, checked against the policy's shapes.

    Args:
      config: the `TrainConfig` whose policy (`TrainConfig.network`) they are for.
      init_params: one run's policy parameters.

    Returns:
      The parameters as numpy arrays.

    Raises:
      ValueError: unless they have the tree and shapes of the policy's own parameters
        (`jax.eval_shape` of its `init`).
    """
    want = jax.eval_shape(lambda key: policies.init_network(key, config.network),
                          jax.ShapeDtypeStruct((2,), np.uint32))
    try:
        params = jax.tree.map(lambda w, leaf: np.asarray(leaf, w.dtype), want, init_params)
        matches = all(w.shape == p.shape for w, p in zip(jax.tree.leaves(want),
                                                         jax.tree.leaves(params)))
    except (TypeError, ValueError):
        matches = False
    if not matches:
        raise ValueError(f"init_params: expected the policy's parameters, shaped "
                         f"{jax.tree.map(lambda leaf: leaf.shape, want)}")
    return params


def first_nonfinite(metrics: Metrics) -> HostArray:
    """The first iteration of each run whose loss or gradient norm is not finite.

    The parameters take a non-finite gradient's step, so this is also where they may stop being
    finite.

    Args:
      metrics: `Metrics` with `[..., I]` leaves.

    Returns:
      ints `[...]`: each run's first such iteration, -1 where there is none.
    """
    bad = ~(np.isfinite(metrics.loss) & np.isfinite(metrics.grad_norm))
    return np.where(bad.any(axis=-1), bad.argmax(axis=-1), -1)


def warn_if_diverged(metrics: Metrics, labels: Sequence[Any] | None = None) -> None:
    """Warns, with a `RuntimeWarning`, once per run that diverged (`first_nonfinite`).

    Args:
      metrics: `Metrics` with `[R, I]` leaves.
      labels: optional: how each run's warning names it (` of {label}`).
    """
    for r, first in enumerate(first_nonfinite(metrics)):
        if first >= 0:
            which = "" if labels is None else f" of {labels[r]}"
            warnings.warn(f"training{which} diverged: the loss or its gradient is not finite "
                          f"from iteration {first} on (counted from 0)", RuntimeWarning,
                          stacklevel=3)
