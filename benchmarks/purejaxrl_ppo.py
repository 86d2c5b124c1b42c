"""purejaxrl's PPO against jaxpg's `ppo-32` on CartPole-v1: time and environment steps to 195.

The peer is the PPO of purejaxrl (Chris Lu, https://github.com/luchris429/purejaxrl,
`purejaxrl/ppo.py`, Apache License 2.0, copyright 2023 Chris Lu): its algorithm, its default
CartPole hyperparameters (`CONFIG`) and its structure, `make_train(config)` returning `train(rng)`,
jitted over a `jax.vmap` of seeds, with `jax.lax.scan` over updates, steps, epochs and minibatches.
Changed from it: gymnax is not installed here, so it steps jaxpg's own CartPole
(`jaxpg.cartpole`, CartPole-v1: truncated at 500 steps) through a small auto-reset wrapper written
as gymnax's (`_env_step`: a finished episode is replaced by a fresh one in the same step, and
`done` is terminated or truncated); distrax is not installed either, so the categorical policy is
`jax.nn.log_softmax` and `jax.random.categorical` on its logits; and purejaxrl's `LogWrapper`
becomes per update the sum and count of the returns of the episodes that ended in it, so that the
recorded metric is their mean (as `returned_episode_returns` over `returned_episode`), an update
where none ended keeping the previous update's value.

Both rows train `--seeds` seeds in one process, under the `jaxpg` command's XLA setting for
several runs (`xla_options.configure_xla()`; on a 2-core machine, purejaxrl's program for 48 or
more seeds stalled at 0% CPU under XLA's defaults and ran under this setting); the compile time
is apart from the run time of the whole training (for jaxpg, a first `sweep` call less a second,
warm one). From r[s, u], seed s's mean episode return at update (jaxpg: iteration) u, and its
moving mean over the last 10 updates m[s, u] (full windows only), each row reports:

- `steps_to_195`: the environment steps done by the first update at which the median over seeds
  of m reaches 195 (for jaxpg, steps to iteration i = sum over iterations <= i of episodes x
  `Metrics.mean_length`, the median over seeds), and `s_to_195`, the run time times the share of
  updates done by then (updates cost alike in purejaxrl; in jaxpg, iterations of longer episodes
  cost a little more, so this share is an estimate).
- `median_seed_steps_to_195`: the median over seeds of the steps at each seed's own first m >= 195
  (jaxpg's `Summary.first_solved`), with `never_solved` the seeds that never got there.
- `final_median_m`: the median over seeds of m at the last update.

jaxpg's `ppo-32` (as in `benchmarks/ppo.py`) plays 10 episodes of at most 200 steps per iteration,
so its returns stop at 200; purejaxrl's CartPole-v1 episodes run to 500.

    python benchmarks/purejaxrl_ppo.py               # 64 seeds, 5e5 steps and 150 iterations
    python benchmarks/purejaxrl_ppo.py --quick       # 2 seeds, tiny budgets: checks it all runs
"""

import argparse
import time
from typing import NamedTuple

import common
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax.linen.initializers import constant, orthogonal
from flax.training.train_state import TrainState

from jaxpg import TrainConfig, cartpole, losses, sweep, xla_options

SOLVED = 195.0
WINDOW = 10  # updates in the moving mean

# purejaxrl's CartPole-v1 config (`purejaxrl/ppo.py`, `__main__`).
CONFIG = {
    "LR": 2.5e-4,
    "NUM_ENVS": 4,
    "NUM_STEPS": 128,
    "TOTAL_TIMESTEPS": 5e5,
    "UPDATE_EPOCHS": 4,
    "NUM_MINIBATCHES": 4,
    "GAMMA": 0.99,
    "GAE_LAMBDA": 0.95,
    "CLIP_EPS": 0.2,
    "ENT_COEF": 0.01,
    "VF_COEF": 0.5,
    "MAX_GRAD_NORM": 0.5,
    "ACTIVATION": "tanh",
    "ANNEAL_LR": True,
}

CARTPOLE_V1 = cartpole.CartPoleParams()  # truncated at 500 steps

# jaxpg's `ppo-32` row of `benchmarks/ppo.py`.
JAXPG_PPO_32 = TrainConfig(loss=losses.PPO(losses.ValueNetwork((32,))), epochs=4, minibatches=2,
                           hidden=(32,), activation="tanh", discount=0.99)


