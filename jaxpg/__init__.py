"""jaxpg: policy-gradient reinforcement learning on CartPole, exact and fast, in JAX.

`import jaxpg` imports neither JAX nor Gymnasium: each public name is imported on first use
(`jaxpg.train`, `from jaxpg import cartpole`), so the `jaxpg` command handles Ctrl-C from its
first moment. `jaxpg/CartPole-v1` and `jaxpg/CartPole-v0` are registered with Gymnasium as it is
imported (at once where it already is); `gymnasium.make` imports their adapters (`jaxpg.envs.gym`).
"""

import importlib
import sys
from types import ModuleType  # (not `types`: jaxpg.types would replace it)

__version__ = "0.1.0"

TYPE_CHECKING = False  # (as typing's, which mypy reads as True, without importing typing)
if TYPE_CHECKING:
    from collections.abc import Sequence
    from importlib.machinery import ModuleSpec

    from jaxpg import animation as render  # noqa: F401  (an attribute, left out of `__all__`)
    from jaxpg import losses
    from jaxpg.envs import cartpole
    from jaxpg.envs import conformance as conformance  # (attributes, left out of `__all__`)
    from jaxpg.envs import gym as gym
    from jaxpg.evaluation import EvalResult, evaluate, robustness
    from jaxpg.executables import keep_programs
    from jaxpg.iteration import Metrics, TrainResult
    from jaxpg.policies import basic_policy
    from jaxpg.results import save_sweep
    from jaxpg.returns import discount_and_normalize_rewards, discount_rewards
    from jaxpg.sweeps import SweepResult, sweep, train
    from jaxpg.train_config import Hyperparams, TrainConfig

# name: module; `conformance` too, as before it moved into `jaxpg.envs`; `render` is the
# animations' module, which holds `jaxpg.envs.render.render_frame` too
_MODULES = {"cartpole": "envs.cartpole", "conformance": "envs.conformance", "gym": "envs.gym",
            "losses": "losses", "render": "animation", "xla_options": "xla_options"}
_DEFINED_IN = {  # public name: the module of jaxpg's that defines it
    "EvalResult": "evaluation",
    "evaluate": "evaluation",
    "robustness": "evaluation",
    "keep_programs": "executables",
    "Metrics": "iteration",
    "TrainResult": "iteration",
    "basic_policy": "policies",
    "save_sweep": "results",  # (it imports scipy and matplotlib)
    "discount_and_normalize_rewards": "returns",
    "discount_rewards": "returns",
    "SweepResult": "sweeps",
    "sweep": "sweeps",
    "train": "sweeps",
    "Hyperparams": "train_config",
    "TrainConfig": "train_config",
}


def __getattr__(name: str) -> object:
    """A public name of jaxpg's or one of its modules, imported on first use."""
    if name in _MODULES:
        return importlib.import_module(f"{__name__}.{_MODULES[name]}")
    if name not in _DEFINED_IN:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_DEFINED_IN[name]}"), name)
    globals()[name] = value  # later uses find it without this function
    return value


def __dir__() -> list[str]:
    """The module's names, those not imported yet included."""
    return sorted({*globals(), *_MODULES, *_DEFINED_IN})


# --- Gymnasium's ids, registered without importing Gymnasium ---------------------------------


# The classic-control tasks of `jaxpg.envs.adapters`, registered beside CartPole's.
_OTHER_IDS = ("Acrobot-v1", "MountainCar-v0", "MountainCarContinuous-v0", "Pendulum-v1")


def _register_ids(gymnasium: ModuleType) -> None:
    """Registers `jaxpg/CartPole-v1`, `jaxpg/CartPole-v0` and the other classic-control tasks
    (`jaxpg/Acrobot-v1`, ...) with `gymnasium` (idempotent).

    Each has the time limit and reward threshold of Gymnasium's id of the same name, and jaxpg's
    adapters as entry points (`jaxpg.envs.gym`'s for CartPole,
    `jaxpg.envs.adapters.ClassicControlEnv` for the others, with the task's name as `env_params`
    and `task`, so that `env_params` given to `gymnasium.make` must be that task's),
    which `gymnasium.make` and `make_vec` import (JAX with them) when first called.

    Args:
      gymnasium: the module `gymnasium`, imported.
    """
    for name in ("CartPole-v1", "CartPole-v0", *_OTHER_IDS):
        env_id = f"jaxpg/{name}"
        if env_id in gymnasium.registry:
            continue
        theirs = gymnasium.spec(name)
        cartpole = name.startswith("CartPole")
        gymnasium.register(
            id=env_id,
            entry_point="jaxpg.envs.gym:CartPoleEnv" if cartpole else
            "jaxpg.envs.adapters:ClassicControlEnv",
            vector_entry_point="jaxpg.envs.gym:CartPoleVectorEnv" if cartpole else None,
            max_episode_steps=theirs.max_episode_steps,
            reward_threshold=theirs.reward_threshold,
            kwargs={} if cartpole else {"env_params": name, "task": name},
        )


class _RegisterOnImport:
    """A finder of `sys.meta_path` that calls `_register_ids` once `gymnasium` is imported.

    The first time `gymnasium` is imported, it leaves `sys.meta_path`, has the other finders
    find the module, and has its loader call `_register_ids` once the module has run.
    """

    def find_spec(self, name: str, path: "Sequence[str] | None",
                  target: ModuleType | None = None) -> "ModuleSpec | None":
        """The other finders' spec of `gymnasium`, its loader registering; None for others."""
        if name != "gymnasium":
            return None
        import importlib.util

        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        loader = spec.loader

        def exec_module(module: ModuleType) -> None:
            del loader.exec_module  # (this function, set on the instance below)
            type(loader).exec_module(loader, module)
            _register_ids(module)

        setattr(loader, "exec_module", exec_module)  # noqa: B010 (a method, set on an instance)
        return spec


if "gymnasium" in sys.modules:
    _register_ids(sys.modules["gymnasium"])
else:
    sys.meta_path.insert(0, _RegisterOnImport())


__all__ = [
    "EvalResult",
    "Hyperparams",
    "Metrics",
    "SweepResult",
    "TrainConfig",
    "TrainResult",
    "basic_policy",
    "cartpole",
    "discount_and_normalize_rewards",
    "discount_rewards",
    "evaluate",
    "keep_programs",
    "losses",
    "robustness",
    "save_sweep",
    "sweep",
    "train",
]
