"""The book's REINFORCE on CartPole in plain numpy, one step at a time on a Gymnasium env.

Géron, Hands-On Machine Learning, chapter 18 ("Policy Gradients"), with the Keras model and
GradientTape replaced by a hand-written Dense(5, elu) -> Dense(1, sigmoid) network and its
backward pass, and Keras's Adam written out. It is the baseline that jaxpg's compiled training is
measured against, and it runs on any Gymnasium env id with CartPole's API (a Box observation and
two actions), e.g. jaxpg's own registered env.

    python benchmarks/book_numpy.py --seed 42 --iterations 150
"""

import argparse
import time
from typing import NamedTuple

import gymnasium as gym
import numpy as np

N_EPISODES_PER_UPDATE = 10
N_MAX_STEPS = 200
DISCOUNT_FACTOR = 0.95
LEARNING_RATE = 0.01


# ---------------------------------------------------------------- the network


def glorot_uniform(rng, fan_in, fan_out):
    limit = np.sqrt(6.0 / (fan_in + fan_out))
    return rng.uniform(-limit, limit, size=(fan_in, fan_out)).astype(np.float32)


def init_model(rng, n_inputs, n_hidden=5):
    """Keras's Dense defaults: Glorot-uniform kernels, zero biases. A list of [W1, b1, W2, b2]."""
    return [
        glorot_uniform(rng, n_inputs, n_hidden),
        np.zeros(n_hidden, np.float32),
        glorot_uniform(rng, n_hidden, 1),
        np.zeros(1, np.float32),
    ]


def elu(z):
    return np.where(z > 0, z, np.expm1(np.minimum(z, 0)))


def sigmoid(z):
    return 1 / (1 + np.exp(-z))


def forward(model, obs):
    """P(left) for one observation `[n_inputs]`, and what the backward pass needs."""
    w1, b1, w2, b2 = model
    z1 = obs @ w1 + b1
    h = elu(z1)
    left_proba = sigmoid(h @ w2 + b2)[0]
    return left_proba, (obs, z1, h)


def bce_gradients(model, cache, left_proba, y_target):
    """Gradients of the binary cross-entropy between `y_target` and P(left), for each variable.

    With a sigmoid output the gradient with respect to the logit is `P(left) - y_target`, as
    Keras computes it from the logit.
    """
    w1, b1, w2, b2 = model
    obs, z1, h = cache
    d_logit = np.float32(left_proba - y_target)
    d_h = w2[:, 0] * d_logit
    d_z1 = d_h * np.where(z1 > 0, 1.0, np.exp(np.minimum(z1, 0))).astype(np.float32)
    return [np.outer(obs, d_z1), d_z1, h[:, None] * d_logit, np.array([d_logit], np.float32)]


# ---------------------------------------------------------------- Adam (Keras's)


class Adam:
    """Keras's Adam: beta1 0.9, beta2 0.999, epsilon 1e-7, with the bias correction in the step."""

    def __init__(self, variables, learning_rate=LEARNING_RATE, beta_1=0.9, beta_2=0.999,
                 epsilon=1e-7):
        self.learning_rate, self.beta_1, self.beta_2, self.epsilon = (
            learning_rate, beta_1, beta_2, epsilon)
        self.m = [np.zeros_like(v) for v in variables]
        self.v = [np.zeros_like(v) for v in variables]
        self.iterations = 0

    def apply_gradients(self, grads, variables):
        """Updates `variables` in place."""
        self.iterations += 1
        t = self.iterations
        alpha = self.learning_rate * np.sqrt(1 - self.beta_2**t) / (1 - self.beta_1**t)
        for var, g, m, v in zip(variables, grads, self.m, self.v):
            m += (1 - self.beta_1) * (g - m)
            v += (1 - self.beta_2) * (np.square(g) - v)
            var -= (alpha * m / (np.sqrt(v) + self.epsilon)).astype(var.dtype)


# ---------------------------------------------------------------- the book's functions


def play_one_step(env, obs, model, rng):
    left_proba, cache = forward(model, np.asarray(obs, np.float32))
    action = int(rng.uniform() > left_proba)  # 1 (right) when u > P(left)
    y_target = 1.0 - action
    grads = bce_gradients(model, cache, left_proba, y_target)
    obs, reward, done, truncated, info = env.step(action)
    return obs, reward, done, truncated, grads


