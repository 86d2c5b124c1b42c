"""A researcher's own network on jaxpg's trainer against the same trainer in plain JAX.

Rows, each timed in this one process (first call, compiling included, then the best of
`--repeats` warm calls), for S seeds of 150 iterations x 10 episodes x 200 steps:

- `mlp`: `sweep(TrainConfig(policy=MLP((32, 32))))`, a two-layer tanh MLP with two logits and the
  book's loss; `plain` the same network and loss in `plain_jax.py` (`jit(vmap(scan(...)))`).
- `mlp-2x64`, `plain-2x64`: the same with two layers of 64.
- `mlp-reward-to-go`, `mlp-baseline`: the 32x32 MLP with the other built-in losses.
- `book`: `sweep(TrainConfig())`, the book's network and loss on the built-in path; `plain-book`
  the plain trainer with the same layer (Dense(5), elu) and two logits.

Every row runs in this process under the `jaxpg` command's XLA setting for many runs
(`jaxpg.xla_options.configure_xla()`, set before JAX starts, as `sweep` sets it in a fresh
process), the plain trainer too. Also:

- `--against DIR`: the default network at the book's settings, 1 seed (`train`) and 1024 seeds
  (`sweep`), each in a fresh process, alternating between this checkout and the one in DIR (an
  older commit: `git worktree add DIR COMMIT`); medians of `--rounds`.
- `--start-up`: fresh processes train one seed of the MLP with its programs kept by
  `keep_programs` or by JAX's persistent compilation cache: a first process that fills the store,
  then `--rounds` that find them there, the two stores alternating; each process's first call,
  the training programs XLA compiled, and its other (small) compiles and their seconds.

    python benchmarks/one_engine.py --seeds 64 --repeats 3
    python benchmarks/one_engine.py --seeds 1024 --repeats 1 --rows mlp,plain
    python benchmarks/one_engine.py --rows none --against /tmp/old --rounds 3
    python benchmarks/one_engine.py --rows none --start-up
    python benchmarks/one_engine.py --quick    # a quick check that everything runs
"""

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

import common
import jax
import numpy as np
import plain_jax

from jaxpg import TrainConfig, sweep, xla_options

ROWS = {
    "mlp": dict(hidden=(32, 32)),
    "plain": dict(hidden=(32, 32), activation="tanh", plain=True),
    "mlp-2x64": dict(hidden=(64, 64)),
    "plain-2x64": dict(hidden=(64, 64), activation="tanh", plain=True),
    "mlp-reward-to-go": dict(hidden=(32, 32), loss="reward-to-go"),
    "mlp-baseline": dict(hidden=(32, 32), loss="baseline"),
    "book": dict(),
    "plain-book": dict(hidden=(5,), activation="elu", plain=True),
}
ROOT = pathlib.Path(__file__).resolve().parent.parent  # this checkout
PEERS = {"mlp-2x64": "plain-2x64", "book": "plain-book"}  # the plain row of each (else `plain`)


def trainer(row, seeds, iterations):
    """`() -> median last-10 mean return` of a row's S seeds, trained once per call."""
    spec = dict(ROWS[row])
    if spec.pop("plain", False):
        train = plain_jax.make_train(plain_jax.MLP(spec["hidden"], spec["activation"]),
                                     iterations=iterations)
        keys = np.arange(seeds)
        return lambda: float(np.median(
            np.asarray(jax.block_until_ready(train(keys))[1])[:, -10:].mean(axis=1)))
    if "hidden" in spec:  # a researcher's own module; the book's network on the built-in path
        spec["policy"] = plain_jax.MLP(spec.pop("hidden"))
    config = TrainConfig(iterations=iterations, **spec)
    return lambda: float(np.median(
        sweep(config, seeds=range(seeds), show_progress=False).summary.final_return))


def time_row(row, seeds, iterations, repeats):
    """The row's first call and best warm call, seconds, and its median last-10 return."""
    run = trainer(row, seeds, iterations)
    first, final = common.time_calls(run, repeats=1)
    warm, _ = common.time_calls(run, repeats=repeats)
    return {"row": row, "seeds": seeds, "first_s": first["min_s"], "warm_s": warm["min_s"],
            "warm_all_s": warm["times_s"], "median_last10": final}


BOOK = """
import json, sys, time
from jaxpg import TrainConfig, sweep, train
seeds = int(sys.argv[1])
run = (lambda: train(TrainConfig(), seed=0, show_progress=False)) if seeds == 1 else (
    lambda: sweep(TrainConfig(), seeds=range(seeds), show_progress=False))
run()
times = []
for _ in range(3):
    start = time.perf_counter()
    run()
    times.append(time.perf_counter() - start)
print(json.dumps(min(times)))
"""


