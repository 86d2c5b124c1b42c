"""One iteration: the fast path's optimizer step as optax defines it; any policy, loss and
optimizer, checked before compiling, trained alike alone and in a sweep (parameters bit for bit,
reported losses to a few units in the last place)."""

import dataclasses

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from conftest import assert_trained_alike, check_alone, xla_compiles

from jaxpg import (
    TrainConfig,
    TrainResult,
    iteration,
    losses,
    policies,
    sweep,
    train,
    train_config,
)


def _optax_steps(config, grads, params):
    """optax's own steps of `config.optimizer` on `params`, whatever their structure."""
    optimizer = train_config.make_optimizer(config, config.learning_rate)
    state = optimizer.init(params)
    for grad in grads:
        updates, state = optimizer.update(grad, state, params)
        params = optax.apply_updates(params, updates)
    return params


def _optimizer_steps(config, grads, params):
    """The same steps as `iteration.optimizer_step` takes them, on flat parameters."""
    flat = policies.flatten(params, config.network)
    _, opt_state = iteration.init_run(config, jax.random.PRNGKey(0), config.hyperparams)
    for grad in grads:
        flat, opt_state = iteration.optimizer_step(
            config, policies.flatten(grad, config.network), opt_state, flat,
            config.learning_rate)
    return flat


