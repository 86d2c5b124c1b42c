"""Evaluates a policy on CartPole, in jaxpg (one compiled batch) or in Gymnasium itself.

Both backends can start from the very same initial states: `gymnasium_reset_states` reads the
float64 states that Gymnasium's `reset(seed=seed + i)` produces, and `evaluate(...,
init_states=...)` starts jaxpg's episodes from them.
"""

import functools
from typing import NamedTuple

import gymnasium
import jax
import numpy as np

from jaxpg import cartpole, rollout

BACKENDS = ("jaxpg", "gymnasium")

# The CartPoleParams fields that Gymnasium's CartPoleEnv keeps as attributes of the same name.
_GYMNASIUM_ATTRIBUTES = ("gravity", "masscart", "masspole", "length", "force_mag", "tau",
                         "x_threshold", "theta_threshold_radians")


class EvalResult(NamedTuple):
    """Statistics of the episode returns (Python floats) and the returns themselves."""

    mean: float
    std: float  # population standard deviation, as np.std
    min: float
    max: float
    returns: np.ndarray  # [episodes] float64


def check_int(name, value, minimum):
    """Raises a ValueError naming `name` unless `value` is an integer >= `minimum` (and < 2**32)."""
    is_int = isinstance(value, int | np.integer) and not isinstance(value, bool)
    if not is_int or not minimum <= value < 2**32:
        raise ValueError(f"{name}: must be an integer in [{minimum}, 2**32), got {value!r}")


def resolve_env(env):
    """A preset name or a `CartPoleParams`, validated, as (env_params, Gymnasium env id).

    A custom `CartPoleParams` maps to `CartPole-v1`, whose settings `make_gymnasium_env` then
    replaces. Only scalar settings can be evaluated (one environment, not a sweep over many).
    """
    if isinstance(env, str):
        return cartpole.make_params(env), env
    if not isinstance(env, cartpole.CartPoleParams):
        raise ValueError(
            f"env: expected a preset name ({', '.join(cartpole.PRESETS)}) or a CartPoleParams, "
            f"got {type(env).__name__}"
        )
    cartpole.check_params(env)
    if any(np.ndim(leaf) != 0 for leaf in jax.tree.leaves(env)):
        raise ValueError("env: every CartPoleParams field must be a scalar here, not an array")
    return env, "CartPole-v1"


def make_gymnasium_env(env_params, env_id="CartPole-v1"):
    """`gymnasium.make(env_id)` with its CartPoleEnv set to `env_params`.

    The TimeLimit truncates at `env_params.max_steps`. `total_mass` and `polemass_length` are
    recomputed the way `CartPoleEnv.__init__` does, from the masses and length, never copied from
    `env_params`: Gymnasium stays the reference even for a `CartPoleParams` that derives them
    wrongly.
    """
    gym_env = gymnasium.make(
        env_id,
        max_episode_steps=int(env_params.max_steps),
        sutton_barto_reward=bool(env_params.sutton_barto_reward),
    )
    reference = gym_env.unwrapped
    for name in _GYMNASIUM_ATTRIBUTES:
        setattr(reference, name, float(getattr(env_params, name)))
    # Gymnasium integrates semi-implicitly for any value other than "euler".
    reference.kinematics_integrator = env_params.integrator
    reference.total_mass = reference.masspole + reference.masscart
    reference.polemass_length = reference.masspole * reference.length
    return gym_env


def reset_gymnasium(gym_env, seed, env_params):
    """`gym_env.reset(seed=seed)` within the reset bounds of `env_params`; returns the obs `[4]`."""
    bounds = {"low": float(env_params.reset_low), "high": float(env_params.reset_high)}
    obs, _ = gym_env.reset(seed=seed, options=bounds)
    return obs


def gymnasium_reset_states(episodes, seed=0, env="CartPole-v1"):
    """The float64 states that Gymnasium's `reset(seed=seed + i)` gives, for i in [0, episodes).

    Returns:
      `[episodes, 4]` float64 (x, x_dot, theta, theta_dot), as `env.unwrapped.state` holds them;
      `cartpole.CartPoleState.from_array` turns them into jaxpg's initial states.
    """
    check_int("episodes", episodes, 1)
    check_int("seed", seed, 0)
    env_params, env_id = resolve_env(env)
    gym_env = make_gymnasium_env(env_params, env_id)
    states = []
    for episode in range(episodes):
        reset_gymnasium(gym_env, seed + episode, env_params)
        states.append(np.array(gym_env.unwrapped.state, dtype=np.float64))
    return np.stack(states)


