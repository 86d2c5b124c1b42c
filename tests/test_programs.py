"""Compiled programs: one per config, calls of several iterations train as calls of one, and
kept on disk by name, or by their code for a user's own parts."""

import dataclasses

import chex
import flax.linen as nn
import jax
import numpy as np
import optax
import pytest
from conftest import xla_compiles

from jaxpg import (
    TrainConfig,
    executables,
    keep_programs,
    policies,
    programs,
    reinforce,
    schedule,
    train,
)


def test_compiles_once_per_config():
    config = TrainConfig(iterations=2, episodes=2, max_steps=10)
    programs._program.cache_clear()
    with xla_compiles() as compiled:
        first = train(config, seed=0, show_progress=False)
        second = train(config, seed=1, show_progress=False)
        train(dataclasses.replace(config, iterations=3), seed=0, show_progress=False)
    assert programs._program.cache_info().misses == 1
    assert compiled.count("jit(_iterate_stacked)") == 1
    assert not np.array_equal(first.metrics.mean_return, second.metrics.mean_return) or \
        not all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(first.policy_params),
                                                     jax.tree.leaves(second.policy_params)))


@pytest.mark.parametrize("num_runs", [1, 2])
@pytest.mark.parametrize("iterations", [3, programs.ITERATIONS_PER_CALL + 2])
def test_calls_of_several_iterations_train_as_calls_of_one(num_runs, iterations):
    config = TrainConfig(iterations=iterations, episodes=2, max_steps=10)
    program = programs.compiled_program(config)
    keys = reinforce.run_keys(range(num_runs))
    hyperparams = config.hyperparams.per_run(num_runs)
    reported = []
    (result,) = schedule.train_blocks(program, config.iterations, [(keys, hyperparams)],
                                      lambda iteration, _: reported.append(iteration))
    assert reported == list(range(config.iterations))
    assert [count for _, count in schedule.calls(iterations)] == (
        [3] if iterations == 3 else [programs.ITERATIONS_PER_CALL, 2])

    state, rows = program.init(keys, hyperparams), []
    for _ in range(config.iterations):
        state, metrics = program.iterate(state, hyperparams, np.int32(1))
        rows.append(np.asarray(metrics)[0])
    one_at_a_time = program.metrics(np.moveaxis(np.stack(rows), 0, -1))  # [R, I] leaves
    chex.assert_trees_all_equal(result.metrics, one_at_a_time)
    chex.assert_trees_all_equal(
        result.policy_params,
        jax.tree.map(lambda leaf: np.moveaxis(leaf, -1, 0),
                     policies.unflatten(np.asarray(state.params), config.network)))


class _Module(nn.Module):
    width: int = 1

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(1)(nn.tanh(nn.Dense(self.width)(obs)))


def test_programs_of_named_parts_are_kept_by_name_and_of_a_users_code_by_their_code(
        tmp_path, monkeypatch):
    """A user's module, loss or optimizer is kept under the digest of its lowered program: the
    same code, even defined anew (a later process), loads its program; other code compiles."""
    monkeypatch.setattr(executables, "_directory", None)
    keep_programs(tmp_path)
    config = TrainConfig(iterations=2, episodes=2, max_steps=10, optimizer="sgd")
    users = [dataclasses.replace(config, policy=_Module()),
             dataclasses.replace(config, optimizer=lambda lr: optax.sgd(lr))]
    results = [train(c, show_progress=False) for c in (config, *users)]
    kept = set(tmp_path.iterdir())
    assert len(kept) == 6  # init and iterate of each
    programs._program.cache_clear()  # as a new process
    with xla_compiles() as compiled:
        again = [train(c, show_progress=False)
                 for c in (config, dataclasses.replace(config, policy=_Module()),
                           dataclasses.replace(config, optimizer=lambda lr: optax.sgd(lr)))]
    assert not [name for name in compiled if "_iterate_stacked" in name or "init_runs" in name]
    chex.assert_trees_all_equal(again, results)
    with xla_compiles() as compiled:
        train(dataclasses.replace(config, policy=_Module(width=2)), show_progress=False)
    assert compiled.count("jit(_iterate_stacked)") == 1
