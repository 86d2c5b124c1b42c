"""Training runs: seeds times a grid of hyperparameters and physics (`sweep`), or one (`train`).

`train` is a sweep of one seed. Every run trains in blocks of runs (`schedule.train_blocks`)
that compute it alike whatever the others are, so seed i of a sweep trains bit for bit as
`train(config, seed=i)`. The runs are spread over every device of every process, and trained in
chunks when a memory budget asks for it.
"""

import dataclasses
import itertools
import math
from collections.abc import Callable, Collection, Mapping, Sequence, Set
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jax.experimental import multihost_utils

from jaxpg import (
    budget,
    iteration,
    programs,
    progress,
    reinforce,
    schedule,
    train_config,
    xla_options,
)
from jaxpg.types import Params
from jaxpg.validation import (
    check_bool,
    check_callback,
    check_choice,
    check_int,
    check_number,
    shown,
)

EVAL_PHYSICS = ("training", "base")  # what `sweep`'s held-out episodes play in
SOLVED_WINDOW = 10  # iterations averaged to decide whether a run is solved, as the book's last 10

# A grid of settings (`expand_grid`): None, a dict of field to one value or a sequence of values,
# or a list (or tuple) of settings, each a dict of field to value.
Grid = dict[str, Any] | list[dict[str, Any]] | tuple[dict[str, Any], ...] | None
# What a sweep's seeds may be: a range, a list or an array of distinct integers in [0, 2**32).
Seeds = Sequence[int] | np.ndarray
# `(iteration, metrics) -> None`, called on the host as iterations complete.
OnIteration = Callable[[int, iteration.Metrics], None]
# The inputs of a chunk of R runs, on the host: (keys `[R, 2]` uint32, `Hyperparams` `[R]`).
RunInputs = tuple[np.ndarray, train_config.Hyperparams]


class Summary(NamedTuple):
    """Statistics across seeds, per grid setting G, over iterations I (`summarize`).

    With r[g, s, i] the mean episode return of seed s under setting g at iteration i (0-based,
    `Metrics.mean_return`), W = min(SOLVED_WINDOW, I) and T = `TrainConfig.solved_return`:

    - median, q25, q75 [g, i]: `np.percentile(r[g, :, i], 50 | 25 | 75)` over the S seeds
      (linear interpolation between seeds).
    - final_return [g, s] = (r[g, s, I-W] + ... + r[g, s, I-1]) / W, the mean of the last W.
    - fraction_solved [g] = #{s : final_return[g, s] >= T} / S.
    - first_solved [g, s]: the first i >= W - 1 whose trailing mean
      m[g, s, i] = (r[g, s, i-W+1] + ... + r[g, s, i]) / W is >= T; -1 if there is none.
    - solved_by [g, i] = #{s : 0 <= first_solved[g, s] <= i} / S, the seeds solved by i.
      solved_by[g, I-1] can exceed fraction_solved[g]: a seed that reached T and fell back
      counts there, not in fraction_solved.

    For comparing settings with confidence intervals, see `jaxpg.stats` and `jaxpg.report`.
    """

    median: np.ndarray  # [G, I] median over seeds of r
    q25: np.ndarray  # [G, I] first quartile over seeds of r
    q75: np.ndarray  # [G, I] third quartile over seeds of r
    final_return: np.ndarray  # [G, S] mean of r over the last W iterations
    fraction_solved: np.ndarray  # [G] share of seeds with final_return >= T
    first_solved: np.ndarray  # [G, S] first iteration whose trailing W-mean is >= T; -1 never
    solved_by: np.ndarray  # [G, I] share of seeds with 0 <= first_solved <= i


