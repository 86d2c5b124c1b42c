"""Is a run's training the same bits whatever block of runs it trains in? Measured by block size.

The hypothesis of one engine: every run trains inside a block of one fixed shape (a run alone in
a block padded with copies of itself), so that alone or in a sweep of any size it is computed by
the same compiled program, and no sum needs rewriting to round alike. Two trainers, each
`jit(vmap over a block of runs(scan over iterations(...)))` with the runs on the leading axis:

- `plain`: `plain_jax.make_train`, the book's loss with a flax MLP of two logits.
- `engine`: jaxpg's own per-run pieces, vmapped and nothing else: `iteration.init_run`, then per
  iteration `rollout.rollout` -> `returns.discount_masked` -> `iteration.learn_run` (the loss's
  `jax.value_and_grad` and the optax step), for any built-in loss, network and optimizer.

For each case: a reference block of seeds 0..15, then blocks of B runs (seeds `k mod 16`) for
each B of `--blocks`, counting the runs whose final parameters differ in any bit from the same
seed's in the reference; then seeds 0..3, each in a block of 8 copies of itself. `--speed` times
64 seeds of the 32x32 MLP (first call and best of two warm calls): the engine block, `sweep`
(jaxpg's trainer) and the plain trainer, in this one process.

    python benchmarks/fixed_block.py                 # every case, 30 iterations
    python benchmarks/fixed_block.py --speed --cases none
    python benchmarks/fixed_block.py --quick         # a quick check that everything runs
"""

import argparse
import hashlib
import time

import common
import jax
import jax.numpy as jnp
import numpy as np
import optax
import plain_jax

from jaxpg import TrainConfig, iteration, losses, policies, returns, rollout, sweep

NETWORKS = {"default": None, "mlp32": (32, 32), "mlp64": (64, 64)}


def clipped_adam(learning_rate):
    """Adam after clipping the gradient's global norm to 1."""
    return optax.chain(optax.clip_by_global_norm(1.0), optax.adam(learning_rate))


# name: (trainer, network, loss, optimizer, TrainConfig's other fields)
CASES = {
    "plain-mlp32": ("plain", "mlp32", "reinforce", "adam", {}),
    "plain-mlp64": ("plain", "mlp64", "reinforce", "adam", {}),
    "engine-mlp32": ("engine", "mlp32", "reinforce", "adam", {}),
    "engine-mlp64": ("engine", "mlp64", "reinforce", "adam", {}),
    "engine-mlp32-reward-to-go": ("engine", "mlp32", "reward-to-go", "adam", {}),
    "engine-mlp32-baseline": ("engine", "mlp32", "baseline", "adam", {}),
    "engine-mlp32-ppo": ("engine", "mlp32", "ppo", "adam", dict(epochs=4, minibatches=2)),
    "engine-default-clipped": ("engine", "default", "reinforce", "clipped", {}),
}


def config_of(network, loss, optimizer, iterations, **fields):
    """The `TrainConfig` of a case."""
    hidden = NETWORKS[network]
    if hidden is not None:
        fields["policy"] = plain_jax.MLP(hidden)
    if optimizer == "clipped":
        fields["optimizer"] = clipped_adam
    return TrainConfig(iterations=iterations, loss=loss, **fields)


def engine_trainer(config):
    """`train(seeds [B]) -> (params, mean returns [B, I])`: `learn_run` vmapped over a block."""
    hyper = jax.tree.map(jnp.asarray, config.hyperparams)

    def train_run(key):
        params, opt_state = iteration.init_run(config, key, hyper)

        def one_iteration(carry, _):
            params, opt_state, key = carry
            key, key_rollout, key_minibatches = jax.random.split(key, 3)
            policy = policies.network_policy(config.network, params["policy"],
                                             num_actions=config.num_actions)
            played = rollout.rollout(key_rollout, policy, hyper.env, config.episodes,
                                     config.max_steps)
            t = played.transitions
            batch = losses.Batch(t.obs, t.action, t.reward, t.alive,
                                 returns.discount_masked(t.reward, t.alive, hyper.discount))
            params, opt_state, *_ = iteration.learn_run(config, params, opt_state, batch, hyper,
                                                        key_minibatches)
            return (params, opt_state, key), played.returns.mean()

        carry = (params, opt_state, jax.random.split(key)[0])
        (params, _, _), curve = jax.lax.scan(one_iteration, carry, length=config.iterations)
        return params, curve

    block = jax.jit(jax.vmap(train_run))
    return lambda seeds: block(jax.vmap(jax.random.PRNGKey)(seeds))


