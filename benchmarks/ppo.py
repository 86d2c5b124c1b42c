"""PPO on CartPole-v1: how soon and how well `losses.PPO` trains, against the book's REINFORCE.

Each row trains `--seeds` seeds for `--iterations` iterations of 10 episodes in one `sweep` (the
first call, compiling included, and one warm call), and reports the median last-10 mean return,
its interquartile mean, and the median first iteration whose trailing 10-iteration mean reaches
195 (`Summary.first_solved`; -1 for a seed that never does):

- `reinforce`: the book's settings, `TrainConfig()`.
- `ppo-dense5`: the default Dense(5) policy and linear critic, 4 epochs x 2 minibatches, at a
  learning rate of 0.003.
- `ppo-32`: a Dense(32, tanh) policy and critic, discount 0.99, 4 epochs x 2 minibatches, at
  0.01 (the README's setting).

Every row runs under the `jaxpg` command's XLA setting for many runs (`xla_options.configure_xla`).

    python benchmarks/ppo.py                 # 64 seeds, 150 iterations
    python benchmarks/ppo.py --quick
"""

import argparse
import time

import common
import numpy as np

from jaxpg import TrainConfig, losses, stats, sweep, xla_options

ROWS = {
    "reinforce": TrainConfig(),
    "ppo-dense5": TrainConfig(loss="ppo", epochs=4, minibatches=2, learning_rate=0.003),
    "ppo-32": TrainConfig(loss=losses.PPO(losses.ValueNetwork((32,))), epochs=4, minibatches=2,
                          hidden=(32,), activation="tanh", discount=0.99),
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=150)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.iterations = 2, 12
    xla_options.configure_xla()  # before the header starts JAX: as `sweep` in a fresh process
    common.print_header("PPO against REINFORCE on CartPole-v1")
    rows = []
    for name, config in ROWS.items():
        config = TrainConfig(**{**config.__dict__, "iterations": args.iterations})
        times = []
        for _ in range(2):
            start = time.perf_counter()
            result = sweep(config, seeds=range(args.seeds), show_progress=False)
            times.append(time.perf_counter() - start)
        final, first = result.summary.final_return[0], result.summary.first_solved[0]
        rows.append({"row": name, "seeds": args.seeds, "first_call_s": times[0],
                     "warm_s": times[1], "median_last10": float(np.median(final)),
                     "iqm_last10": float(stats.iqm(final)),
                     "median_first_solved": float(np.median(first)),
                     "never_solved": int(np.sum(first < 0))})
    common.print_table(rows, ["row", "seeds", "first_call_s", "warm_s", "median_last10",
                              "iqm_last10", "median_first_solved", "never_solved"])
    common.write_results("ppo", args, rows)


if __name__ == "__main__":
    main()
