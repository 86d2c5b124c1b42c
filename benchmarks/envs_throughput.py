"""Classic-control environment steps per second with random actions, jaxpg against its peers.

For each of Acrobot-v1, MountainCar-v0, Pendulum-v1 and MountainCarContinuous-v0 (`jaxpg.envs`),
and N environments stepped together with auto-reset:

- jaxpg: `rollout.stream` with `rollout.random_policy` (uniform over the actions, or over
  [ACTION_LOW, ACTION_HIGH]), jitted with 512-bit vectors (`xla_options.WIDE_VECTORS`), as
  `env_throughput.py` measures CartPole; one program per (env, N, T) whose scan length T is chosen
  so that a run takes about `--seconds` (or fixed with `--steps`); compile time is reported apart.
  The random actions and the reset states are drawn inside the program and so are counted; the
  stream draws reset states for every environment once every `rollout.STREAM_CHUNK` steps (and
  again for one that resets twice in them), not at every step.
- gymnax (when importable): the same id with `vmap` over environments and `lax.scan` over time;
  the auto-reset is gymnax's own `step`, which draws a reset state for every environment at every
  step, the actions its action space's `sample`, inside the program as for jaxpg.
- Every program runs under the jaxpg command's XLA setting (`xla_options.configure_xla`), set
  before JAX starts: XLA compiles a `while` loop of few bytes into one function rather than
  kernel by kernel.
- gymnasium-vector: `gymnasium.make_vec(id, N, vectorization_mode="sync")` (Gymnasium has no
  numpy vector env of these four), auto-resetting in its default next-step mode. Actions for all
  N environments are drawn with one `action_space.sample()` per step, outside the timed region:
  only `env.step` is timed. It always runs for about `--seconds`.

    python benchmarks/envs_throughput.py            # full run, ~1 s per measurement
    python benchmarks/envs_throughput.py --quick    # a quick check that everything runs
    python benchmarks/envs_throughput.py --steps 256 --seconds 0.2 --repeats 1   # small settings
"""

import argparse
import time

import common
import env_pieces
import env_throughput  # its timing and ratios; it also gives JAX one CPU device per core

from jaxpg import xla_options

# Before JAX starts its backends: the jaxpg command's XLA setting, for every program of the
# process, gymnax's too. It compiles a stream's loop into one function rather than kernel by
# kernel (docs/performance.md).
xla_options.configure_xla()

import gymnasium as gym  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from jaxpg import cartpole  # noqa: E402
from jaxpg.envs import MODULES  # noqa: E402

# CartPole's two presets are measured by env_throughput.py.
TASKS = tuple(name for name, module in MODULES.items() if module is not cartpole)

IMPLS = ("jaxpg", "gymnax", "gymnasium-vector")


# ---------------------------------------------------------------- programs that step N envs T times


def scan_program(reset_all, step_all, num_steps):
    """`key -> (states, total reward)`: T steps of N environments under `lax.scan`, jitted.

    The states are returned so that XLA computes them (MountainCar's rewards alone are -1 and do
    not need them).

    Args:
      reset_all: `key -> states` of the N environments.
      step_all: `(states, key) -> (states, rewards [N])`, actions drawn from `key`.
      num_steps: T.
    """
    def program(key):
        key_reset, key_steps = jax.random.split(key)

        def one_step(carry, step_key):
            state, total = carry
            state, reward = step_all(state, step_key)
            return (state, total + reward.sum()), None

        carry, _ = jax.lax.scan(one_step, (reset_all(key_reset), jnp.zeros(())),
                                jax.random.split(key_steps, num_steps))
        return carry

    return jax.jit(program)


def jaxpg_program(module, num_envs, num_steps):
    """N auto-resetting envs of `module`, T random steps: `rollout.stream`, jitted with 512-bit
    vectors."""
    return env_pieces.stream_program(num_envs, num_steps, xla_options.WIDE_VECTORS,
                                     module.PRESETS[module.NAME])


def gymnax_program(gymnax, env_id, num_envs, num_steps):
    """N gymnax envs, whose `step` auto-resets, T random steps (`scan_program`)."""
    env, env_params = gymnax.make(env_id)
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    sample = jax.vmap(env.action_space(env_params).sample)

    def reset_all(key):
        return reset(jax.random.split(key, num_envs), env_params)[1]

    def step_all(state, key):
        key_action, key_env = jax.random.split(key)
        action = sample(jax.random.split(key_action, num_envs))
        # gymnax 1.x returns (obs, state, reward, terminated, truncated, info)
        outputs = step(jax.random.split(key_env, num_envs), state, action, env_params)
        return outputs[1], outputs[2]

    return scan_program(reset_all, step_all, num_steps)


