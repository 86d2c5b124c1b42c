"""What training needs in memory, estimated from its settings alone.

The estimate comes before anything is traced or allocated: settings far beyond the machine end in
one line, not in a crash or a hang.

The estimate (`needed_bytes`) is a host's, in floats of JAX's default dtype:

- each step of each episode that a run plays: `STEP_FLOATS`, plus `UNIT_FLOATS` per hidden unit of
  the default network: its record, the loss's values and every layer's activations with their
  gradients, as XLA lays out one iteration; with several updates an iteration (`epochs` or
  `minibatches` above 1), `EPOCH_STEP_FLOATS` more per step for each epoch, whose shuffled copy of
  the episodes XLA lays out whole;
- the parameters of every run, with their gradient and optimizer state: `PARAMETER_COPIES` floats
  each;
- the metrics of every run, `METRIC_FLOATS` per iteration, and `CALL_BYTES` of bookkeeping for
  each program call of each block of runs (`schedule.train_blocks`).

Steps count for the runs that train at once on a CPU, one block of runs per core
(`schedule.cpu_blocks`); parameters and metrics for every run. A user's own module or a loss's
critic adds what this cannot see without tracing it, as does the device memory of an accelerator,
which a sweep's `memory_budget` bounds by XLA's own account (`sweeps.fitting_chunk_size`).

Playing episodes without training (`evaluation_bytes`, `render_bytes`) keeps every step's record
in memory: `EVAL_STEP_FLOATS` per step of each episode that plays at once, and a drawn episode
`FRAME_BYTES` per frame besides. The default network's layers are bounded too, by what XLA's CPU
compiler can build (`MAX_UNITS`).
"""

import decimal
import os
from typing import Any

import flax.linen as nn
import jax
import numpy as np

from jaxpg import losses, policies, rollout, schedule
from jaxpg.programs import ITERATIONS_PER_CALL
from jaxpg.train_config import TrainConfig
from jaxpg.validation import check_int

# Per step of an episode, XLA's buffers for one iteration of one run: STEP_FLOATS + UNIT_FLOATS *
# hidden units, fitted to `memory_analysis()` (docs/performance.md).
STEP_FLOATS = 15
UNIT_FLOATS = 4
# Per step of an episode and per epoch, with several updates an iteration: the epochs' shuffled
# minibatches, by `memory_analysis()` (32 to 64 epochs of 10 to 40 episodes, float32) 38 bytes on
# CartPole, 9.5 floats, and up to 59 with PPO on Acrobot, 14.75 floats of which the 2 observations
# beyond CartPole's 4 are counted apart: 13 covers both.
EPOCH_STEP_FLOATS = 13
PARAMETER_COPIES = 5  # the parameters, their gradient, two moments and the trained copy returned
METRIC_FLOATS = 16  # six metrics and up to two of a loss's own, kept twice (trained, returned)
CALL_BYTES = 6000  # the host's bookkeeping of one call (docs/performance.md)
USABLE_SHARE = 0.8  # of the machine's memory: the process and the system need the rest
# Per step of an episode played without training: 37 bytes in float32 by `memory_analysis()` of
# evaluate's program (1 to 4000 episodes, 200 to 4000 steps), about 9.3 floats.
EVAL_STEP_FLOATS = 10
# Per step of a drawn episode's full record (`rollout.rollout`): 78 bytes in float32, 19.5 floats.
RECORD_FLOATS = 20
FRAME_BYTES = 500 * 600 * 3  # a uint8 RGB frame of `render.render_frame` (600x400, 500x500)
# Units per layer of the default network that XLA's CPU compiler builds: `jaxpg train --iterations
# 1` takes 14 s with hidden 1000, 48 s with 2000 and 76 s with 4000; 10000 overflows the compiler's
# stack after about 80 s (2-core CPU, jaxlib 0.10).
MAX_UNITS = 4000


