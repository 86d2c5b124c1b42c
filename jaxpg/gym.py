"""Gymnasium `Env` and `VectorEnv` backed by jaxpg's jittable CartPole.

After `register()`, `gymnasium.make("jaxpg/CartPole-v1")` and
`gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=N)` (also `-v0`) behave as Gymnasium's own
`CartPole-v1` and its `CartPoleVectorEnv`: the same spaces, float32 observations, rewards,
termination, time limits and next-step autoreset. Random numbers differ: resets draw from a JAX key
derived from the environment's `np_random`, so `reset(seed=...)` is deterministic but does not give
Gymnasium's initial states.
"""

import functools

import gymnasium
import jax
import numpy as np
from gymnasium import spaces
from gymnasium.envs.classic_control import utils
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from jaxpg import cartpole, render, rollout

# Compiled once per static configuration (integrator, reward scheme, number of environments);
# the physics values are traced arguments, so changing them does not recompile.
_step = jax.jit(cartpole.step)


@jax.jit
def _reset(seed, env_params):
    return cartpole.reset(jax.random.PRNGKey(seed), env_params)


@functools.partial(jax.jit, static_argnums=1)
def _vector_reset(seed, num_envs, env_params):
    key, key_reset = jax.random.split(jax.random.PRNGKey(seed))
    obs, stream_state = rollout.stream_reset(key_reset, num_envs, env_params)
    return key, obs, stream_state


@jax.jit
def _vector_step(key, stream_state, action, env_params):
    key, key_reset = jax.random.split(key)
    return key, *rollout.autoreset_step(key_reset, stream_state, action, env_params)


def observation_space(env_params):
    """Gymnasium's CartPole observation space: twice the termination thresholds, float32."""
    high = np.array(
        [env_params.x_threshold * 2, np.inf, env_params.theta_threshold_radians * 2, np.inf],
        dtype=np.float32,
    )
    return spaces.Box(-high, high, dtype=np.float32)


def _make_params(env_params, sutton_barto_reward):
    """The `CartPoleParams` of an environment: `env_params` (default v1), validated."""
    env_params = cartpole.V1 if env_params is None else env_params
    cartpole.check_params(env_params)
    if sutton_barto_reward:
        env_params = env_params.replace(sutton_barto_reward=True)
    return env_params


def _check_render_mode(render_mode, metadata):
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        raise ValueError(
            f"render_mode: must be None or one of {', '.join(metadata['render_modes'])}, "
            f"got {render_mode!r}"
        )


def _draw_seed(np_random):
    """A JAX seed from the environment's generator, so that `reset(seed=...)` fixes it."""
    return np.uint32(np_random.integers(2**32))


def _reset_params(env_params, options):
    """`env_params` with the reset bounds that `options` ("low", "high") may override."""
    low, high = utils.maybe_parse_reset_bounds(
        options, float(env_params.reset_low), float(env_params.reset_high)
    )
    return env_params.replace(reset_low=low, reset_high=high)


class CartPoleEnv(gymnasium.Env):
    """One CartPole, stepped by `jaxpg.cartpole.step`; a drop-in for Gymnasium's `CartPoleEnv`.

    As Gymnasium's, it never truncates by itself: `gymnasium.make` adds the `TimeLimit` wrapper
    (500 steps for v1, 200 for v0), so `env_params.max_steps` plays no part here. Stepping after
    termination gives reward 0 (-1 with the Sutton-Barto reward) and a warning, as Gymnasium does.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, sutton_barto_reward=False, render_mode=None, env_params=None):
        """Creates the environment.

        Args:
          sutton_barto_reward: 0 per step and -1 on termination instead of 1 per step.
          render_mode: None or "rgb_array".
          env_params: `CartPoleParams` for other physics; CartPole-v1's by default.
        """
        _check_render_mode(render_mode, self.metadata)
        self.env_params = _make_params(env_params, sutton_barto_reward)
        self.render_mode = render_mode
        self.action_space = spaces.Discrete(2)
        self.observation_space = observation_space(self.env_params)
        self._state = None
        self._steps_beyond_terminated = None

    @property
    def state(self):
        """The physical state `[4]` (x, x_dot, theta, theta_dot), float64; None before reset.

        Settable, as Gymnasium's `CartPoleEnv.state`, e.g. to start from a chosen state.
        """
        return None if self._state is None else np.array(self._state.to_array(), np.float64)

    @state.setter
    def state(self, values):
        values = np.asarray(values)
        if values.shape != (4,):
            raise ValueError(f"state: expected shape (4,), got {values.shape}")
        self._state = cartpole.CartPoleState.from_array(values)

    def reset(self, *, seed=None, options=None):
        """Starts an episode; `options` may set the reset bounds "low" and "high"."""
        super().reset(seed=seed)
        obs, self._state = _reset(
            _draw_seed(self.np_random), _reset_params(self.env_params, options)
        )
        self._steps_beyond_terminated = None
        return np.array(obs, dtype=np.float32), {}

    def step(self, action):
        """One step: 1 pushes right, 0 left. Returns (obs, reward, terminated, False, {})."""
        if not self.action_space.contains(action):
            raise ValueError(f"action: must be 0 (push left) or 1 (push right), got {action!r}")
        if self._state is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        obs, self._state, reward, terminated, _ = _step(
            self._state, np.int32(action), self.env_params
        )
        obs, reward, terminated = jax.device_get((obs, reward, terminated))
        terminated = bool(terminated)
        reward = float(reward)
        if terminated:
            if self._steps_beyond_terminated is None:
                self._steps_beyond_terminated = 0
            else:
                if self._steps_beyond_terminated == 0:
                    gymnasium.logger.warn(
                        "You are calling 'step()' even though this environment has already "
                        "returned terminated = True; call 'reset()' first."
                    )
                self._steps_beyond_terminated += 1
                reward = -1.0 if self.env_params.sutton_barto_reward else 0.0
        return np.array(obs, dtype=np.float32), reward, terminated, False, {}

    def render(self):
        """The current frame as uint8 `[400, 600, 3]` in "rgb_array" mode."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "You are calling render method without specifying any render mode, e.g. "
                'gymnasium.make("jaxpg/CartPole-v1", render_mode="rgb_array")'
            )
            return None
        if self._state is None:
            return None
        return render.render_frame(self._state, self.env_params)


