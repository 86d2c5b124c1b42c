"""Many trained policies in many physics settings: `jaxpg.evaluation.robustness` against its peers.

The policies are a sweep's (`--policies` seeds of `TrainConfig()`, trained untimed first); the
settings are the product of `--lengths` and `--masspoles`; every policy plays `--episodes` episodes
of at most `--max-steps` steps in every setting. Three ways, in this process, under the `jaxpg`
command's XLA setting (`jaxpg.xla_options.configure_xla`):

- robustness: `robustness(...)`, one compiled program for every policy and setting; its first call
  (tracing, compiling and one run) is timed apart from the warm calls that follow (median of
  `--repeats`);
- evaluate loop: `evaluate(network_policy(...), env=setting)` for each policy and setting, one
  call each, the whole loop timed (its first call compiles the first time);
- user vmap: a user's own `jax.vmap` over policies and settings of `rollout.rollout` in one `jit`,
  as a user would write it without `robustness` (its episodes are not `evaluate`'s: it lets
  `rollout` draw the initial states).

Steps are the steps played inside episodes (the sum of the returns), the same for the first two,
which must return equal arrays (checked).

    python benchmarks/robustness.py          # 64 policies x 40 settings x 100 episodes of 200 steps
    python benchmarks/robustness.py --quick  # 4 policies x 4 settings x 10 episodes: checks it runs
"""

import argparse
import itertools
import time

import common

from jaxpg import xla_options

xla_options.configure_xla()  # before JAX starts: the setting of the `jaxpg` command

import jax
import numpy as np

from jaxpg import TrainConfig, cartpole, policies, rollout
from jaxpg.evaluation import evaluate, robustness
from jaxpg.sweeps import sweep


def floats(text):
    return [float(v) for v in text.split(",")]


def evaluate_loop(policy_params, network, settings, episodes, max_steps):
    """Returns `[G, S, P, E]` of `evaluate` called once per policy and setting."""
    grid_shape = jax.tree.leaves(policy_params)[0].shape[:2]
    returns = np.zeros((*grid_shape, len(settings), episodes))
    for g, s in np.ndindex(grid_shape):
        policy = policies.network_policy(network, run_params(policy_params, g, s))
        for p, setting in enumerate(settings):
            returns[g, s, p] = evaluate(policy, episodes, max_steps,
                                        cartpole.V1.replace(**setting)).returns
    return returns


def run_params(policy_params, g, s):
    """The parameters of run (g, s) of a sweep's `[G, S, ...]`."""
    return jax.tree.map(lambda leaf: leaf[g, s], policy_params)


def user_vmap(network, episodes, max_steps):
    """A user's own program: `rollout.rollout` under `jax.vmap` over policies, then settings."""

    @jax.jit
    def play(flat_params, physics):
        def one(params, setting):
            return rollout.rollout(jax.random.PRNGKey(0), policies.network_policy(network, params),
                                   cartpole.V1.replace(**setting), episodes, max_steps).returns

        return jax.vmap(lambda params: jax.vmap(lambda s: one(params, s))(physics))(flat_params)

    return play


def timed(fn, *args, repeats=1):
    """(first call's seconds, `common.time_calls` of the warm calls, result)."""
    start = time.perf_counter()
    result = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    warm, result = common.time_calls(fn, *args, repeats=repeats)
    return first, warm, result


def main():
    parser = argparse.ArgumentParser(description="robustness evaluation against its peers")
    parser.add_argument("--quick", action="store_true", help="small sizes: only checks it runs")
    parser.add_argument("--policies", type=int, default=64, help="seeds trained (default 64)")
    parser.add_argument("--lengths", type=floats,
                        default=[0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 3.0])
    parser.add_argument("--masspoles", type=floats, default=[0.05, 0.1, 0.3, 0.5, 1.0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--max-steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3,
                        help="warm calls of robustness and the user vmap (the loop: one)")
    parser.add_argument("--peers", default="evaluate-loop,user-vmap",
                        help="peers to measure, of evaluate-loop, user-vmap (default both)")
    args = parser.parse_args()
    if args.quick:
        args.policies, args.lengths, args.masspoles, args.episodes = 4, [0.5, 1.0], [0.1, 0.5], 10
    config = TrainConfig()
    grid = {"length": args.lengths, "masspole": args.masspoles}
    settings = [dict(zip(grid, values)) for values in itertools.product(*grid.values())]
    common.print_header(f"{args.policies} policies x {len(settings)} physics settings x "
                        f"{args.episodes} episodes of at most {args.max_steps} steps")
    swept = sweep(config, seeds=range(args.policies), show_progress=False)
    size = {"policies": args.policies, "settings": len(settings), "episodes": args.episodes,
            "max_steps": args.max_steps}
    rows = []

    def row(impl, first, warm_s, returns):
        steps = float(np.sum(returns))
        rows.append({"impl": impl, **size, "first_call_s": first, "warm_s": warm_s,
                     "compile_s": first - warm_s, "steps": steps, "steps_per_s": steps / warm_s})
        print(f"{impl}: first call {first:.2f} s, warm {warm_s:.2f} s", flush=True)

    first, warm, result = timed(
        lambda: robustness(swept.policy_params, grid, args.episodes, args.max_steps,
                           network=config.network).returns, repeats=args.repeats)
    row("robustness", first, warm["median_s"], result)
    peers = args.peers.split(",")
    if "evaluate-loop" in peers:
        # The whole loop twice: the first time its first call compiles.
        first, warm, looped = timed(evaluate_loop, swept.policy_params, config.network, settings,
                                    args.episodes, args.max_steps)
        np.testing.assert_array_equal(looped, result)
        row("evaluate loop", first, warm["median_s"], looped)
    if "user-vmap" in peers:
        flat = jax.tree.map(lambda leaf: leaf.reshape(-1, *leaf.shape[2:]), swept.policy_params)
        physics = {name: np.asarray([s[name] for s in settings], np.float32) for name in grid}
        first, warm, vmapped = timed(user_vmap(config.network, args.episodes, args.max_steps),
                                     flat, physics, repeats=args.repeats)
        row("user vmap", first, warm["median_s"], vmapped)
    common.print_table(rows, list(rows[0]), title="robustness evaluation")
    common.write_results("robustness", args, rows)


if __name__ == "__main__":
    main()