def play_multiple_episodes(env, n_episodes, n_max_steps, model, rng):
    all_rewards = []
    all_grads = []
    for _episode in range(n_episodes):
        current_rewards = []
        current_grads = []
        obs, info = env.reset()
        for _step in range(n_max_steps):
            obs, reward, done, truncated, grads = play_one_step(env, obs, model, rng)
            current_rewards.append(reward)
            current_grads.append(grads)
            if done or truncated:
                break
        all_rewards.append(current_rewards)
        all_grads.append(current_grads)
    return all_rewards, all_grads


def discount_rewards(rewards, discount_factor):
    discounted = np.array(rewards, dtype=float)
    for step in range(len(rewards) - 2, -1, -1):
        discounted[step] += discounted[step + 1] * discount_factor
    return discounted


def discount_and_normalize_rewards(all_rewards, discount_factor):
    all_discounted_rewards = [discount_rewards(rewards, discount_factor)
                              for rewards in all_rewards]
    flat_rewards = np.concatenate(all_discounted_rewards)
    reward_mean = flat_rewards.mean()
    reward_std = flat_rewards.std()
    return [(discounted_rewards - reward_mean) / reward_std
            for discounted_rewards in all_discounted_rewards]


def mean_weighted_grads(all_final_rewards, all_grads):
    """For each variable, the mean over every step of every episode of reward * gradient."""
    weights = np.concatenate(all_final_rewards)
    steps = [grads for episode in all_grads for grads in episode]
    return [
        np.tensordot(weights, np.stack([g[i] for g in steps]), axes=1).astype(np.float32)
        / len(steps)
        for i in range(len(steps[0]))
    ]


# ---------------------------------------------------------------- training


class History(NamedTuple):
    """Per iteration: mean return of the episodes, steps simulated, wall-clock seconds."""

    mean_returns: list
    steps: list
    seconds: list


def make_env(env_id):
    """`gymnasium.make(env_id)`; jaxpg's ids (`jaxpg/CartPole-v1`) are registered first."""
    if env_id.startswith("jaxpg/"):
        from jaxpg import gym as jaxpg_gym

        jaxpg_gym.register()
    return gym.make(env_id)


def run(seed=42, iterations=150, env_id="CartPole-v1", verbose=False):
    """The book's training loop; returns its `History`."""
    env = make_env(env_id)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)  # later resets continue the env's own seeded generator
    env.action_space.seed(seed)
    model = init_model(rng, env.observation_space.shape[0])
    optimizer = Adam(model)
    history = History([], [], [])
    for iteration in range(iterations):
        start = time.perf_counter()
        all_rewards, all_grads = play_multiple_episodes(
            env, N_EPISODES_PER_UPDATE, N_MAX_STEPS, model, rng)
        all_final_rewards = discount_and_normalize_rewards(all_rewards, DISCOUNT_FACTOR)
        optimizer.apply_gradients(mean_weighted_grads(all_final_rewards, all_grads), model)
        history.seconds.append(time.perf_counter() - start)
        history.mean_returns.append(sum(map(sum, all_rewards)) / N_EPISODES_PER_UPDATE)
        history.steps.append(sum(map(len, all_rewards)))
        if verbose:
            print(f"\rIteration: {iteration + 1}/{iterations}, "
                  f"mean rewards: {history.mean_returns[-1]:.1f}", end="")
    if verbose:
        print()
    env.close()
    return history


def train(seed=42, iterations=150, env_id="CartPole-v1"):
    """Trains with the book's settings; the mean return of each iteration's episodes."""
    return run(seed, iterations, env_id).mean_returns


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--iterations", type=int, default=150)
    parser.add_argument("--env", default="CartPole-v1", help="any Gymnasium env id")
    args = parser.parse_args()
    history = run(args.seed, args.iterations, args.env, verbose=True)
    total_s, total_steps = sum(history.seconds), sum(history.steps)
    print(f"{total_steps} steps in {total_s:.2f} s ({total_steps / total_s:,.0f} steps/s); "
          f"last mean return {history.mean_returns[-1]:.1f}")


if __name__ == "__main__":
    main()
