"""What jaxpg's losses reach on Gymnasium's classic-control tasks, 64 seeds each, and whether the
trained policies play alike in Gymnasium.

Each row of `ROWS` trains `--seeds` seeds of one config in one `sweep`, with `--eval-episodes`
held-out episodes per run (sampled and greedy actions, `SweepResult.eval_returns`). A run's final
return is the mean of its training mean returns over the last 10 iterations; the row reports the
IQM over runs of the final returns with its 95 % bootstrap interval (`jaxpg.stats`), their median
and the share of runs at or above the environment's threshold (Gymnasium's `reward_threshold`;
jaxpg's -200 for Pendulum-v1, which has none), the IQM of the held-out returns, the environment
steps played in training (the median over runs), and the time: `first_call_s` is a one-iteration
sweep of the same config, which compiles the program that the full sweep then reuses (programs
do not depend on the number of iterations) and plays one iteration, and `run_s` the full sweep.

Every network is a Dense(32)-tanh policy (`hidden`, `activation`) with a Dense(32)-elu critic
(`losses.ValueNetwork((32,))`, or (32, 32) with a (32, 32) policy), trained with Adam; each
iteration plays 10 episodes of the environment's time limit (CartPole-v1 at Gymnasium's 500
steps and threshold 475, not the book's 200 and 195). A row's other settings are in its config,
printed and written.

One PNG per environment in `--figures` (default `docs/`, `learning_<env>.png`) shows the IQM over
runs of each iteration's mean return with its 95 % bootstrap band (whole runs resampled,
`stats.iqm_curve`), a line per row.

The transfer check plays the first `--transfer-policies` runs of each row in Gymnasium's own
environment (`gymnasium.make(id)`), `--transfer-episodes` episodes each (reset seeds 0, 1, ...),
greedy (the distribution's mode) and sampled, stepping it with the action of jaxpg's network (a
continuous one as `np.array([a], float32)`), and compares the mean return with jaxpg's held-out
episodes of the same policies: both 95 % bootstrap intervals of the mean (episodes resampled per
policy, `stats.bootstrap_ci` with policies as tasks), and whether they overlap.

    python benchmarks/envs_learning.py                  # 64 seeds (about 15 minutes on 2 cores)
    python benchmarks/envs_learning.py --quick          # 2 seeds, 12 iterations: checks it runs
    python benchmarks/envs_learning.py --envs Acrobot-v1 --figures /tmp
"""

import argparse
import dataclasses
import pathlib
import tempfile
import time

import common
import gymnasium
import jax
import numpy as np

from jaxpg import TrainConfig, distributions, losses, plots, policies, stats, sweep

WINDOW = 10  # iterations in a run's final return
CONFIDENCE = 0.95
DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"


def _config(env, loss, hidden=(32,), **settings):
    """A row's `TrainConfig`: a `hidden` tanh policy and a critic of the same layers, 10 episodes
    of the environment's time limit per iteration, Adam."""
    critic = losses.ValueNetwork(hidden)
    built = {"baseline": losses.Baseline(critic), "ppo": losses.PPO(critic)}[loss]
    return TrainConfig(env=env, loss=built, hidden=hidden, activation="tanh", episodes=10,
                       **settings)


PPO_UPDATES = {"epochs": 4, "minibatches": 2}

# (environment, label, config); each environment's rows share their iterations, for one picture.
ROWS = [
    ("CartPole-v1", "baseline", _config("CartPole-v1", "baseline", max_steps=500,
                                        solved_return=475.0, iterations=100, discount=0.99)),
    ("Acrobot-v1", "baseline", _config("Acrobot-v1", "baseline", iterations=150, discount=0.99,
                                       entropy_coef=0.01)),
    ("Acrobot-v1", "ppo", _config("Acrobot-v1", "ppo", iterations=150, discount=0.99,
                                  **PPO_UPDATES)),
    ("MountainCar-v0", "baseline", _config("MountainCar-v0", "baseline", iterations=60,
                                           discount=0.99, entropy_coef=0.01)),
    ("MountainCar-v0", "ppo", _config("MountainCar-v0", "ppo", iterations=60, discount=0.99,
                                      entropy_coef=0.01, **PPO_UPDATES)),
    ("Pendulum-v1", "baseline", _config("Pendulum-v1", "baseline", iterations=100,
                                        discount=0.95)),
    ("Pendulum-v1", "ppo", _config("Pendulum-v1", "ppo", hidden=(32, 32), iterations=100,
                                   discount=0.95, **PPO_UPDATES)),
    ("MountainCarContinuous-v0", "baseline", _config("MountainCarContinuous-v0", "baseline",
                                                     iterations=50, discount=0.99)),
    ("MountainCarContinuous-v0", "ppo", _config("MountainCarContinuous-v0", "ppo", iterations=50,
                                                discount=0.99, **PPO_UPDATES)),
]


