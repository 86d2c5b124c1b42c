"""Compile time, run time and environment steps per second of REINFORCE training, jaxpg vs numpy.

jaxpg trains R runs (seeds 0..R-1) of the book's settings (`TrainConfig()`) at once with
`schedule.train_blocks`, whose compiled program runs ten iterations a call; compiling its two
programs (`init` and `iterate`, for each size of block of runs that `train_blocks` trains:
`schedule.part_blocks`, as `train_blocks` compiles them: `schedule.prepare`) is timed apart from
the runs, which follow one untimed warm-up run. The
numpy book implementation (`book_numpy.py`: one seed, one step at a time on Gymnasium's
CartPole-v1) runs in the same process for scale.

Step counts:
- simulated steps: steps inside an episode before it ended (sum over runs and iterations of
  mean_length * episodes); the only kind the numpy trainer takes.
- padded steps: iterations * episodes * max_steps * R, the fixed horizon of every iteration.
- skipped: the share of padded steps the rollout never simulates, because every episode of every
  run in a block of runs (`schedule.cpu_blocks`) had ended before their chunk of `rollout.CHUNK`
  steps (from each block's longest episode in each iteration). The gradient's time loop stops
  there too; its step signals are computed for all steps at once.

Each R is measured in a process of its own, started afresh, with the XLA setting that the `jaxpg`
command has for R runs (`jaxpg.xla_options.configure_xla(runs=R)`: one thread for XLA's CPU
client for one run), unless XLA_FLAGS already passes backend options or PJRT_NPROC (or NPROC) is
set; XLA's own defaults are measured with `XLA_FLAGS` set to `jaxpg.xla_options.XLA_DEFAULTS`. Its
compile time is therefore that of a cold process, and its peak RSS that process's peak. The numpy
trainer runs in the script's own process, whose peak the file's top-level `peak_rss_mib` is.

    python benchmarks/train_throughput.py                    # seeds 1 to 1024; 150 iterations
    python benchmarks/train_throughput.py --quick            # a quick check that everything runs
"""

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time

import book_numpy
import common
import flax.linen as nn
import numpy as np

from jaxpg import programs, rollout, schedule, train_config, xla_options
from jaxpg.sweeps import check_seeds, expand_grid, run_inputs


def step_counts(config, num_runs, mean_lengths):
    """(simulated steps, padded steps) of R runs whose `mean_lengths` are `[R, I]`."""
    simulated = float(np.sum(mean_lengths)) * config.episodes
    padded = config.iterations * config.episodes * config.max_steps * num_runs
    return simulated, padded


def skipped_fraction(config, max_lengths):
    """Share of padded steps in chunks after every episode ended; `max_lengths` `[R, I]`."""
    chunk = min(rollout.CHUNK, config.max_steps)
    computed = 0.0
    for start, stop in schedule.cpu_blocks(max_lengths.shape[0])[0]:
        block = max_lengths[start:stop]
        longest = np.max(block, axis=0)  # a block skips a chunk once all its episodes ended
        steps = np.minimum(np.ceil(longest / chunk) * chunk, config.max_steps)
        computed += float(np.sum(steps)) * block.shape[0]
    return 1.0 - computed / (config.max_steps * config.iterations * max_lengths.shape[0])


def compile_programs(program, blocks):
    """Compiles `program` for `blocks` as `schedule.train_blocks` does (`schedule.prepare`), timed.

    Returns:
      {"lower_s": until every program is traced and lowered, "compile_s": then until every one is
      compiled}; `iterate`'s compile starts while `init` is still being traced, so their sum is
      the time `schedule.train_blocks` takes to have its programs, and neither part alone is XLA's.
    """
    start = time.perf_counter()
    programs = schedule.prepare(program, blocks)
    lowered_at = time.perf_counter()
    for compiled in programs:
        compiled.result()
    done = time.perf_counter()
    return {"lower_s": lowered_at - start, "compile_s": done - lowered_at}


class BookModule(nn.Module):
    """The default network's shape written as a user would: Dense(5) -> elu -> Dense(1)."""

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(1)(nn.elu(nn.Dense(5)(obs)))