class SweepResult(NamedTuple):
    """Every run of a sweep, `[G, S, ...]`: grid settings by seeds, and the config they share."""

    seeds: np.ndarray  # [S] uint32
    # G dicts {"learning_rate": ..., "discount": ..., "entropy_coef": ..., physics}
    grid: list[dict[str, float]]
    policy_params: dict  # leaves [G, S, ...]
    metrics: iteration.Metrics  # leaves [G, S, I]
    summary: Summary  # statistics across seeds (`summarize`)
    eval_returns: np.ndarray | None = None  # [G, S, N] held-out returns, actions sampled
    eval_greedy_returns: np.ndarray | None = None  # [G, S, N] the same episodes, greedy actions
    critic_params: dict | None = None  # leaves [G, S, ...]: a loss's critic; None without one
    config: train_config.TrainConfig | None = None  # every run's (the grid's values aside)


MAX_SETTINGS = 2**20  # a grid's settings at most: far beyond what memory trains at once


def expand_grid(config: train_config.TrainConfig, grid: Grid) -> list[dict[str, float]]:
    """The grid's settings, each with the hyperparameters and the physical fields the grid names.

    Fields that the grid leaves out keep `config`'s values. A dict's settings are its product, the
    last field varying fastest.

    Args:
      config: the `TrainConfig` of every run.
      grid: None (`config`'s one setting); a dict of field to values, whose product the settings
        are; or a list of dicts, the settings themselves. Fields: `grid_fields(config)`.

    Returns:
      G dicts {field: value}: every hyperparameter, and the physical fields that the grid names.

    Raises:
      ValueError: naming the field, for an unknown field, an empty or repeated list of values,
        or a value out of range (a mass at or below 0, a discount above 1, anything not finite).
    """
    if grid is None or isinstance(grid, dict):
        _check_fields(dict(grid or {}), config)
        axes = _axes(dict(grid or {}))
        count = math.prod(len(values) for values in axes.values())
        if count > MAX_SETTINGS:
            raise ValueError(f"grid: {count} settings (the product of its values); at most "
                             f"{MAX_SETTINGS}")
        names = [*train_config.HYPERPARAMETERS, *(n for n in axes if n in config.physics)]
        values: list[list[Any]] = [axes.get(name, [getattr(config, name, None)]) for name in names]
        settings = [dict(zip(names, combo)) for combo in itertools.product(*values)]
    elif isinstance(grid, list | tuple) and grid and all(isinstance(s, dict) for s in grid):
        named = set().union(*grid)
        _check_fields(named, config)
        settings = [{**{name: getattr(config, name) for name in train_config.HYPERPARAMETERS},
                     **{name: getattr(config.env_params, name)
                        for name in config.physics if name in named},
                     **{name: check_number(name, value)
                        for name, value in setting.items()}}
                    for setting in grid]
        if len({tuple(sorted(zip(s, _as_trained(list(s.values())))))
                for s in settings}) != len(settings):
            raise ValueError("grid: the list repeats a setting (in the float training computes "
                             "in)")
    else:
        raise ValueError(f"grid: expected None, a dict of field to values or a non-empty list of "
                         f"dicts, got {shown(grid)}")
    for setting in settings:
        _check_setting(config, setting)
    return settings


def grid_fields(config: train_config.TrainConfig) -> tuple[str, ...]:
    """The fields a grid may vary: the hyperparameters and the environment's physics."""
    return (*train_config.HYPERPARAMETERS, *config.physics)


def _check_fields(names: Collection[str], config: train_config.TrainConfig) -> None:
    """Raises a ValueError naming the fields of `names` that are not `grid_fields(config)`."""
    allowed = grid_fields(config)
    unknown = set(names) - set(allowed)
    if unknown:
        raise ValueError(f"grid: unknown field(s) {', '.join(sorted(map(str, unknown)))} of "
                         f"{config.env_name}; allowed: {', '.join(allowed)}")


def _check_not_drawn(settings: list[dict[str, float]], config: train_config.TrainConfig) -> None:
    """Raises a ValueError naming the fields that the settings (`expand_grid`) vary and
    `config.randomize` draws per episode: training would replace the grid's values by its draws,
    every setting training alike, and only held-out episodes of the base physics read them."""
    drawn = sorted(set().union(*settings) & {name for name, _ in config.randomize})
    if drawn:
        raise ValueError(f"grid: varies {', '.join(drawn)}, which the config's randomize draws "
                         f"per episode in place of the grid's values; vary one or the other, or "
                         f"evaluate each setting's values with eval_physics='base'")


