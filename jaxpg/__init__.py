"""jaxpg: policy-gradient reinforcement learning on CartPole, exact and fast, in JAX.

`jaxpg.sweep` and `jaxpg.evaluate` name the functions; import from their modules with
`from jaxpg.sweep import ...` and `from jaxpg.evaluate import ...`.
"""

__version__ = "0.1.0"

from jaxpg import cartpole, gym
from jaxpg.evaluate import evaluate
from jaxpg.executables import enable as keep_programs
from jaxpg.policies import basic_policy
from jaxpg.iteration import TrainResult
from jaxpg.reinforce import train
from jaxpg.train_config import TrainConfig
from jaxpg.returns import discount_and_normalize_rewards, discount_rewards
from jaxpg.sweep import sweep

gym.register()

__all__ = [
    "cartpole",
    "basic_policy",
    "discount_rewards",
    "discount_and_normalize_rewards",
    "evaluate",
    "keep_programs",
    "sweep",
    "TrainConfig",
    "TrainResult",
    "train",
]