def machine_memory() -> int | None:
    """Bytes of physical memory (`os.sysconf`); None where the system does not say."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def needed_bytes(config: TrainConfig, runs: int = 1) -> int:
    """Estimated bytes of memory that training `runs` runs of `config` needs (module docstring).

    Args:
      config: the `TrainConfig`.
      runs: how many runs train, in one chunk.

    Returns:
      An int; it grows with iterations, episodes, max_steps, hidden units, epochs and runs.
    """
    itemsize = _itemsize()
    # The blocks as a CPU trains them, one per core at a time, each padded to `size` runs.
    blocks, size = schedule.cpu_block_count(runs)
    alone = size == 1
    # A run alone plays whole vectors of episodes (`rollout.LANES`); a block, its runs side by side.
    episodes = rollout.played_episodes(config.episodes, rollout.LANES if alone else 1)
    at_once = schedule.runs_at_once(runs)
    networks = [config.network, losses.critic(config.loss)]
    units = sum(sum(net.hidden) for net in networks if isinstance(net, policies.PolicyNetwork))
    obs_size = config.env_module.OBS_SIZE
    parameters = sum(_parameters(net, obs_size) for net in networks)
    # Fitted on CartPole's 4 observations; a step records (and the policy reads) each one more.
    extra = max(0, obs_size - 4)
    steps = config.max_steps * episodes * (STEP_FLOATS + extra + UNIT_FLOATS * units)
    if config.updates > 1:  # every epoch's minibatches, laid out at once
        steps += config.max_steps * config.episodes * config.epochs * (EPOCH_STEP_FLOATS + extra)
    kept = PARAMETER_COPIES * parameters + METRIC_FLOATS * config.iterations
    calls = -(-config.iterations // ITERATIONS_PER_CALL)
    return (at_once * steps + runs * kept) * itemsize + blocks * calls * CALL_BYTES


def _parameters(network: nn.Module | None, obs_size: int) -> int:
    """How many parameters a `policies.PolicyNetwork` of `obs_size` inputs has; 0 for any other
    module or None."""
    if not isinstance(network, policies.PolicyNetwork):
        return 0
    sizes = [obs_size, *network.hidden, network.outputs]
    return sum((inputs + 1) * outputs for inputs, outputs in zip(sizes[:-1], sizes[1:]))


def check(config: TrainConfig, runs: int = 1, what: str = "1 run") -> None:
    """Checks that the machine has the memory to train `runs` runs of `config`.

    Args:
      config: the `TrainConfig`.
      runs: how many runs train, in one chunk.
      what: how the message names the runs, such as "64 seeds x 2 settings".

    Raises:
      ValueError: in one line, naming `hidden` for a layer of the default network wider than
        `MAX_UNITS`, or when training needs more memory (`needed_bytes`) than `USABLE_SHARE` of
        the machine's.
    """
    if config.policy is None and max(config.hidden, default=0) > MAX_UNITS:
        raise ValueError(f"hidden: at most {MAX_UNITS} units per layer of the default network "
                         f"(XLA's CPU compiler crashes on wider ones), got {config.hidden}")
    network = "" if config.policy is not None else f", hidden {config.hidden}"
    epochs = f" in {config.epochs} epochs" if config.epochs > 1 else ""
    check_fits(needed_bytes(config, runs), "memory",
               f"training {what} for {config.iterations} iterations of {config.episodes} "
               f"episodes of at most {config.max_steps} steps{epochs}{network}")


def evaluation_bytes(episodes: int, max_steps: int, runs: int = 1) -> int:
    """Estimated bytes of memory that playing `runs` x `episodes` episodes at once needs.

    Args:
      episodes: E, episodes per run.
      max_steps: T, the longest an episode may run.
      runs: how many policies (or physics settings) play at once.

    Returns:
      An int: `EVAL_STEP_FLOATS` floats per step of every episode.
    """
    # As Python ints: numpy's would overflow, and pass any check.
    return int(runs) * int(episodes) * int(max_steps) * EVAL_STEP_FLOATS * _itemsize()


def render_bytes(max_steps: int, env_steps: int) -> int:
    """Estimated bytes of memory that drawing one episode of at most `max_steps` steps needs.

    Args:
      max_steps: the most steps drawn; the episode plays one step more.
      env_steps: the environment's own time limit (`CartPoleParams.max_steps`), which also ends it.

    Returns:
      An int: the episode's record and its frames, at most `min(max_steps, env_steps) + 1`.
    """
    max_steps = int(max_steps)
    frames = min(max_steps, int(env_steps)) + 1
    return (max_steps + 1) * RECORD_FLOATS * _itemsize() + frames * FRAME_BYTES


def check_fits(needed: int, name: str, doing: str) -> None:
    """Checks that `needed` bytes fit in `USABLE_SHARE` of the machine's memory.

    Args:
      needed: the estimate, in bytes.
      name: what the message names first: the argument that sets the size, or "memory".
      doing: what needs the memory, such as "playing 10 episodes of at most 200 steps".

    Raises:
      ValueError: in one line, `name: doing needs about ...; this machine has ...`, when it does
        not fit.
    """
    have = machine_memory()
    if have is not None and needed > USABLE_SHARE * have:
        raise ValueError(f"{name}: {doing} needs about {format_bytes(needed)}; this machine has "
                         f"{format_bytes(have)}, of which jaxpg may use {USABLE_SHARE:.0%}")


def _itemsize() -> int:
    """Bytes of a float of JAX's default dtype: 4, or 8 with `jax_enable_x64`."""
    return np.dtype(jax.dtypes.canonicalize_dtype(float)).itemsize


def check_memory_budget(memory_budget: Any) -> None:
    """Checks a sweep's `memory_budget`.

    Args:
      memory_budget: None, or bytes of memory.

    Raises:
      ValueError: unless it is None or a positive integer number of bytes within the machine's
        memory.
    """
    if memory_budget is None:
        return
    check_int("memory_budget", memory_budget)
    have = machine_memory()
    if have is not None and memory_budget > have:
        raise ValueError(f"memory_budget: {format_bytes(memory_budget)} is more than this "
                         f"machine has ({format_bytes(have)}); allowed: 1 byte to "
                         f"{format_bytes(have)}, or none")


def format_bytes(count: int) -> str:
    """`count` bytes in the largest binary unit up to EiB that keeps a number of at least 1.

    To four digits, `23.52 GiB`; exactly, for numbers of any size (a float would overflow).
    """
    count = int(count)
    units = ["bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"]
    power = min(max(count.bit_length() - 1, 0) // 10, len(units) - 1)
    return f"{decimal.Decimal(count) / 1024**power:.4g} {units[power]}"