def _axes(grid: dict[str, Any]) -> dict[str, list[float]]:
    """A dict grid's axes as lists of Python numbers; a ValueError for an empty or repeated one.

    Each value is checked as given (`check_number`), before numpy could make a list's `True` or
    `"2"` a number of the list's dtype.
    """
    axes = {}
    for name, values in grid.items():
        given = list(values) if isinstance(values, list | tuple) else np.atleast_1d(values)
        options = [check_number(name, value) for value in given]
        if not options:
            raise ValueError(f"{name}: the grid needs at least one value")
        if len(set(_as_trained(options))) != len(options):
            raise ValueError(f"{name}: the grid repeats a value (in the float training computes "
                             f"in): {options}")
        axes[name] = options
    return axes


def _as_trained(values: list[float]) -> list[float]:
    """`values` as training computes with them: rounded to JAX's default float (one too large for
    it is the field's own check's to name)."""
    with np.errstate(over="ignore"):
        return np.asarray(values, jax.dtypes.canonicalize_dtype(float)).tolist()


def setting_hyperparams(
    config: train_config.TrainConfig, setting: dict[str, float]
) -> train_config.Hyperparams:
    """The `Hyperparams` (scalars) of one setting of `expand_grid`, which checked it.

    Args:
      config: the `TrainConfig` of every run, whose physics the setting's physical fields modify.
      setting: one setting of `expand_grid`.

    Returns:
      `Hyperparams` of Python scalars, `env` the setting's environment params.
    """
    return train_config.Hyperparams(
        **{name: setting[name] for name in train_config.HYPERPARAMETERS},
        env=config.env_params.replace(
            **{name: value for name, value in setting.items() if name in config.physics}))


def _check_setting(config: train_config.TrainConfig, setting: dict[str, float]) -> None:
    """Checks one setting's hyperparameters and physics (`setting_hyperparams`).

    Raises:
      ValueError: naming the field, for a value out of range.
    """
    train_config.check_hyperparams(**{name: setting[name] for name in train_config.HYPERPARAMETERS})
    config.env_module.check_params(setting_hyperparams(config, setting).env)


# The message of a ValueError for seeds that are not a sequence of integers in range.
SEEDS_ALLOWED = "seeds: must be a non-empty sequence of distinct integers in [0, 2**32)"


def count_seeds(seeds: Seeds) -> int:
    """How many seeds `seeds` holds, found without making an array of them.

    A range is checked by its bounds here; other sequences are checked by `check_seeds`.

    Args:
      seeds: a sequence of S seeds.

    Returns:
      S.

    Raises:
      ValueError: where `seeds` is no sequence (a dict, whose keys are not seeds, or a set, whose
        order is not the caller's, included), is empty, or is a range out of [0, 2**32).
    """
    if isinstance(seeds, Mapping | Set):
        raise ValueError(f"{SEEDS_ALLOWED}, got a {type(seeds).__name__}")
    if isinstance(seeds, range) and seeds and not (
            0 <= min(seeds[0], seeds[-1]) and max(seeds[0], seeds[-1]) < 2**32):
        raise ValueError(f"{SEEDS_ALLOWED}, got {shown(seeds)}")
    try:
        count = len(seeds)
    except TypeError:
        raise ValueError(f"{SEEDS_ALLOWED}, got {shown(seeds)}") from None
    if count == 0:
        raise ValueError(f"{SEEDS_ALLOWED}, got none")
    return count