def vector_env_block(env, block):
    """A Gymnasium vector env: a function stepping it `block` times, timing only `step`."""
    env.reset(seed=0)
    env.action_space.seed(0)

    def step_block():
        elapsed = 0.0
        for _ in range(block):
            action = env.action_space.sample()
            start = time.perf_counter()
            env.step(action)
            elapsed += time.perf_counter() - start
        return elapsed

    return step_block, block


# ---------------------------------------------------------------- measuring


def measure(impl, env_id, num_envs, args, gymnax):
    module = MODULES[env_id]
    if impl == "jaxpg":
        return env_throughput.measure_jax(
            lambda n, t: jaxpg_program(module, n, t), num_envs, args)
    if impl == "gymnax":
        return env_throughput.measure_jax(
            lambda n, t: gymnax_program(gymnax, env_id, n, t), num_envs, args)
    if impl == "gymnasium-vector":
        env = gym.make_vec(env_id, num_envs, vectorization_mode="sync")
        loop_args = argparse.Namespace(**{**vars(args), "steps": 0})  # always --seconds
        return env_throughput.measure_loop(*vector_env_block(env, max(1, 256 // num_envs)),
                                           num_envs=num_envs, args=loop_args)
    raise ValueError(impl)


# ---------------------------------------------------------------- main


def parse_args():
    parser = argparse.ArgumentParser(
        description="Classic-control env steps per second, random actions")
    parser.add_argument("--quick", action="store_true",
                        help="short measurements (0.1 s, 1 repeat) to check that all runs")
    parser.add_argument("--envs", default=",".join(TASKS),
                        help=f"comma-separated subset of {', '.join(TASKS)}")
    parser.add_argument("--sizes", default="1,256,4096",
                        help="comma-separated numbers of environments N")
    parser.add_argument("--impls", default=",".join(IMPLS),
                        help=f"comma-separated subset of {', '.join(IMPLS)}")
    parser.add_argument("--seconds", type=float, default=1.0,
                        help="target seconds per measured run (default 1.0)")
    parser.add_argument("--steps", type=int, default=0,
                        help="steps per env per run of the JAX programs instead of the "
                             "--seconds target (Gymnasium's loop always runs for --seconds)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measurement (median)")
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.repeats = 0.1, 1
    args.sizes = [int(n) for n in args.sizes.split(",")]
    args.envs, args.impls = args.envs.split(","), args.impls.split(",")
    for option, chosen, allowed in (("--envs", args.envs, TASKS), ("--impls", args.impls,
                                                                      IMPLS)):
        unknown = set(chosen) - set(allowed)
        if unknown:
            parser.error(f"{option}: unknown {', '.join(sorted(unknown))}; allowed: "
                         f"{', '.join(allowed)}")
    if any(n < 1 for n in args.sizes):
        parser.error("--sizes: every N must be a positive integer")
    return args


def main():
    args = parse_args()
    common.print_header("Classic-control environment throughput, random actions, auto-reset")
    gymnax = None
    if "gymnax" in args.impls:
        gymnax = common.optional_import("gymnax", env_throughput.GYMNAX_HINT)
    rows = []
    for env_id in args.envs:
        for impl in args.impls:
            if impl == "gymnax" and gymnax is None:
                continue
            for num_envs in args.sizes:
                row = {"env": env_id, "impl": impl,
                       **measure(impl, env_id, num_envs, args, gymnax)}
                rows.append(row)
                print(f"{env_id:>24}  {impl:>16}  N={num_envs:<6}  "
                      f"{row['steps_per_s']:>14,.0f} steps/s", flush=True)

    columns = ["env", "impl", "n", "steps_per_env", "steps", "run_s", "steps_per_s", "lower_s",
               "compile_s"]
    common.print_table(rows, columns, title="steps/s (median run; compile timed apart)")
    summaries = {}
    for env_id in args.envs:
        env_rows = [row for row in rows if row["env"] == env_id]
        ran = {row["impl"] for row in env_rows}
        print(f"\n{env_id}")
        summaries[env_id] = [env_throughput.ratios(env_rows, "jaxpg", peer)
                             for peer in ("gymnasium-vector", "gymnax")
                             if "jaxpg" in ran and peer in ran]
        for summary in summaries[env_id]:
            env_throughput.print_ratios(summary)
    path = common.write_results(
        "envs_throughput", args, rows, ratios=summaries,
        notes={
            "jaxpg, gymnax": "random actions and reset states drawn inside the compiled program "
                             "(counted)",
            "gymnasium-vector": "actions drawn per step outside the timed region",
            "jaxpg": "compiled with xla_options.WIDE_VECTORS (512-bit vectors)",
        },
    )
    common.write_chart([{**row, "impl": f"{row['impl']} {row['env']}"} for row in rows], path,
                       "Classic-control env steps/s (random actions)",
                       xlabel="N (environments)")


if __name__ == "__main__":
    main()
