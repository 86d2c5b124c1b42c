"""Training on the host: which runs train together, on which threads, and in which calls."""

import concurrent.futures
import functools
import os
import threading
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from jaxpg import executables
from jaxpg.iteration import Evaluation, Metrics, TrainResult, TrainState
from jaxpg.programs import ITERATIONS_PER_CALL, Program
from jaxpg.train_config import Hyperparams
from jaxpg.types import Array, HostArray, Params

# The runs of one device: (keys uint32 `[R, 2]`, `Hyperparams` `[R]`), numpy or on the device.
Part = tuple[Array | HostArray, Hyperparams]


def calls(iterations: int) -> list[tuple[int, int]]:
    """`(first iteration, count)` of each program call that trains for `iterations` iterations."""
    return [(start, min(ITERATIONS_PER_CALL, iterations - start))
            for start in range(0, iterations, ITERATIONS_PER_CALL)]


CPU_BLOCK = 16  # runs a CPU trains together at most: one vector of them (`rollout.LANES`)
# Runs per core that train alone rather than in a block: a run alone vectorises over its episodes
# (docs/performance.md).
ALONE_PER_CORE = 2


def usable_cores() -> int:
    """The cores this process may run on (all of them where the OS does not say)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def cpu_blocks(num_runs: int) -> tuple[list[tuple[int, int]], int]:
    """The blocks in which a CPU trains `num_runs` runs, one thread per core.

    Up to `ALONE_PER_CORE` runs per core train alone, a block each. More train in blocks of at
    most `CPU_BLOCK` runs whose sizes differ by at most one, as many as a multiple of the usable
    cores, so that every core trains and all finish together, padded to a whole vector of floats:
    4, 8 or 16 runs. XLA vectorises over the runs in whole vectors and loops over the rest one by
    one, so a block padded to a whole vector trains sooner. One size, one program to compile.

    Args:
      num_runs: how many runs train.

    Returns:
      (`(start, stop)` of each block's runs, the size every block is padded to with copies of its
      own runs).
    """
    num_blocks, size = cpu_block_count(num_runs)
    bounds = [i * num_runs // num_blocks for i in range(num_blocks + 1)]
    return list(zip(bounds[:-1], bounds[1:])), size


def runs_at_once(num_runs: int) -> int:
    """How many runs a CPU trains at once for `num_runs` runs: a block per core, each padded to
    its size with copies of its runs (`cpu_blocks`)."""
    num_blocks, size = cpu_block_count(num_runs)
    return min(num_blocks, usable_cores()) * size


def cpu_block_count(num_runs: int) -> tuple[int, int]:
    """How many blocks `cpu_blocks` makes of `num_runs` runs, and the size each is padded to."""
    cores = usable_cores()
    if num_runs <= ALONE_PER_CORE * cores:
        return num_runs, 1
    num_blocks = -(-num_runs // (CPU_BLOCK * cores)) * cores
    largest = -(-num_runs // num_blocks)
    return num_blocks, max(4, 1 << (largest - 1).bit_length())


def train_blocks(
    program: Program, iterations: int, parts: Sequence[Part],
    on_iteration: Callable[[int, Metrics], None] | None = None,
    policy_params: Params | None = None, eval_episodes: int = 0,
    critic_params: Params | None = None, eval_randomized: bool = True,
) -> list[TrainResult]:
    """Trains each part's runs for `iterations` iterations, every part on its own device.

    On a CPU a part trains in `cpu_blocks`, spread over one thread per core: XLA runs such small
    programs on the thread that calls them, and a small block stops its rollout as soon as its own
    episodes have ended. Runs train alike in any batch, so the blocks and their copies of runs
    change nothing in the results. The programs of every part's blocks are compiled first, side
    by side (`prepare`).

    Args:
      program: from `programs.compiled_program`.
      iterations: how many times to iterate.
      parts: a list of (keys `[R_p, 2]`, `Hyperparams` `[R_p]`), each on the device that trains it.
      on_iteration: optional `(iteration, Metrics) -> None`, the metrics' leaves `[sum of R_p]`,
        called on the host for every iteration in order, while later ones are already training.
      policy_params: optional parameters of one run's policy that every run starts from.
      critic_params: optional parameters of one run's critic that every run's critic starts
        from.
      eval_episodes: how many held-out episodes each run's final policy plays (`Program.evaluate`).
      eval_randomized: whether they draw the config's randomised physics (`Program.evaluate`).

    Returns:
      One `TrainResult` per part, with numpy leaves `[R_p, ...]`, metrics `[R_p, iterations]`
      and, with `eval_episodes`, an `Evaluation` `[R_p, eval_episodes]`.
    """
    blocks, owners, owned = [], [], []  # owned: how many of a block's runs are its part's
    for index, part in enumerate(parts):
        for block, runs in part_blocks(part):
            blocks.append(block)
            owners.append(index)
            owned.append(runs)
    start_from = () if policy_params is None and critic_params is None else (
        policy_params, critic_params)
    blocks = [(*block, *start_from) for block in blocks]
    prepare(program, blocks)
    schedule = calls(iterations)
    # Each call's stacked metrics of each block; each block's final TrainState and Evaluation.
    history: list[list[Any]] = [[None] * len(blocks) for _ in schedule]
    finals: list[Any] = [None] * len(blocks)
    evaluations: list[Evaluation | None] = [None] * len(blocks)
    num_workers = min(len(blocks), usable_cores())
    finished = [0] * len(schedule)  # workers that dispatched each call
    failed: list[Sequence[int]] = []  # workers that raised
    progress_made = threading.Condition()
    stop = threading.Event()  # the caller was interrupted: workers end before their next call

    def train_blocks(indices: Sequence[int]) -> None:
        """Trains the blocks `indices` in turn, call by call, on this thread."""
        try:
            states = {i: program.init(*blocks[i]) for i in indices}
            for call, (_, count) in enumerate(schedule):
                for i in indices:
                    if stop.is_set():  # with nothing of theirs left running in XLA
                        jax.block_until_ready(list(states.values()))
                        return
                    states[i], history[call][i] = program.iterate(
                        states[i], blocks[i][1], np.int32(count))
                with progress_made:
                    finished[call] += 1
                    progress_made.notify_all()
            for i in indices:
                evaluations[i] = jax.device_get(
                    program.evaluate(states[i], blocks[i][1], episodes=eval_episodes,
                                     randomized=eval_randomized)
                    if eval_episodes else None)
                finals[i] = jax.device_get(states[i])
        except BaseException:
            with progress_made:
                failed.append(indices)
                progress_made.notify_all()
            raise

    with concurrent.futures.ThreadPoolExecutor(num_workers) as pool:
        workers = [pool.submit(train_blocks, range(w, len(blocks), num_workers))
                   for w in range(num_workers)]
        try:
            for call, (start, count) in enumerate(schedule if on_iteration is not None else []):
                with progress_made:
                    progress_made.wait_for(lambda: finished[call] == num_workers or failed)
                if finished[call] < num_workers:
                    break  # a worker failed; its error is raised below
                shown = np.concatenate([np.asarray(m)[:count, :, :runs]
                                        for m, runs in zip(history[call], owned)], axis=-1)
                for offset, rows in enumerate(shown):
                    on_iteration(  # type: ignore[misc]  # (the loop runs only with a hook)
                        start + offset, program.metrics(rows))
            for worker in workers:
                worker.result()
        except BaseException:  # Ctrl-C above all (KeyboardInterrupt), or the hook's error
            stop.set()
            _wait_through_interrupts(workers)
            raise

    results = []
    for index in range(len(parts)):
        mine = [i for i, owner in enumerate(owners) if owner == index]
        metrics = jax.device_get([[history[c][i] for i in mine] for c in range(len(schedule))])
        rows = np.concatenate([  # [I, fields, R_p]
            np.concatenate([m[..., :owned[i]] for m, i in zip(call, mine)], axis=-1)[:count]
            for call, (_, count) in zip(metrics, schedule)])
        stacked = program.metrics(np.moveaxis(rows, 0, -1))
        params = jax.tree.map(  # leaves [..., R_p]
            lambda *leaves: np.concatenate(leaves, axis=-1),
            *[jax.tree.map(lambda leaf, i=i: leaf[..., :owned[i]], finals[i].params)
              for i in mine])
        runs_first = functools.partial(jax.tree.map, lambda leaf: np.moveaxis(leaf, -1, 0))
        evaluation = None if not eval_episodes else jax.tree.map(  # [R_p, N]
            lambda *leaves: np.concatenate(leaves),
            *[jax.tree.map(lambda leaf, i=i: leaf[:owned[i]], evaluations[i]) for i in mine])
        results.append(TrainResult(runs_first(program.policy_params(params)), stacked,
                                   evaluation, runs_first(program.critic_params(params))))
    return results


def _wait_through_interrupts(futures: Sequence[concurrent.futures.Future[Any]]) -> None:
    """Waits for `futures` to end, however often Ctrl-C is pressed meanwhile.

    So the workers end before their caller does, rather than under the interpreter's shutdown.
    """
    while True:
        try:
            concurrent.futures.wait(futures)
            return
        except KeyboardInterrupt:
            continue


def prepare(program: Program, blocks: Sequence[tuple[Any, ...]]
            ) -> list[concurrent.futures.Future[executables.Program]]:
    """Starts compiling (or loading) `program` for `blocks`.

    This thread traces and lowers `iterate` for each block first, then `init`; other threads
    compile each program as soon as it is lowered. `iterate`'s compile, the longest, so runs while
    `init` is traced and compiled.

    Args:
      program: from `programs.compiled_program`.
      blocks: `program.init`'s arguments for each block: keys `[R, 2]`, `Hyperparams` `[R]`, and
        the policy parameters to start from, if any.

    Returns:
      The `concurrent.futures.Future`s of their programs: every block's `iterate`, then `init`.
    """
    iterates = [program.iterate.prepare(_state_like(program, *block), block[1], np.int32(1))
                for block in blocks]
    return iterates + [program.init.prepare(*block) for block in blocks]


def _state_like(program: Program, keys: Array | HostArray, *init_args: Any) -> TrainState:
    """The `TrainState` that `program.init(keys, *init_args)` returns, as placed shapes.

    Its leaves are `jax.ShapeDtypeStruct`s placed as the arrays will be: committed to the keys'
    device where the keys are. Read from `init`'s program where it is at hand (kept on disk),
    traced otherwise.
    """
    init = program.init.loaded(keys, *init_args)
    # A loaded program is a compiled one, which has `out_info` (`executables.Program` types a call).
    shapes = (program.init.eval_shape(keys, *init_args) if init is None
              else init.out_info)  # type: ignore[attr-defined]
    sharding = keys.sharding if isinstance(keys, jax.Array) and keys.committed else None
    return jax.tree.map(
        lambda leaf: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, sharding=sharding), shapes)


def device_blocks(num_runs: int, device: jax.Device) -> tuple[list[tuple[int, int]], int]:
    """The blocks in which `device` trains `num_runs` runs, as `cpu_blocks` gives them.

    On a CPU they are `cpu_blocks`; elsewhere the runs train whole, in one block.
    """
    if device.platform != "cpu":
        return [(0, num_runs)], num_runs
    return cpu_blocks(num_runs)


def part_blocks(part: Part) -> list[tuple[Part, int]]:
    """A part's runs in the blocks that `train_blocks` trains (`device_blocks`).

    Args:
      part: (keys `[R, 2]`, `Hyperparams` `[R]`) of the runs of one device.

    Returns:
      `(inputs, runs)` of each block: its keys and `Hyperparams`, whose first `runs` runs are the
      part's and the rest copies of them, where the block needs them.
    """
    keys = part[0]
    device = next(iter(keys.devices())) if isinstance(keys, jax.Array) else jax.devices()[0]
    bounds, size = device_blocks(keys.shape[0], device)

    def block(start: int, stop: int) -> Part:
        """The runs `start` to `stop` of `part`, padded to `size` with copies of them."""
        full = stop - start == size
        runs = slice(start, stop) if full else np.resize(np.arange(start, stop), size)
        return jax.tree.map(lambda leaf: leaf[runs], part)

    return [(block(start, stop), stop - start) for start, stop in bounds]