def check_seeds(seeds: Seeds) -> np.ndarray:
    """The seeds as a `[S]` uint32 array; a ValueError unless they are distinct integers in range.

    Args:
      seeds: a non-empty sequence (a range, list or array) of distinct integers in [0, 2**32).

    Returns:
      `[S]` uint32 seeds, in the given order.
    """
    count_seeds(seeds)
    seeds = np.asarray(seeds if isinstance(seeds, np.ndarray) else list(seeds))
    if seeds.ndim != 1 or not np.issubdtype(seeds.dtype, np.integer):
        raise ValueError(f"{SEEDS_ALLOWED}, got {shown(seeds)}")
    if seeds.min() < 0 or seeds.max() >= 2**32:
        raise ValueError("seeds: must lie in [0, 2**32)")
    if np.unique(seeds).size != seeds.size:
        raise ValueError("seeds: must be distinct")
    return seeds.astype(np.uint32)


def check_arguments(
    config: train_config.TrainConfig,
    seeds: Seeds,
    grid: Grid = None,
    memory_budget: int | None = None,
    eval_episodes: int = 0,
    eval_physics: str = "training",
) -> tuple[np.ndarray, list[dict[str, float]]]:
    """Checks the arguments of `sweep`, and the memory that its runs need (`budget`).

    Everything is checked before anything is traced or allocated.

    Args:
      config: the `TrainConfig` every run shares.
      seeds: S seeds (`check_seeds`).
      grid: the grid of settings (`expand_grid`).
      memory_budget: optional bytes of memory one device may use (`budget.check_memory_budget`).
      eval_episodes: N, held-out episodes each run's final policy plays, in [0, 2**20].
      eval_physics: their physics, one of `EVAL_PHYSICS`; "training" unless N > 0.

    Returns:
      (the `[S]` seeds as `check_seeds` gives them, the G settings of `expand_grid`).

    Raises:
      ValueError: one line naming the argument, for any of them out of range, a grid of a field
        that `config.randomize` draws (but with `eval_physics="base"`), or one that needs more
        memory than the machine has, with the estimate: "memory" where one run does not fit
        (`budget.check`), "seeds" where the S x G runs do not, "eval_episodes" where their
        held-out episodes do not (`budget.evaluation_bytes`).
    """
    if not isinstance(config, train_config.TrainConfig):
        raise ValueError(f"config: expected a TrainConfig, got {type(config).__name__}")
    num_seeds = count_seeds(seeds)
    settings = expand_grid(config, grid)
    budget.check_memory_budget(memory_budget)
    eval_episodes = check_int("eval_episodes", eval_episodes, 0, 2**20)
    check_choice("eval_physics", eval_physics, EVAL_PHYSICS)
    if eval_physics == "training":
        _check_not_drawn(settings, config)
    if eval_physics != "training" and not eval_episodes:
        raise ValueError(f"eval_physics: {eval_physics!r} chooses the physics of held-out "
                         "episodes; give eval_episodes too")
    runs = num_seeds * len(settings)
    budget.check(config)
    try:
        budget.check(config, runs, f"{num_seeds} seeds x {len(settings)} settings")
    except ValueError as error:  # one run fits: the runs' count is what does not
        raise ValueError(f"seeds: {str(error).removeprefix('memory: ')}") from None
    # A block of runs per core plays at once (`schedule.train_blocks`); the returns of every
    # episode of every run are kept, sampled and greedy: two floats of 4 bytes.
    at_once = schedule.runs_at_once(runs)
    returns = runs * eval_episodes * 8
    budget.check_fits(
        budget.evaluation_bytes(eval_episodes, config.max_steps, at_once) + returns,
        "eval_episodes", f"playing {eval_episodes} held-out episodes of at most "
        f"{config.max_steps} steps for each of {runs} runs, {at_once} at once")
    return check_seeds(seeds), settings