def book_seconds(tree, seeds):
    """The best of three warm calls for the default network, in a fresh process of `tree`'s
    jaxpg (None: this checkout's), under that jaxpg's own XLA setting (`train` and `sweep` set it
    where nothing else has)."""
    env = {name: value for name, value in os.environ.items() if name != "XLA_FLAGS"}
    if tree is not None:
        env["PYTHONPATH"] = tree
    # Started in the tree whose jaxpg it times: `python -c` imports from its directory first.
    child = subprocess.run([sys.executable, "-c", BOOK, str(seeds)], capture_output=True,
                           text=True, check=True, env=env, cwd=tree or ROOT)
    return json.loads(child.stdout.splitlines()[-1])


START = """
import json, sys, time
sys.path.insert(0, sys.argv[2])
import jax, plain_jax
from jaxpg import TrainConfig, keep_programs, train
compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, fun_name="", **kw: compiles.append((fun_name, duration))
    if event == "/jax/core/compile/backend_compile_duration" else None)
if sys.argv[4] == "kept":
    keep_programs(sys.argv[1])
else:  # JAX's own persistent compilation cache, as `jaxpg reproduce` uses it
    jax.config.update("jax_compilation_cache_dir", sys.argv[1])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
start = time.perf_counter()
train(TrainConfig(policy=plain_jax.MLP((32, 32)), iterations=int(sys.argv[3])),
      show_progress=False)
programs = [name for name, _ in compiles if "init_runs" in name or "_iterate_stacked" in name]
print(json.dumps({"first_call_s": time.perf_counter() - start, "training_programs": programs,
                  "other_compiles": len(compiles) - len(programs),
                  "compile_s": sum(duration for _, duration in compiles)}))
"""


STORES = ("kept", "jax-cache")  # `keep_programs`, or JAX's persistent compilation cache


def start_up(iterations, rounds):
    """Processes training one MLP seed, for each store: a first that fills it, then `rounds`
    that find their programs there, the stores alternating."""
    here = str(pathlib.Path(__file__).parent)

    def process(directory, store):
        return json.loads(subprocess.run(
            [sys.executable, "-c", START, directory, here, str(iterations), store],
            capture_output=True, text=True, check=True).stdout.splitlines()[-1])

    with tempfile.TemporaryDirectory() as kept, tempfile.TemporaryDirectory() as cache:
        directories = dict(zip(STORES, (kept, cache)))
        processes = {store: [process(directories[store], store)] for store in STORES}
        for _ in range(rounds):
            for store in STORES:
                processes[store].append(process(directories[store], store))
    return processes


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="64", help="comma-separated numbers of seeds")
    parser.add_argument("--iterations", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rows", default="mlp,plain,mlp-2x64,plain-2x64,mlp-reward-to-go,"
                        "mlp-baseline", help="comma-separated rows, or none")
    parser.add_argument("--against", help="a checkout of another commit for the default network")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--start-up", action="store_true")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.iterations, args.repeats, args.rounds = "4", 3, 1, 1
    xla_options.configure_xla()  # before the header starts JAX: as `sweep` in a fresh process
    common.print_header("a researcher's network: jaxpg's engine against plain JAX")
    rows = [] if args.rows == "none" else [
        time_row(row, int(seeds), args.iterations, args.repeats)
        for seeds in args.seeds.split(",") for row in args.rows.split(",")]
    for row in rows:
        peer = row["row"] if row["row"].startswith("plain") else PEERS.get(row["row"], "plain")
        plain = next((r for r in rows if r["seeds"] == row["seeds"] and r["row"] == peer), None)
        if plain is not None:
            row["speed_over_plain"] = plain["warm_s"] / row["warm_s"]
    if rows:
        common.print_table(rows, ["row", "seeds", "first_s", "warm_s", "speed_over_plain",
                                  "median_last10"])
    extra = {}
    if args.against:
        book = {f"{tree}-{seeds}": [] for tree in ("new", "old") for seeds in (1, 1024)}
        for _ in range(args.rounds):
            for seeds in (1, 1024):
                book[f"new-{seeds}"].append(book_seconds(None, seeds))
                book[f"old-{seeds}"].append(book_seconds(args.against, seeds))
        extra["default_network"] = {name: {"all_s": times, "median_s": statistics.median(times)}
                                    for name, times in book.items()}
        for seeds in (1, 1024):
            new, old = (extra["default_network"][f"{tree}-{seeds}"]["median_s"]
                        for tree in ("new", "old"))
            print(f"default network, {seeds} seeds: this checkout {new:.3f} s, {args.against} "
                  f"{old:.3f} s (medians of {args.rounds}): {old / new:.2f}x")
    if args.start_up:
        extra["start_up"] = start_up(args.iterations, args.rounds)
        for store, processes in extra["start_up"].items():
            for i, process in enumerate(processes):
                print(f"MLP, 1 seed, {store}, process {i}: first call "
                      f"{process['first_call_s']:.2f} s, training programs compiled: "
                      f"{process['training_programs']}, other compiles: "
                      f"{process['other_compiles']}, {process['compile_s']:.2f} s in XLA")
            print(f"{store}: median first call of the later processes "
                  f"{statistics.median(p['first_call_s'] for p in processes[1:]):.2f} s")
    common.write_results("one_engine", args, rows, **extra)


if __name__ == "__main__":
    main()
