"""Where a CartPole environment step's time goes: the pieces of a user's loop and of the stream.

Each piece is its own program, a `jit` of `lax.scan` over T steps of N environments (the carry: the
environments' `CartPoleState` and an int32 counter `[N]` that every piece updates, so that nothing
is computed away): the carry alone, `vmap(cartpole.step)` with actions from the state, with the
auto-reset's select, `jax.random`'s draws a user makes at every step (`randint`, `bernoulli`,
`split(key, N)`, `split` and `vmap(cartpole.reset)`), `rollout.random_policy`, a user's whole loop
(as `env_throughput.py`'s jaxpg-user), the same loop drawing `jaxpg.rng`'s equal numbers, and
`rollout.stream` itself. The programs run in turn, `--repeats` rounds; the fastest and the median
time per environment step of each. `--wide-vectors` compiles every program with 512-bit vectors
(`jaxpg.xla_options.WIDE_VECTORS`).

    python benchmarks/env_pieces.py                          # N = 4096 and 65536
    python benchmarks/env_pieces.py --sizes 4096 --repeats 3  # a quick check
    python benchmarks/env_pieces.py --wide-vectors
"""

import argparse
import functools
import statistics
import time

import common
import jax
import jax.numpy as jnp

from jaxpg import cartpole, rng, rollout, xla_options

ENV_PARAMS = cartpole.V1
STEPS_PER_RUN = 2**23  # N x T of each program


RESET = jax.vmap(cartpole.reset, in_axes=(0, None))  # over keys
STEP = jax.vmap(cartpole.step, in_axes=(0, 0, None))  # over states and actions


def select(done, fresh, state):
    """`fresh` where `done`, else `state`: a user's auto-reset."""
    return jax.tree.map(lambda new, old: jnp.where(done, new, old), fresh, state)


def user_step(num_envs, split, draw_actions):
    """A user's step: actions, `cartpole.step`, fresh states from `split(key, N)` keys for all."""

    def body(state, count, key):
        key_action, key_reset = split(key, 2)
        _, state, _, terminated, truncated = STEP(state, draw_actions(key_action), ENV_PARAMS)
        done = terminated | truncated
        return select(done, RESET(split(key_reset, num_envs), ENV_PARAMS)[1], state), count + done

    return body


def pieces(num_envs):
    """{name: `(state, count [N], key) -> (state, count)`}, one step of each piece."""
    shape = (num_envs,)

    def physics(state, count, key):
        del key
        _, state, _, terminated, truncated = STEP(state, count & 1, ENV_PARAMS)
        return state, count + (terminated | truncated)

    def physics_select(state, count, key):
        _, stepped, _, terminated, truncated = STEP(state, count & 1, ENV_PARAMS)
        done = terminated | truncated
        return select(done, state, stepped), count + done

    def draw(numbers):
        """A piece that adds `numbers(key)` `[N]` to the counter."""
        return lambda state, count, key: (state, count + numbers(key))

    def split_words(key):
        keys = jax.random.split(key, num_envs)
        return (keys[:, 0] ^ keys[:, 1]).astype(jnp.int32)  # both words: the whole hash

    def split_reset(state, count, key):
        return RESET(jax.random.split(key, num_envs), ENV_PARAMS)[1], count

    def randint(key):
        return jax.random.randint(key, shape, 0, 2)

    return {
        "carry alone (x + 1)": lambda state, count, key: (
            jax.tree.map(lambda leaf: leaf + 1, state), count + 1),
        "physics (vmap(step))": physics,
        "physics + auto-reset select": physics_select,
        "jax.random.randint": draw(randint),
        "jax.random.bernoulli": draw(lambda key: jax.random.bernoulli(key, 0.5, shape)),
        "jax.random.split(key, N)": draw(split_words),
        "rollout.random_policy": draw(lambda key: rollout.random_policy(
            jnp.zeros((num_envs, cartpole.OBS_SIZE)), key)),
        "split + vmap(reset)": split_reset,
        "user loop": user_step(num_envs, jax.random.split, randint),
        "user loop, jaxpg.rng's numbers": user_step(
            num_envs, rng.split, lambda key: (rng.uniform(key, shape) < 0.5).astype(jnp.int32)),
    }


def piece_program(body, num_envs, num_steps, options=None):
    """`key -> (state, count)`: `body` scanned over `num_steps` steps of `num_envs` envs, jitted
    with XLA's compiler `options`."""

    def program(key):
        _, state = rollout.reset_batch(key, num_envs, ENV_PARAMS)

        def one_step(carry, step_key):
            return body(*carry, step_key), None

        carry = (state, jnp.zeros(num_envs, jnp.int32))
        return jax.lax.scan(one_step, carry, jax.random.split(key, num_steps))[0]

    return jax.jit(program, compiler_options=options)


def random_stream(num_envs, num_steps, env_params=ENV_PARAMS):
    """`key -> (StreamState, StreamStats)`: `rollout.stream` of `env_params`' environment with
    random actions (`rollout.random_policy`)."""
    policy = functools.partial(rollout.random_policy, env_params=env_params)
    return lambda key: rollout.stream(key, policy, env_params, num_envs, num_steps)


def stream_program(num_envs, num_steps, options=None, env_params=ENV_PARAMS):
    """`random_stream` jitted with XLA's compiler `options`."""
    return jax.jit(random_stream(num_envs, num_steps, env_params), compiler_options=options)


def measure(num_envs, repeats, options=None):
    """Rows of ns per environment step of every piece at N = `num_envs`, timed in turn, each
    compiled with XLA's compiler `options`."""
    num_steps = max(8, STEPS_PER_RUN // num_envs // 8 * 8)
    key = jax.random.PRNGKey(0)
    programs = {name: piece_program(body, num_envs, num_steps, options)
                for name, body in pieces(num_envs).items()}
    programs["rollout.stream"] = stream_program(num_envs, num_steps, options)
    compiled, compile_s = {}, {}
    for name, program in programs.items():
        compiled[name], times = common.compile_jitted(program, key)
        compile_s[name] = times["compile_s"]
        jax.block_until_ready(compiled[name](key))  # warm-up
    times = {name: [] for name in compiled}
    for _ in range(repeats):
        for name, run in compiled.items():
            start = time.perf_counter()
            jax.block_until_ready(run(key))
            times[name].append(time.perf_counter() - start)
    steps = num_envs * num_steps
    return [{"piece": name, "n": num_envs, "steps_per_env": num_steps,
             "min_ns": min(runs) / steps * 1e9, "median_ns": statistics.median(runs) / steps * 1e9,
             "compile_s": compile_s[name], "times_s": runs} for name, runs in times.items()]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="4096,65536", help="comma-separated numbers of envs N")
    parser.add_argument("--repeats", type=int, default=7, help="rounds of runs (min and median)")
    parser.add_argument("--wide-vectors", action="store_true",
                        help="compile every program with 512-bit vectors (WIDE_VECTORS)")
    args = parser.parse_args()
    args.sizes = [int(n) for n in args.sizes.split(",")]
    if any(n < 1 for n in args.sizes) or args.repeats < 1:
        parser.error("--sizes and --repeats: positive integers")
    common.print_header("Where a CartPole step's time goes, ns per environment step")
    options = xla_options.WIDE_VECTORS if args.wide_vectors else None
    rows = [row for num_envs in args.sizes for row in measure(num_envs, args.repeats, options)]
    common.print_table(rows, ["piece", "n", "steps_per_env", "min_ns", "median_ns", "compile_s"],
                       title="ns per environment step (each piece its own program)")
    common.write_results("env_pieces", args, rows)


if __name__ == "__main__":
    main()