# ---------------------------------------------------------------- training


def train_row(config, seeds, eval_episodes):
    """Trains `seeds` runs of `config`, compiling in a one-iteration sweep first.

    Returns:
      (the full sweep's `SweepResult`, {"first_call_s", "run_s"})
    """
    start = time.perf_counter()
    sweep(dataclasses.replace(config, iterations=1), seeds=range(seeds), show_progress=False,
          eval_episodes=eval_episodes)
    compiled = time.perf_counter()
    result = sweep(config, seeds=range(seeds), show_progress=False, eval_episodes=eval_episodes)
    return result, {"first_call_s": compiled - start, "run_s": time.perf_counter() - compiled}


def learning_row(env, label, config, result, times):
    """The row of the learning table: final returns over runs, held-out returns, steps, times."""
    mean_return = result.metrics.mean_return[0]  # [S, I]
    final = mean_return[:, -WINDOW:].mean(axis=1)
    low, high = stats.bootstrap_ci(final, "iqm", CONFIDENCE)
    steps = (result.metrics.mean_length[0] * config.episodes).sum(axis=1)
    return {
        "env": env, "loss": label, "seeds": final.size, "iterations": config.iterations,
        "hidden": config.hidden, "lr": config.learning_rate, "discount": config.discount,
        "entropy": config.entropy_coef, "updates": f"{config.epochs}x{config.minibatches}",
        "iqm_final": float(stats.iqm(final)), "ci_low": low, "ci_high": high,
        "median_final": float(np.median(final)),
        "solved": float(np.mean(final >= config.solved_return)),
        "iqm_eval_sampled": float(stats.iqm(result.eval_returns[0].mean(axis=1))),
        "iqm_eval_greedy": float(stats.iqm(result.eval_greedy_returns[0].mean(axis=1))),
        "median_steps": float(np.median(steps)), **times,
        "final_returns": final,
    }


def learning_figure(env, labels, results, folder):
    """`learning_<env>.png` in `folder`: each row's IQM curve over runs with its 95 % band."""
    bands = [stats.iqm_curve(r.metrics.mean_return[0], confidence=CONFIDENCE) for r in results]
    name = env.split("-")[0].lower()
    path = pathlib.Path(folder) / f"learning_{name}.png"
    config = results[0].config
    legend = [f"{env} {label}: IQM of {r.seeds.size} seeds (95 % band), {config.episodes} "
              f"episodes per iteration" for label, r in zip(labels, results)]
    plots.iqm_curves(bands[0].x, [b.estimate for b in bands], [b.low for b in bands],
                     [b.high for b in bands], legend, path, solved_return=config.solved_return)
    print(f"wrote {path}")
    return path


# ---------------------------------------------------------------- transfer to Gymnasium


def action_function(config):
    """A jitted `(policy_params [P, ...], obs [P, E, K], u [P, E]) -> (sampled, greedy)`, each
    `[P, E]`: P policies' actions for E observations each."""

    def act(policy_params, obs, u):
        dist = policies.distribution(config.network, policy_params, obs, config.num_actions)
        return distributions.sample(dist, u), distributions.mode(dist)

    return jax.jit(jax.vmap(act))


def gymnasium_returns(config, policy_params, episodes, greedy, seed=0):
    """Returns `[E, P]` of P policies (leaves `[P, ...]`), each playing `episodes` episodes of
    `gymnasium.make(config.env_name)` reset with seeds `seed`, `seed + 1`, ...

    All P x E episodes step together, one network call per step for all of them.
    """
    act = action_function(config)
    count = jax.tree.leaves(policy_params)[0].shape[0]
    games = [[gymnasium.make(config.env_name) for _ in range(episodes)] for _ in range(count)]
    obs = np.stack([[game.reset(seed=seed + e)[0] for e, game in enumerate(row)]
                    for row in games]).astype(np.float32)
    done = np.zeros((count, episodes), bool)
    total = np.zeros((count, episodes))
    rng = np.random.default_rng(seed)
    while not done.all():
        u = rng.random((count, episodes), dtype=np.float32)
        actions = np.asarray(act(policy_params, obs, u)[1 if greedy else 0])
        for p, e in zip(*np.nonzero(~done)):
            action = (np.array([actions[p, e]], np.float32) if config.num_actions is None
                      else int(actions[p, e]))
            obs[p, e], reward, terminated, truncated, _ = games[p][e].step(action)
            total[p, e] += reward
            done[p, e] = terminated or truncated
    for game in (game for row in games for game in row):
        game.close()
    return total.T