class CartPoleVectorEnv(gymnasium.vector.VectorEnv):
    """N CartPoles stepped together by `rollout.autoreset_step`; as Gymnasium's `CartPoleVectorEnv`.

    Next-step autoreset: the step after an environment terminates or truncates ignores its
    action and resets it, with reward 0 and terminated and truncated False. Truncation happens
    after `max_episode_steps` steps.
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs=1,
        max_episode_steps=None,
        render_mode=None,
        sutton_barto_reward=False,
        env_params=None,
    ):
        """Creates the environments.

        Args:
          num_envs: N.
          max_episode_steps: the time limit; `env_params.max_steps` (500) by default.
          render_mode: None or "rgb_array".
          sutton_barto_reward: 0 per step and -1 on termination instead of 1 per step.
          env_params: `CartPoleParams` for other physics; CartPole-v1's by default.
        """
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs: must be a positive integer, got {num_envs!r}")
        _check_render_mode(render_mode, self.metadata)
        env_params = _make_params(env_params, sutton_barto_reward)
        if max_episode_steps is not None:
            env_params = env_params.replace(max_steps=max_episode_steps)
            cartpole.check_params(env_params)
        self.env_params = env_params
        self.num_envs = num_envs
        self.max_episode_steps = int(env_params.max_steps)
        self.render_mode = render_mode
        self.single_action_space = spaces.Discrete(2)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.single_observation_space = observation_space(env_params)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._key = None
        self._stream = None
        self._episode_params = env_params

    @property
    def state(self):
        """The physical states `[4, N]` (rows x, x_dot, theta, theta_dot), float64, as Gymnasium's.

        Settable; setting it keeps each environment's step count and pending autoreset.
        """
        if self._stream is None:
            return None
        return np.array(self._stream.env_state.to_array(), np.float64).T

    @state.setter
    def state(self, values):
        if self._stream is None:
            raise gymnasium.error.ResetNeeded("call reset() before setting the state")
        values = np.asarray(values)
        if values.shape != (4, self.num_envs):
            raise ValueError(f"state: expected shape (4, {self.num_envs}), got {values.shape}")
        env_state = cartpole.CartPoleState.from_array(values.T, time=self._stream.env_state.time)
        self._stream = self._stream._replace(env_state=env_state)

    def reset(self, *, seed=None, options=None):
        """Resets every environment; `options` may set the reset bounds "low" and "high"."""
        super().reset(seed=seed)
        self._episode_params = _reset_params(self.env_params, options)
        self._key, obs, self._stream = _vector_reset(
            _draw_seed(self.np_random), self.num_envs, self._episode_params
        )
        return np.array(obs, dtype=np.float32), {}

    def step(self, actions):
        """Steps every environment. Returns (obs [N, 4], reward [N], terminated, truncated, {})."""
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,) or not np.isin(actions, (0, 1)).all():
            raise ValueError(
                f"actions: expected {self.num_envs} actions, each 0 (push left) or 1 (push "
                f"right), got {actions!r}"
            )
        if self._stream is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        self._key, obs, self._stream, reward, terminated, truncated = _vector_step(
            self._key, self._stream, actions.astype(np.int32), self._episode_params
        )
        obs, reward, terminated, truncated = jax.device_get((obs, reward, terminated, truncated))
        return (
            np.array(obs, dtype=np.float32),
            np.array(reward, dtype=np.float32),
            np.array(terminated),
            np.array(truncated),
            {},
        )

    def render(self):
        """One uint8 frame `[400, 600, 3]` per environment, in "rgb_array" mode."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "You are calling render method without specifying any render mode, e.g. "
                'gymnasium.make_vec("jaxpg/CartPole-v1", render_mode="rgb_array")'
            )
            return None
        if self._stream is None:
            raise ValueError("cannot render before reset()")
        return tuple(render.render_frame(self._stream.env_state, self.env_params))


def register():
    """Registers `jaxpg/CartPole-v1` and `jaxpg/CartPole-v0` with Gymnasium (idempotent)."""
    for name, env_params in cartpole.PRESETS.items():
        env_id = f"jaxpg/{name}"
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="jaxpg.gym:CartPoleEnv",
            vector_entry_point="jaxpg.gym:CartPoleVectorEnv",
            max_episode_steps=int(env_params.max_steps),
            reward_threshold=cartpole.REWARD_THRESHOLDS[name],
            kwargs={"env_params": env_params},
        )
