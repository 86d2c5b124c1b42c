"""`train`: the book's settings learn, transfer to Gymnasium, rerun bit for bit.

Also warm starts, hooks and progress.
"""


import chex
import jax
import numpy as np
import pytest

from jaxpg import (
    TrainConfig,
    evaluate,
    policies,
    programs,
    reinforce,
    schedule,
    train,
)
from jaxpg.iteration import Metrics


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


def test_progress_reports_every_iteration(capsys):
    import io

    from jaxpg import progress

    config = TrainConfig(iterations=5, episodes=2, max_steps=10)
    stream = io.StringIO()
    hyperparams = config.hyperparams.per_run()
    with progress.bar(config.iterations, stream=stream) as on_iteration:
        (result,) = schedule.train_blocks(programs.compiled_program(config), config.iterations,
                                          [(reinforce.run_keys([0]), hyperparams)], on_iteration)
    lines = stream.getvalue().splitlines()
    assert [line.split(",")[0] for line in lines] == [f"Iteration: {i}/5" for i in range(1, 6)]
    last_mean = result.metrics.mean_return[0, -1]
    assert lines[-1].split(",")[1].startswith(f" mean rewards: {last_mean:.1f}")


def test_run_keys_are_jax_prng_keys():
    seeds = [0, 1, 12345, 2**31, 2**32 - 1]
    np.testing.assert_array_equal(reinforce.run_keys(seeds),
                                  np.stack([jax.random.PRNGKey(s) for s in seeds]))
    assert reinforce.run_keys(seeds).dtype == np.uint32


def test_the_first_iteration_of_a_non_finite_loss_or_gradient_is_found_per_run():
    loss = np.array([[1.0, np.nan, 2.0, 3.0], [1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, np.inf]])
    grad_norm = np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, np.inf, 1.0], [1.0, 1.0, 1.0, 1.0]])
    metrics = Metrics(loss, loss, loss, loss, loss, grad_norm)
    np.testing.assert_array_equal(reinforce.first_nonfinite(metrics), [1, 2, 3])
    finite = metrics._replace(loss=np.ones(4), grad_norm=np.ones(4))
    assert reinforce.first_nonfinite(finite) == -1
