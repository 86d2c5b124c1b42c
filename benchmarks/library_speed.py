"""`train` and `sweep` called from Python against the `jaxpg` command, each in a fresh process.

The command sets up XLA for the runs it trains (`jaxpg.xla_options.configure_xla(runs=...)`); a
Python program that calls `train` or `sweep` first gets the setting from them
(`xla_options.configure_unstarted`: all but the one thread for XLA that the command gives a run
alone). Each round runs one process of each kind, alternating, both compiling afresh
(`--no-cache`; no `keep_programs`), and compares the time inside `train`/`sweep` (compiling and
training), which the command writes to its results.

    python benchmarks/library_speed.py                  # 1 and 256 seeds, 5 rounds
    python benchmarks/library_speed.py --rounds 1       # a quick check that everything runs
"""

import argparse
import json
import pathlib
import statistics
import subprocess
import sys
import tempfile

import common

PYTHON = """
import json, sys, time
from jaxpg import TrainConfig, sweep, train
seeds = int(sys.argv[1])
start = time.perf_counter()
if seeds == 1:
    train(TrainConfig(), seed=42, show_progress=False)
else:
    sweep(TrainConfig(), seeds=range(seeds), show_progress=False)
print(json.dumps(time.perf_counter() - start))
"""


def command_seconds(seeds, out):
    """Seconds inside `train`/`sweep` of a `jaxpg train` (1 seed) or `jaxpg sweep` process."""
    args = (["train", "--seed", "42"] if seeds == 1 else ["sweep", "--seeds", str(seeds)])
    subprocess.run([sys.executable, "-m", "jaxpg.cli", *args, "--quiet", "--no-cache",
                    "--out", str(out)], check=True, capture_output=True)
    results = out / ("metrics.json" if seeds == 1 else "summary.json")
    return json.loads(results.read_text())["seconds"]


def python_seconds(seeds):
    """Seconds inside `train`/`sweep` of a Python process that calls it, nothing set up."""
    child = subprocess.run([sys.executable, "-c", PYTHON, str(seeds)], check=True,
                           capture_output=True, text=True)
    return json.loads(child.stdout.splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,256", help="comma-separated numbers of seeds")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    common.print_header("train and sweep from Python against the jaxpg command")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for seeds in [int(s) for s in args.seeds.split(",")]:
            times = {"command": [], "python": []}
            for round_ in range(args.rounds):
                out = pathlib.Path(scratch) / f"{seeds}-{round_}"
                times["command"].append(command_seconds(seeds, out))
                times["python"].append(python_seconds(seeds))
            medians = {kind: statistics.median(values) for kind, values in times.items()}
            rows.append({"seeds": seeds, **{f"{kind}_s": values for kind, values in times.items()},
                         **{f"{kind}_median_s": m for kind, m in medians.items()},
                         "python_over_command": medians["python"] / medians["command"]})
            print(f"{seeds} seeds: command {medians['command']:.2f} s, python "
                  f"{medians['python']:.2f} s (medians of {args.rounds}): "
                  f"{rows[-1]['python_over_command']:.2f}x", flush=True)
    common.write_results("library_speed", args, rows)


if __name__ == "__main__":
    main()
