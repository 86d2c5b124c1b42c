"""TrainConfig: bad settings are refused before compiling; any optax optimizer by name."""


import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxpg import (
    TrainConfig,
    train,
)
from jaxpg.train_config import OPTIMIZERS, steps_on_gradients


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
    ("solved_return", "x", "solved_return: must be a number"),
    ("solved_return", float("nan"), "solved_return: must be finite"),
    ("learning_rate", "0.01", "learning_rate: must be a number"),
    ("learning_rate", True, "learning_rate: must be a number"),
    ("learning_rate", float("inf"), "learning_rate: must be finite"),
    ("discount", [0.9, 0.95], r"discount: must be a number \(one value; a sweep's grid takes"),
    ("entropy_coef", np.array([0.0]), "entropy_coef: must be a number"),
    ("optimizer", "lbfgs", "optimizer: cannot train with 'lbfgs'"),
    ("hidden", 5, "hidden: must be a tuple of positive layer sizes"),
])
def test_bad_config_is_rejected_before_compiling(field, value, match):
    with pytest.raises(ValueError, match=f"^{match}"):
        TrainConfig(**{field: value})


def test_numbers_of_numpy_and_jax_are_taken():
    config = TrainConfig(learning_rate=np.float32(0.02), discount=np.float64(0.9),
                         solved_return=np.int64(100), entropy_coef=jnp.float32(0.0))
    assert config.hyperparams.per_run().learning_rate == np.float32(0.02)


def test_the_optimizers_listed_exclude_those_that_need_more_than_the_gradient():
    """optax's lbfgs also asks its update for the loss's value, gradient and function."""
    with pytest.raises(ValueError) as error:
        TrainConfig(optimizer="nope")
    listed = error.value.args[0].split("in all: ")[1].rstrip(")").split(", ")
    assert "lbfgs" in OPTIMIZERS and "lbfgs" not in listed and "adam" in listed
    assert all(steps_on_gradients(OPTIMIZERS[name](learning_rate=0.01)) for name in listed)
    assert not steps_on_gradients(optax.lbfgs(0.01))


# Each kind of optimizer of the list: elementwise on one vector (adam, tested throughout),
# per array with per-layer statistics (lamb), factored moments (sm3), with a key of its own
# (noisy_sgd), a plain scaling (scale_by_learning_rate).
@pytest.mark.parametrize("name", ["lamb", "sm3", "noisy_sgd", "scale_by_learning_rate"])
def test_a_listed_optimizer_trains(name):
    result = train(TrainConfig(iterations=1, episodes=1, max_steps=2, optimizer=name), seed=0,
                   show_progress=False)
    assert np.all(np.isfinite(result.metrics.loss))


def test_any_optax_optimizer_by_name():
    result = train(TrainConfig(iterations=2, episodes=2, max_steps=10, optimizer="sgd",
                               hidden=(3, 3), activation="tanh"), seed=0, show_progress=False)
    assert np.all(np.isfinite(result.metrics.loss))
