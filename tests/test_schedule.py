"""Host scheduling: blocks of runs on threads train every run as it trains alone."""


import threading
import time

import jax
import numpy as np
import pytest
from conftest import assert_trained_alike

from jaxpg import (
    TrainConfig,
    programs,
    reinforce,
    schedule,
)


def test_a_run_trains_the_same_beside_a_thousand_others():
    """Sums and layouts are batch-invariant up to large R, not only at the 64 seeds of a sweep."""
    config = TrainConfig(iterations=3, episodes=3, max_steps=30)
    program = programs.compiled_program(config)

    def train_runs(seeds):
        hyperparams = config.hyperparams.per_run(len(seeds))
        (result,) = schedule.train_blocks(program, config.iterations,
                                          [(reinforce.run_keys(seeds), hyperparams)])
        return result

    many = train_runs(np.arange(1030))
    for seed in (0, 7, 1029):
        alone = train_runs([seed])
        assert_trained_alike(jax.tree.map(lambda leaf: leaf[seed], many),
                             jax.tree.map(lambda leaf: leaf[0], alone))


def test_blocks_on_several_threads_report_every_iteration_in_order():
    config = TrainConfig(iterations=4, episodes=2, max_steps=10)
    num_runs = 3 * schedule.CPU_BLOCK + 5  # four blocks over the threads
    hyperparams = config.hyperparams.per_run(num_runs)
    reported = []
    (result,) = schedule.train_blocks(programs.compiled_program(config), config.iterations,
                                      [(reinforce.run_keys(np.arange(num_runs)), hyperparams)],
                                      lambda i, means: reported.append((i, means)))
    assert [i for i, _ in reported] == [0, 1, 2, 3]
    for i, means in reported:
        np.testing.assert_array_equal(means.mean_return, result.metrics.mean_return[:, i])


@pytest.mark.parametrize("num_runs", [1, 2, 3, 5, 8, 15, 16, 17, 63, 64, 65, 129, 1030])
@pytest.mark.parametrize("cores", [1, 2, 3, 16, 256])
def test_cpu_blocks_cover_the_runs_padded_to_one_size(num_runs, cores, monkeypatch):
    monkeypatch.setattr(schedule, "usable_cores", lambda: cores)
    blocks, size = schedule.cpu_blocks(num_runs)
    assert blocks[0][0] == 0 and blocks[-1][1] == num_runs
    assert all(stop == start for (_, stop), (start, _) in zip(blocks, blocks[1:]))
    sizes = [stop - start for start, stop in blocks]
    assert max(sizes) - min(sizes) <= 1 and min(sizes) > 0 and max(sizes) <= size
    if num_runs <= schedule.ALONE_PER_CORE * cores:
        assert size == 1 and len(blocks) == num_runs
    else:
        assert size in (4, 8, 16) and size < 2 * max(sizes) and size <= schedule.CPU_BLOCK
        assert len(blocks) % cores == 0  # every core trains
    # What the memory estimate counts: the first block of each core, padded.
    assert schedule.runs_at_once(num_runs) == min(len(blocks), cores) * size
    assert schedule.cpu_block_count(num_runs) == (len(blocks), size)


@pytest.mark.parametrize("cores", [1, 2])  # one block of 5 runs padded to 8; blocks of 2 and 3 to 4
def test_blocks_padded_with_copies_train_their_runs_as_alone(cores, monkeypatch):
    monkeypatch.setattr(schedule, "usable_cores", lambda: cores)
    config = TrainConfig(iterations=3, episodes=3, max_steps=30)
    blocks, size = schedule.cpu_blocks(5)
    assert size > max(stop - start for start, stop in blocks)  # copies in every block
    hyperparams = config.hyperparams.per_run(5)._replace(
        learning_rate=np.linspace(0.005, 0.02, 5, dtype=np.float32))
    part = (reinforce.run_keys(np.arange(5)), hyperparams)
    program = programs.compiled_program(config)
    (together,) = schedule.train_blocks(program, config.iterations, [part])
    for run in range(5):
        (alone,) = schedule.train_blocks(program, config.iterations,
                                         [jax.tree.map(lambda leaf: leaf[run:run + 1], part)])
        assert_trained_alike(jax.tree.map(lambda leaf: leaf[run], together),
                             jax.tree.map(lambda leaf: leaf[0], alone))


def test_a_failing_run_raises_instead_of_hanging():
    config = TrainConfig(iterations=3, episodes=2, max_steps=10)
    program = programs.compiled_program(config)

    class Failing:  # an iteration that fails when it is called, as on a lost device
        def prepare(self, *args):
            return None

        def __call__(self, train_state, hyperparams, count):
            raise RuntimeError("device lost")

    hyperparams = config.hyperparams.per_run(300)
    with pytest.raises(RuntimeError, match="device lost"):
        schedule.train_blocks(program._replace(iterate=Failing()), config.iterations,
                              [(reinforce.run_keys(np.arange(300)), hyperparams)], lambda *_: None)


@pytest.mark.parametrize("interruption", [KeyboardInterrupt, RuntimeError])
def test_an_interrupted_caller_stops_every_worker_at_its_next_call(interruption):
    """Ctrl-C (KeyboardInterrupt) while the runs train, or the hook's error: `train_blocks` raises
    it once the workers have stopped, each before its next program call, not when training ends."""
    config = TrainConfig(iterations=1000, episodes=2, max_steps=10)
    program = programs.compiled_program(config)
    num_runs = 3 * schedule.CPU_BLOCK  # blocks on every thread
    num_blocks = len(schedule.cpu_blocks(num_runs)[0])
    num_workers = min(num_blocks, schedule.usable_cores())
    calls = []
    interrupted = threading.Event()

    class Held:  # the program's iteration, counting its calls; a worker's second round waits
        def prepare(self, *args):
            return program.iterate.prepare(*args)

        def __call__(self, *args):
            calls.append(threading.get_ident())
            if calls.count(threading.get_ident()) > num_blocks // num_workers:
                assert interrupted.wait(timeout=60)  # until well after the caller was interrupted
            return program.iterate(*args)

    def interrupt(iteration, metrics):
        assert iteration == 0  # every block's first call is done; each worker holds its next
        threading.Timer(0.5, interrupted.set).start()
        raise interruption

    with pytest.raises(interruption):
        schedule.train_blocks(program._replace(iterate=Held()), config.iterations,
                              [(reinforce.run_keys(np.arange(num_runs)),
                                config.hyperparams.per_run(num_runs))], interrupt)
    # Each worker made the one call it held and no other, of 100 calls per block.
    assert len(calls) == num_blocks + num_workers
    time.sleep(0.2)
    assert len(calls) == num_blocks + num_workers  # no worker still calls
