"""Gymnasium's classic-control tasks as pure, jittable JAX modules, each equal to Gymnasium's.

Every module has the same interface, as `jaxpg.envs.cartpole` (CartPole's):

- `NAME` (the Gymnasium id), `OBS_SIZE`, and `NUM_ACTIONS` (discrete actions, int `[...]`) or
  `ACTION_LOW` and `ACTION_HIGH` (one continuous action, float `[...]`, in the presets' range;
  `action_bounds(env_params)` gives a params' own);
- a `flax.struct` params dataclass whose numbers are pytree leaves (a sweep can vmap over them)
  and whose program-changing options are static fields; its presets (`PRESETS` by id, and `V0`
  or `V1`), `make_params(env, **overrides)` and `check_params(env_params)`;
- a state dataclass with `time` (steps taken), `from_array` and `to_array`;
- `reset(key, env_params) -> (obs, state)`, `observe(state) -> obs` and
  `step(state, action, env_params) -> (obs, state, reward, terminated, truncated)`.

`MODULES` maps each Gymnasium id to its module, CartPole's two included; the trainer finds an
environment's module from its params (`module_of`). A gymnax environment, or a user's own with
its interface, joins them through `from_gymnax` (`jaxpg.envs.gymnax_style`).
"""

import dataclasses
import functools
from types import ModuleType
from typing import Any

import numpy as np

from jaxpg.envs import (
    acrobot,
    cartpole,
    continuous_mountain_car,
    gymnax_style,
    mountain_car,
    pendulum,
)
from jaxpg.envs.gymnax_style import from_gymnax
from jaxpg.validation import check_int

MODULES: dict[str, ModuleType] = {
    **{name: cartpole for name in cartpole.PRESETS},
    **{module.NAME: module
       for module in (acrobot, mountain_car, continuous_mountain_car, pendulum)},
}
# The return that counts as solved where Gymnasium names none (Pendulum-v1): jaxpg's choice.
_SOLVED = {"Pendulum-v1": -200.0}
# CartPole's book threshold, below Gymnasium's 475 for v1: the book's episodes last 200 steps.
_SOLVED_CARTPOLE = 195.0
_BOOK_STEPS = 200


def module_of(env_params: Any) -> Any:
    """The environment module whose params `env_params` are (a `gymnax_style.Module` for
    `GymnaxParams`).

    Raises:
      ValueError: naming `env` for anything else than one environment's params.
    """
    if isinstance(env_params, gymnax_style.GymnaxParams):
        return gymnax_style.module(env_params.env)
    for module in dict.fromkeys(MODULES.values()):
        if isinstance(env_params, _params_type(module)):
            return module
    raise ValueError(f"env: expected an environment's name ({', '.join(MODULES)}) or its params "
                     f"(such as cartpole.CartPoleParams), got {type(env_params).__name__}")


def _params_type(module: Any) -> type:
    """The params dataclass of an environment module."""
    return type(next(iter(module.PRESETS.values())))


def resolve(env: Any) -> Any:
    """An environment's params from its name (a preset) or from its params, validated.

    Args:
      env: a name of `MODULES`, or an environment's params dataclass.

    Returns:
      The params.

    Raises:
      ValueError: naming `env` for an unknown name, another kind of value or a field that is an
        array (one environment's physics: a sweep varies them by its grid), or the field at
        fault for invalid params (the module's `check_params`).
    """
    if isinstance(env, str):
        if env not in MODULES:
            raise ValueError(f"env: unknown {env!r}; allowed: {', '.join(MODULES)}")
        return _preset(env)
    module_of(env).check_params(env)
    arrays = [field.name for field in dataclasses.fields(env) if np.ndim(getattr(env, field.name))]
    if arrays:
        raise ValueError(f"env: every field of {type(env).__name__} must be a number, not an "
                         f"array ({', '.join(arrays)}); a sweep's grid varies them")
    return env


@functools.cache
def _preset(name: str) -> Any:
    """The params of the preset `name`, made and checked once (params are immutable)."""
    return MODULES[name].make_params(name)


def physics(module: Any) -> tuple[str, ...]:
    """The fields of an environment's params that sweeps and randomisation may vary.

    Every number but the reset bounds and `max_steps`; static fields change the program. A
    module may name them (`PHYSICS`: none of a gymnax-style environment's).
    """
    if hasattr(module, "PHYSICS"):
        return tuple(module.PHYSICS)
    return tuple(field.name for field in dataclasses.fields(_params_type(module))
                 if field.metadata.get("pytree_node", True)
                 and not field.name.startswith("reset") and field.name != "max_steps")


def program_params(env_params: Any) -> Any:
    """The params that stand for every physics of one compiled program: the module's first
    preset with the static fields (which change the program) of `env_params`."""
    static = {field.name: getattr(env_params, field.name)
              for field in dataclasses.fields(env_params)
              if not field.metadata.get("pytree_node", True)}
    return next(iter(module_of(env_params).PRESETS.values())).replace(**static)


def is_built_in(module: Any) -> bool:
    """Whether the module is one of jaxpg's own (`MODULES`), whose programs its config decides."""
    return any(module is built_in for built_in in MODULES.values())


def is_discrete(module: Any) -> bool:
    """Whether the environment's actions are integers (`NUM_ACTIONS`), not one float."""
    return hasattr(module, "NUM_ACTIONS")


def max_steps(env_params: Any) -> int:
    """The most steps of a training episode by default: the environment's time limit (for
    CartPole the book's 200, or its time limit where that is shorter)."""
    limit = int(env_params.max_steps)
    return min(_BOOK_STEPS, limit) if module_of(env_params) is cartpole else limit


def check_episode_steps(max_steps: Any, env_params: Any) -> int:
    """`max_steps` as an `int`; a ValueError naming it unless it is 1 to the time limit of
    `env_params`' environment (its `max_steps`), which ends every episode there anyway: a longer
    `max_steps` would say more steps than any episode plays."""
    steps = check_int("max_steps", max_steps)
    limit = int(env_params.max_steps)
    if steps > limit:
        raise ValueError(f"max_steps: at most {limit}, the environment's time limit (its params' "
                         f"max_steps), got {steps}")
    return steps


def solved_return(env_params: Any) -> float:
    """The mean return that counts as solved by default: Gymnasium's reward threshold (195, the
    book's, for CartPole; a gymnax-style environment's: its task's, or 0 for one jaxpg does not
    know)."""
    module = module_of(env_params)
    if module is cartpole:
        return _SOLVED_CARTPOLE
    if not is_built_in(module) and module.NAME in MODULES:  # gymnax's version of a task
        return solved_return(MODULES[module.NAME].PRESETS[module.NAME])
    return float(getattr(module, "REWARD_THRESHOLDS", _SOLVED)[module.NAME])


__all__ = ["MODULES", "acrobot", "continuous_mountain_car", "from_gymnax", "is_built_in",
           "is_discrete", "max_steps",
           "module_of", "mountain_car", "pendulum", "physics", "program_params", "resolve",
           "solved_return"]
