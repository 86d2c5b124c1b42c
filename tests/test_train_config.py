"""TrainConfig: bad settings are refused before compiling; any optax optimizer by name."""


import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxpg import (
    TrainConfig,
    cartpole,
    train,
)
from jaxpg.sweeps import expand_grid
from jaxpg.train_config import OPTIMIZERS, steps_on_gradients

# What float32 holds: the largest magnitude, 3.403e38, and the smallest normal number, 1.175e-38.
TOO_LARGE = r"must be at most 3\.403e\+38 in magnitude \(the largest float32\)"
TOO_SMALL = r"must be at least 1\.175e-38 \(the smallest normal float32\)"


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
    ("hidden", {5: 1}, "hidden: must be a tuple of positive layer sizes"),  # no order of layers
    # Numbers that float32, the dtype training takes them in, cannot hold.
    ("learning_rate", 1e300, f"learning_rate: {TOO_LARGE}, got 1e\\+300$"),
    ("learning_rate", 1e-300, f"learning_rate: {TOO_SMALL}, got 1e-300$"),  # 0 in float32
    ("learning_rate", 1e-40, f"learning_rate: {TOO_SMALL}"),  # subnormal in float32
    ("discount", 1e-300, f"discount: {TOO_SMALL}"),
    ("entropy_coef", 1e39, f"entropy_coef: {TOO_LARGE}"),
    ("env", cartpole.CartPoleParams(length=1e308), f"length: {TOO_LARGE}, got 1e\\+308$"),
    ("env", cartpole.CartPoleParams(tau=1e-300), f"tau: {TOO_SMALL}"),
    ("env", cartpole.CartPoleParams(masspole=1e30, length=1e10),
     f"masspole \\* length: {TOO_LARGE}, got 1e\\+40$"),
    ("randomize", {"length": (0.3, 1e39)}, f"length: {TOO_LARGE}"),
    ("randomize", {"tau": (1e-300, 0.02)}, f"tau: {TOO_SMALL}"),
    ("randomize", {"length": (float("nan"), 1.0)}, "length: must be finite, got NaN or infinity$"),
    # Each bound is held, but a draw scales by the width, 6e38.
    ("randomize", {"gravity": (-3e38, 3e38)}, f"gravity \\(high - low\\): {TOO_LARGE}"),
    # Wrong kinds of randomize.
    ("randomize", 5, "randomize: expected a dict {field: \\(low, high\\)} or"),
    ("randomize", None, "randomize: expected a dict"),
    ("randomize", "length", "randomize: expected a dict"),
    ("randomize", [("length",)], "randomize: expected a dict"),
    # More steps than the environment's time limit, which would end every episode first.
    ("max_steps", 501, "max_steps: at most 500, the environment's time limit .*, got 501$"),
    # Bounds that `float` would take, one by one: "12" as (1, 2), b"12" as (49, 50).
    ("randomize", {"length": "12"}, "length: expected a range \\(low, high\\), got '12'$"),
    ("randomize", {"length": b"12"}, "length: expected a range"),
    ("randomize", {"length": {0.3, 0.6}}, "length: expected a range"),  # in no given order
    ("randomize", {"length": ("0.25", "2")}, "length: must be a number, got '0.25'$"),
    ("randomize", {"length": (True, 2)}, "length: must be a number, got True$"),
    # Ragged: numpy's own message, which named no field.
    ("randomize", {"length": ((0.3,), 0.6)}, "length: expected a range \\(low, high\\), got "
                                            "\\(\\(0.3,\\), 0.6\\)$"),
    ("randomize", [("length", (0.3, 0.6)), ("length", (0.4, 0.5))],
     "randomize: length is given two ranges; give each field one$"),
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
    one, two = (train(TrainConfig(iterations=n, episodes=1, max_steps=5, optimizer=name), seed=0,
                      show_progress=False) for n in (1, 2))
    assert np.all(np.isfinite(two.metrics.loss))
    # The second iteration's step moved every layer's parameters.
    for before, after in zip(*(jax.tree.leaves(r.policy_params) for r in (one, two))):
        assert np.all(np.isfinite(after)) and not np.array_equal(before, after)


def test_any_optax_optimizer_by_name():
    result = train(TrainConfig(iterations=2, episodes=2, max_steps=10, optimizer="sgd",
                               hidden=(3, 3), activation="tanh"), seed=0, show_progress=False)
    assert np.all(np.isfinite(result.metrics.loss))


def test_zero_is_allowed_where_a_value_underflows_to_it_and_the_smallest_normal_float32_is():
    smallest = float(np.finfo(np.float32).smallest_normal)
    config = TrainConfig(entropy_coef=1e-300, learning_rate=smallest, discount=smallest)
    assert config.hyperparams.per_run().entropy_coef == 0


def test_physics_are_checked_in_jax_default_float_and_hyperparameters_in_float32():
    """With jax_enable_x64 the physics compute in float64, which holds 1e-300; the optimizer's
    settings stay float32."""
    with jax.enable_x64(True):
        assert TrainConfig(env=cartpole.CartPoleParams(tau=1e-300)).env_params.tau == 1e-300
        with pytest.raises(ValueError, match=f"^learning_rate: {TOO_SMALL}"):
            TrainConfig(learning_rate=1e-300)


