"""Do seeds train alone exactly as side by side? The check to run after any change for speed.

Trains seeds 0..R-1 of the book's settings side by side in one worker thread (blocks of at most
`schedule.CPU_BLOCK` runs, padded with copies to a whole vector: `schedule.cpu_blocks`), then
each seed alone, each under the `jaxpg` command's XLA setting for it: the blocks in this process,
with XLA's threads one per core as a sweep has them, and the seeds alone in a process of their own
that gives XLA one thread, as `jaxpg train` does. At least `schedule.ALONE_PER_CORE + 1` seeds:
fewer would train alone in the blocks' process too. It counts the seeds whose parameters or
statistics differ in any bit (-0 and +0 differ too). Programs of one run and of several are
compiled apart, and XLA can round them differently (see `jaxpg.xla_options`): the suite checks
21 seeds (two blocks padded to 16), this script as many as asked.

    python benchmarks/check_alone.py                 # seeds 0 to 63; about 20 s
    python benchmarks/check_alone.py --seeds 4 --iterations 10
    python benchmarks/check_alone.py --variant baseline   # a config of the other path
    XLA_FLAGS=--xla_cpu_max_isa=AVX2 python benchmarks/check_alone.py   # as on an AVX2 machine

Exits with status 1 when some seed differs.
"""

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np
from train_throughput import VARIANTS

from jaxpg import programs, schedule, train_config, xla_options
from jaxpg.sweeps import check_seeds, expand_grid, run_inputs


def train(num_seeds, iterations, variant, seed=None):
    """The `TrainResult` of seeds 0..num_seeds-1 trained in one part, or of `seed` alone, as
    `{path of a leaf (jax.tree_util.keystr): leaf [R, ...]}`; `variant` names the config
    (`train_throughput.VARIANTS`)."""
    config = train_config.TrainConfig(iterations=iterations, **VARIANTS[variant])
    inputs = run_inputs(config, check_seeds(range(num_seeds)), expand_grid(config, None))
    if seed is not None:
        inputs = jax.tree.map(lambda x: x[seed:seed + 1], inputs)
    (result,) = schedule.train_blocks(programs.compiled_program(config), iterations, [inputs])
    leaves, _ = jax.tree_util.tree_flatten_with_path(result)
    return {jax.tree_util.keystr(path): np.asarray(leaf) for path, leaf in leaves}


def train_alone(num_seeds, iterations, variant, path):
    """Trains each seed alone, as `jaxpg train` would, and saves its leaves in `path` as
    `f"{seed} {leaf's path}"`."""
    xla_options.configure_xla(runs=1)  # before JAX starts its backends
    np.savez(path, **{f"{seed} {name}": leaf[0] for seed in range(num_seeds)
                      for name, leaf in train(num_seeds, iterations, variant, seed).items()})


def differing_seeds(num_seeds, iterations, variant):
    """(seeds with other parameters alone, seeds with any difference, the leaves that differ) of
    seeds 0..num_seeds-1."""
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "alone.npz"
        child = subprocess.run([sys.executable, __file__, "--seeds", str(num_seeds),
                                "--iterations", str(iterations), "--variant", variant,
                                "--alone", str(path)])
        if child.returncode:
            sys.exit(f"training the seeds alone failed (status {child.returncode})")
        with np.load(path) as saved:
            alone = dict(saved)
    xla_options.configure_xla()  # before JAX starts its backends, as a sweep of many runs
    schedule.usable_cores = lambda: 1  # one thread trains the blocks: none of the seeds alone
    together = train(num_seeds, iterations, variant)
    other_params, any_difference, leaves = [], [], set()
    for seed in range(num_seeds):
        differs = {name for name, leaf in together.items()
                   if alone[f"{seed} {name}"].tobytes() != leaf[seed].tobytes()}
        if any(name.startswith(".policy_params") for name in differs):
            other_params.append(seed)
        if differs:
            any_difference.append(seed)
        leaves |= differs
    return other_params, any_difference, sorted(leaves)


def main():
    parser = argparse.ArgumentParser(description="seeds alone against the same seeds in one block")
    parser.add_argument("--seeds", type=int, default=64, help="seeds 0..N-1 (default 64)")
    parser.add_argument("--iterations", type=int, default=150, help="(default the book's 150)")
    parser.add_argument("--variant", choices=list(VARIANTS), default="builtin",
                        help="the config: the book's (builtin), or another policy or loss")
    parser.add_argument("--alone", type=Path, help=argparse.SUPPRESS)  # the seeds-alone process
    args = parser.parse_args()
    fewest = schedule.ALONE_PER_CORE + 1  # on the one core it gives the block, fewer train alone
    if args.seeds < fewest:
        parser.error(f"--seeds: at least {fewest} (fewer seeds would train alone in the block's "
                     f"process too), got {args.seeds}")
    if args.alone:
        return train_alone(args.seeds, args.iterations, args.variant, args.alone)
    other_params, any_difference, leaves = differing_seeds(args.seeds, args.iterations,
                                                           args.variant)
    print(f"{len(other_params)} of {args.seeds} seeds ended with other parameters alone "
          f"{other_params}; {len(any_difference)} differed in some statistic {any_difference}"
          f"{' (' + ', '.join(leaves) + ')' if leaves else ''}")
    sys.exit(1 if any_difference else 0)


if __name__ == "__main__":
    main()
