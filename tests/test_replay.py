"""replay: the rollout records what a module's gradient reads, and the gradient from those records
equals JAX's own."""

import dataclasses

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpg import TrainConfig, iteration, policies, replay, train


class MLP(nn.Module):
    """Hidden layers of `activation`, then `outputs` logits."""

    hidden: tuple[int, ...] = (32, 32)
    activation: str = "tanh"
    outputs: int = 2

    @nn.compact
    def __call__(self, obs):
        for size in self.hidden:
            obs = getattr(nn, self.activation)(nn.Dense(size)(obs))
        return nn.Dense(self.outputs)(obs)


class Centred(nn.Module):
    """A module that mixes observations: each is centred on the batch's mean."""

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(2)(obs - obs.mean(axis=tuple(range(obs.ndim - 1))))


class LogSoftmaxHead(nn.Module):
    """Log-probabilities of two actions, as a categorical head is often written."""

    @nn.compact
    def __call__(self, obs):
        return jax.nn.log_softmax(nn.Dense(2)(nn.tanh(nn.Dense(8)(obs))))


class Outer(nn.Module):
    """A product that contracts no axis: each hidden unit times each of three weights."""

    @nn.compact
    def __call__(self, obs):
        hidden = nn.tanh(nn.Dense(4)(obs))
        outer = jnp.einsum("...i,j->...ij", hidden, self.param("w", nn.initializers.normal(), (3,)))
        return nn.Dense(2)(outer.reshape(*outer.shape[:-2], 12))


class HostPreprocessed(nn.Module):
    """Observations preprocessed on the host: no derivative with respect to them."""

    @nn.compact
    def __call__(self, obs):
        obs = jax.pure_callback(lambda x: np.tanh(x).astype(x.dtype),
                                jax.ShapeDtypeStruct(obs.shape, obs.dtype), obs,
                                vmap_method="expand_dims")
        return nn.Dense(1)(nn.tanh(nn.Dense(8)(obs)))


MODULES = [MLP(), MLP((16,), "relu"), MLP((8, 8), "gelu"), policies.GaussianNetwork((8,)),
           policies.PolicyNetwork((5,)), LogSoftmaxHead(), Outer()]


def _params(module):
    return module.init(jax.random.PRNGKey(0), jnp.zeros(4))


@pytest.mark.parametrize("activation", ["tanh", "swish"])
def test_an_mlp_records_its_output_and_each_hidden_layer_only(activation):
    """Two logits and 32 values a layer: what else the derivative reads is computed again from
    them (1 - tanh(x) from tanh(x); `jax.nn.swish`, a `jax.jit` function traced inline, from its
    input)."""
    module = MLP(activation=activation)
    plan = replay.plan(module.apply, _params(module), jnp.zeros((200, 10, 4)))
    assert plan.rows == ((2,), (32,), (32,))


@pytest.mark.parametrize("module", MODULES, ids=lambda m: f"{type(m).__name__}")
def test_the_replayed_gradient_equals_jaxs_own(module):
    params = _params(module)
    obs = jax.random.normal(jax.random.PRNGKey(1), (20, 10, 4))
    plan = replay.plan(module.apply, params, obs)
    assert replay.same_layout(plan, replay.plan(module.apply, params, obs[0]))
    recorded = jax.jit(lambda p, o: replay.record(plan, p, o))(params, obs)
    replayed = replay.replayed(plan)
    weights = jax.random.normal(jax.random.PRNGKey(2),
                                jax.eval_shape(module.apply, params, obs).shape)

    def loss(apply):
        return jax.jit(jax.value_and_grad(lambda p: jnp.sum(apply(p) * weights)))(params)

    chex.assert_trees_all_close(loss(lambda p: replayed(p, obs, recorded)),
                                loss(lambda p: module.apply(p, obs)), rtol=1e-5, atol=1e-5)
    chex.assert_trees_all_close(replay.output(plan, recorded), module.apply(params, obs),
                                rtol=1e-6, atol=1e-6)


def test_a_module_without_a_derivative_in_its_observations_trains():
    """The pass is differentiated with respect to the parameters only, as the loss is."""
    config = TrainConfig(policy=HostPreprocessed(), iterations=2, episodes=2, max_steps=20)
    assert np.all(np.isfinite(train(config, seed=0, show_progress=False).metrics.grad_norm))


def test_a_module_that_mixes_observations_is_not_replayed():
    obs = jnp.zeros((200, 10, 4))
    assert replay.plan(Centred().apply, _params(Centred()), obs) is None
    config = TrainConfig(policy=Centred(), iterations=2, episodes=3, max_steps=20)
    assert iteration.replay_plan(config, (3,)) is None


@pytest.mark.parametrize("changes, replays", [
    ({"policy": MLP()}, True),
    ({"policy": MLP(), "loss": "baseline", "entropy_coef": 0.01}, True),
    ({"policy": MLP(), "loss": "ppo"}, True),  # one update: the policy that played is stepped
    ({"policy": MLP(), "loss": "ppo", "epochs": 2}, False),
    ({}, False),  # the fast path records its own
])
def test_the_gradient_replays_where_one_update_steps_the_policy_that_played(changes, replays):
    config = TrainConfig(iterations=2, episodes=4, max_steps=20, **changes)
    assert (iteration.replay_plan(config, (4,)) is not None) == replays


def test_training_with_the_rollouts_records_equals_training_without():
    config = TrainConfig(policy=MLP(), iterations=1, episodes=4, max_steps=30)
    hyper = jax.tree.map(lambda leaf: jnp.full(3, leaf), config.hyperparams.per_run())
    state = iteration.init_runs(config, jax.random.split(jax.random.PRNGKey(3), 3), hyper)
    episodes, _, keys = iteration._play(config, state, hyper, None)
    assert episodes.policy_features is not None
    learned = jax.jit(lambda e: iteration._learn(config, state, e, hyper, keys))
    chex.assert_trees_all_close(learned(episodes),
                                learned(episodes._replace(policy_features=None)),
                                rtol=1e-5, atol=1e-6)
    again = dataclasses.replace(config, policy=MLP())
    assert iteration.replay_plan(again, (4,)) is iteration.replay_plan(config, (4,))