# Configs trained beside the built-in path: a user's module, the baseline loss, an entropy bonus.
VARIANTS = {
    "builtin": {},
    "module": {"policy": BookModule()},
    "baseline": {"loss": "baseline"},
    "entropy": {"entropy_coef": 0.01},
}


def measure_jaxpg(config, num_runs, repeats, variant="builtin"):
    """`measure_row` in a fresh process with the `jaxpg` command's setting for `num_runs` runs."""
    command = [sys.executable, __file__, "--row", str(num_runs), "--variants", variant,
               "--iterations", str(config.iterations), "--repeats", str(repeats)]
    child = subprocess.run(command, stdout=subprocess.PIPE, text=True)
    rows = [line[len(ROW):] for line in child.stdout.splitlines() if line.startswith(ROW)]
    if child.returncode or len(rows) != 1:
        sys.exit(f"the row of R={num_runs} failed (status {child.returncode})")
    return json.loads(rows[0])


ROW = "row: "  # the line of a row's process that holds its measurements, as JSON


def measure_row(config, num_runs, repeats, variant="builtin"):
    """Compiles the training of `num_runs` seeds, runs it once, then times `repeats` runs."""
    xla_options.configure_xla(runs=num_runs)  # before JAX starts its backends
    # Seeds 0..R-1 under the config's own settings, passed as a sweep passes them.
    keys, hyperparams = run_inputs(config, check_seeds(range(num_runs)), expand_grid(config, None))
    program = programs.compiled_program(config)
    parts = [(keys, hyperparams)]
    times = compile_programs(program, [block for block, _ in schedule.part_blocks(parts[0])])
    schedule.train_blocks(program, config.iterations, parts)  # warm-up
    timing, (result,) = common.time_calls(
        schedule.train_blocks, program, config.iterations, parts, repeats=repeats
    )
    metrics = result.metrics
    simulated, padded = step_counts(config, num_runs, np.asarray(metrics.mean_length))
    # With a reward of 1 per step, an episode's return is its length.
    skipped = skipped_fraction(config, np.asarray(metrics.max_return))
    impl = "jaxpg" if variant == "builtin" else f"jaxpg-{variant}"
    return _row(impl, num_runs, config.iterations, timing["median_s"], simulated, padded,
                np.mean(np.asarray(metrics.mean_return)[:, -1]),
                times_s=timing["times_s"], skipped_fraction=skipped,
                xla_cpu_threads=next((os.environ[name] for name in xla_options.THREADS
                                      if os.environ.get(name)), "one per core"), **times)


def measure_book(config, iterations, env_id):
    """The numpy book trainer, one seed; with fewer iterations than the config's, its run time is
    extrapolated from the mean time per iteration (an underestimate: episodes lengthen as the
    policy learns). Steps per second are those measured."""
    history = book_numpy.run(seed=0, iterations=iterations, env_id=env_id)
    seconds = sum(history.seconds)
    padded = iterations * book_numpy.N_EPISODES_PER_UPDATE * book_numpy.N_MAX_STEPS
    row = _row("book-numpy", 1, iterations, seconds, sum(history.steps), padded,
               history.mean_returns[-1], env=env_id)
    row["run_s_for_config_iterations"] = seconds / iterations * config.iterations
    row["extrapolated"] = iterations != config.iterations
    return row


def _row(impl, num_runs, iterations, run_s, simulated, padded, final_mean_return, **extra):
    return {
        "impl": impl,
        "n": num_runs,
        "iterations": iterations,
        "run_s": run_s,
        "simulated_steps": simulated,
        "padded_steps": padded,
        "steps_per_s": simulated / run_s,
        "padded_steps_per_s": padded / run_s,
        "final_mean_return": float(final_mean_return),
        **extra,
        "peak_rss_mib": common.peak_rss_mib(),
    }


