"""End-to-end time of a `jaxpg train` process on the defaults, by where its programs come from.

Each round runs one process of each kind, alternating, so that the machine's drift touches all
alike; the table gives the median, min and max wall time of each (imports, training, results and
picture written), and the median time inside `train` (finding or compiling the programs, then the
150 iterations), which `jaxpg train` writes to metrics.json:

- kept: the programs that `train` keeps whole (`jaxpg.executables`), written by an untimed first
  run;
- jax cache: JAX's persistent compilation cache, warmed by an untimed first run; the process
  still traces and lowers the programs to look them up;
- compile: `--no-cache`, compiling afresh.

    python benchmarks/start_up.py                  # 6 rounds
    python benchmarks/start_up.py --rounds 2       # a quick check that everything runs
"""

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import common

# `train` turns on its own store unless --no-cache; with JAX's cache set first it finds the store
# off (one process never uses both) and looks its programs up in JAX's cache.
JAX_CACHE = """
import sys, jax
jax.config.update("jax_compilation_cache_dir", sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
from jaxpg import cli
cli.main(sys.argv[2:])
"""


def commands(scratch):
    """{kind: (command, environment, results directory)}, under `scratch`."""
    train = ["train", "--quiet", "--out"]
    env = {**os.environ, "XDG_CACHE_HOME": str(scratch / "home")}
    cli = [sys.executable, "-m", "jaxpg.cli"]
    return {
        "kept": ([*cli, *train, str(scratch / "kept")], env, scratch / "kept"),
        "jax cache": ([sys.executable, "-c", JAX_CACHE, str(scratch / "xla"), *train,
                       str(scratch / "jax"), "--no-cache"], env, scratch / "jax"),
        "compile": ([*cli, *train, str(scratch / "compile"), "--no-cache"], env,
                    scratch / "compile"),
    }


def timed_run(command, env, out):
    """(wall time of the process, its time inside `train`) in seconds."""
    start = time.perf_counter()
    subprocess.run(command, env=env, check=True, capture_output=True)
    wall = time.perf_counter() - start
    return wall, json.loads((out / "metrics.json").read_text())["seconds"]


def main():
    parser = argparse.ArgumentParser(description="end-to-end time of a jaxpg train process")
    parser.add_argument("--rounds", type=int, default=6, help="processes of each kind (default 6)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        runs = commands(pathlib.Path(scratch))
        first = {kind: timed_run(*runs[kind])[0] for kind in ("kept", "jax cache")}  # warm them
        times = {kind: [] for kind in runs}
        for round_ in range(args.rounds):
            for kind, run in runs.items():
                times[kind].append(timed_run(*run))
            print(f"round {round_ + 1}/{args.rounds}: "
                  + ", ".join(f"{kind} {t[-1][0]:.2f} s" for kind, t in times.items()), flush=True)
    rows = []
    for kind, pairs in times.items():
        wall, train = zip(*pairs)
        rows.append({"programs from": kind, "median_s": statistics.median(wall), "min_s": min(wall),
                     "max_s": max(wall), "train_median_s": statistics.median(train),
                     "first_run_s": first.get(kind)})
    common.print_table(rows, list(rows[0]), title="jaxpg train on the defaults, whole process")
    common.write_results("start_up", args, rows, times_s=times)


if __name__ == "__main__":
    main()