@pytest.mark.parametrize("name", sorted(train_config.ELEMENTWISE_OPTIMIZERS))
def test_optimizers_step_as_optax_defines_them_on_each_array(name):
    """The fast path's optimizers, stepped on the flat vector, update each parameter as they
    would per array."""
    config = TrainConfig(optimizer=name, hidden=(5, 3))
    params = policies.init_network(jax.random.PRNGKey(1), config.network)
    rng = np.random.default_rng(2)
    grads = [jax.tree.map(lambda leaf: rng.normal(size=leaf.shape).astype(np.float32), params)
             for _ in range(3)]
    expected = policies.flatten(_optax_steps(config, grads, params), config.network)
    np.testing.assert_allclose(_optimizer_steps(config, grads, params), expected,
                               rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("name", ["lamb", "adafactor"])
def test_optimizers_of_whole_arrays_take_the_engine(name):
    """Stepped on one vector, lamb's per-layer trust ratio and adafactor's factored moments would
    update otherwise than per array: they train off the fast path."""
    config = TrainConfig(optimizer=name, hidden=(5, 3))
    assert not config.hand_gradient
    params = policies.init_network(jax.random.PRNGKey(1), config.network)
    rng = np.random.default_rng(2)
    grads = [jax.tree.map(lambda leaf: rng.normal(size=leaf.shape).astype(np.float32), params)
             for _ in range(3)]
    expected = policies.flatten(_optax_steps(config, grads, params), config.network)
    one_vector = _optax_steps(config, [policies.flatten(g, config.network) for g in grads],
                              policies.flatten(params, config.network))
    assert not np.allclose(one_vector, expected, rtol=1e-3, atol=1e-4)


# --- Any policy, loss and optimizer: differentiated by JAX, run by `runwise` --------------------

SMALL = TrainConfig(iterations=3, episodes=3, max_steps=20)


def test_minibatches_hold_every_episode_once_per_epoch():
    config = TrainConfig(episodes=6, epochs=3, minibatches=2)
    batch = losses.Batch(*(jnp.broadcast_to(jnp.arange(6.0), (4, 6)) for _ in range(5)))
    split = iteration.minibatches(config, batch, jax.random.PRNGKey(0))
    assert split.obs.shape == (6, 4, 3)  # [epochs * minibatches, T, E / minibatches]
    episodes = np.asarray(split.obs[:, 0]).reshape(3, 6)  # each epoch's order
    assert all(sorted(order) == list(range(6)) for order in episodes)
    assert len({tuple(order) for order in episodes}) > 1  # shuffled anew


@pytest.mark.parametrize("changes, match", [
    ({"minibatches": 3}, r"minibatches: must divide episodes \(10\), got 3"),
    ({"epochs": 0}, "epochs")])
def test_bad_epochs_and_minibatches_are_named(changes, match):
    with pytest.raises(ValueError, match=match):
        TrainConfig(**changes)


class BookModule(nn.Module):
    """The default network's shape as a user writes it; `outputs` logits per observation."""

    outputs: int = 1

    @nn.compact
    def __call__(self, obs):
        logit = nn.Dense(1)(nn.elu(nn.Dense(5)(obs)))
        if self.outputs == 2:  # a categorical policy: logits of (left, right)
            return jnp.concatenate([logit, jnp.zeros_like(logit)], axis=-1)
        return logit


class MLP(nn.Module):
    """Two tanh layers and two logits, as a researcher writes a wider policy."""

    @nn.compact
    def __call__(self, obs):
        for size in (32, 32):
            obs = nn.tanh(nn.Dense(size)(obs))
        return nn.Dense(2)(obs)


def _clipped_adam(learning_rate):
    return optax.chain(optax.clip_by_global_norm(1.0), optax.adam(learning_rate))


def _assert_seeds_train_alone_as_in_a_sweep(config):
    """Seeds 0 to 4 alone and in one sweep: parameters, returns and the critic bit for bit,
    gradient norms to one unit in the last place (`assert_trained_alike`); the loss's reported
    values (the loss and its metrics) to a few units: computed apart from the gradient, they can
    round differently alone (LLVM fuses a multiplication and an addition into one rounding in one
    program's layout and not in the other's)."""
    together = sweep(config, seeds=range(5), show_progress=False)
    for s in range(5):
        alone = train(config, seed=s, show_progress=False)
        beside = jax.tree.map(lambda leaf: leaf[0, s], TrainResult(
            together.policy_params, together.metrics, critic_params=together.critic_params))
        assert_trained_alike(alone._replace(metrics=alone.metrics._replace(loss=0, extra={})),
                             beside._replace(metrics=beside.metrics._replace(loss=0, extra={})))
        for name in ("loss", "extra"):
            for got, want in zip(jax.tree.leaves(getattr(alone.metrics, name)),
                                 jax.tree.leaves(getattr(beside.metrics, name))):
                np.testing.assert_array_max_ulp(got, want, maxulp=4)


# Minibatches of two episodes where there are several updates: of one, they are a known
# exception (README).
@pytest.mark.parametrize("changes", [
    {"loss": "baseline"},
    {"entropy_coef": 0.01},
    {"loss": "reward-to-go", "hidden": ()},
    {"policy": BookModule()},
    {"policy": MLP()},
    {"policy": MLP(), "loss": "reward-to-go"},
    {"policy": MLP(), "loss": "baseline"},
    {"policy": BookModule(), "optimizer": _clipped_adam},
    {"optimizer": _clipped_adam},  # the default network, off the fast path
    {"loss": "ppo"},
    {"loss": "ppo", "episodes": 6, "epochs": 2, "minibatches": 3},  # a scan over minibatches
    {"loss": losses.PPO(losses.ValueNetwork((32,))), "hidden": (32,), "activation": "tanh",
     "episodes": 6, "epochs": 4, "minibatches": 3},
])
def test_a_seed_trains_alone_as_in_a_sweep(changes):
    config = dataclasses.replace(SMALL, **changes)
    assert not config.hand_gradient
    _assert_seeds_train_alone_as_in_a_sweep(config)


@pytest.mark.parametrize("changes", [{}, {"entropy_coef": 0.01}, {"loss": "ppo"},
                                     {"policy": BookModule()}])
def test_a_seed_of_one_episode_an_iteration_trains_alone_as_in_a_sweep(changes):
    """One episode an iteration, which a block of runs plays twice (`rollout.played_episodes`;
    played once, XLA rounded a run's physics otherwise in a block than alone), and one update
    with Adam, which steps with the runs first (`runwise.runs_first`; with the runs last, its
    moments rounded otherwise alone from the second iteration on)."""
    _assert_seeds_train_alone_as_in_a_sweep(
        TrainConfig(iterations=3, episodes=1, max_steps=20, **changes))


def test_the_baselines_seeds_train_alone_as_in_a_sweep_for_the_books_150_iterations():
    """Seeds 0 to 15 with the baseline loss, alone and in one block (`benchmarks/check_alone.py`):
    the same parameters after 150 iterations of the book's size. A few iterations of a small
    batch do not show every difference: a linear critic written as `Dense(1)` trained 13 of these
    16 seeds differently alone (docs/performance.md)."""
    result = check_alone("--seeds", "16", "--variant", "baseline")
    assert result.stdout.startswith("0 of 16 seeds ended with other parameters alone"), (
        result.stdout + result.stderr)


def test_a_categorical_policy_trains_as_its_logit_difference():
    one = train(dataclasses.replace(SMALL, policy=BookModule(1)), seed=3, show_progress=False)
    two = train(dataclasses.replace(SMALL, policy=BookModule(2)), seed=3, show_progress=False)
    chex.assert_trees_all_equal(one, two)


def test_a_users_module_learns_to_balance():
    config = TrainConfig(iterations=60, policy=BookModule(), loss="baseline", entropy_coef=0.001)
    result = train(config, seed=0, show_progress=False)
    returns = np.asarray(result.metrics.mean_return)
    assert returns[-10:].mean() > 2 * returns[:10].mean()
    assert set(result.metrics.extra) == {"entropy", "value_loss"}
    assert result.metrics.extra["value_loss"].shape == (60,)


def test_the_fast_path_serves_the_default_network_with_the_books_loss_only():
    assert TrainConfig().hand_gradient
    assert TrainConfig(hidden=()).hand_gradient
    assert TrainConfig(optimizer="sgd").hand_gradient
    for changes in ({"entropy_coef": 0.1}, {"loss": "baseline"}, {"policy": BookModule()},
                    {"optimizer": "lamb"}, {"optimizer": _clipped_adam}):
        assert not TrainConfig(**changes).hand_gradient


class _Wrong(nn.Module):
    @nn.compact
    def __call__(self, obs):
        return nn.Dense(3)(obs)


@pytest.mark.parametrize("changes, match", [
    ({"policy": _Wrong()}, r"policy: .* must return logits shaped \(20, 3\), \(20, 3, 1\) or "
                           r"\(20, 3, 2\), got \(20, 3, 3\)"),
    ({"loss": lambda params, apply_fn, batch, hyper: 0.0}, "loss: must return"),
    ({"loss": lambda params, apply_fn, batch, hyper: (jnp.zeros(2), {})}, "loss: must return"),
    ({"loss": lambda params, apply_fn, batch, hyper: (0.0, {"m": jnp.zeros(3)})},
     "loss: must return"),
    ({"optimizer": lambda lr: "adam"}, "optimizer: the function must return an optax"),
    ({"optimizer": lambda lr: optax.lbfgs(lr)}, "optimizer: the function's optimizer asks for "
                                                "more than the gradient"),
    ({"policy": "mlp"}, "policy: expected None or a flax.linen.Module"),
])
def test_bad_parts_are_named_before_anything_compiles(changes, match):
    with xla_compiles() as compiled, pytest.raises(ValueError, match=match):
        train(dataclasses.replace(SMALL, **changes), show_progress=False)
    assert not [name for name in compiled if "_iterate_stacked" in name or "init_runs" in name]


def test_a_loss_that_becomes_nan_is_reported_with_its_first_iteration():
    def exploding(params, apply_fn, batch, hyper):
        loss, metrics = losses.reinforce(params, apply_fn, batch, hyper)
        return loss + jnp.log(hyper.learning_rate - 0.02), metrics  # NaN at lr 0.01

    with pytest.warns(RuntimeWarning, match="diverged: the loss or its gradient is not finite "
                                            "from iteration 0 on"):
        train(dataclasses.replace(SMALL, loss=exploding), show_progress=False)
