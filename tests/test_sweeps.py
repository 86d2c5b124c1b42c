"""Sweeps: seed i of a sweep is `train(seed=i)` exactly; chunks; summary statistics; bad input."""

import dataclasses

import chex
import jax
import numpy as np
import pytest
from conftest import (
    SMALL_CONFIG,
    SMALL_GRID,
    SMALL_SEEDS,
    assert_trained_alike,
    xla_compiles,
)

from jaxpg import TrainConfig, TrainResult, budget, cartpole, programs, schedule, sweeps, train
from jaxpg.sweeps import chunk_size, device_bytes, fitting_chunk_size, summarize, sweep


@pytest.fixture(scope="module")
def book_sweep():
    return sweep(TrainConfig(), seeds=range(64), show_progress=False)


def test_sixty_four_seeds_learn(book_sweep):
    assert book_sweep.metrics.mean_return.shape == (1, 64, 150)
    assert np.median(book_sweep.summary.final_return) >= 175


@pytest.mark.parametrize("seed", [0, 37, 63])
def test_seed_in_sweep_equals_seed_alone(book_sweep, seed):
    alone = train(TrainConfig(), seed=seed, show_progress=False)
    assert_trained_alike(jax.tree.map(lambda a: a[0, seed], (book_sweep.metrics,
                                                             book_sweep.policy_params)),
                         (alone.metrics, alone.policy_params))


def test_grid_runs_every_setting_and_matches_train():
    config = TrainConfig(iterations=20)
    grid = {"learning_rate": [0.003, 0.01], "discount": [0.9, 0.99]}
    swept = sweep(config, seeds=[5, 6], grid=grid, show_progress=False)
    assert [(g["learning_rate"], g["discount"]) for g in swept.grid] == [
        (0.003, 0.9), (0.003, 0.99), (0.01, 0.9), (0.01, 0.99)]
    assert swept.metrics.loss.shape == (4, 2, 20)
    alone = train(TrainConfig(iterations=20, learning_rate=0.01, discount=0.9), seed=6,
                  show_progress=False)
    assert_trained_alike(jax.tree.map(lambda a: a[2, 1], swept.metrics), alone.metrics)


@pytest.mark.parametrize("changes", [{}, {"loss": "baseline", "optimizer": "sgd"}])
def test_a_grid_value_equal_to_the_presets_trains_as_train(changes):
    """Physics is always an input of the program: `length` 0.5 in a grid is CartPole-v1's."""
    config = dataclasses.replace(TrainConfig(iterations=12), **changes)
    swept = sweep(config, seeds=range(3), grid={"length": [0.5, 1.0]}, show_progress=False)
    for seed in range(3):
        alone = train(config, seed=seed, show_progress=False)
        chex.assert_trees_all_equal(
            jax.tree.map(lambda a: a[0, seed], (swept.metrics, swept.policy_params)),
            (alone.metrics, alone.policy_params))


def test_a_sweep_carries_its_config_and_its_critics_which_warm_start():
    config = TrainConfig(iterations=2, episodes=3, max_steps=20, loss="baseline",
                         optimizer="sgd")
    swept = sweep(config, seeds=range(3), show_progress=False)
    assert swept.config == config
    critic = jax.tree.map(lambda a: a[0, 1], swept.critic_params)
    alone = train(config, seed=1, show_progress=False)
    chex.assert_trees_all_equal(alone.critic_params, critic)
    assert train(TrainConfig(iterations=1), show_progress=False).critic_params is None
    # A learning rate too small to move the weights: the critic is the one given, bit for bit.
    still = train(dataclasses.replace(config, iterations=1, learning_rate=1e-30), seed=7,
                  init_critic_params=critic, show_progress=False)
    chex.assert_trees_all_equal(still.critic_params, critic)
    with pytest.raises(ValueError, match="init_critic_params: the loss 'reinforce' has no critic"):
        train(TrainConfig(), init_critic_params=critic, show_progress=False)
    with pytest.raises(ValueError, match="init_critic_params: expected the critic's parameters"):
        train(config, init_critic_params={"params": {}}, show_progress=False)


