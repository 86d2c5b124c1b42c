"""Gymnasium's classic-control tasks as pure, jittable JAX modules, each equal to Gymnasium's.

Every module has the same interface, as `jaxpg.cartpole`:

- `NAME` (the Gymnasium id), `OBS_SIZE`, and `NUM_ACTIONS` (discrete actions, int `[...]`) or
  `ACTION_LOW` and `ACTION_HIGH` (one continuous action, float `[...]`);
- a `flax.struct` params dataclass whose numbers are pytree leaves (a sweep can vmap over them)
  and whose program-changing options are static fields; its presets (`PRESETS` by id, and `V0`
  or `V1`), `make_params(env, **overrides)` and `check_params(env_params)`;
- a state dataclass with `time` (steps taken), `from_array` and `to_array`;
- `reset(key, env_params) -> (obs, state)`, `observe(state) -> obs` and
  `step(state, action, env_params) -> (obs, state, reward, terminated, truncated)`.

`MODULES` maps each Gymnasium id to its module.
"""

from jaxpg.envs import acrobot, continuous_mountain_car, mountain_car, pendulum

MODULES = {module.NAME: module
           for module in (acrobot, mountain_car, continuous_mountain_car, pendulum)}

__all__ = ["MODULES", "acrobot", "continuous_mountain_car", "mountain_car", "pendulum"]
