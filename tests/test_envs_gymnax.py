"""A gymnax-style environment (a user's own here, gymnax's where it is installed) trains as
jaxpg's own do: alone as in a sweep, with its actions' kind of policy."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from jaxpg import TrainConfig, envs, evaluate, policies, sweep, train


@struct.dataclass
class _State:
    position: jax.Array
    time: jax.Array


@struct.dataclass
class _Params:
    goal: float = 1.0
    max_steps_in_episode: int = 30


class Corridor:
    """Walk to `goal` from 0: action a moves by m / 4, m = a - 1 (continuous: a clipped to
    [-1, 1]), for a reward of m - 1 until the goal is reached. Written as gymnax's are."""

    def __init__(self, continuous=False):
        self.continuous = continuous

    @property
    def default_params(self):
        return _Params()

    @property
    def name(self):
        return "Corridor"

    def observation_space(self, params):
        return SimpleNamespace(shape=(2,))

    def action_space(self, params):
        return SimpleNamespace(shape=(1,)) if self.continuous else SimpleNamespace(n=3)

    def get_obs(self, state):
        return jnp.stack([state.position, state.time / 30.0])

    def reset_env(self, key, params):
        state = _State(jax.random.uniform(key, (), minval=-0.1, maxval=0.1), jnp.int32(0))
        return self.get_obs(state), state

    def step_env(self, key, state, action, params):
        move = jnp.clip(action, -1, 1) if self.continuous else action - 1
        state = _State(state.position + move / 4, state.time + 1)
        done = state.position >= params.goal
        return self.get_obs(state), state, (move - 1.0).astype(jnp.float32), done, {}


@pytest.mark.parametrize("continuous", [False, True])
def test_a_gymnax_style_environment_trains_alone_as_in_a_sweep_and_learns(continuous):
    corridor = envs.from_gymnax(Corridor(continuous))
    config = TrainConfig(env=corridor, hidden=(8,), iterations=40, learning_rate=0.03)
    assert config.max_steps == 30 and config.num_actions == (None if continuous else 3)
    alone = train(config, seed=1, show_progress=False)
    swept = sweep(config, seeds=[0, 1], show_progress=False)
    np.testing.assert_array_equal(alone.metrics.mean_return, swept.metrics.mean_return[0, 1])
    # Walking right reaches the goal in 4 or 5 steps for a return of 0; standing still scores
    # -30, a random walk about -30 (its steps average -1).
    first, last = alone.metrics.mean_return[:5].mean(), alone.metrics.mean_return[-5:].mean()
    assert last > first + 5, (first, last)
    network = config.network
    policy = policies.network_policy(network, alone.policy_params,
                                     num_actions=config.num_actions).replace(greedy=True)
    assert evaluate(policy, episodes=10, max_steps=30, env=corridor).mean > -10


def test_a_gymnax_style_environment_is_checked_and_varies_no_field():
    with pytest.raises(ValueError, match="^env: expected a gymnax-style environment, object has "
                                         "no reset_env"):
        envs.from_gymnax(object())
    with pytest.raises(ValueError, match="^max_steps: must be an integer"):
        envs.from_gymnax(Corridor(), max_steps=0)
    with pytest.raises(ValueError, match="^randomize: unknown field 'goal'; allowed: $"):
        TrainConfig(env=envs.from_gymnax(Corridor()), randomize={"goal": (1, 2)})


def test_gymnax_acrobot_trains_as_jaxpgs_own_learns():
    gymnax = pytest.importorskip("gymnax")
    env, params = gymnax.make("Acrobot-v1")
    config = TrainConfig(env=envs.from_gymnax(env, params), loss="baseline", hidden=(32,),
                         iterations=25)
    assert (config.max_steps, config.solved_return) == (500, -100.0)
    result = train(config, seed=0, show_progress=False)
    assert result.metrics.mean_return[-5:].mean() > -200  # a random policy: about -500