def test_chunked_sweep_equals_one_chunk_and_compiles_once(small_sweep, capsys):
    programs._program.cache_clear()  # nothing compiled yet
    with xla_compiles() as compiled:
        program = programs.compiled_program(SMALL_CONFIG)
        budget = 3 * device_bytes(program, SMALL_CONFIG.iterations, 1)
        chunked = sweep(SMALL_CONFIG, SMALL_SEEDS, SMALL_GRID, memory_budget=budget)
    # One run's program, which measures what a run needs, and the program of a chunk's blocks
    # (the same one where three runs train alone), each compiled once for all four chunks.
    _, block = schedule.cpu_blocks(3)
    assert compiled.count("jit(_iterate_stacked)") == len({1, block})
    assert_trained_alike(chunked, small_sweep)
    # Ten runs, three at a time: the last chunk is run 10 and two copies of it.
    last_lines = [line for line in capsys.readouterr().err.splitlines() if "Iteration: 3/3" in line]
    assert [line.split(":")[0] for line in last_lines] == [
        "runs 1-3 of 10", "runs 4-6 of 10", "runs 7-9 of 10", "runs 10-10 of 10"]
    assert all("(mean of 3 runs)" in line for line in last_lines)


def test_budget_below_one_run_is_one_line_error():
    needed = device_bytes(programs.compiled_program(SMALL_CONFIG), SMALL_CONFIG.iterations, 1)
    message = rf"^memory_budget: .* allowed: None or at least {needed}$"
    with pytest.raises(ValueError, match=message):
        sweep(SMALL_CONFIG, seeds=[0], memory_budget=needed - 1)


def test_chunk_shrinks_until_its_program_fits(monkeypatch):
    # Bytes that grow faster than the runs: n runs need 100 n (1 + n / 10).
    monkeypatch.setattr(sweeps, "device_bytes",
                        lambda program, iterations, n: 100 * n * (1 + n / 10))
    # One run needs 110, so the first guess is 9 runs, balanced to 7 (20 runs in 3 chunks), which
    # need 1190; 7 * 1000 // 1190 = 5 per chunk need 750.
    assert fitting_chunk_size(None, 3, num_runs=20, memory_budget=1000) == 5


@pytest.mark.parametrize("num_runs, num_devices, max_per_device, size", [
    (10, 1, None, 10),   # one chunk
    (5, 2, None, 6),     # padded to a multiple of the devices
    (1024, 1, 1000, 512),  # two chunks, halves rather than 1000 + 24
    (10, 1, 3, 3),       # four chunks: ceil(10 / 4) = 3
    (10, 2, 2, 4),       # five runs per device, at most two: chunks of 2, 2 and 1 (+1 padding)
    (3, 4, 1, 4),        # fewer runs than devices
])
def test_chunk_size(num_runs, num_devices, max_per_device, size):
    assert chunk_size(num_runs, num_devices, max_per_device) == size


def test_summary_statistics():
    # Two seeds, 12 iterations: seed 0 reaches 200 from iteration 2 on, seed 1 stays at 10.
    mean_return = np.array([[[0, 0] + [200] * 10, [10] * 12]], dtype=float)
    s = summarize(mean_return, solved_return=195)
    np.testing.assert_array_equal(s.median[0], np.median(mean_return[0], axis=0))
    np.testing.assert_array_equal(s.final_return, [[200, 10]])
    np.testing.assert_array_equal(s.fraction_solved, [0.5])
    # The trailing 10-iteration mean first reaches 195 at iteration 11 (iterations 2..11 all 200).
    np.testing.assert_array_equal(s.first_solved, [[11, -1]])
    np.testing.assert_array_equal(s.solved_by[0, 10:], [0, 0.5])


