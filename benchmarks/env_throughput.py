"""CartPole environment steps per second with random actions, jaxpg against its peers.

For N environments stepped together, with auto-reset:

- jaxpg: `rollout.stream` with `rollout.random_policy`, jitted with 512-bit vectors
  (`xla_options.WIDE_VECTORS`, as its docstring advises); one program per (N, T) whose scan
  length T is chosen so that a run takes about `--seconds`; compile time is reported apart. The
  random actions are drawn inside the program and so are counted.
- jaxpg-user: `cartpole.step` as a researcher steps it in a program of their own: a `jit` of
  `lax.scan` over steps of `vmap(cartpole.step)`, auto-reset by `vmap(cartpole.reset)` (keys from
  `jax.random.split`) at every step, random actions from `jax.random.randint`; drawn inside the
  program and counted.
- jaxpg-sharded: the program of the jaxpg row with its N environments split over every device.
  On a CPU the script asks JAX for one device per usable core
  (`--xla_force_host_platform_device_count`, unless XLA_FLAGS already sets it), so that the parts
  run at once; every other program here still runs on one device, with the others idle beside it.
  N must divide evenly; other sizes are skipped, with a line that says so.
- gymnax (when importable): `CartPole-v1` with `vmap` over environments and `lax.scan` over time,
  as gymnax's documentation does; the auto-reset is gymnax's own `step`. Actions are drawn in bulk
  inside the program, as for jaxpg, and counted.
- gymnasium-vector: Gymnasium's numpy `CartPoleVectorEnv`. Actions for all N environments are
  drawn with one numpy call per step, outside the timed region: only `env.step` is timed.
- gymnasium (N = 1 only): `gymnasium.make("CartPole-v1")`, reset when an episode ends. Actions are
  drawn in blocks beforehand; the timed loop holds `step` and the resets.
- jaxpg-gym-vector and jaxpg-gym (N = 1 only): jaxpg's Gymnasium adapters (`jaxpg.gym`), timed as
  the two above: `gymnasium.make_vec("jaxpg/CartPole-v1", N)` and
  `gymnasium.make("jaxpg/CartPole-v1")`.

    python benchmarks/env_throughput.py            # full run, ~1 s per measurement
    python benchmarks/env_throughput.py --quick    # a quick check that everything runs
"""

import argparse
import os
import statistics
import time

import common

if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    # Before JAX starts its backend (importing it starts none): one CPU device per core, for
    # jaxpg-sharded. GPUs are unaffected.
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_"
                               f"device_count={common.usable_cores()}").strip()

import env_pieces  # noqa: E402
import gymnasium as gym  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv  # noqa: E402

from jaxpg import xla_options  # noqa: E402

IMPLS = ("jaxpg", "jaxpg-user", "jaxpg-sharded", "gymnax", "gymnasium-vector", "gymnasium",
         "jaxpg-gym-vector", "jaxpg-gym")
SINGLE = ("gymnasium", "jaxpg-gym")  # one environment: N = 1 only
ADAPTERS = {"jaxpg-gym-vector": "gymnasium-vector", "jaxpg-gym": "gymnasium"}  # and their peers
MAX_SCAN_STEPS = 2**22  # bounds the [T, 2] array of step keys
GYMNAX_HINT = (
    "gymnax 1.0.1 pins gymnasium<1.4 (and imports six without declaring it); see "
    "benchmarks/README.md for a separate environment to run it in"
)


# ---------------------------------------------------------------- programs that step N envs T times


def jaxpg_program(num_envs, num_steps, sharded=False):
    """`key -> (StreamState, StreamStats)`: N auto-resetting jaxpg envs, T random steps.

    `sharded` splits the environments over every device: XLA partitions the program, and each
    device steps its share (the statistics are summed over devices).
    """
    if not sharded:
        return env_pieces.stream_program(num_envs, num_steps, xla_options.WIDE_VECTORS)
    program = env_pieces.random_stream(num_envs, num_steps)
    mesh = jax.sharding.Mesh(np.array(jax.devices()), ("env",))
    split, whole = (jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(*axes))
                    for axes in (("env",), ()))
    state, stats = jax.eval_shape(program, jax.random.PRNGKey(0))
    return jax.jit(program, out_shardings=(jax.tree.map(lambda _: split, state),
                                           jax.tree.map(lambda _: whole, stats)),
                   compiler_options=xla_options.WIDE_VECTORS)


def user_program(num_envs, num_steps):
    """`key -> (state, episodes [N])`: N jaxpg envs as a researcher steps them, `env_pieces.py`'s
    user loop: `vmap(cartpole.step)` under `lax.scan`, auto-reset by `vmap(cartpole.reset)` on
    `split(key, N)` keys in the same step, `jax.random.randint` actions."""
    return env_pieces.piece_program(env_pieces.pieces(num_envs)["user loop"], num_envs, num_steps)


