"""The memory estimate: what training needs, from its settings alone, against the machine."""

import dataclasses

import jax
import numpy as np
import pytest
from conftest import xla_compiles

from jaxpg import TrainConfig, budget, cartpole, policies, programs, train
from jaxpg.evaluation import _as_argument, _jaxpg_returns
from jaxpg.sweeps import device_bytes


def test_the_machine_has_memory():
    assert budget.machine_memory() > 2**28


@pytest.mark.parametrize("field, larger", [("iterations", 1500), ("episodes", 100),
                                           ("max_steps", 2000), ("hidden", (50,)),
                                           ("epochs", 64)])
def test_the_estimate_grows_with_every_size(field, larger):
    config = TrainConfig(env=cartpole.CartPoleParams(max_steps=2000))  # (a time limit of 2000)
    bigger = dataclasses.replace(config, **{field: larger})
    assert budget.needed_bytes(bigger) > budget.needed_bytes(config)
    assert budget.needed_bytes(config, 4096) > budget.needed_bytes(config, 64)


def test_the_estimate_of_a_run_is_near_what_xla_lays_out():
    """Within a factor of two of XLA's own account (`sweeps.device_bytes`) of one run."""
    config = TrainConfig(iterations=10, episodes=100, max_steps=200, hidden=(16,))
    measured = device_bytes(programs.compiled_program(config), config.iterations, 1)
    assert measured / 2 < budget.needed_bytes(config) < 2 * measured


@pytest.mark.parametrize("changes, runs, asked", [
    ({"episodes": 10**9}, 1, "training 1 run for 150 iterations of 1000000000 episodes of at "
                             "most 200 steps, hidden (5,) needs about"),
    ({"hidden": (4000,) * 1000}, 1, "hidden (4000, 4000, 4000,"),
    ({"iterations": 10**9}, 1, "for 1000000000 iterations"),
    # Every epoch's shuffled minibatches are laid out at once: about 95 TiB here.
    ({"epochs": 10**9}, 1, "at most 200 steps in 1000000000 epochs, hidden (5,) needs about"),
    ({}, 2**32, "training 4294967296 runs for"),
])
def test_sizes_beyond_the_machine_are_refused_in_one_line(changes, runs, asked):
    with pytest.raises(ValueError) as error:
        budget.check(dataclasses.replace(TrainConfig(), **changes), runs, f"{runs} runs"
                     if runs > 1 else "1 run")
    message = error.value.args[0]
    assert message.startswith("memory: ") and asked in message and "\n" not in message
    assert f"this machine has {budget.format_bytes(budget.machine_memory())}" in message


def test_train_refuses_them_before_anything_compiles():
    with xla_compiles() as compiled, pytest.raises(ValueError, match="^memory: "):
        train(TrainConfig(env=cartpole.CartPoleParams(max_steps=2**31 - 1), max_steps=2**31 - 1),
              show_progress=False)
    assert not compiled


@pytest.mark.parametrize("value, match", [(0, "positive integer"), (1.5, "positive integer"),
                                          (True, "positive integer"),
                                          (10**400, "is more than this machine has")])
def test_bad_memory_budgets_are_refused(value, match):
    with pytest.raises(ValueError, match=f"^memory_budget: .*{match}"):
        budget.check_memory_budget(value)
    budget.check_memory_budget(None)
    budget.check_memory_budget(np.int64(2**30))


@pytest.mark.parametrize("count, text", [(0, "0 bytes"), (1023, "1023 bytes"), (1536, "1.5 KiB"),
                                         (3 * 2**30, "3 GiB"), (10**400, "8.674e+381 EiB")])
def test_sizes_are_written_in_binary_units(count, text):
    assert budget.format_bytes(count) == text


def test_the_evaluation_estimate_is_near_what_xla_lays_out():
    """Within a factor of two of XLA's account of `evaluate`'s program."""
    compiled = _jaxpg_returns.lower(
        jax.random.PRNGKey(0), cartpole.V1, None, _as_argument(policies.basic_policy), 300,
        100).compile()
    memory = compiled.memory_analysis()
    measured = memory.temp_size_in_bytes + memory.output_size_in_bytes
    assert measured / 2 < budget.evaluation_bytes(300, 100) < 2 * measured


def test_a_drawing_counts_its_frames_up_to_the_environments_limit():
    # 200 steps: 201 records of 20 floats and 201 frames; past the limit of 500, 501 frames.
    item = budget._itemsize()
    assert budget.render_bytes(200, 500) == 201 * 20 * item + 201 * budget.FRAME_BYTES
    assert budget.render_bytes(10**4, 500) == 10001 * 20 * item + 501 * budget.FRAME_BYTES


def test_layers_wider_than_the_compiler_builds_are_refused_by_name():
    with pytest.raises(ValueError, match=rf"^hidden: at most {budget.MAX_UNITS} units .* got "
                                         rf"\(5, {budget.MAX_UNITS + 1}\)$"):
        budget.check(TrainConfig(hidden=(5, budget.MAX_UNITS + 1)))
    budget.check(TrainConfig(hidden=(budget.MAX_UNITS,), episodes=1, max_steps=10))