@pytest.mark.parametrize("kwargs, match", [
    (dict(seeds=[]), "seeds"),
    (dict(seeds=[1, 1]), "seeds"),
    (dict(seeds=[-1]), "seeds"),
    (dict(seeds=5), "seeds: must be a non-empty sequence"),
    (dict(seeds=range(2**33)), "seeds: must be a non-empty sequence"),  # checked by its bounds
    (dict(seeds=range(2**32)), "seeds: training 4294967296 seeds"),  # before making its array
    (dict(grid={"learning_rate": ["0.01"]}), "learning_rate: must be a number"),
    (dict(grid={"lr": [0.1]}), "grid"),
    (dict(grid={"discount": [0.0]}), "discount"),
    (dict(grid={"learning_rate": [-1.0]}), "learning_rate"),
    (dict(memory_budget=0), "memory_budget"),
    (dict(memory_budget=2.5e9), "memory_budget"),
    (dict(memory_budget="2G"), "memory_budget"),
    (dict(memory_budget=2**80), "memory_budget: .* is more than this machine has"),
])
def test_bad_sweeps_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sweep(TrainConfig(iterations=1), **kwargs)


# --- Grids over any field, physics included -----------------------------------------------------

PHYSICS_CONFIG = TrainConfig(iterations=3, episodes=3, max_steps=30)


def test_a_physics_grid_compiles_once_and_a_run_trains_as_train_with_that_physics():
    grid = {"length": [0.5, 1.0], "masspole": [0.1, 0.3]}
    swept = sweep(PHYSICS_CONFIG, seeds=range(3), grid=grid, show_progress=False)
    assert [(s["length"], s["masspole"]) for s in swept.grid] == [
        (0.5, 0.1), (0.5, 0.3), (1.0, 0.1), (1.0, 0.3)]
    with xla_compiles() as compiled:  # new values: the same program
        sweep(PHYSICS_CONFIG, seeds=range(3), grid={"length": [0.7, 2.0], "masspole": [0.2, 0.4]},
              show_progress=False)
    assert not compiled
    alone = train(dataclasses.replace(PHYSICS_CONFIG, env=cartpole.make_params(
        "CartPole-v1", length=1.0, masspole=0.3)), seed=2, show_progress=False)
    assert_trained_alike(alone, jax.tree.map(lambda leaf: leaf[3, 2], TrainResult(
        swept.policy_params, swept.metrics)))


def test_a_grid_of_the_default_physics_is_the_sweep_without_one():
    plain = sweep(PHYSICS_CONFIG, seeds=range(3), show_progress=False)
    default = sweep(PHYSICS_CONFIG, seeds=range(3), grid={"length": [0.5], "gravity": [9.8]},
                    show_progress=False)
    chex.assert_trees_all_equal((plain.policy_params, plain.metrics),
                                (default.policy_params, default.metrics))


def test_a_list_of_settings_trains_each():
    grid = [{"length": 0.5}, {"length": 1.0, "learning_rate": 0.02}]
    swept = sweep(PHYSICS_CONFIG, seeds=range(2), grid=grid, show_progress=False)
    assert [(s["length"], s["learning_rate"]) for s in swept.grid] == [(0.5, 0.01), (1.0, 0.02)]
    assert swept.summary.final_return.shape == (2, 2)
    alone = train(dataclasses.replace(PHYSICS_CONFIG, learning_rate=0.02, env=cartpole.make_params(
        "CartPole-v1", length=1.0)), seed=1, show_progress=False)
    assert_trained_alike(alone, jax.tree.map(lambda leaf: leaf[1, 1], TrainResult(
        swept.policy_params, swept.metrics)))


