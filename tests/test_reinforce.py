"""REINFORCE: the book's gradient computed literally, training quality, and bad settings."""

import dataclasses
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from conftest import assert_trained_alike, xla_compiles

from jaxpg import TrainConfig, evaluate, policies, reinforce, returns, rollout, train


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


def _assert_accumulated_equals_autodiff(policy_params, network, transitions, advantages):
    expected = jax.value_and_grad(reinforce.reinforce_loss)(
        policy_params, network, transitions, advantages)
    chex.assert_trees_all_close(
        reinforce.loss_and_grad(policy_params, network, transitions, advantages), expected,
        rtol=1e-5, atol=1e-7)


def test_gradient_equals_the_books_algorithm():
    network, policy_params, transitions = _played(TrainConfig(episodes=4, max_steps=40), 3, 4)
    assert int(transitions.alive.sum()) > 40  # several steps of several episodes
    advantages = returns.discount_and_normalize_masked(transitions.reward, transitions.alive, 0.95)
    book = _book_gradient(network, policy_params, transitions)
    ours = jax.grad(reinforce.reinforce_loss)(policy_params, network, transitions, advantages)
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
    are those of `reinforce_loss`, and bit for bit those it gets alone."""
    network, *played = _runs_side_by_side(TrainConfig(episodes=3, max_steps=25), 3, 5)
    lengths = np.asarray(played[1].alive.sum(axis=0))
    assert lengths.min() < 25 and lengths.max() > 5  # some episodes end, some last
    loss, grads = reinforce.loss_and_grad(played[0], network, *played[1:])
    for r in range(3):
        params, mine, weights = _one_run(r, True, *played)
        alone = reinforce.loss_and_grad(params, network, mine, weights)
        chex.assert_trees_all_equal(alone, jax.tree.map(lambda leaf: leaf[..., r : r + 1],
                                                        (loss, grads)))
        params, mine, weights = _one_run(r, False, *played)
        expected = jax.value_and_grad(reinforce.reinforce_loss)(params, network, mine, weights)
        chex.assert_trees_all_close(jax.tree.map(lambda leaf: leaf[..., 0], alone), expected,
                                    rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("hidden", [(5,), (4, 4, 4)])
def test_compiled_gradient_of_a_run_alone_is_its_gradient_beside_others(hidden):
    """As training compiles it: XLA fuses a run alone's additions otherwise than runs side by side,
    and only a compiled program shows whether they round alike (a run alone adding a step's shares
    as one vector rounded otherwise with three hidden layers)."""
    network, *played = _runs_side_by_side(TrainConfig(episodes=10, max_steps=30, hidden=hidden),
                                          4, 9)
    compiled = jax.jit(lambda params, *rest: reinforce.loss_and_grad(params, network, *rest))
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


@pytest.fixture(scope="module")
def book_run():
    return train(TrainConfig(), seed=42, show_progress=False)


def test_book_settings_learn_to_balance(book_run):
    mean_return = np.asarray(book_run.metrics.mean_return)
    assert mean_return.shape == (150,)
    # The book printed 199.6 at its last iteration; the bar is the last-10 mean >= 180.
    assert mean_return[-10:].mean() >= 180
    assert mean_return[:10].mean() < 100  # it learned: it did not start there


def test_trained_policy_transfers_to_gymnasium(book_run):
    config = TrainConfig()
    policy = policies.network_policy(config.network, book_run.policy_params)
    result = evaluate(policy, episodes=100, max_steps=200, backend="gymnasium", seed=0)
    assert result.mean >= 180


def test_a_rerun_is_bit_identical(book_run):
    again = train(TrainConfig(), seed=42, show_progress=False)
    chex.assert_trees_all_equal(again, book_run)


def test_compiles_once_per_config():
    config = TrainConfig(iterations=2, episodes=2, max_steps=10)
    reinforce._program.cache_clear()
    with xla_compiles() as compiled:
        first = train(config, seed=0, show_progress=False)
        second = train(config, seed=1, show_progress=False)
        train(dataclasses.replace(config, iterations=3), seed=0, show_progress=False)
    assert reinforce._program.cache_info().misses == 1
    assert compiled.count("jit(_iterate_stacked)") == 1
    assert not np.array_equal(first.metrics.mean_return, second.metrics.mean_return) or \
        not all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(first.policy_params), jax.tree.leaves(second.policy_params)))


def test_progress_reports_every_iteration(capsys):
    import io
    from jaxpg import progress

    config = TrainConfig(iterations=5, episodes=2, max_steps=10)
    stream = io.StringIO()
    hyperparams = jax.tree.map(lambda v: jnp.asarray([v], jnp.float32), config.hyperparams)
    with progress.bar(config.iterations, stream=stream) as on_iteration:
        (result,) = reinforce.run(reinforce.compiled_program(config), config.iterations,
                                  [(reinforce.run_keys([0]), hyperparams)], on_iteration)
    lines = stream.getvalue().splitlines()
    assert [line.split(",")[0] for line in lines] == [f"Iteration: {i}/5" for i in range(1, 6)]
    assert lines[-1].split(",")[1].startswith(f" mean rewards: {result.metrics.mean_return[0, -1]:.1f}")


@pytest.mark.parametrize("num_runs", [1, 2])
@pytest.mark.parametrize("iterations", [3, reinforce.ITERATIONS_PER_CALL + 2])
def test_calls_of_several_iterations_train_as_calls_of_one(num_runs, iterations):
    config = TrainConfig(iterations=iterations, episodes=2, max_steps=10)
    program = reinforce.compiled_program(config)
    keys = reinforce.run_keys(range(num_runs))
    hyperparams = jax.tree.map(lambda v: np.full(num_runs, v, np.float32), config.hyperparams)
    reported = []
    (result,) = reinforce.run(program, config.iterations, [(keys, hyperparams)],
                              lambda iteration, _: reported.append(iteration))
    assert reported == list(range(config.iterations))
    assert [count for _, count in reinforce.calls(iterations)] == (
        [3] if iterations == 3 else [reinforce.ITERATIONS_PER_CALL, 2])

    state, rows = program.init(keys, hyperparams), []
    for _ in range(config.iterations):
        state, metrics = program.iterate(state, hyperparams, np.int32(1))
        rows.append(np.asarray(metrics)[0])
    one_at_a_time = reinforce.Metrics(*np.moveaxis(np.stack(rows), 0, -1))  # [R, I] leaves
    chex.assert_trees_all_equal(result.metrics, one_at_a_time)
    chex.assert_trees_all_equal(
        result.policy_params,
        jax.tree.map(lambda leaf: np.moveaxis(leaf, -1, 0),
                     policies.unflatten(np.asarray(state.policy_params), config.network)))


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


def _optax_steps(config, grads, params):
    """optax's own steps of `config.optimizer` on `params`, whatever their structure."""
    optimizer = reinforce.make_optimizer(config, config.learning_rate)
    state = optimizer.init(params)
    for grad in grads:
        updates, state = optimizer.update(grad, state, params)
        params = optax.apply_updates(params, updates)
    return params


