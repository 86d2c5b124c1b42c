"""The fast path's gradient: the book's algorithm computed literally, runs alone and together."""

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpg import (
    TrainConfig,
    hand_gradient,
    policies,
    returns,
    rollout,
)


def _book_gradient(network, policy_params, transitions):
    """The book's algorithm, literally: per-step gradients of the binary cross-entropy between
    P(left) and the target 1 - action, weighted by the discounted normalised returns of
    `discount_and_normalize_rewards` (the list API), then averaged per variable over every step."""
    obs, actions, rewards, alive = (np.asarray(a) for a in transitions)
    lengths = alive.sum(axis=0)
    all_rewards = [rewards[:n, e].tolist() for e, n in enumerate(lengths)]
    final_rewards = returns.discount_and_normalize_rewards(all_rewards, 0.95)

    def bce(params, o, y):
        p_left = jax.nn.sigmoid(network.apply(params, o))
        return -(y * jnp.log(p_left) + (1 - y) * jnp.log(1 - p_left))

    step_grad = jax.jit(jax.grad(bce))
    weighted = []
    for e, n in enumerate(lengths):
        for t in range(n):
            g = step_grad(policy_params, obs[t, e], 1.0 - actions[t, e])
            weighted.append(jax.tree.map(lambda v: final_rewards[e][t] * v, g))
    return jax.tree.map(lambda *vs: jnp.mean(jnp.stack(vs), axis=0), *weighted)


def _played(config, params_seed, rollout_seed):
    """A network's initial parameters and the episodes it plays: (network, params, transitions)."""
    network = config.network
    policy_params = policies.init_network(jax.random.PRNGKey(params_seed), network)
    transitions = rollout.rollout(
        jax.random.PRNGKey(rollout_seed), policies.network_policy(network, policy_params),
        config.env_params, config.episodes, config.max_steps,
    ).transitions
    return network, policy_params, transitions


def _compiled(function, network):
    """`function(policy_params, network, transitions, advantages)`, compiled for `network`
    (evaluated op by op, a gradient of a few hundred steps takes seconds)."""
    return jax.jit(lambda *args: function(args[0], network, *args[1:]))


def _assert_accumulated_equals_autodiff(policy_params, network, transitions, advantages):
    expected = _compiled(jax.value_and_grad(hand_gradient.reinforce_loss), network)(
        policy_params, transitions, advantages)
    chex.assert_trees_all_close(
        _compiled(hand_gradient.loss_and_grad, network)(policy_params, transitions, advantages),
        expected, rtol=1e-5, atol=1e-7)


def test_gradient_equals_the_books_algorithm():
    network, policy_params, transitions = _played(TrainConfig(episodes=4, max_steps=40), 3, 4)
    assert int(transitions.alive.sum()) > 40  # several steps of several episodes
    advantages = returns.discount_and_normalize_masked(transitions.reward, transitions.alive, 0.95)
    book = _book_gradient(network, policy_params, transitions)
    ours = _compiled(jax.grad(hand_gradient.reinforce_loss), network)(
        policy_params, transitions, advantages)
    chex.assert_trees_all_close(ours, book, rtol=2e-4, atol=1e-6)
    # The loss and gradient that training accumulates step by step are the same.
    _assert_accumulated_equals_autodiff(policy_params, network, transitions, advantages)


def _runs_side_by_side(config, num_runs, seed):
    """(network, policy_params, transitions, advantages) of `num_runs` runs played side by side
    (on the trailing axis)."""
    network = config.network
    keys = jax.random.split(jax.random.PRNGKey(seed), num_runs)
    policy_params = jax.vmap(lambda k: policies.init_network(k, network), out_axes=-1)(keys)
    transitions = rollout.rollout(keys, policies.network_policy(network, policy_params),
                                  config.env_params, config.episodes, config.max_steps).transitions
    advantages = returns.discount_and_normalize_masked(transitions.reward, transitions.alive, 0.95)
    return network, policy_params, transitions, advantages


def _one_run(r, keep_axis, policy_params, transitions, advantages):
    """Run r's parameters, transitions and advantages (observations keep their last axis)."""
    index = slice(r, r + 1) if keep_axis else r
    pick = functools.partial(jax.tree.map, lambda leaf: leaf[..., index])
    mine = pick(transitions._replace(obs=None))._replace(obs=transitions.obs[..., index, :])
    return pick(policy_params), mine, pick(advantages)


