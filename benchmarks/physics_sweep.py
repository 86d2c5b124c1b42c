"""Sweeping physics: a grid of 8 lengths x 64 seeds, and 512 seeds with domain randomisation,
against 512 seeds at CartPole-v1's one length, in one process with the command's XLA setting.

Each sweep runs once untimed (compiling; its compile time is reported apart), then `--repeats`
times timed; the table gives the median and the ratio to the one-length sweep.

    python benchmarks/physics_sweep.py                 # 150 iterations, 3 repeats
    python benchmarks/physics_sweep.py --iterations 10 --repeats 1   # a quick check
"""

import argparse
import dataclasses
import statistics
import time

import common

from jaxpg import xla_options

LENGTHS = [0.25, 0.4, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8]


def cases(config):
    """{name: (config, seeds, grid)} of the sweeps measured: 512 runs each."""
    return {
        "one length": (config, range(512), None),
        "8 lengths": (config, range(64), {"length": LENGTHS}),
        "randomised length": (dataclasses.replace(config, randomize={"length": (0.25, 2.8)}),
                              range(512), None),
    }


def timed(config, seeds, grid):
    from jaxpg import sweep

    start = time.perf_counter()
    sweep(config, seeds=seeds, grid=grid, show_progress=False)
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    xla_options.configure_xla()  # before JAX starts: as the command for many runs
    from jaxpg import TrainConfig

    config = TrainConfig(iterations=args.iterations)
    common.print_header("Sweeping physics: 512 runs each")
    rows = []
    for name, (case_config, seeds, grid) in cases(config).items():
        first = timed(case_config, seeds, grid)  # compiles
        times = [timed(case_config, seeds, grid) for _ in range(args.repeats)]
        rows.append({"case": name, "first_call_s": first, "times_s": times,
                     "run_s": statistics.median(times)})
        print(f"{name:>18}: {rows[-1]['run_s']:.2f} s (median of {args.repeats}); first call "
              f"{first:.2f} s", flush=True)
    base = rows[0]["run_s"]
    for row in rows:
        row["ratio_to_one_length"] = row["run_s"] / base
        print(f"{row['case']:>18}: {row['ratio_to_one_length']:.2f}x the one-length sweep")
    common.write_results("physics_sweep", args, rows)


if __name__ == "__main__":
    main()
