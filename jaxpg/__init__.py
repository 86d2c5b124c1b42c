"""jaxpg: policy-gradient reinforcement learning on CartPole, exact and fast, in JAX."""

from jaxpg import cartpole
from jaxpg.policies import basic_policy
from jaxpg.reinforce import TrainConfig, TrainResult, train
from jaxpg.returns import discount_and_normalize_rewards, discount_rewards

__version__ = "0.1.0"

__all__ = [
    "cartpole",
    "basic_policy",
    "discount_rewards",
    "discount_and_normalize_rewards",
    "TrainConfig",
    "TrainResult",
    "train",
]
