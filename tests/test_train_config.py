"""TrainConfig: bad settings are refused before compiling; any optax optimizer by name."""


import numpy as np
import pytest

from jaxpg import (
    TrainConfig,
    train,
)


@pytest.mark.parametrize("field, value, match", [
    ("iterations", 0, "iterations"),
    ("episodes", -1, "episodes"),
    ("max_steps", 2.5, "max_steps"),
    ("discount", 0.0, "discount"),
    ("discount", 1.01, "discount"),
    ("learning_rate", 0.0, "learning_rate"),
    ("optimizer", "adamm", "optimizer"),
    ("activation", "softmaxx", "activation"),
    ("env", "CartPole-v9", "env"),
])
def test_bad_config_is_rejected_before_compiling(field, value, match):
    with pytest.raises(ValueError, match=match):
        TrainConfig(**{field: value})


def test_any_optax_optimizer_by_name():
    result = train(TrainConfig(iterations=2, episodes=2, max_steps=10, optimizer="sgd",
                               hidden=(3, 3), activation="tanh"), seed=0, show_progress=False)
    assert np.all(np.isfinite(result.metrics.loss))