def _optimizer_steps(config, grads, params):
    """The same steps as `reinforce.optimizer_step` takes them, on flat parameters."""
    flat = policies.flatten(params, config.network)
    _, opt_state = reinforce.init_run(config, jax.random.PRNGKey(0), config.hyperparams)
    for grad in grads:
        flat, opt_state = reinforce.optimizer_step(
            config, policies.flatten(grad, config.network), opt_state, flat,
            config.learning_rate)
    return flat


@pytest.mark.parametrize("name", sorted(reinforce.ELEMENTWISE_OPTIMIZERS) + ["lamb", "adafactor"])
def test_optimizers_step_as_optax_defines_them_on_each_array(name):
    """The optimizers stepped on the flat vector update each parameter as they would per array;
    the others (lamb's per-layer trust ratio, adafactor's factored moments) step per array."""
    config = TrainConfig(optimizer=name, hidden=(5, 3))
    params = policies.init_network(jax.random.PRNGKey(1), config.network)
    rng = np.random.default_rng(2)
    grads = [jax.tree.map(lambda leaf: rng.normal(size=leaf.shape).astype(np.float32), params)
             for _ in range(3)]
    expected = policies.flatten(_optax_steps(config, grads, params), config.network)
    np.testing.assert_allclose(_optimizer_steps(config, grads, params), expected,
                               rtol=1e-6, atol=1e-7)
    if name not in reinforce.ELEMENTWISE_OPTIMIZERS:  # on one vector, another update
        one_vector = _optax_steps(config, [policies.flatten(g, config.network) for g in grads],
                                  policies.flatten(params, config.network))
        assert not np.allclose(one_vector, expected, rtol=1e-3, atol=1e-4)


def test_run_keys_are_jax_prng_keys():
    seeds = [0, 1, 12345, 2**31, 2**32 - 1]
    np.testing.assert_array_equal(reinforce.run_keys(seeds),
                                  np.stack([jax.random.PRNGKey(s) for s in seeds]))
    assert reinforce.run_keys(seeds).dtype == np.uint32