@pytest.mark.parametrize("grid, match", [
    ({"frob": [1.0]}, "grid: unknown field"),
    ({"length": [0.0]}, "length: must be positive"),
    ({"masscart": [-1.0]}, "masscart: must be positive"),
    ({"tau": [float("nan")]}, "tau: must be finite"),
    ({"gravity": [float("inf")]}, "gravity: must be finite"),
    ({"length": []}, "length: the grid needs at least one value"),
    ({"length": [1.0, 1.0]}, "length: the grid repeats a value"),
    # Not numbers, each as given: numpy would make them 1.0 and 2.0 in a list of floats.
    ({"learning_rate": [0.01, True]}, "learning_rate: must be a number, got True"),
    ({"length": [np.bool_(True), 0.5]}, "length: must be a number, got np.True_"),
    ({"length": [0.5, "2"]}, "length: must be a number, got '2'"),
    ([{"length": 1.0}, {"length": 1.0}], "grid: the list repeats a setting"),
    # Apart in float64, one number in the float32 training computes in.
    ({"learning_rate": [0.01, 0.010000000000000002]}, "learning_rate: the grid repeats a value"),
    ([{"length": 1.0}, {"length": 1.0 + 1e-12}], "grid: the list repeats a setting"),
    # A billion settings: refused before any is made.
    ({"learning_rate": list(np.linspace(0.001, 0.1, 1000)),
      "discount": list(np.linspace(0.5, 0.999, 1000)),
      "entropy_coef": list(np.linspace(0.0, 0.1, 1000))}, "grid: 1000000000 settings"),
    ([], "grid: expected"),
])
def test_bad_grids_are_named_before_compiling(grid, match):
    programs._program.cache_clear()  # as a new process: a program compiled before would hide it
    with xla_compiles() as compiled, pytest.raises(ValueError, match=match):
        sweep(PHYSICS_CONFIG, seeds=range(2), grid=grid, show_progress=False)
    assert not compiled


def test_domain_randomisation_trains_and_bad_ranges_are_named():
    config = dataclasses.replace(PHYSICS_CONFIG, randomize={"length": (0.25, 2.0)})
    swept = sweep(config, seeds=range(3), show_progress=False)
    alone = train(config, seed=1, show_progress=False)
    assert_trained_alike(alone, jax.tree.map(lambda leaf: leaf[0, 1], TrainResult(
        swept.policy_params, swept.metrics)))
    plain = train(PHYSICS_CONFIG, seed=1, show_progress=False)
    assert not np.array_equal(plain.metrics.mean_return, alone.metrics.mean_return)
    for ranges, match in [({"length": (2.0, 1.0)}, "length: the range's low is above"),
                          ({"mass": (1.0, 2.0)}, "randomize: unknown field"),
                          ({"masspole": (0.0, 1.0)}, "masspole: must be positive")]:
        with pytest.raises(ValueError, match=match):
            TrainConfig(randomize=ranges)


@pytest.mark.parametrize("grid", [{"length": [0.5, 1.0]}, [{"masspole": 0.2}, {"length": 1.0}]])
def test_a_grid_of_a_randomised_field_is_refused_before_compiling(grid):
    """Training draws the field per episode: every setting trained alike, the grid ignored."""
    config = dataclasses.replace(PHYSICS_CONFIG, randomize={"length": (0.25, 2.0)})
    with xla_compiles() as compiled, pytest.raises(
            ValueError, match="^grid: varies length, which the config's randomize draws per "
                              "episode in place of the grid's values; vary one or the other, or "
                              "evaluate each setting's values with eval_physics='base'$"):
        sweep(config, seeds=range(2), grid=grid, show_progress=False)
    assert not compiled


def test_a_grid_of_a_randomised_field_evaluates_each_value_at_the_base_physics():
    config = dataclasses.replace(PHYSICS_CONFIG, iterations=1, max_steps=200,
                                 randomize={"length": (0.25, 2.0)})
    swept = sweep(config, seeds=range(1), grid={"length": [0.3, 1.5]}, eval_episodes=3,
                  eval_physics="base", show_progress=False)
    params = swept.policy_params["params"]["Dense_0"]["kernel"]
    np.testing.assert_array_equal(params[0], params[1])  # trained alike: the draws, not the grid
    assert not np.array_equal(swept.eval_greedy_returns[0], swept.eval_greedy_returns[1])


