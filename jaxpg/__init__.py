"""jaxpg: policy-gradient reinforcement learning on CartPole, exact and fast, in JAX."""

__version__ = "0.1.0"

from jaxpg import cartpole, gym, losses
from jaxpg.evaluation import EvalResult, evaluate, robustness
from jaxpg.executables import keep_programs
from jaxpg.iteration import Metrics, TrainResult
from jaxpg.policies import basic_policy
from jaxpg.returns import discount_and_normalize_rewards, discount_rewards
from jaxpg.sweeps import SweepResult, sweep, train
from jaxpg.train_config import Hyperparams, TrainConfig

gym.register()


def __getattr__(name: str) -> object:
    """`save_sweep` (`jaxpg.results`), imported on first use: it imports scipy and matplotlib,
    which `import jaxpg` does without."""
    if name == "save_sweep":
        from jaxpg.results import save_sweep

        return save_sweep
    raise AttributeError(f"module 'jaxpg' has no attribute {name!r}")


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