def test_a_run_trains_the_same_beside_a_thousand_others():
    """Sums and layouts are batch-invariant up to large R, not only at the 64 seeds of a sweep."""
    config = TrainConfig(iterations=3, episodes=3, max_steps=30)
    program = reinforce.compiled_program(config)

    def train_runs(seeds):
        hyperparams = jax.tree.map(lambda v: np.full(len(seeds), v, np.float32), config.hyperparams)
        (result,) = reinforce.run(program, config.iterations,
                                  [(reinforce.run_keys(seeds), hyperparams)])
        return result

    many = train_runs(np.arange(1030))
    for seed in (0, 7, 1029):
        alone = train_runs([seed])
        assert_trained_alike(jax.tree.map(lambda leaf: leaf[seed], many),
                             jax.tree.map(lambda leaf: leaf[0], alone))


def test_blocks_on_several_threads_report_every_iteration_in_order():
    config = TrainConfig(iterations=4, episodes=2, max_steps=10)
    num_runs = 3 * reinforce.CPU_BLOCK + 5  # four blocks over the threads
    hyperparams = jax.tree.map(lambda v: np.full(num_runs, v, np.float32), config.hyperparams)
    reported = []
    (result,) = reinforce.run(reinforce.compiled_program(config), config.iterations,
                              [(reinforce.run_keys(np.arange(num_runs)), hyperparams)],
                              lambda iteration, means: reported.append((iteration, means)))
    assert [iteration for iteration, _ in reported] == [0, 1, 2, 3]
    for iteration, means in reported:
        np.testing.assert_array_equal(means, result.metrics.mean_return[:, iteration])


@pytest.mark.parametrize("num_runs", [1, 2, 3, 5, 8, 15, 16, 17, 63, 64, 65, 129, 1030])
@pytest.mark.parametrize("cores", [1, 2, 3, 16, 256])
def test_cpu_blocks_cover_the_runs_padded_to_one_size(num_runs, cores, monkeypatch):
    monkeypatch.setattr(reinforce, "usable_cores", lambda: cores)
    blocks, size = reinforce.cpu_blocks(num_runs)
    assert blocks[0][0] == 0 and blocks[-1][1] == num_runs
    assert all(stop == start for (_, stop), (start, _) in zip(blocks, blocks[1:]))
    sizes = [stop - start for start, stop in blocks]
    assert max(sizes) - min(sizes) <= 1 and min(sizes) > 0 and max(sizes) <= size
    if num_runs <= reinforce.ALONE_PER_CORE * cores:
        assert size == 1 and len(blocks) == num_runs
    else:
        assert size in (4, 8, 16) and size < 2 * max(sizes) and size <= reinforce.CPU_BLOCK
        assert len(blocks) % cores == 0  # every core trains


@pytest.mark.parametrize("cores", [1, 2])  # one block of 5 runs padded to 8; blocks of 2 and 3 to 4
def test_blocks_padded_with_copies_train_their_runs_as_alone(cores, monkeypatch):
    monkeypatch.setattr(reinforce, "usable_cores", lambda: cores)
    config = TrainConfig(iterations=3, episodes=3, max_steps=30)
    blocks, size = reinforce.cpu_blocks(5)
    assert size > max(stop - start for start, stop in blocks)  # copies in every block
    hyperparams = reinforce.Hyperparams(np.linspace(0.005, 0.02, 5, dtype=np.float32),
                                        np.full(5, 0.95, np.float32))
    part = (reinforce.run_keys(np.arange(5)), hyperparams)
    program = reinforce.compiled_program(config)
    (together,) = reinforce.run(program, config.iterations, [part])
    for run in range(5):
        (alone,) = reinforce.run(program, config.iterations,
                                 [jax.tree.map(lambda leaf: leaf[run:run + 1], part)])
        assert_trained_alike(jax.tree.map(lambda leaf: leaf[run], together),
                             jax.tree.map(lambda leaf: leaf[0], alone))


def test_a_failing_run_raises_instead_of_hanging():
    config = TrainConfig(iterations=3, episodes=2, max_steps=10)
    program = reinforce.compiled_program(config)

    class Failing:  # an iteration that fails when it is called, as on a lost device
        def prepare(self, *args):
            return None

        def __call__(self, train_state, hyperparams, count):
            raise RuntimeError("device lost")

    hyperparams = jax.tree.map(lambda v: np.full(300, v, np.float32), config.hyperparams)
    with pytest.raises(RuntimeError, match="device lost"):
        reinforce.run(program._replace(iterate=Failing()), config.iterations,
                      [(reinforce.run_keys(np.arange(300)), hyperparams)], lambda *_: None)