def transfer_rows(env, label, config, result, count, episodes):
    """Gymnasium against jaxpg's held-out episodes for the first `count` runs, greedy and sampled:
    each side's mean return and its 95 % interval (episodes resampled per policy), and whether
    the intervals overlap."""
    policy_params = jax.tree.map(lambda leaf: leaf[0, :count], result.policy_params)
    rows = []
    held_outs = {"greedy": result.eval_greedy_returns, "sampled": result.eval_returns}
    for mode, held_out in held_outs.items():
        ours = held_out[0, :count].T  # [N, P]: episodes as runs, policies as tasks
        theirs = gymnasium_returns(config, policy_params, episodes,
                                   greedy=mode == "greedy")
        (low, high), (gym_low, gym_high) = (stats.bootstrap_ci(x, "mean", CONFIDENCE)
                                            for x in (ours, theirs))
        rows.append({
            "env": env, "loss": label, "mode": mode, "policies": count,
            "jaxpg_mean": float(ours.mean()), "jaxpg_low": low, "jaxpg_high": high,
            "gym_mean": float(theirs.mean()), "gym_low": gym_low, "gym_high": gym_high,
            "agree": bool(low <= gym_high and gym_low <= high),
            "jaxpg_returns": ours.T, "gym_returns": theirs.T,
        })
    return rows


# ---------------------------------------------------------------- main


LEARNING_COLUMNS = ["env", "loss", "iterations", "iqm_final", "ci_low", "ci_high", "median_final",
                    "solved", "iqm_eval_greedy", "median_steps", "first_call_s", "run_s"]
TRANSFER_COLUMNS = ["env", "loss", "mode", "jaxpg_mean", "jaxpg_low", "jaxpg_high", "gym_mean",
                    "gym_low", "gym_high", "agree"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=64)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--transfer-policies", type=int, default=4)
    parser.add_argument("--transfer-episodes", type=int, default=20)
    parser.add_argument("--envs", default=",".join(dict.fromkeys(env for env, _, _ in ROWS)))
    parser.add_argument("--figures", help="folder of the PNGs (default docs/; with --quick, a "
                        "temporary folder)")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.eval_episodes, args.transfer_policies, args.transfer_episodes = 2, 3, 2, 3
    if args.figures is None:
        args.figures = tempfile.mkdtemp() if args.quick else str(DOCS)
    iterations = 12 if args.quick else None  # at least WINDOW
    common.print_header("jaxpg's losses on the classic-control tasks")
    wanted = args.envs.split(",")
    learning, transfer, by_env = [], [], {}
    for env, label, config in ROWS:
        if env not in wanted:
            continue
        if iterations is not None:
            config = dataclasses.replace(config, iterations=iterations)
        print(f"\n{env} {label}: {config}", flush=True)
        result, times = train_row(config, args.seeds, args.eval_episodes)
        learning.append(learning_row(env, label, config, result, times))
        common.print_table(learning[-1:], LEARNING_COLUMNS)
        start = time.perf_counter()
        transfer += transfer_rows(env, label, config, result,
                                  min(args.transfer_policies, args.seeds), args.transfer_episodes)
        print(f"transfer check: {time.perf_counter() - start:.1f} s")
        common.print_table(transfer[-2:], TRANSFER_COLUMNS)
        by_env.setdefault(env, []).append((label, result))
    common.print_table(learning, LEARNING_COLUMNS, "final return (mean of the last 10 iterations)")
    common.print_table(transfer, TRANSFER_COLUMNS, "Gymnasium against jaxpg's held-out episodes")
    figures = [learning_figure(env, *zip(*rows), args.figures) for env, rows in by_env.items()]
    configs = {f"{env} {label}": repr(config) for env, label, config in ROWS if env in wanted}
    common.write_results("envs_learning", args, learning, transfer=transfer, configs=configs,
                         figures=[str(path) for path in figures])


if __name__ == "__main__":
    main()
