"""The Python API refuses values that would answer wrongly without a word, in one line naming the
argument, before anything compiles."""

import gymnasium
import jax
import numpy as np
import optax
import pytest
from conftest import xla_compiles

from jaxpg import (
    TrainConfig,
    checkpoint,
    envs,
    evaluate,
    evaluation,
    policies,
    programs,
    report,
    results,
    stats,
    sweep,
    train,
)


@pytest.mark.parametrize("value, match", [
    (np.nan, "must be finite"),  # a NaN state never falls: every episode would last 200 steps
    (1e39, r"must be at most 3\.403e\+38 in magnitude"),  # infinite in float32
])
def test_initial_states_that_the_episodes_cannot_start_from_are_refused(value, match):
    states = [[0.0, 0.0, 0.01, 0.0], [0.0, 0.0, 0.0, value]]
    with xla_compiles() as compiled, pytest.raises(ValueError, match=f"^init_states: {match}"):
        evaluate(policies.basic_policy, episodes=2, init_states=states)
    assert not compiled


@pytest.mark.parametrize("trainer", [train, lambda config, **kw: sweep(config, [0, 1], **kw)])
def test_an_on_iteration_that_is_no_function_is_refused(trainer):
    programs._program.cache_clear()  # as a new process: a program compiled before would hide it
    with xla_compiles() as compiled, pytest.raises(
            ValueError, match="^on_iteration: must be a function .* or None, got int$"):
        trainer(TrainConfig(iterations=1), on_iteration=5)
    assert not compiled


@pytest.mark.parametrize("env, field, value, match", [
    ("Acrobot-v1", "link_mass_1", 1e39, r"must be at most 3\.403e\+38 in magnitude"),  # inf in f32
    ("MountainCar-v0", "force", 1e39, r"must be at most 3\.403e\+38 in magnitude"),
    ("Pendulum-v1", "dt", 1e-300, r"must be at least 1\.175e-38"),  # 0 in float32: a frozen pole
    ("MountainCarContinuous-v0", "power", 1e-300, r"must be at least 1\.175e-38"),
])
def test_physics_that_float32_cannot_hold_are_refused_on_every_task(env, field, value, match):
    with xla_compiles() as compiled, pytest.raises(ValueError, match=f"^{field}: {match}"):
        TrainConfig(env=envs.MODULES[env].make_params(env, **{field: value}))
    assert not compiled


_BOOK_PARAMS = policies.init_network(jax.random.PRNGKey(0), TrainConfig().network, 4)


@pytest.mark.parametrize("call, match", [
    (lambda: report.compare(["unread"], confidence="0.9"), "^confidence: must be a number"),
    (lambda: report.compare("unread"), "^sweeps: expected a list of sweep folders"),
    (lambda: results.save_sweep(None, "unwritten"), "^result: expected what jaxpg.sweep returns"),
    (lambda: evaluation.robustness(policies.basic_policy, network="mlp"),
     "^network: expected the policy's flax module"),
    # Before any episode is played, not a TypeError once the first chunk has.
    (lambda: evaluation.evaluate(policies.basic_policy, episodes=2, on_chunk=3),
     "^on_chunk: must be a function .* or None, got int$"),
    (lambda: evaluation.robustness(policies.basic_policy, episodes=2, on_chunk=3),
     "^on_chunk: must be a function"),
    # The basic policy reads CartPole's pole angle: in another task's observation, another number.
    (lambda: evaluate(policies.basic_policy, episodes=3, env="Acrobot-v1"),
     "^policy: basic_policy plays CartPole .*, got Acrobot-v1$"),
    (lambda: evaluation.robustness(policies.basic_policy, episodes=2, env="Pendulum-v1"),
     "^policies: basic_policy plays CartPole"),
    (lambda: TrainConfig(optimizer=optax.adam(0.1)),
     "^optimizer: expected a name or a function learning_rate -> optimizer"),
    (lambda: checkpoint.select_run(None, 0, 0),
     "^loaded: expected a Checkpoint \\(checkpoint.load's\\), got NoneType$"),
    (lambda: train(TrainConfig(iterations=2), show_progress="no"),  # not a truthy string
     "^show_progress: must be True or False, got 'no'$"),
    (lambda: checkpoint.save("", _BOOK_PARAMS, TrainConfig()),  # not ./policy.msgpack
     "^path: expected a file or a directory, got an empty path$"),
    (lambda: checkpoint.save("p.msgpack", {}, TrainConfig()),
     r"^policy_params: parameters do not fit the policy PolicyNetwork; expected shapes \{"),
    (lambda: gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=2, max_episode_steps=0),
     "^max_episode_steps: must be a positive integer, got 0$"),
    (lambda: gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=2**40),  # 8 TiB of its spaces
     "^num_envs: 1099511627776 environments need more memory than this machine has$"),
    # An argument with nothing to act on: no held-out episodes to play in the base physics.
    (lambda: sweep(TrainConfig(iterations=1), [0], eval_physics="base"),
     "^eval_physics: 'base' chooses the physics of held-out episodes; give eval_episodes too$"),
    (lambda: TrainConfig(optimizer=["adam"]), r"^optimizer: unknown \['adam'\]; allowed: "),
    (lambda: sweep(TrainConfig(iterations=1), [0], grid={5: [0.1]}),
     r"^grid: unknown field\(s\) 5 of CartPole-v1; allowed: "),
    # A dict's keys are no seeds, and a set's order is not the caller's.
    (lambda: sweep(TrainConfig(iterations=1), {0: 1}), "^seeds: must be .*, got a dict$"),
    (lambda: sweep(TrainConfig(iterations=1), {0, 1}), "^seeds: must be .*, got a set$"),
    # An empty path is not the working directory.
    (lambda: report.compare([""]),
     "^sweeps\\[0\\]: must be a sweep folder or a SweepResult, got an empty path$"),
    (lambda: checkpoint.load(""), "^path: expected a file or a directory, got an empty path$"),
    (lambda: checkpoint.load(None), "^path: expected a file or a directory, got NoneType$"),
    (lambda: stats.bootstrap_ci(np.ones(4), confidence="0.9"),  # not a TypeError of `<`
     "^confidence: must be a number, got '0.9'$"),
])
def test_arguments_of_the_wrong_kind_are_named_in_one_line(call, match, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=match):
        call()
    assert not list(tmp_path.iterdir())  # nothing read or written


def _step_vec(actions):
    env = gymnasium.make_vec("jaxpg/CartPole-v1", num_envs=len(actions))
    env.reset(seed=0)
    env.step(actions)


@pytest.mark.parametrize("call, start", [
    (lambda: sweep(TrainConfig(iterations=1), np.arange(8).reshape(4, 2)), "seeds: "),
    (lambda: TrainConfig(randomize={"length": np.ones((2, 2))}), "length: "),
    (lambda: TrainConfig(iterations=np.ones((3, 3), int)), "iterations: "),
    (lambda: evaluate(policies.basic_policy, 3, 20, init_states=np.zeros((3, 4), bool)),
     "init_states: "),
    (lambda: _step_vec(np.full(100, 2)), "actions: "),
])
def test_a_value_whose_repr_spans_lines_is_shown_on_one(call, start):
    with pytest.raises(ValueError) as error:
        call()
    message = str(error.value)
    assert message.startswith(start) and "\n" not in message and len(message) < 400, message
