"""Do seeds train alone exactly as side by side? The check to run after any change for speed.

Trains seeds 0..R-1 of the book's settings side by side on one core (in blocks of at most
`reinforce.CPU_BLOCK` runs), then each seed alone, under the `jaxpg` command's XLA setting (XLA's
threads one per core for both; the command gives a run alone one thread, which trains bit for bit
alike: `tests/test_flags.py`), and counts the seeds whose parameters or statistics differ in any
bit (-0 and +0 differ too).
Programs of one run and of several are compiled apart, and XLA can round them differently (see
`jaxpg.flags`): the suite checks 16 seeds, this script as many as asked.

    python benchmarks/check_alone.py                 # seeds 0 to 63; about 15 s
    python benchmarks/check_alone.py --seeds 4 --iterations 10

Exits with status 1 when some seed differs.
"""

import argparse
import sys

import jax
import numpy as np

from jaxpg import flags, reinforce
from jaxpg.sweep import check_seeds, expand_grid, run_inputs

flags.configure_xla()  # before JAX starts its backends


def _same_bits(a, b):
    return all(np.asarray(x).tobytes() == np.asarray(y).tobytes()
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def differing_seeds(num_seeds, iterations):
    """(seeds with other parameters alone, seeds with any difference) of seeds 0..num_seeds-1."""
    reinforce.usable_cores = lambda: 1  # blocks as large as they come
    config = reinforce.TrainConfig(iterations=iterations)
    program = reinforce.compiled_program(config)
    inputs = run_inputs(check_seeds(range(num_seeds)), expand_grid(config, None))
    (together,) = reinforce.run(program, iterations, [inputs])
    other_params, any_difference = [], []
    for seed in range(num_seeds):
        (alone,) = reinforce.run(program, iterations,
                                 [jax.tree.map(lambda x: x[seed:seed + 1], inputs)])
        mine = jax.tree.map(lambda x: x[seed], together)
        alone = jax.tree.map(lambda x: x[0], alone)
        params = not _same_bits(alone.policy_params, mine.policy_params)
        metrics = not _same_bits(alone.metrics, mine.metrics)
        if params:
            other_params.append(seed)
        if params or metrics:
            any_difference.append(seed)
    return other_params, any_difference


def main():
    parser = argparse.ArgumentParser(description="seeds alone against the same seeds in one block")
    parser.add_argument("--seeds", type=int, default=64, help="seeds 0..N-1 (default 64)")
    parser.add_argument("--iterations", type=int, default=150, help="(default the book's 150)")
    args = parser.parse_args()
    other_params, any_difference = differing_seeds(args.seeds, args.iterations)
    print(f"{len(other_params)} of {args.seeds} seeds ended with other parameters alone "
          f"{other_params}; {len(any_difference)} differed in some statistic {any_difference}")
    sys.exit(1 if any_difference else 0)


if __name__ == "__main__":
    main()