def gymnax_program(gymnax, num_envs, num_steps):
    """`key -> total reward`: N gymnax envs under `vmap`, T random steps under `lax.scan`."""
    env, env_params = gymnax.make("CartPole-v1")
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))  # gymnax's step auto-resets

    def program(key):
        key_reset, key_steps = jax.random.split(key)
        _, state = reset(jax.random.split(key_reset, num_envs), env_params)

        def one_step(carry, step_key):
            state, total = carry
            key_action, key_env = jax.random.split(step_key)
            action = jax.random.randint(key_action, (num_envs,), 0, 2)
            # gymnax 1.x returns (obs, state, reward, terminated, truncated, info)
            outputs = step(jax.random.split(key_env, num_envs), state, action, env_params)
            state, reward = outputs[1], outputs[2]
            return (state, total + reward.sum()), None

        (_, total), _ = jax.lax.scan(
            one_step, (state, jnp.zeros(())), jax.random.split(key_steps, num_steps)
        )
        return total

    return jax.jit(program)


# ---------------------------------------------------------------- measuring


def measure_jax(make_program, num_envs, args, **extra):
    """Compiles, picks T for about `args.seconds` per run, and times `args.repeats` runs."""
    key = jax.random.PRNGKey(0)
    num_steps = args.steps or max(8, min(1024, 2**16 // num_envs))
    for _ in range(0 if args.steps else 3):  # calibrate T on short runs, then compile the real one
        compiled, _ = common.compile_jitted(make_program(num_envs, num_steps), key)
        elapsed = common.time_calls(compiled, key, repeats=2)[0]["min_s"]
        if args.seconds / 4 <= elapsed <= args.seconds * 2 or num_steps >= MAX_SCAN_STEPS:
            break
        num_steps = common.scaled_length(num_steps, elapsed, args.seconds,
                                         highest=MAX_SCAN_STEPS)
    compiled, compile_times = common.compile_jitted(make_program(num_envs, num_steps), key)
    jax.block_until_ready(compiled(jax.random.PRNGKey(1)))  # warm-up
    timing, _ = common.time_calls(compiled, key, repeats=args.repeats)
    return _row(num_envs, num_steps, timing, **compile_times, **extra)


def measure_loop(step_block, block, num_envs, args):
    """Times `step_block()` (which steps every env `block` times and returns its timed seconds)
    until `args.seconds` have been timed, `args.repeats` times; or `args.steps` steps if given."""
    step_block()  # warm-up
    times, steps = [], []
    for _ in range(args.repeats):
        elapsed, count = 0.0, 0
        while (count < args.steps) if args.steps else (elapsed < args.seconds):
            elapsed += step_block()
            count += block
        times.append(elapsed / count)
        steps.append(count)
    per_step = statistics.median(times)
    timing = {"median_s": per_step * steps[0], "min_s": min(times) * steps[0],
              "times_s": [t * s for t, s in zip(times, steps)]}
    return _row(num_envs, steps[0], timing)


def _row(num_envs, num_steps, timing, **extra):
    steps = num_envs * num_steps
    return {
        "n": num_envs,
        "steps_per_env": num_steps,
        "steps": steps,
        "run_s": timing["median_s"],
        "steps_per_s": steps / timing["median_s"],
        "times_s": timing["times_s"],
        **extra,
    }


def vector_env_block(env, block=16):
    """A vector env of N environments (Gymnasium's CartPoleVectorEnv, or jaxpg's): a function
    stepping it `block` times, timing only `step`."""
    num_envs = env.num_envs
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step_block():
        elapsed = 0.0
        for _ in range(block):
            action = rng.integers(0, 2, size=num_envs)
            start = time.perf_counter()
            env.step(action)
            elapsed += time.perf_counter() - start
        return elapsed

    return step_block, block


def single_env_block(env_id, block=1000):
    """One `gymnasium.make(env_id)` env, reset on done: `block` steps per call."""
    env = gym.make(env_id)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step_block():
        actions = rng.integers(0, 2, size=block).tolist()
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return time.perf_counter() - start

    return step_block, block


def measure(impl, num_envs, args, gymnax):
    if impl == "jaxpg":
        return measure_jax(jaxpg_program, num_envs, args)
    if impl == "jaxpg-user":
        return measure_jax(user_program, num_envs, args)
    if impl == "jaxpg-sharded":
        return measure_jax(lambda n, t: jaxpg_program(n, t, sharded=True), num_envs, args,
                           devices=jax.device_count())
    if impl == "gymnax":
        return measure_jax(lambda n, t: gymnax_program(gymnax, n, t), num_envs, args)
    if impl == "gymnasium-vector":
        env = CartPoleVectorEnv(num_envs=num_envs)
        return measure_loop(*vector_env_block(env), num_envs=num_envs, args=args)
    if impl == "jaxpg-gym-vector":
        env = gym.make_vec("jaxpg/CartPole-v1", num_envs)
        return measure_loop(*vector_env_block(env), num_envs=num_envs, args=args)
    if impl in SINGLE:
        env_id = "CartPole-v1" if impl == "gymnasium" else "jaxpg/CartPole-v1"
        return measure_loop(*single_env_block(env_id), num_envs=num_envs, args=args)
    raise ValueError(impl)


# ---------------------------------------------------------------- ratios


def ratios(rows, numerator, denominator):
    """numerator / denominator steps per second at each N both ran, and at each one's best N."""
    by_impl = {}
    for row in rows:
        by_impl.setdefault(row["impl"], {})[row["n"]] = row["steps_per_s"]
    top, bottom = by_impl.get(numerator, {}), by_impl.get(denominator, {})
    at_n = {n: top[n] / bottom[n] for n in sorted(top) if n in bottom}
    best = {impl: max(rates.items(), key=lambda item: item[1]) for impl, rates in by_impl.items()}
    at_best = None
    if top and bottom:
        at_best = {"ratio": best[numerator][1] / best[denominator][1],
                   f"{numerator}_n": best[numerator][0], f"{denominator}_n": best[denominator][0]}
    return {"numerator": numerator, "denominator": denominator, "at_n": at_n,
            "at_best_n": at_best,
            "best_n": {impl: {"n": n, "steps_per_s": rate} for impl, (n, rate) in best.items()}}


def print_ratios(summary):
    name = f"{summary['numerator']} / {summary['denominator']}"
    for n, ratio in summary["at_n"].items():
        print(f"{name} at N={n}: {ratio:,.2f}x")
    if summary["at_best_n"]:
        best = summary["at_best_n"]
        print(f"{name} at each one's best N: {best['ratio']:,.2f}x")


def print_best(summary):
    for impl, best in summary["best_n"].items():
        print(f"best N for {impl}: {best['n']} ({best['steps_per_s']:,.0f} steps/s)")


# ---------------------------------------------------------------- main


def parse_args():
    parser = argparse.ArgumentParser(description="CartPole env steps per second, random actions")
    parser.add_argument("--quick", action="store_true",
                        help="short measurements (0.1 s, 1 repeat) to check that all runs")
    parser.add_argument("--sizes", default="1,256,4096,65536",
                        help="comma-separated numbers of environments N")
    parser.add_argument("--impls", default=",".join(IMPLS),
                        help=f"comma-separated subset of {', '.join(IMPLS)}")
    parser.add_argument("--seconds", type=float, default=1.0,
                        help="target seconds per measured run (default 1.0)")
    parser.add_argument("--steps", type=int, default=0,
                        help="steps per env per run instead of the --seconds target")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measurement (median)")
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.repeats = 0.1, 1
    args.sizes = [int(n) for n in args.sizes.split(",")]
    args.impls = args.impls.split(",")
    unknown = set(args.impls) - set(IMPLS)
    if unknown:
        parser.error(f"--impls: unknown {', '.join(sorted(unknown))}; allowed: {', '.join(IMPLS)}")
    if any(n < 1 for n in args.sizes):
        parser.error("--sizes: every N must be a positive integer")
    return args


def main():
    args = parse_args()
    common.print_header("CartPole-v1 environment throughput, random actions, auto-reset")
    gymnax = None
    if "gymnax" in args.impls:
        gymnax = common.optional_import("gymnax", GYMNAX_HINT)
    rows = []
    for impl in args.impls:
        if impl == "gymnax" and gymnax is None:
            continue
        for num_envs in args.sizes:
            if impl in SINGLE and num_envs != 1:
                continue
            if impl == "jaxpg-sharded" and num_envs % jax.device_count():
                print(f"{impl:>16}  N={num_envs:<6}  skipped: N does not split evenly over "
                      f"{jax.device_count()} devices")
                continue
            row = {"impl": impl, **measure(impl, num_envs, args, gymnax)}
            rows.append(row)
            print(f"{impl:>16}  N={num_envs:<6}  {row['steps_per_s']:>14,.0f} steps/s", flush=True)

    columns = ["impl", "n", "steps_per_env", "steps", "run_s", "steps_per_s", "lower_s",
               "compile_s"]
    common.print_table(rows, columns, title="steps/s (median run; compile timed apart)")
    ran = {row["impl"] for row in rows}
    pairs = [*((ours, peer) for ours in ("jaxpg", "jaxpg-user", "jaxpg-sharded")
               for peer in ("gymnasium-vector", "gymnax")), *ADAPTERS.items()]
    summaries = [ratios(rows, ours, peer) for ours, peer in pairs if ours in ran and peer in ran]
    print()
    print_best(ratios(rows, "jaxpg", "jaxpg"))
    for summary in summaries:
        print_ratios(summary)
    path = common.write_results(
        "env_throughput", args, rows, ratios=summaries,
        notes={
            "jax_impls": "random actions drawn inside the compiled program (counted)",
            "jaxpg, jaxpg-sharded": "compiled with xla_options.WIDE_VECTORS (512-bit vectors)",
            "gymnasium-vector": "actions drawn per step with numpy outside the timed region",
            "gymnasium": "actions drawn in blocks beforehand; resets are timed",
            "jaxpg-gym-vector, jaxpg-gym": "timed as gymnasium-vector and gymnasium",
        },
    )
    common.write_chart(rows, path, "CartPole-v1 env steps/s (random actions)",
                       xlabel="N (environments)")


if __name__ == "__main__":
    main()