def test_randomize_takes_lists_as_pairs_and_keeps_them_sorted():
    config = TrainConfig(randomize=[["tau", [0.01, 0.02]], ("length", (0.3, 0.6))])
    assert config.randomize == (("length", (0.3, 0.6)), ("tau", (0.01, 0.02)))


def test_randomize_takes_a_range_as_a_numpy_or_jax_array_alike():
    """A JAX array of two was refused as no range, where numpy's was taken."""
    ranges = [TrainConfig(randomize={"length": array([0.25, 0.5])}).randomize
              for array in (np.array, jnp.array)]
    assert ranges[0] == ranges[1] == (("length", (0.25, 0.5)),)


@pytest.mark.parametrize("grid, match", [
    ({"length": [0.5, 1e39]}, f"length: {TOO_LARGE}"),
    ({"tau": [0.02, 1e-300]}, f"tau: {TOO_SMALL}"),
    ({"masspole": [1e30], "length": [1e10]}, f"masspole \\* length: {TOO_LARGE}"),
    ([{"learning_rate": 1e-300}], f"learning_rate: {TOO_SMALL}"),
    ([{"entropy_coef": 1e39}], f"entropy_coef: {TOO_LARGE}"),
])
def test_grid_values_that_float32_cannot_hold_are_refused(grid, match):
    with pytest.raises(ValueError, match=f"^{match}"):
        expand_grid(TrainConfig(), grid)


class IntegerLogits(nn.Module):
    """A policy whose logits are int32."""

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(1)(obs)[..., 0].astype(jnp.int32)


def _updates_as_a_list(learning_rate):
    """SGD whose update returns the updates' leaves as a list, not the parameters' tree."""
    sgd = optax.sgd(learning_rate)
    return optax.GradientTransformation(
        sgd.init, lambda grads, state, params=None: (jax.tree.leaves(grads), state))


def _updates_alone(learning_rate):
    """SGD whose update returns the updates without the state."""
    sgd = optax.sgd(learning_rate)
    return optax.GradientTransformation(
        sgd.init, lambda grads, state, params=None: sgd.update(grads, state, params)[0])


def _state_in_a_list(learning_rate):
    """SGD with momentum whose update returns its state inside a list."""
    sgd = optax.sgd(learning_rate, momentum=0.9)

    def update(grads, state, params=None):
        updates, state = sgd.update(grads, state, params)
        return updates, [state]

    return optax.GradientTransformation(sgd.init, update)


def _integer_updates(learning_rate):
    """SGD whose updates are rounded to integers (which would leave every weight where it is)."""
    sgd = optax.sgd(learning_rate)

    def update(grads, state, params=None):
        updates, state = sgd.update(grads, state, params)
        return jax.tree.map(lambda leaf: leaf.astype(jnp.int32), updates), state

    return optax.GradientTransformation(sgd.init, update)


def _update_of_vectors_only(learning_rate):
    """SGD whose update fails on a parameter with no axes (as optax's sm3 does on a bias)."""
    sgd = optax.sgd(learning_rate)

    def update(grads, state, params=None):
        if any(leaf.ndim == 0 for leaf in jax.tree.leaves(grads)):
            raise IndexError("list index out of range")
        return sgd.update(grads, state, params)

    return optax.GradientTransformation(sgd.init, update)


@pytest.mark.parametrize("fields, match", [
    ({"policy": IntegerLogits()}, "policy: the module's logits must be floating, got int32$"),
    ({"optimizer": _update_of_vectors_only, "loss": "baseline"},  # the linear critic's bias: ()
     r"optimizer: cannot step the parameters, of shapes \{'critic': .*'bias': \(\).*: "
     r"IndexError: list index out of range$"),
    ({"optimizer": _state_in_a_list},
     r"optimizer: its update must return state of its init's tree, shapes and dtypes, "),
    ({"optimizer": _integer_updates},
     r"optimizer: its update must return floating updates, got \['int32'\]$"),
    ({"optimizer": _updates_as_a_list},
     "optimizer: its update must return updates of the parameters' tree and shapes, "),
    ({"optimizer": _updates_as_a_list, "loss": "baseline"},
     r"optimizer: its update must return updates of the parameters' tree and shapes, "
     r"\{'critic': .*, 'policy': .*\}, got \[\(.*\)\]$"),
    ({"optimizer": _updates_alone, "loss": "baseline"},
     r"optimizer: its update must return \(updates, state\), got dict$"),
])
def test_a_policy_or_optimizer_of_the_wrong_kind_is_named_before_compiling(fields, match):
    config = TrainConfig(iterations=1, episodes=1, max_steps=2, **fields)
    with pytest.raises(ValueError, match=f"^{match}") as error:
        train(config, seed=0, show_progress=False)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize(("env", "steps"), [
    ("CartPole-v1", 200),  # the book's
    (cartpole.CartPoleParams(max_steps=40), 40),  # a shorter time limit
    ("CartPole-v0", 200),
    ("Acrobot-v1", 500),  # the time limit of the others
])
def test_episodes_run_by_default_the_books_200_steps_or_the_time_limit(env, steps):
    assert TrainConfig(env=env).max_steps == steps