def sweep(
    config: train_config.TrainConfig = train_config.TrainConfig(),
    seeds: Seeds = range(64),
    grid: Grid = None,
    show_progress: bool = True,
    memory_budget: int | None = None,
    on_iteration: OnIteration | None = None,
    eval_episodes: int = 0,
    init_params: Params | None = None,
    init_critic_params: Params | None = None,
    eval_physics: str = "training",
) -> SweepResult:
    """Trains every seed under every grid setting, on every device, in chunks that fit a budget.

    Args:
      config: the `TrainConfig` every run shares.
      seeds: a sequence (a range, list or array) of S distinct integers in [0, 2**32).
      grid: optional: a dict of `grid_fields(config)` (hyperparameters and physics) to values,
        whose product the settings are, or a list of settings (`expand_grid`).
      show_progress: show the iterations done, with the mean return of the runs (per chunk, when
        there are several): one line rewritten in place on a terminal, about ten lines in a log
        (`jaxpg.progress`).
      memory_budget: optional bytes of memory one device may use for a chunk of runs (see
        `fitting_chunk_size`); None trains all runs in one chunk. A budget above the machine's
        memory is a ValueError, as is one below what one run needs (raised after compiling one
        run's program, which measures it).
      on_iteration: optional `(iteration, metrics) -> None`, called on the host as iterations
        complete, in order, with a `Metrics` of the runs training now (`[C]` leaves: the chunk's
        runs, setting-major, as `SweepResult` orders them).
      eval_episodes: N: after training, each run's final policy plays N fresh episodes of its
        own (`iteration.evaluate_runs`), with actions sampled and greedy.
      init_params: optional policy parameters (a checkpoint's), shaped as the policy's own, that
        every run's policy starts from; the optimizer starts afresh.
      init_critic_params: optional parameters of the loss's critic (a result's
        `critic_params` of one run) that every run's critic starts from.
      eval_physics: the physics of the held-out episodes: "training" (the default), each run's
        own, every episode drawing `config.randomize`'s fields from their ranges as in training;
        or "base", each run's own without drawing them (the config's physics and the run's grid
        values).

    Returns:
      `SweepResult` with `[G, S, ...]` leaves, the `Summary` (and with `eval_episodes`, the
      held-out returns `[G, S, N]`) and `config`, on every process.

    Raises:
      ValueError: one line naming the argument, for any of them out of range (`check_arguments`),
        or `init_params` not shaped as the policy's parameters, before anything is compiled;
        for a `memory_budget` below one run's need, after compiling.
    """
    seeds, settings = check_arguments(config, seeds, grid, memory_budget, eval_episodes,
                                      eval_physics)
    eval_episodes = check_int("eval_episodes", eval_episodes, 0, 2**20)
    check_bool("show_progress", show_progress)
    check_callback("on_iteration", on_iteration, "(iteration, metrics) -> None")
    if init_params is not None:
        init_params = reinforce.check_init_params(config, init_params)
    if init_critic_params is not None:
        init_critic_params = reinforce.check_init_params(config, init_critic_params, critic=True)
    inputs = run_inputs(config, seeds, settings)
    num_runs = inputs[0].shape[0]
    xla_options.configure_unstarted()
    # The fast path only where no run has an entropy bonus: one program serves every setting.
    entropy = max(setting["entropy_coef"] for setting in settings)
    program = programs.compiled_program(dataclasses.replace(config, entropy_coef=entropy))
    if memory_budget is None:
        chunk = chunk_size(num_runs, jax.device_count())
    else:
        chunk = fitting_chunk_size(program, config.iterations, num_runs, memory_budget)
    result = None
    for start in range(0, num_runs, chunk):
        stop = min(start + chunk, num_runs)
        # Every chunk has the same shape, so the program compiles once; the last one is padded
        # with copies of the last run, whose results are dropped.
        indices = np.minimum(np.arange(start, start + chunk), num_runs - 1)
        label = f"runs {start + 1}-{stop} of {num_runs}" if chunk < num_runs else ""
        with progress.bar(config.iterations, show_progress, label=label) as bar:
            part = train_on_devices(program, config.iterations, _take(inputs, indices),
                                    progress.together(bar, on_iteration), eval_episodes,
                                    (init_params, init_critic_params),
                                    eval_physics == "training")
        if result is None:
            result = jax.tree.map(
                lambda leaf: np.empty((num_runs, *leaf.shape[1:]), leaf.dtype), part)
        for out, leaf in zip(jax.tree.leaves(result), jax.tree.leaves(part)):
            out[start:stop] = leaf[: stop - start]
    num_settings, num_seeds = len(settings), seeds.size
    result = jax.tree.map(
        lambda leaf: leaf.reshape(num_settings, num_seeds, *leaf.shape[1:]), result)
    summary = summarize(result.metrics.mean_return, config.solved_return)
    reinforce.warn_if_diverged(
        jax.tree.map(lambda leaf: leaf.reshape(num_runs, -1), result.metrics),
        [f"seed {seed} with {setting}" for setting in settings for seed in seeds])
    sampled, greedy = (None, None) if result.evaluation is None else result.evaluation
    return SweepResult(seeds, settings, result.policy_params, result.metrics, summary, sampled,
                       greedy, result.critic_params, config)


