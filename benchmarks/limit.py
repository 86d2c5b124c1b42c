"""The book's REINFORCE workload at the machine's limit, a hand-vectorised C program, against jaxpg.

The workload is `TrainConfig()`'s: REINFORCE with a Dense(5) elu -> Dense(1) sigmoid policy, 150
iterations of 10 episodes of at most 200 steps, Adam. The C programs in `benchmarks/limit/` train
it with one run per vector lane (`limit_reinforce.c` with AVX-512, `limit_reinforce_avx2.c` with
AVX2), float32 throughout, with their own random numbers and polynomial sines (their headers say
what they approximate). This script builds the one the CPU runs (or `--program`) with the line in
its header, runs it, and in the same process times jaxpg's `sweep` of `--seeds` seeds and `train`
of one seed: the first call (compiling) apart from the median of `--repeats` warm calls. The
ratios are jaxpg's warm time over the C program's: `--seeds` seeds against the C program's R runs
on two threads (the program's own setting), one seed against its R = 1 on one thread. jaxpg runs
under the command's XLA setting for many runs (`xla_options.configure_xla()`, as `sweep` sets it
in a fresh process; the command would give a run alone one thread, which a process also sweeping
does not).

    python benchmarks/limit.py                             # 1024 seeds, 3 repeats
    python benchmarks/limit.py --seeds 64 --repeats 1      # a quick check that everything runs
"""

import argparse
import pathlib
import re
import shutil
import subprocess
import tempfile

import common

from jaxpg import TrainConfig, sweep, train, xla_options

SOURCES = pathlib.Path(__file__).resolve().parent / "limit"
PROGRAMS = {"avx512": "limit_reinforce.c", "avx2": "limit_reinforce_avx2.c"}
# The build line of each program's header.
BUILD = ["gcc", "-O3", "-march=native", "-ffast-math", "-fopenmp"]
# A row of the C program's table: "R=1024, 2 threads  0.5687  172141790  3.027e+08  5.402e+08".
ROW = re.compile(r"^R=(\d+), (\d+) threads?\s+([\d.]+)\s+(\d+)\s+([\d.e+]+)\s+([\d.e+]+)\s*$")


def cpu_program():
    """`avx512` if this CPU has AVX-512 (its foundation and the BW/DQ/VL parts), else `avx2`."""
    flags = set()
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                break
    return "avx512" if {"avx512f", "avx512bw", "avx512dq", "avx512vl"} <= flags else "avx2"


def build(program, folder):
    """Compiles the C program `program` into `folder`; returns its path."""
    binary = folder / PROGRAMS[program].removesuffix(".c")
    subprocess.run([*BUILD, "-o", str(binary), str(SOURCES / PROGRAMS[program]), "-lm"],
                   check=True)
    return binary


def run_limit(binary, runs, repeats):
    """Runs the C program on `runs` runs; its table's rows and its output."""
    output = subprocess.run([str(binary), "-R", str(runs), "-reps", str(repeats)], check=True,
                            capture_output=True, text=True).stdout
    rows = []
    for line in output.splitlines():
        match = ROW.match(line.strip())
        if match:
            r, threads, seconds, steps, _, _ = match.groups()
            rows.append({"impl": f"C {binary.name}", "runs": int(r), "threads": int(threads),
                         "run_s": float(seconds), "real_steps": int(steps)})
    if len(rows) != 3:
        raise RuntimeError(f"{binary.name}: expected a table of three rows, got:\n{output}")
    return rows, output


def time_jaxpg(label, call, config, repeats):
    """The first call of `call()` (compiling) and the median of `repeats` warm calls; the real
    steps of its result (`config`'s episodes x mean length, summed over iterations and runs)."""
    first, _ = common.time_calls(call, repeats=1)
    warm, result = common.time_calls(call, repeats=repeats)
    lengths = result.metrics.mean_length
    return {"impl": f"jaxpg {label}", "runs": lengths.size // config.iterations,
            "first_call_s": first["min_s"], "run_s": warm["median_s"], "times_s": warm["times_s"],
            "real_steps": int(round(float(lengths.sum()) * config.episodes))}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1024,
                        help="seeds of jaxpg's sweep and runs of the C program (default 1024)")
    parser.add_argument("--repeats", type=int, default=3, help="warm calls and C runs (median)")
    parser.add_argument("--program", choices=sorted(PROGRAMS),
                        help="the C program to build (default: AVX-512 where the CPU has it)")
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error("--seeds: must be a positive integer")
    if shutil.which(BUILD[0]) is None:
        parser.error(f"{BUILD[0]} is not on PATH: it builds the C program")
    args.program = args.program or cpu_program()
    xla_options.configure_xla()  # before JAX starts: as the command for many runs
    common.print_header("The book's REINFORCE: a hand-vectorised C program against jaxpg")

    with tempfile.TemporaryDirectory() as folder:
        rows, output = run_limit(build(args.program, pathlib.Path(folder)), args.seeds,
                                 args.repeats)
    print(output)
    config = TrainConfig()
    rows.append(time_jaxpg(f"sweep {args.seeds} seeds", lambda: sweep(
        config, seeds=range(args.seeds), show_progress=False), config, args.repeats))
    rows.append(time_jaxpg("train 1 seed", lambda: train(config, seed=42, show_progress=False),
                           config, args.repeats))
    for row in rows:
        row["real_steps_per_s"] = row["real_steps"] / row["run_s"]
    common.print_table(rows, ["impl", "runs", "threads", "first_call_s", "run_s", "real_steps",
                              "real_steps_per_s"],
                       title="seconds (C: its median; jaxpg: median warm call)")
    one_thread, all_threads, alone, swept, trained = rows
    ratios = {f"sweep {args.seeds} / C R={args.seeds} {all_threads['threads']}T":
              swept["run_s"] / all_threads["run_s"],
              f"sweep {args.seeds} / C R={args.seeds} 1T": swept["run_s"] / one_thread["run_s"],
              "train 1 / C R=1 1T": trained["run_s"] / alone["run_s"]}
    print()
    for name, ratio in ratios.items():
        print(f"time ratio {name}: {ratio:,.1f}x")
    common.write_results("limit", args, rows, ratios=ratios, limit_output=output)


if __name__ == "__main__":
    main()