class ActorCritic(nn.Module):
    """purejaxrl's actor and critic: two 64-unit layers each, orthogonal initialisation."""

    action_dim: int
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x):
        """Logits `[..., action_dim]` and value `[...]` of observations `[..., obs_dim]`."""
        activation = nn.relu if self.activation == "relu" else nn.tanh

        def dense(features, scale):
            return nn.Dense(features, kernel_init=orthogonal(scale), bias_init=constant(0.0))

        actor = activation(dense(64, np.sqrt(2))(x))
        actor = activation(dense(64, np.sqrt(2))(actor))
        logits = dense(self.action_dim, 0.01)(actor)
        critic = activation(dense(64, np.sqrt(2))(x))
        critic = activation(dense(64, np.sqrt(2))(critic))
        critic = dense(1, 1.0)(critic)
        return logits, jnp.squeeze(critic, axis=-1)


class Transition(NamedTuple):
    done: jnp.ndarray
    action: jnp.ndarray
    value: jnp.ndarray
    reward: jnp.ndarray
    log_prob: jnp.ndarray
    obs: jnp.ndarray
    ended_return: jnp.ndarray  # the return of the episode that ended at this step, else 0


def log_prob_of(logits, action):
    """Log-probabilities `[...]` of integer actions `[...]` under logits `[..., A]`."""
    log_probs = jax.nn.log_softmax(logits)
    return jnp.take_along_axis(log_probs, action[..., None], axis=-1)[..., 0]


def entropy_of(logits):
    """Entropy `[...]` of the categorical distributions of logits `[..., A]`."""
    log_probs = jax.nn.log_softmax(logits)
    return -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1)


def auto_reset_step(key, state, action, env_params):
    """One CartPole step that starts a fresh episode where one ended, as gymnax's `step`.

    Args:
      key: PRNG key for the reset.
      state: `(CartPoleState, episode return so far)`, `[]` leaves.
      action: int `[]`, 0 or 1.
      env_params: `CartPoleParams`.

    Returns:
      (obs `[4]` (the fresh episode's where one ended), state, reward `[]`, done `[]` bool,
      ended_return `[]`: the finished episode's return where one ended, else 0).
    """
    env_state, episode_return = state
    obs, env_state, reward, terminated, truncated = cartpole.step(env_state, action, env_params)
    done = terminated | truncated
    reset_obs, reset_state = cartpole.reset(key, env_params)
    env_state = jax.tree.map(lambda r, s: jnp.where(done, r, s), reset_state, env_state)
    obs = jnp.where(done, reset_obs, obs)
    episode_return = episode_return + reward
    ended_return = jnp.where(done, episode_return, 0.0)
    return obs, (env_state, jnp.where(done, 0.0, episode_return)), reward, done, ended_return