def parse_args():
    parser = argparse.ArgumentParser(description="REINFORCE training throughput, jaxpg vs numpy")
    parser.add_argument("--quick", action="store_true",
                        help="seeds 1,8, 10 iterations, 5 numpy iterations: checks that all runs")
    parser.add_argument("--seeds", default="1,8,64,256,1024",
                        help="comma-separated numbers of seeds R trained at once")
    parser.add_argument("--iterations", type=int, default=None,
                        help="training iterations (default: TrainConfig's, the book's 150)")
    parser.add_argument("--repeats", type=int, default=None,
                        help="timed runs per R (default: 3 up to 64 seeds, else 1)")
    parser.add_argument("--book-iterations", type=int, default=None,
                        help="iterations of the numpy trainer (default: as --iterations; "
                             "fewer are extrapolated); 0 skips it")
    parser.add_argument("--book-env", default="CartPole-v1",
                        help="Gymnasium env id the numpy trainer runs on")
    parser.add_argument("--variants", default="builtin",
                        help="comma-separated configs to train, each R in turn: "
                             + ", ".join(VARIANTS))
    parser.add_argument("--row", type=int, help=argparse.SUPPRESS)  # one R, printed as JSON
    args = parser.parse_args()
    if args.quick:
        args.seeds = "1,8"
        args.iterations = args.iterations or 10
        args.book_iterations = 5 if args.book_iterations is None else args.book_iterations
    args.seeds = [int(r) for r in args.seeds.split(",")]
    args.variants = args.variants.split(",")
    if not set(args.variants) <= set(VARIANTS):
        parser.error(f"--variants: allowed: {', '.join(VARIANTS)}")
    if any(r < 1 for r in args.seeds):
        parser.error("--seeds: every R must be a positive integer")
    return args


def main():
    args = parse_args()
    config = train_config.TrainConfig()
    if args.iterations:
        config = dataclasses.replace(config, iterations=args.iterations)
    if args.row is not None:
        (variant,) = args.variants
        config = dataclasses.replace(config, **VARIANTS[variant])
        print(ROW + json.dumps(measure_row(config, args.row, repeats(args, args.row), variant)))
        return
    xla_options.configure_xla()  # the rows' processes inherit it; each adds its own threads
    book_iterations = config.iterations if args.book_iterations is None else args.book_iterations
    common.print_header(f"REINFORCE training throughput: {config}")

    rows = []
    for num_runs in sorted(args.seeds):
        for variant in args.variants:
            rows.append(measure_jaxpg(config, num_runs, repeats(args, num_runs), variant))
            _print_progress(rows[-1])
    if book_iterations:
        rows.append(measure_book(config, book_iterations, args.book_env))
        _print_progress(rows[-1])

    columns = ["impl", "n", "iterations", "lower_s", "compile_s", "run_s", "steps_per_s",
               "padded_steps_per_s", "skipped_fraction", "final_mean_return", "peak_rss_mib",
               "xla_cpu_threads"]
    common.print_table(rows, columns, title="steps/s = simulated steps / run_s (median run)")
    book = [row for row in rows if row["impl"] == "book-numpy"]
    if book and book[0]["extrapolated"]:
        estimate = book[0]["run_s_for_config_iterations"]
        print(f"book-numpy ran {book[0]['iterations']} iterations; {config.iterations} would "
              f"take about {estimate:.1f} s (extrapolated, an underestimate)")
    for row in rows:
        if row["impl"] == "jaxpg" and book:
            print(f"jaxpg R={row['n']}: {row['steps_per_s'] / book[0]['steps_per_s']:,.1f}x "
                  f"the numpy trainer's simulated steps/s")
    builtin = {row["n"]: row["run_s"] for row in rows if row["impl"] == "jaxpg"}
    for row in rows:
        if row["impl"].startswith("jaxpg-") and row["n"] in builtin:
            compiled = row["lower_s"] + row["compile_s"]
            print(f"{row['impl']} R={row['n']}: {row['run_s'] / builtin[row['n']]:.2f}x the "
                  f"built-in path's run time, compiled in {compiled:.2f} s")
    path = common.write_results("train_throughput", args, rows, config=dataclasses.asdict(config))
    common.write_chart(rows, path, "REINFORCE training, simulated env steps/s",
                       xlabel="R (seeds trained at once)")


def repeats(args, num_runs):
    """Timed runs of R runs: `--repeats`, or 3 up to 64 seeds and 1 above."""
    return args.repeats or (3 if num_runs <= 64 else 1)


def _print_progress(row):
    print(f"{row['impl']:>14}  R={row['n']:<5}  {row['run_s']:8.2f} s  "
          f"{row['steps_per_s']:>14,.0f} simulated steps/s", flush=True)


if __name__ == "__main__":
    main()