# A frozen dataclass: one default instance is safe to share.
def train(config: train_config.TrainConfig = train_config.TrainConfig(), seed: int = 0,
          init_params: Params | None = None,
          on_iteration: OnIteration | None = None,
          show_progress: bool = True,
          init_critic_params: Params | None = None) -> iteration.TrainResult:
    """Trains one policy: a `sweep` of one seed, which it trains bit for bit as any sweep does.

    Args:
      config: the `TrainConfig`.
      seed: an integer in [0, 2**32): the run's key is `jax.random.PRNGKey(seed)`.
      init_params: optional policy parameters to start from (a checkpoint's), shaped as the
        policy's own; the optimizer starts afresh.
      on_iteration: optional `(iteration, metrics) -> None`, called on the host as iterations
        complete, in order, with that iteration's `Metrics` (scalar leaves).
      show_progress: print progress lines on stderr.
      init_critic_params: optional parameters of the loss's critic to start from (a
        `TrainResult`'s `critic_params`).

    Returns:
      `TrainResult`: the final `policy_params`, `Metrics` with `[iterations]` leaves and, for a
      loss with a critic, its `critic_params`.

    Raises:
      ValueError: for a config that is not a `TrainConfig`, a seed out of range, training that
        needs more memory than the machine's (`budget.check`), or `init_params` not shaped as
        the policy's parameters; each before anything compiles.
    """
    check_int("seed", seed, 0, 2**32)
    check_callback("on_iteration", on_iteration, "(iteration, metrics) -> None")
    first_run = None if on_iteration is None else (
        lambda i, metrics: on_iteration(i, jax.tree.map(lambda leaf: leaf[0], metrics)))
    result = sweep(config, [seed], show_progress=show_progress, on_iteration=first_run,
                   init_params=init_params, init_critic_params=init_critic_params)
    return jax.tree.map(lambda leaf: leaf[0, 0], iteration.TrainResult(
        result.policy_params, result.metrics, critic_params=result.critic_params))


def run_inputs(
    config: train_config.TrainConfig, seeds: np.ndarray, settings: Sequence[dict[str, float]]
) -> RunInputs:
    """The key and hyperparameters of every run, on the host, setting-major.

    Args:
      config: the `TrainConfig` every run shares.
      seeds: `[S]` seeds, as `check_seeds` gives them.
      settings: G settings of `expand_grid`.

    Returns:
      (keys `[R, 2]` uint32, `Hyperparams` with `[R]` leaves) as numpy arrays, where
      R = G * S and run g * S + s is seed s under setting g.
    """
    keys = np.tile(np.asarray(reinforce.run_keys(seeds)), (len(settings), 1))
    hypers = train_config.stack([setting_hyperparams(config, setting) for setting in settings])
    return keys, jax.tree.map(lambda leaf: np.repeat(leaf, seeds.size), hypers)


