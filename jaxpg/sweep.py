"""Many training runs at once: seeds times a grid of learning rates and discounts, one program.

Every run of a sweep is the same compiled program as `train` runs alone, vmapped; seed i of a
sweep therefore trains exactly as `train(config, seed=i)`.
"""

import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg import progress, reinforce

GRID_FIELDS = ("learning_rate", "discount")
SOLVED_WINDOW = 10  # iterations averaged to decide whether a run is solved, as the book's last 10


class Summary(NamedTuple):
    """Statistics across seeds, per grid setting G, over iterations I."""

    median: np.ndarray  # [G, I] median over seeds of the iteration's mean return
    q25: np.ndarray  # [G, I] first quartile
    q75: np.ndarray  # [G, I] third quartile
    final_return: np.ndarray  # [G, S] mean return over the last SOLVED_WINDOW iterations
    fraction_solved: np.ndarray  # [G] share of seeds whose final_return reaches solved_return
    first_solved: np.ndarray  # [G, S] first iteration whose trailing-window mean reaches it; -1 never
    solved_by: np.ndarray  # [G, I] share of seeds solved at or before each iteration


class SweepResult(NamedTuple):
    """Every run of a sweep, `[G, S, ...]`: grid settings by seeds."""

    seeds: np.ndarray  # [S]
    grid: list  # G dicts {"learning_rate": ..., "discount": ...}
    policy_params: dict  # leaves [G, S, ...]
    metrics: reinforce.Metrics  # leaves [G, S, I]
    summary: Summary


def expand_grid(config, grid):
    """The grid's settings as a list of dicts; fields the grid leaves out keep `config`'s value."""
    grid = dict(grid or {})
    unknown = set(grid) - set(GRID_FIELDS)
    if unknown:
        raise ValueError(
            f"grid: unknown field(s) {', '.join(sorted(unknown))}; allowed: {', '.join(GRID_FIELDS)}"
        )
    values = []
    for name in GRID_FIELDS:
        options = list(np.atleast_1d(grid.get(name, getattr(config, name))).tolist())
        if not options:
            raise ValueError(f"grid: {name} needs at least one value")
        values.append(options)
    settings = [dict(zip(GRID_FIELDS, combo)) for combo in itertools.product(*values)]
    for setting in settings:
        reinforce.check_hyperparams(**setting)
    return settings


def check_seeds(seeds):
    """The seeds as a `[S]` uint32 array; a ValueError unless they are distinct integers in range."""
    seeds = np.asarray(list(seeds) if not isinstance(seeds, np.ndarray) else seeds)
    if seeds.ndim != 1 or seeds.size == 0 or not np.issubdtype(seeds.dtype, np.integer):
        raise ValueError("seeds: must be a non-empty sequence of integers")
    if seeds.min() < 0 or seeds.max() >= 2**32:
        raise ValueError("seeds: must lie in [0, 2**32)")
    if np.unique(seeds).size != seeds.size:
        raise ValueError("seeds: must be distinct")
    return seeds.astype(np.uint32)


def sweep(config=reinforce.TrainConfig(), seeds=range(64), grid=None, show_progress=True):
    """Trains every seed under every grid setting in one compiled program.

    Args:
      config: the `TrainConfig` every run shares.
      seeds: S distinct integer seeds.
      grid: optional `{"learning_rate": [...], "discount": [...]}`; the runs are its product.

    Returns:
      `SweepResult` with `[G, S, ...]` leaves and the `Summary`.
    """
    seeds = check_seeds(seeds)
    settings = expand_grid(config, grid)
    num_settings, num_seeds = len(settings), seeds.size
    # Runs are laid out setting-major: run g * S + s is seed s under setting g.
    keys = jnp.tile(reinforce.run_keys(seeds), (num_settings, 1))
    hyperparams = reinforce.Hyperparams(
        *(
            jnp.repeat(jnp.asarray([s[name] for s in settings], jnp.float32), num_seeds)
            for name in GRID_FIELDS
        )
    )
    with progress.bar(config.iterations, enabled=show_progress):
        result = reinforce.compiled_program(config, show_progress)(keys, hyperparams)
        result = jax.device_get(result)
    result = jax.tree.map(lambda leaf: leaf.reshape(num_settings, num_seeds, *leaf.shape[1:]), result)
    summary = summarize(result.metrics.mean_return, config.solved_return)
    return SweepResult(seeds, settings, result.policy_params, result.metrics, summary)


def summarize(mean_return, solved_return):
    """Summary statistics of `[G, S, I]` per-iteration mean returns."""
    mean_return = np.asarray(mean_return, dtype=np.float64)
    q25, median, q75 = np.percentile(mean_return, [25, 50, 75], axis=1)
    window = min(SOLVED_WINDOW, mean_return.shape[-1])
    # Trailing means over full windows: trailing[..., i] averages iterations i - window + 1 .. i.
    cumsum = np.cumsum(mean_return, axis=-1)
    trailing = np.full(mean_return.shape, -np.inf)
    trailing[..., window - 1 :] = (
        cumsum[..., window - 1 :]
        - np.concatenate([np.zeros_like(cumsum[..., :1]), cumsum[..., :-window]], axis=-1)
    ) / window
    reached = trailing >= solved_return
    first_solved = np.where(reached.any(axis=-1), reached.argmax(axis=-1), -1)
    final_return = trailing[..., -1]
    iterations = np.arange(mean_return.shape[-1])
    solved_by = ((first_solved[..., None] >= 0) & (first_solved[..., None] <= iterations)).mean(axis=1)
    return Summary(
        median=median,
        q25=q25,
        q75=q75,
        final_return=final_return,
        fraction_solved=(final_return >= solved_return).mean(axis=1),
        first_solved=first_solved,
        solved_by=solved_by,
    )