def evaluate(policy, episodes=500, max_steps=200, env="CartPole-v1", seed=0, backend="jaxpg",
             init_states=None):
    """Plays `episodes` episodes of at most `max_steps` steps and summarizes their returns.

    With backend "jaxpg" the episodes run as one compiled `rollout.rollout` from
    `jax.random.PRNGKey(seed)`. With backend "gymnasium", episode i runs in `gymnasium.make(env)`
    from `reset(seed=seed + i)`, one step at a time, as the book does; the policy's uniform at step
    t of episode i is drawn from `fold_in(fold_in(PRNGKey(seed), i), t)`. An episode also ends when the
    environment's own time limit (`max_steps` of its CartPoleParams) truncates it.

    Args:
      policy: `(obs [E, 4], u [E]) -> action [E]` with u uniform in [0, 1), e.g.
        `policies.basic_policy`.
      episodes: E, a positive integer.
      max_steps: the longest an episode may run, a positive integer.
      env: a preset name ("CartPole-v1", "CartPole-v0") or a `cartpole.CartPoleParams`.
      seed: a non-negative integer.
      backend: "jaxpg" or "gymnasium".
      init_states: optional `[E, 4]` initial states (jaxpg only), e.g. `gymnasium_reset_states`.

    Returns:
      `EvalResult` with the returns `[E]`.
    """
    if not callable(policy):
        raise ValueError(f"policy: must be a callable (obs, u) -> action, got {policy!r}")
    check_int("episodes", episodes, 1)
    check_int("max_steps", max_steps, 1)
    check_int("seed", seed, 0)
    if backend not in BACKENDS:
        raise ValueError(f"backend: must be {' or '.join(BACKENDS)}, got {backend!r}")
    env_params, env_id = resolve_env(env)
    if backend == "gymnasium":
        if init_states is not None:
            raise ValueError(
                "init_states: only with backend jaxpg; Gymnasium starts from reset(seed=seed + i)"
            )
        returns = _gymnasium_returns(policy, episodes, max_steps, env_params, env_id, seed)
    else:
        init_state = None if init_states is None else _init_state(init_states, episodes)
        returns = _jaxpg_returns(
            jax.random.PRNGKey(seed), env_params, init_state, policy, episodes, max_steps
        )
    return summarize(returns)


def summarize(returns):
    """`EvalResult` of returns `[E]`."""
    returns = np.asarray(returns, dtype=np.float64)
    return EvalResult(
        float(returns.mean()), float(returns.std()), float(returns.min()), float(returns.max()),
        returns,
    )


def _init_state(init_states, episodes):
    """`init_states` `[episodes, 4]` as a `CartPoleState`, in jaxpg's float dtype."""
    shape = np.shape(init_states)
    if shape != (episodes, 4):
        raise ValueError(f"init_states: expected shape ({episodes}, 4), got {shape}")
    return cartpole.CartPoleState.from_array(np.asarray(init_states))


# The policy is static (hashed by identity), so a module-level function such as basic_policy
# compiles once per shape and settings, however often it is evaluated.
@functools.partial(jax.jit, static_argnames=("policy", "episodes", "max_steps"))
def _jaxpg_returns(key, env_params, init_state, policy, episodes, max_steps):
    return rollout.rollout(key, policy, env_params, episodes, max_steps, init_state).returns


@functools.partial(jax.jit, static_argnums=0)
def _act(policy, obs, key, episode, t):
    """The policy's action for one observation `[4]`, with the uniform of step t of `episode`."""
    key = jax.random.fold_in(jax.random.fold_in(key, episode), t)
    return policy(obs[None], jax.random.uniform(key, (1,)))[0]


def _gymnasium_returns(policy, episodes, max_steps, env_params, env_id, seed):
    """Returns `[episodes]` of episodes played in Gymnasium, one Python step at a time."""
    gym_env = make_gymnasium_env(env_params, env_id)
    key = jax.random.PRNGKey(seed)
    returns = np.zeros(episodes)
    for episode in range(episodes):
        obs = reset_gymnasium(gym_env, seed + episode, env_params)
        for t in range(max_steps):
            action = int(_act(policy, obs, key, episode, t))
            obs, reward, terminated, truncated, _ = gym_env.step(action)
            returns[episode] += reward
            if terminated or truncated:
                break
    return returns