def make_train(config, env_params=CARTPOLE_V1):
    """purejaxrl's PPO trainer on jaxpg's CartPole.

    Args:
      config: a dict with `CONFIG`'s keys; NUM_UPDATES and MINIBATCH_SIZE are added to it.
      env_params: the `CartPoleParams` played (CartPole-v1's by default).

    Returns:
      `train(rng)` -> {"runner_state", "metrics": {"ended_sum" `[NUM_UPDATES]`, "ended_count"
      `[NUM_UPDATES]`}}: the sum and count of the returns of the episodes that ended per update.
    """
    config["NUM_UPDATES"] = int(
        config["TOTAL_TIMESTEPS"] // config["NUM_STEPS"] // config["NUM_ENVS"])
    config["MINIBATCH_SIZE"] = config["NUM_ENVS"] * config["NUM_STEPS"] // config["NUM_MINIBATCHES"]

    def linear_schedule(count):
        frac = 1.0 - (count // (config["NUM_MINIBATCHES"] * config["UPDATE_EPOCHS"])
                      ) / config["NUM_UPDATES"]
        return config["LR"] * frac

    def train(rng):
        # INIT NETWORK
        network = ActorCritic(2, activation=config["ACTIVATION"])
        rng, _rng = jax.random.split(rng)
        network_params = network.init(_rng, jnp.zeros(4))
        learning_rate = linear_schedule if config["ANNEAL_LR"] else config["LR"]
        tx = optax.chain(optax.clip_by_global_norm(config["MAX_GRAD_NORM"]),
                         optax.adam(learning_rate=learning_rate, eps=1e-5))
        train_state = TrainState.create(apply_fn=network.apply, params=network_params, tx=tx)

        # INIT ENV
        rng, _rng = jax.random.split(rng)
        reset_rng = jax.random.split(_rng, config["NUM_ENVS"])
        obsv, env_state = jax.vmap(cartpole.reset, in_axes=(0, None))(reset_rng, env_params)
        env_state = (env_state, jnp.zeros(config["NUM_ENVS"], obsv.dtype))

        # TRAIN LOOP
        def _update_step(runner_state, unused):
            # COLLECT TRAJECTORIES
            def _env_step(runner_state, unused):
                train_state, env_state, last_obs, rng = runner_state

                # SELECT ACTION
                rng, _rng = jax.random.split(rng)
                logits, value = network.apply(train_state.params, last_obs)
                action = jax.random.categorical(_rng, logits)
                log_prob = log_prob_of(logits, action)

                # STEP ENV
                rng, _rng = jax.random.split(rng)
                rng_step = jax.random.split(_rng, config["NUM_ENVS"])
                obsv, env_state, reward, done, ended_return = jax.vmap(
                    auto_reset_step, in_axes=(0, 0, 0, None)
                )(rng_step, env_state, action, env_params)
                transition = Transition(done, action, value, reward, log_prob, last_obs,
                                        ended_return)
                runner_state = (train_state, env_state, obsv, rng)
                return runner_state, transition

            runner_state, traj_batch = jax.lax.scan(
                _env_step, runner_state, None, config["NUM_STEPS"])

            # CALCULATE ADVANTAGE
            train_state, env_state, last_obs, rng = runner_state
            _, last_val = network.apply(train_state.params, last_obs)

            def _calculate_gae(traj_batch, last_val):
                def _get_advantages(gae_and_next_value, transition):
                    gae, next_value = gae_and_next_value
                    done, value, reward = transition.done, transition.value, transition.reward
                    delta = reward + config["GAMMA"] * next_value * (1 - done) - value
                    gae = delta + config["GAMMA"] * config["GAE_LAMBDA"] * (1 - done) * gae
                    return (gae, value), gae

                _, advantages = jax.lax.scan(
                    _get_advantages, (jnp.zeros_like(last_val), last_val), traj_batch,
                    reverse=True, unroll=16)
                return advantages, advantages + traj_batch.value

            advantages, targets = _calculate_gae(traj_batch, last_val)

            # UPDATE NETWORK
            def _update_epoch(update_state, unused):
                def _update_minbatch(train_state, batch_info):
                    traj_batch, advantages, targets = batch_info

                    def _loss_fn(params, traj_batch, gae, targets):
                        # RERUN NETWORK
                        logits, value = network.apply(params, traj_batch.obs)
                        log_prob = log_prob_of(logits, traj_batch.action)

                        # CALCULATE VALUE LOSS
                        value_pred_clipped = traj_batch.value + (
                            value - traj_batch.value).clip(-config["CLIP_EPS"], config["CLIP_EPS"])
                        value_losses = jnp.square(value - targets)
                        value_losses_clipped = jnp.square(value_pred_clipped - targets)
                        value_loss = 0.5 * jnp.maximum(value_losses, value_losses_clipped).mean()

                        # CALCULATE ACTOR LOSS
                        ratio = jnp.exp(log_prob - traj_batch.log_prob)
                        gae = (gae - gae.mean()) / (gae.std() + 1e-8)
                        loss_actor1 = ratio * gae
                        loss_actor2 = jnp.clip(
                            ratio, 1.0 - config["CLIP_EPS"], 1.0 + config["CLIP_EPS"]) * gae
                        loss_actor = -jnp.minimum(loss_actor1, loss_actor2).mean()
                        entropy = entropy_of(logits).mean()

                        total_loss = (loss_actor + config["VF_COEF"] * value_loss
                                      - config["ENT_COEF"] * entropy)
                        return total_loss, (value_loss, loss_actor, entropy)

                    grad_fn = jax.value_and_grad(_loss_fn, has_aux=True)
                    total_loss, grads = grad_fn(train_state.params, traj_batch, advantages,
                                                targets)
                    train_state = train_state.apply_gradients(grads=grads)
                    return train_state, total_loss

                train_state, traj_batch, advantages, targets, rng = update_state
                rng, _rng = jax.random.split(rng)
                # Batching and Shuffling
                batch_size = config["MINIBATCH_SIZE"] * config["NUM_MINIBATCHES"]
                permutation = jax.random.permutation(_rng, batch_size)
                batch = (traj_batch, advantages, targets)
                batch = jax.tree.map(lambda x: x.reshape((batch_size,) + x.shape[2:]), batch)
                shuffled_batch = jax.tree.map(lambda x: jnp.take(x, permutation, axis=0), batch)
                # Mini-batch Updates
                minibatches = jax.tree.map(
                    lambda x: jnp.reshape(x, [config["NUM_MINIBATCHES"], -1] + list(x.shape[1:])),
                    shuffled_batch)
                train_state, total_loss = jax.lax.scan(_update_minbatch, train_state, minibatches)
                update_state = (train_state, traj_batch, advantages, targets, rng)
                return update_state, total_loss

            # Updating Training State and Metrics:
            update_state = (train_state, traj_batch, advantages, targets, rng)
            update_state, loss_info = jax.lax.scan(
                _update_epoch, update_state, None, config["UPDATE_EPOCHS"])
            train_state = update_state[0]
            metric = {"ended_sum": traj_batch.ended_return.sum(),
                      "ended_count": traj_batch.done.sum()}
            rng = update_state[-1]
            runner_state = (train_state, env_state, last_obs, rng)
            return runner_state, metric

        rng, _rng = jax.random.split(rng)
        runner_state = (train_state, env_state, obsv, _rng)
        runner_state, metric = jax.lax.scan(
            _update_step, runner_state, None, config["NUM_UPDATES"])
        return {"runner_state": runner_state, "metrics": metric}

    return train


# ---------------------------------------------------------------- measurement


def returns_per_update(ended_sum, ended_count):
    """The mean return of the episodes that ended per update, carried over updates with none.

    Args:
      ended_sum: `[S, U]` the sum of the returns of the episodes that ended per update.
      ended_count: `[S, U]` their number.

    Returns:
      `[S, U]` float64: their mean; an update where none ended keeps the previous value (0 before
      the first episode ends).
    """
    ended_sum, ended_count = np.asarray(ended_sum, np.float64), np.asarray(ended_count)
    # The index of the last update at or before u where an episode ended (0 where none did yet).
    last = np.maximum.accumulate(np.where(ended_count > 0, np.arange(ended_count.shape[-1]), 0),
                                 axis=-1)
    mean = ended_sum / np.maximum(ended_count, 1)
    return np.take_along_axis(mean, last, axis=-1)


def moving_mean(returns):
    """`[S, U - WINDOW + 1]`: each seed's mean return over the `WINDOW` updates ending at each."""
    return np.lib.stride_tricks.sliding_window_view(returns, WINDOW, axis=-1).mean(axis=-1)


def first_reached(moving):
    """`[S]` int: each seed's first window (0-based) whose moving mean reaches 195; -1 if none."""
    solved = moving >= SOLVED
    return np.where(solved.any(axis=-1), solved.argmax(axis=-1), -1)


def reaching(returns, steps, run_s):
    """When and how far `returns` get: the row's figures described in the module docstring.

    Args:
      returns: `[S, U]` each seed's mean episode return per update.
      steps: `[S, U]` the environment steps each seed has done by the end of each update.
      run_s: the run time of the whole training, in seconds.

    Returns:
      a dict: steps_to_195, s_to_195 (None if the median never reaches 195),
      median_seed_steps_to_195 (None if half the seeds or more never do), never_solved,
      final_median_m, total_steps (the median over seeds).
    """
    moving = moving_mean(returns)
    moving_steps = steps[:, WINDOW - 1:]  # [S, U - W + 1]: the steps by each window's last update
    median = np.median(moving, axis=0)
    reached = np.flatnonzero(median >= SOLVED)
    first = int(reached[0]) if reached.size else None
    seed_first = first_reached(moving)
    seed_steps = np.where(seed_first >= 0, moving_steps[np.arange(len(moving)), seed_first],
                          np.inf)
    seed_median = float(np.median(seed_steps))
    updates = returns.shape[-1]
    return {
        "steps_to_195": None if first is None else float(np.median(moving_steps[:, first])),
        "s_to_195": None if first is None else run_s * (first + WINDOW) / updates,
        "median_seed_steps_to_195": seed_median if np.isfinite(seed_median) else None,
        "never_solved": int(np.sum(seed_first < 0)),
        "final_median_m": float(median[-1]),
        "total_steps": float(np.median(steps[:, -1])),
    }


def measure_purejaxrl(seeds, total_timesteps):
    """Compiles and runs purejaxrl's PPO for `seeds` seeds; the row of figures."""
    config = {**CONFIG, "TOTAL_TIMESTEPS": total_timesteps}
    rngs = jax.random.split(jax.random.PRNGKey(42), seeds)
    train = jax.jit(jax.vmap(make_train(config)))
    compiled, compile_times = common.compile_jitted(train, rngs)
    timing, out = common.time_calls(compiled, rngs, repeats=1)
    metrics = jax.device_get(out["metrics"])
    returns = returns_per_update(metrics["ended_sum"], metrics["ended_count"])
    steps_per_update = config["NUM_ENVS"] * config["NUM_STEPS"]
    steps = np.broadcast_to(steps_per_update * np.arange(1, returns.shape[-1] + 1), returns.shape)
    return {"impl": "purejaxrl-ppo", "seeds": seeds, "updates": config["NUM_UPDATES"],
            "compile_s": compile_times["lower_s"] + compile_times["compile_s"],
            "run_s": timing["median_s"], **reaching(returns, steps, timing["median_s"])}


def measure_jaxpg(seeds, iterations):
    """Runs jaxpg's `ppo-32` twice in one `sweep` of `seeds` seeds; the row of figures."""
    config = TrainConfig(**{**JAXPG_PPO_32.__dict__, "iterations": iterations})
    times = []
    for _ in range(2):
        start = time.perf_counter()
        result = sweep(config, seeds=range(seeds), show_progress=False)
        times.append(time.perf_counter() - start)
    returns = np.asarray(result.metrics.mean_return[0], np.float64)  # [S, I]
    steps = np.cumsum(config.episodes * np.asarray(result.metrics.mean_length[0], np.float64),
                      axis=-1)
    # Each seed's first crossing is jaxpg's own Summary.first_solved, counted in iterations.
    first = first_reached(moving_mean(returns))
    if not np.array_equal(np.where(first >= 0, first + WINDOW - 1, -1),
                          result.summary.first_solved[0]):
        raise RuntimeError("the moving mean's first crossings differ from Summary.first_solved")
    return {"impl": "jaxpg-ppo-32", "seeds": seeds, "updates": iterations,
           "compile_s": times[0] - times[1], "run_s": times[1],
            **reaching(returns, steps, times[1])}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=64)
    parser.add_argument("--total-timesteps", type=float, default=CONFIG["TOTAL_TIMESTEPS"],
                        help="purejaxrl's TOTAL_TIMESTEPS")
    parser.add_argument("--iterations", type=int, default=150, help="jaxpg's iterations")
    parser.add_argument("--quick", action="store_true", help="2 seeds, tiny budgets")
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.total_timesteps, args.iterations = 2, 2**14, 12
    steps_per_update = CONFIG["NUM_ENVS"] * CONFIG["NUM_STEPS"]
    if args.seeds < 1:
        parser.error(f"--seeds: must be at least 1, got {args.seeds}")
    if args.total_timesteps < WINDOW * steps_per_update:
        parser.error(f"--total-timesteps: must be at least {WINDOW * steps_per_update} "
                     f"({WINDOW} updates), got {args.total_timesteps}")
    if args.iterations < WINDOW:
        parser.error(f"--iterations: must be at least {WINDOW}, got {args.iterations}")
    xla_options.configure_xla()
    common.print_header("purejaxrl's PPO against jaxpg's ppo-32 on CartPole-v1")
    rows = [measure_purejaxrl(args.seeds, args.total_timesteps),
            measure_jaxpg(args.seeds, args.iterations)]
    common.print_table(rows, ["impl", "seeds", "updates", "compile_s", "run_s", "total_steps",
                              "steps_to_195", "s_to_195", "median_seed_steps_to_195",
                              "never_solved", "final_median_m"])
    common.write_results("purejaxrl_ppo", args, rows)


if __name__ == "__main__":
    main()