def trainer_of(case, iterations):
    """The case's `train(seeds [B]) -> (params, curves)`."""
    kind, network, loss, optimizer, fields = CASES[case]
    if kind == "plain":
        return plain_jax.make_train(plain_jax.MLP(NETWORKS[network]), iterations=iterations)
    return engine_trainer(config_of(network, loss, optimizer, iterations, **fields))


def digests(params):
    """A short hash of each run's parameters, `[B]`."""
    leaves = [np.asarray(leaf) for leaf in jax.tree.leaves(params)]
    return [hashlib.sha1(b"".join(leaf[row].tobytes() for leaf in leaves)).hexdigest()
            for row in range(leaves[0].shape[0])]


def bits_by_block(case, iterations, blocks):
    """{"B=...": runs differing from the reference block, "padded": ...} of a case."""
    train = trainer_of(case, iterations)

    def trained(seeds):
        return digests(jax.block_until_ready(train(jnp.asarray(seeds, jnp.uint32))[0]))

    reference = trained(range(16))
    row = {"case": case}
    for size in blocks:
        seeds = [k % 16 for k in range(size)]
        row[f"B={size}"] = sum(d != reference[k] for d, k in zip(trained(seeds), seeds))
    row["padded"] = sum(trained([k] * 8)[0] != reference[k] for k in range(4))
    return row


def speed(iterations, seeds=64):
    """First and best warm seconds of 64 seeds of the 32x32 MLP: engine, `sweep`, plain."""
    config = config_of("mlp32", "reinforce", "adam", iterations)
    engine, plain = trainer_of("engine-mlp32", iterations), trainer_of("plain-mlp32", iterations)
    keys = jnp.arange(seeds, dtype=jnp.uint32)
    calls = {"engine": lambda: engine(keys),
             "jaxpg sweep": lambda: sweep(config, seeds=range(seeds)),
             "plain": lambda: plain(keys)}
    rows = []
    for name, call in calls.items():
        start = time.perf_counter()
        jax.block_until_ready(call())
        first = time.perf_counter() - start
        timing, _ = common.time_calls(call, repeats=2)
        rows.append({"trainer": name, "first_s": first, "warm_s": timing["min_s"]})
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(CASES),
                        help="comma-separated names of CASES, or none")
    parser.add_argument("--iterations", type=int, default=30)
    parser.add_argument("--blocks", default="1,2,3,4,8,32", help="block sizes")
    parser.add_argument("--speed", action="store_true", help="time 64 seeds of the MLP too")
    parser.add_argument("--quick", action="store_true", help="2 iterations, 2 cases, B=1,8")
    args = parser.parse_args()
    if args.quick:
        args.cases, args.iterations, args.blocks = "plain-mlp32,engine-default-clipped", 2, "1,8"
    common.print_header("Bits of a run by the size of its block")
    blocks = [int(b) for b in args.blocks.split(",")]
    cases = [] if args.cases == "none" else args.cases.split(",")
    rows = [bits_by_block(case, args.iterations, blocks) for case in cases]
    common.print_table(rows, ["case", *(f"B={b}" for b in blocks), "padded"],
                       "runs whose parameters differ from the same seed's in a block of 16")
    timings = speed(args.iterations) if args.speed else []
    if timings:
        common.print_table(timings, ["trainer", "first_s", "warm_s"], "64 seeds, 32x32 MLP")
    common.write_results("fixed_block", args, rows, speed=timings)


if __name__ == "__main__":
    main()