def test_accumulated_gradient_of_runs_side_by_side():
    """Three runs on the trailing axis, 25 steps (a padded last chunk): each run's loss and gradient
    are those of `reinforce_loss`, and bit for bit those it gets alone, compiled as training
    compiles them."""
    network, *played = _runs_side_by_side(TrainConfig(episodes=3, max_steps=25), 3, 5)
    lengths = np.asarray(played[1].alive.sum(axis=0))
    assert lengths.min() < 25 and lengths.max() > 5  # some episodes end, some last
    compiled = jax.jit(lambda params, *rest: hand_gradient.loss_and_grad(params, network, *rest))
    loss, grads = compiled(*played)
    for r in range(3):
        alone = compiled(*_one_run(r, True, *played))
        chex.assert_trees_all_equal(alone, jax.tree.map(lambda leaf: leaf[..., r : r + 1],
                                                        (loss, grads)))
        params, mine, weights = _one_run(r, False, *played)
        expected = _compiled(jax.value_and_grad(hand_gradient.reinforce_loss), network)(
            params, mine, weights)
        chex.assert_trees_all_close(jax.tree.map(lambda leaf: leaf[..., 0], alone), expected,
                                    rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("hidden", [(5,), (4, 4, 4)])
def test_compiled_gradient_of_a_run_alone_is_its_gradient_beside_others(hidden):
    """As training compiles it: XLA fuses a run alone's additions otherwise than runs side by side,
    and only a compiled program shows whether they round alike (a run alone adding a step's shares
    as one vector rounded otherwise with three hidden layers)."""
    network, *played = _runs_side_by_side(TrainConfig(episodes=10, max_steps=30, hidden=hidden),
                                          4, 9)
    compiled = jax.jit(lambda params, *rest: hand_gradient.loss_and_grad(params, network, *rest))
    together = compiled(*played)
    for r in range(4):
        chex.assert_trees_all_equal(compiled(*_one_run(r, True, *played)),
                                    jax.tree.map(lambda leaf: leaf[..., r : r + 1], together))


@pytest.mark.parametrize("hidden, activation", [((3, 4), "tanh"), ((7,), "relu")])
def test_accumulated_gradient_of_other_networks(hidden, activation):
    """Deeper and wider networks and other activations, one episode lasting all 45 steps."""
    config = TrainConfig(episodes=12, max_steps=45, hidden=hidden, activation=activation)
    network, policy_params, transitions = _played(config, 8, 7)
    assert int(transitions.alive.sum(axis=0).max()) == 45
    advantages = returns.discount_and_normalize_masked(transitions.reward, transitions.alive, 0.95)
    _assert_accumulated_equals_autodiff(policy_params, network, transitions, advantages)


def test_accumulated_gradient_of_eleven_layers_in_sorted_order():
    """Parameters that went through a tree map list Dense_10 before Dense_2; layers go by number."""
    config = TrainConfig(episodes=4, max_steps=20, hidden=(3,) * 10, activation="tanh")
    network, policy_params, transitions = _played(config, 5, 6)
    policy_params = jax.tree.map(lambda leaf: leaf, policy_params)
    assert list(policy_params["params"])[:3] == ["Dense_0", "Dense_1", "Dense_10"]
    advantages = returns.discount_and_normalize_masked(transitions.reward, transitions.alive, 0.95)
    _assert_accumulated_equals_autodiff(policy_params, network, transitions, advantages)


def test_accumulated_gradient_of_steps_that_are_no_prefix():
    """Alive steps need not start an episode: the loop runs to the last alive step of any."""
    network, policy_params, transitions = _played(TrainConfig(episodes=3, max_steps=12), 3, 4)
    steps = jnp.arange(12)
    alive = jnp.stack([(steps >= 6) & (steps < 10), steps < 3, steps % 2 == 0], axis=1)
    transitions = transitions._replace(alive=alive, reward=alive.astype(jnp.float32))
    advantages = returns.discount_and_normalize_masked(transitions.reward, alive, 0.95)
    _assert_accumulated_equals_autodiff(policy_params, network, transitions, advantages)


@pytest.mark.parametrize("hidden", [(5,), (4, 4, 4)])
def test_hidden_activations_a_rollout_records_give_the_gradient(hidden):
    """`HiddenRecordingPolicy` plays the network's episodes, recording its hidden activations; the
    loss and gradient from them are `reinforce_loss`'s, for runs side by side (bit for bit those
    that compute the activations again) and for a run alone, whose recorded activations are
    padded as its episodes are. (Training records them for runs side by side only: the training
    tests compare a run alone with the same run in a sweep.)"""
    config = TrainConfig(episodes=10, max_steps=30, hidden=hidden)
    network, policy_params, transitions, advantages = _runs_side_by_side(config, 4, 9)
    keys = jax.random.split(jax.random.PRNGKey(9), 4)
    recorded = rollout.rollout(keys, policies.HiddenRecordingPolicy(network, policy_params),
                               config.env_params, config.episodes, config.max_steps)
    chex.assert_trees_all_equal(recorded.transitions, transitions)
    (features,) = recorded.policy_features
    assert features.shape == (sum(hidden), 30, 10, 4)
    computed = policies.forward_layers(policy_params, transitions.obs, "elu")[1][1:]
    chex.assert_trees_all_close(policies.hidden_layers(features, network), computed,
                                rtol=1e-6, atol=1e-7)
    compiled = jax.jit(lambda params, *rest: hand_gradient.loss_and_grad(params, network, *rest))
    from_record = compiled(policy_params, transitions, advantages, features)
    chex.assert_trees_all_equal(from_record,
                                compiled(policy_params, transitions, advantages, None))
    for r in range(4):
        params, mine, weights = _one_run(r, False, policy_params, transitions, advantages)
        expected = _compiled(jax.value_and_grad(hand_gradient.reinforce_loss), network)(
            params, mine, weights)
        chex.assert_trees_all_close(jax.tree.map(lambda leaf: leaf[..., r], from_record),
                                    expected, rtol=1e-5, atol=1e-7)
    # A run alone on a run axis of one, its episodes played in whole vectors and the recorded
    # activations padded with theirs.
    params = jax.tree.map(lambda leaf: leaf[..., 1], policy_params)
    alone = rollout.rollout(keys[1], policies.HiddenRecordingPolicy(network, params),
                            config.env_params, config.episodes, config.max_steps,
                            lanes=rollout.LANES)
    mine = jax.tree.map(lambda leaf: jnp.expand_dims(leaf, 2), alone.transitions)
    weights = returns.discount_and_normalize_masked(mine.reward, mine.alive, 0.95)
    expected = _compiled(jax.value_and_grad(hand_gradient.reinforce_loss), network)(
        params, alone.transitions, weights[:, :, 0])
    chex.assert_trees_all_close(
        jax.tree.map(lambda leaf: leaf[..., 0], compiled(
            jax.tree.map(lambda leaf: leaf[..., None], params), mine, weights,
            alone.policy_features[0][..., None])),
        expected, rtol=1e-5, atol=1e-7)