def _take(tree: Any, index: Any) -> Any:
    """`tree` with every leaf indexed by `index`: the runs it selects."""
    return jax.tree.map(lambda leaf: leaf[index], tree)


def train_on_devices(
    program: programs.Program,
    iterations: int,
    inputs: RunInputs,
    on_iteration: OnIteration | None = None,
    eval_episodes: int = 0,
    start_from: tuple[Params | None, Params | None] = (None, None),
    eval_randomized: bool = True,
) -> iteration.TrainResult:
    """Trains runs `[C]`, a multiple of the device count, on every device of every process.

    Process p trains the p-th of `jax.process_count()` equal blocks of the runs, each of its
    devices an equal share of that block. Every device runs the one-device program on its own runs:
    one program partitioned across devices is compiled with other (equally valid) floating-point
    rewrites, and seed i would no longer train bit for bit as seed i alone.

    Args:
      program: `programs.compiled_program(config)`.
      iterations: how many iterations to train.
      inputs: (keys `[C, 2]`, `Hyperparams` `[C]`) as numpy arrays, the same on every process.
      on_iteration: optional `(iteration, metrics) -> None` for this process's runs.
      eval_episodes: N: held-out episodes each run's final policy plays after training (0: none).
      start_from: optional parameters of one run's (policy, critic) that every run starts from.
      eval_randomized: whether the held-out episodes draw `config.randomize`'s physics.

    Returns:
      `TrainResult` with numpy leaves `[C, ...]` (and with `eval_episodes`, its `Evaluation`
      `[C, N]`), on every process.
    """
    devices = jax.local_devices()
    per_process = inputs[0].shape[0] // jax.process_count()
    per_device = per_process // len(devices)
    first = jax.process_index() * per_process
    shares = [slice(first + i * per_device, first + (i + 1) * per_device)
              for i in range(len(devices))]
    parts = [jax.device_put(_take(inputs, share), device) for share, device in zip(shares, devices)]
    local = schedule.train_blocks(program, iterations, parts, on_iteration, start_from[0],
                                  eval_episodes, start_from[1], eval_randomized)
    local = jax.tree.map(lambda *leaves: np.concatenate(leaves), *local)
    return multihost_utils.process_allgather(local, tiled=True)


def device_bytes(program: programs.Program, iterations: int, num_runs: int) -> int:
    """Device memory that training `num_runs` runs for `iterations` iterations on one device needs.

    XLA's buffer assignment for one call of `program` (its arguments, among them the training
    state; outputs; temporaries; generated code), from the compiled program's
    `memory_analysis()`, plus every call's metrics, which stay on the device until the end.
    A CPU trains the runs in blocks (`schedule.device_blocks`): every block's state and metrics
    count, and the temporaries of as many blocks as train at once. It compiles the program that
    training runs, for this process's first device, so that training reuses it.

    Args:
      program: `programs.compiled_program(config)`.
      iterations: how many iterations to train.
      num_runs: the runs that the device trains.

    Returns:
      Bytes.
    """
    device = jax.local_devices()[0]
    bounds, size = schedule.device_blocks(num_runs, device)
    blocks, at_once = len(bounds), min(len(bounds), schedule.usable_cores())
    placed = jax.sharding.SingleDeviceSharding(device)
    keys = jax.ShapeDtypeStruct((size, 2), jnp.uint32, sharding=placed)
    hyperparams = jax.tree.map(
        lambda leaf: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, sharding=placed),
        program.hyperparams(size))
    state = jax.tree.map(
        lambda leaf: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, sharding=placed),
        program.init.eval_shape(keys, hyperparams),
    )
    count = jax.ShapeDtypeStruct((), jnp.int32)  # as `schedule.train_blocks` passes it: np.int32
    _, metrics = program.iterate.eval_shape(state, hyperparams, count)
    # Optional in jax's types, for a backend without the analysis.
    stats = cast(Any, program.iterate.lower(state, hyperparams, count).compile().memory_analysis())
    kept = stats.argument_size_in_bytes + stats.output_size_in_bytes - stats.alias_size_in_bytes
    history = len(schedule.calls(iterations)) * metrics.size * metrics.dtype.itemsize
    return (blocks * (kept + history) + at_once * stats.temp_size_in_bytes
            + stats.generated_code_size_in_bytes)