def test_held_out_episodes_are_each_runs_own_alike_alone_and_in_a_sweep():
    config = dataclasses.replace(PHYSICS_CONFIG, iterations=5)
    many = sweep(config, seeds=range(6), grid={"learning_rate": [0.01, 0.03]}, eval_episodes=7,
                 show_progress=False)
    assert many.eval_returns.shape == many.eval_greedy_returns.shape == (2, 6, 7)
    few = sweep(config, seeds=range(2), eval_episodes=7, show_progress=False)  # runs alone
    np.testing.assert_array_equal(few.eval_returns[0], many.eval_returns[0, :2])
    np.testing.assert_array_equal(few.eval_greedy_returns[0], many.eval_greedy_returns[0, :2])
    assert not np.array_equal(many.eval_returns[0, 0], many.eval_returns[0, 1])  # own episodes
    assert sweep(config, seeds=range(2), show_progress=False).eval_returns is None
    with pytest.raises(ValueError, match="eval_episodes: must be an integer"):
        sweep(config, seeds=range(2), eval_episodes=-1, show_progress=False)


def test_held_out_episodes_draw_the_training_ranges_unless_asked_for_the_base_physics():
    config = dataclasses.replace(PHYSICS_CONFIG, iterations=5,
                                 randomize={"length": (0.1, 3.0), "force_mag": (2.0, 30.0)})
    drawn = sweep(config, seeds=range(6), eval_episodes=20, show_progress=False)
    base = sweep(config, seeds=range(6), eval_episodes=20, eval_physics="base",
                 show_progress=False)
    np.testing.assert_array_equal(drawn.policy_params["params"]["Dense_0"]["kernel"],
                                  base.policy_params["params"]["Dense_0"]["kernel"])
    assert not np.array_equal(drawn.eval_returns, base.eval_returns)
    unrandomised = dataclasses.replace(config, randomize={})
    plain = sweep(unrandomised, seeds=range(2), eval_episodes=20, show_progress=False)
    np.testing.assert_array_equal(
        plain.eval_returns, sweep(unrandomised, seeds=range(2), eval_episodes=20,
                                  eval_physics="base", show_progress=False).eval_returns)
    alone = sweep(config, seeds=range(2), eval_episodes=20, show_progress=False)  # runs alone
    np.testing.assert_array_equal(alone.eval_returns[0], drawn.eval_returns[0, :2])
    with pytest.raises(ValueError, match="eval_physics"):
        sweep(config, seeds=range(2), eval_episodes=2, eval_physics="default",
              show_progress=False)


def test_seeds_and_held_out_episodes_beyond_memory_are_refused_in_one_line_naming_them(
        monkeypatch):
    monkeypatch.setattr(budget, "machine_memory", lambda: 2**30)  # 1 GiB, of which 80% usable
    monkeypatch.setattr(schedule, "usable_cores", lambda: 2)
    config = TrainConfig(iterations=10, episodes=2, max_steps=20)
    seeds, settings = sweeps.check_arguments(config, range(4), eval_episodes=100)  # fits
    assert seeds.tolist() == [0, 1, 2, 3] and len(settings) == 1
    with pytest.raises(ValueError, match=r"^seeds: training 10000000 seeds x 1 settings for 10 "
                                         r"iterations .* needs about [\d.]+ GiB; this machine "
                                         r"has 1 GiB, of which jaxpg may use 80%$"):
        sweeps.check_arguments(config, range(10**7))
    # 4 runs train alone, one per core: 2 runs at once x 1048575 episodes x 20 steps x 10 floats
    # x 4 bytes = 1677720000, and the returns kept, 4 x 1048575 x 8 = 33554400: 1711274400 bytes
    # = 1.594 GiB.
    with pytest.raises(ValueError, match=r"^eval_episodes: playing 1048575 held-out episodes of "
                                         r"at most 20 steps for each of 4 runs, 2 at once needs "
                                         r"about 1\.594 GiB; this machine has 1 GiB"):
        sweeps.check_arguments(config, range(4), eval_episodes=2**20 - 1)
    with pytest.raises(ValueError, match=r"^memory: training 1 run "):  # one run is too much
        sweeps.check_arguments(dataclasses.replace(config, episodes=10**6), range(4))