def fitting_chunk_size(
    program: programs.Program, iterations: int, num_runs: int, memory_budget: int
) -> int:
    """Runs per chunk such that each device's share, as XLA compiles it, fits `memory_budget` bytes.

    The first guess gives every run what one run needs; the guess's own program is then compiled
    and measured, and the chunk shrinks while it does not fit: XLA lays out programs of different
    sizes differently, so their bytes do not grow exactly in proportion to their runs.

    Args:
      program: `programs.compiled_program(config)`.
      iterations: how many iterations to train.
      num_runs: every run of the sweep.
      memory_budget: bytes of memory one device may use for a chunk.

    Returns:
      Runs per chunk, a multiple of the device count (`chunk_size`).

    Raises:
      ValueError: naming `memory_budget`, where it is less than one run needs.
    """
    num_devices = jax.device_count()
    needed = device_bytes(program, iterations, 1)
    if memory_budget < needed:
        raise ValueError(
            f"memory_budget: {memory_budget} bytes is less than one run needs on a device "
            f"({needed} bytes with this config); allowed: None or at least {needed}"
        )
    max_per_device = memory_budget // needed
    while True:
        size = chunk_size(num_runs, num_devices, max_per_device)
        per_device = size // num_devices
        used = device_bytes(program, iterations, per_device)
        if used <= memory_budget:
            return size
        max_per_device = max(1, per_device * memory_budget // used)


def chunk_size(num_runs: int, num_devices: int, max_per_device: int | None = None) -> int:
    """Runs per chunk: a multiple of `num_devices`, at most `max_per_device` per device.

    Of the sizes that need the fewest chunks, the smallest, so that the last chunk needs the least
    padding.

    Args:
      num_runs: every run to train.
      num_devices: the devices that train a chunk together.
      max_per_device: optional: the most runs one device may train at once.

    Returns:
      Runs per chunk.
    """
    per_device = -(-num_runs // num_devices)
    if max_per_device is not None:
        num_chunks = -(-per_device // max_per_device)
        per_device = -(-per_device // num_chunks)
    return per_device * num_devices


def last_mean(mean_return: npt.ArrayLike) -> np.ndarray | float:
    """The mean of the last `SOLVED_WINDOW` iterations (of all, where fewer), in float64.

    `Summary.final_return` and `jaxpg train`'s last-10 mean both.

    Args:
      mean_return: `[..., I]` per-iteration mean returns.

    Returns:
      `[...]` float64: a numpy float for `[I]`.
    """
    window = min(SOLVED_WINDOW, np.shape(mean_return)[-1])
    return np.asarray(mean_return, dtype=np.float64)[..., -window:].mean(axis=-1)


def summarize(mean_return: npt.ArrayLike, solved_return: float) -> Summary:
    """Summary statistics of `[G, S, I]` per-iteration mean returns.

    Args:
      mean_return: `[G, S, I]` each run's mean return per iteration (`Metrics.mean_return`).
      solved_return: T, the trailing mean at which a run counts as solved.

    Returns:
      `Summary` over the G settings, S seeds and I iterations.
    """
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
    final_return = cast(np.ndarray, last_mean(mean_return))  # [G, S]: an array
    iterations = np.arange(mean_return.shape[-1])
    solved_by = ((first_solved[..., None] >= 0)
                 & (first_solved[..., None] <= iterations)).mean(axis=1)
    return Summary(
        median=median,
        q25=q25,
        q75=q75,
        final_return=final_return,
        fraction_solved=(final_return >= solved_return).mean(axis=1),
        first_solved=first_solved,
        solved_by=solved_by,
    )
