"""Training on every environment of `jaxpg.envs`: alone as in a sweep, grids and randomisation
over the environment's own fields, action distributions, checkpoints and the command line."""

import dataclasses
import math

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from jaxpg import (
    TrainConfig,
    checkpoint,
    cli,
    distributions,
    envs,
    evaluate,
    policies,
    robustness,
    sweep,
    train,
)

# One iteration's worth of a short episode per environment: enough to reach every piece.
_SMALL = {"iterations": 3, "episodes": 4, "max_steps": 40, "hidden": (8,)}


@pytest.mark.parametrize("env, loss", [("Acrobot-v1", "reinforce"), ("MountainCar-v0", "baseline"),
                                       ("Pendulum-v1", "reward-to-go"),
                                       ("MountainCarContinuous-v0", "baseline")])
def test_a_seed_trains_alone_as_in_a_sweep(env, loss):
    """Seed 5 alone and in a sweep of 6, more than train alone on two cores
    (`schedule.ALONE_PER_CORE`): the sweep's seeds train in a block."""
    config = TrainConfig(env=env, loss=loss, entropy_coef=0.01, **_SMALL)
    alone = train(config, seed=5, show_progress=False)
    swept = sweep(config, seeds=range(6), show_progress=False)
    for name, value in alone.metrics.columns().items():
        np.testing.assert_array_equal(value, swept.metrics.columns()[name][0, 5], err_msg=name)
    for got, want in zip(jax.tree.leaves(alone.policy_params),
                         jax.tree.leaves(swept.policy_params)):
        np.testing.assert_array_equal(got, want[0, 5])
    assert np.all(np.isfinite(alone.metrics.grad_norm))


def test_a_continuous_tasks_mean_return_is_the_same_alone_and_in_a_block():
    """Returns that are not whole numbers, averaged in a fixed order: averaged by XLA, a block's
    mean return differed from the run's alone in its last bit."""
    config = TrainConfig(env="MountainCarContinuous-v0", iterations=12, episodes=3, max_steps=40)
    alone = train(config, seed=5, show_progress=False)
    swept = sweep(config, seeds=range(6), show_progress=False)
    np.testing.assert_array_equal(alone.metrics.mean_return, swept.metrics.mean_return[0, 5])


@pytest.mark.parametrize("env", ["Pendulum-v1"])
def test_ppo_of_several_updates_trains_alone_as_in_a_sweep(env):
    """Several updates per batch (a scan over minibatches): the parameters and the critic bit for
    bit, the reported values to a few units in the last place, as on CartPole
    (tests/test_iteration.py)."""
    config = TrainConfig(env=env, loss="ppo", epochs=2, minibatches=2, **_SMALL)
    alone = train(config, seed=1, show_progress=False)
    swept = sweep(config, seeds=[0, 1, 2], show_progress=False)
    for got, want in zip(jax.tree.leaves((alone.policy_params, alone.critic_params)),
                         jax.tree.leaves((swept.policy_params, swept.critic_params))):
        np.testing.assert_array_equal(got, want[0, 1])
    for name, value in alone.metrics.columns().items():
        np.testing.assert_array_max_ulp(value, swept.metrics.columns()[name][0, 1], maxulp=4)
    assert set(swept.metrics.extra) == {"approx_kl", "clip_fraction", "value_loss"}


def test_the_default_network_fits_the_environment_and_its_settings_are_its_own():
    acrobot = TrainConfig(env="Acrobot-v1")
    assert acrobot.network == policies.PolicyNetwork((5,), "elu", outputs=3)
    assert isinstance(TrainConfig(env="Pendulum-v1").network, policies.GaussianNetwork)
    # Gymnasium's time limits and thresholds; the book's 200 steps and 195 on CartPole.
    assert (acrobot.max_steps, acrobot.solved_return) == (500, -100.0)
    assert (TrainConfig().max_steps, TrainConfig().solved_return) == (200, 195.0)
    assert not acrobot.hand_gradient and TrainConfig().hand_gradient


def test_a_grid_and_randomisation_vary_the_environments_own_fields():
    config = TrainConfig(env="Pendulum-v1", randomize={"mass": (0.5, 2.0)}, **_SMALL)
    result = sweep(config, seeds=[0], grid={"max_torque": [1.0, 2.0]}, show_progress=False)
    assert [s["max_torque"] for s in result.grid] == [1.0, 2.0]
    # A weaker motor gets less torque out of the same policy: the settings differ.
    assert not np.array_equal(result.metrics.mean_return[0], result.metrics.mean_return[1])
    # The drawn masses change the episodes: the same sweep without them trains otherwise.
    fixed = sweep(dataclasses.replace(config, randomize=()), seeds=[0],
                  grid={"max_torque": [1.0, 2.0]}, show_progress=False)
    assert not np.array_equal(result.metrics.mean_return, fixed.metrics.mean_return)


@pytest.mark.parametrize("make, message", [
    (lambda: TrainConfig(env="Acrobot-v2"), "env: unknown 'Acrobot-v2'; allowed: CartPole-v1"),
    (lambda: TrainConfig(env=5), "env: expected an environment's name"),
    (lambda: TrainConfig(env="Acrobot-v1", randomize={"masscart": (1, 2)}),
     "randomize: unknown field 'masscart'; allowed: dt"),
    (lambda: sweep(TrainConfig(env="MountainCar-v0"), seeds=[0], grid={"length": [1.0]}),
     "grid: unknown field(s) length of MountainCar-v0"),
    (lambda: TrainConfig(env=envs.acrobot.V1.replace(torque_noise_max=0.1)), "torque_noise_max"),
    (lambda: TrainConfig(env=envs.pendulum.V1.replace(mass=-1.0)), "mass: must be positive"),
    # One environment's physics are numbers: an array would train on its first entry.
    (lambda: TrainConfig(env=envs.pendulum.V1.replace(max_torque=np.array([0.5, 2.0]))),
     "env: every field of PendulumParams must be a number, not an array (max_torque)"),
    (lambda: TrainConfig(env=envs.cartpole.V1.replace(length=np.array([2.0, 1.0]))),
     "env: every field of CartPoleParams must be a number, not an array (length)"),
    (lambda: envs.cartpole.make_params("CartPole-v1", sutton_barto_reward="no"),
     "sutton_barto_reward: must be True or False, got 'no'"),
])
def test_bad_environments_are_refused_in_one_line(make, message):
    with pytest.raises(ValueError, match="^" + message.replace("(", r"\(").replace(")", r"\)")):
        make()


class _MeanOnly(nn.Module):
    """A continuous policy module that forgets the log standard deviation."""

    @nn.compact
    def __call__(self, obs):
        return nn.Dense(1)(obs)


def test_a_policy_of_the_wrong_kind_for_the_environment_is_refused_before_training():
    with pytest.raises(ValueError, match=r"policy: for observations \(.*3\) the module must "
                                         r"return \(mean, log standard deviation\) shaped"):
        train(TrainConfig(env="Pendulum-v1", policy=_MeanOnly(), **_SMALL), seed=0)


def test_categorical_samples_and_log_probabilities_agree():
    logits = jnp.asarray([0.3, -1.2, 0.9])
    dist = distributions.Categorical(jnp.broadcast_to(logits, (30000, 3)))
    u = jax.random.uniform(jax.random.PRNGKey(0), (30000,))
    counts = np.bincount(np.asarray(dist.sample(u)), minlength=3) / 30000
    probs = np.exp(np.asarray(dist.log_prob(jnp.arange(3).repeat(10000)))[::10000])
    np.testing.assert_allclose(probs, scipy.special.softmax(np.asarray(logits)), rtol=1e-6)
    np.testing.assert_allclose(counts, probs, atol=0.01)  # 3 standard errors of 0.0028
    # -sum p log p of the softmax, and the likeliest action, 2.
    np.testing.assert_allclose(dist.entropy()[0], scipy.stats.entropy(probs), rtol=1e-6)
    assert int(dist.mode()[0]) == 2


def test_gaussian_samples_and_log_densities_agree():
    dist = distributions.Gaussian(jnp.full((30000,), 0.5), jnp.full((30000,), math.log(2.0)))
    u = jax.random.uniform(jax.random.PRNGKey(1), (30000,))
    draws = np.asarray(dist.sample(u))
    assert abs(draws.mean() - 0.5) < 0.04 and abs(draws.std() - 2.0) < 0.04  # 3.5 std errors
    np.testing.assert_allclose(dist.log_prob(jnp.asarray(1.7)),
                               scipy.stats.norm(0.5, 2.0).logpdf(1.7), rtol=1e-6)
    np.testing.assert_allclose(dist.entropy()[0], scipy.stats.norm(0.5, 2.0).entropy(), rtol=1e-6)
    # u = 0 and the highest uniform stay finite.
    extreme = distributions.Gaussian(jnp.zeros(2), jnp.zeros(2)).sample(
        jnp.asarray([0.0, 1 - 2.0**-23], jnp.float32))
    assert np.all(np.isfinite(extreme))


def test_a_checkpoint_of_another_environment_loads_with_its_physics(tmp_path):
    config = TrainConfig(env=envs.acrobot.V1.replace(link_mass_2=1.5), **_SMALL)
    result = train(config, seed=0, show_progress=False)
    checkpoint.save(tmp_path / "policy.msgpack", result.policy_params, config)
    loaded = checkpoint.load(tmp_path / "policy.msgpack")
    assert loaded.config == config
    for got, want in zip(jax.tree.leaves(loaded.policy_params),
                         jax.tree.leaves(result.policy_params)):
        np.testing.assert_array_equal(got, want)


def test_the_command_trains_another_environment_and_refuses_fields_it_lacks(tmp_path, capsys):
    status = cli.run_command(["train", "--env", "MountainCar-v0", "--force", "0.002",
                              "--iterations", "2", "--episodes", "2", "--max-steps", "30",
                              "--out", str(tmp_path / "run"), "--quiet", "--no-cache"])
    assert status == 0 and (tmp_path / "run" / "policy.msgpack").is_file()
    assert checkpoint.load(tmp_path / "run").config.env_params.force == 0.002
    status = cli.run_command(["train", "--env", "Acrobot-v1", "--masscart", "2",
                              "--out", str(tmp_path / "other"), "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1
    assert "--masscart: Acrobot-v1 has no field masscart" in lines[0]
    assert not (tmp_path / "other").exists()


def test_the_command_evaluates_a_policy_in_its_own_environment_and_refuses_another(
        tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    config = TrainConfig(env="Acrobot-v1", **_SMALL)
    checkpoint.save(tmp_path / "acrobot/", train(config, seed=0).policy_params, config)
    capsys.readouterr()
    assert cli.run_command(["evaluate", "--policy", "acrobot", "--episodes", "3",
                            "--link-mass-2", "1,2", "--out", "table"]) == 0
    assert "in jaxpg Acrobot-v1" in capsys.readouterr().out
    assert (tmp_path / "table" / "robustness.png").is_file()
    status = cli.run_command(["evaluate", "--env", "CartPole-v1", "--policy", "acrobot"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1
    assert "env: acrobot plays Acrobot-v1, got CartPole-v1" in lines[0]


@pytest.mark.parametrize("env", ["MountainCarContinuous-v0"])
def test_robustness_plays_each_cell_as_evaluate_does(env):
    config = TrainConfig(env=env, **_SMALL)
    result = sweep(config, seeds=[0, 1], show_progress=False)
    field = config.physics[-1]
    values = [getattr(config.env_params, field), 1.25 * getattr(config.env_params, field)]
    table = robustness(result, {field: values}, episodes=5, max_steps=30, seed=3)
    policy = policies.network_policy(config.network,
                                     jax.tree.map(lambda leaf: leaf[0, 1], result.policy_params),
                                     num_actions=config.num_actions)
    alone = evaluate(policy, episodes=5, max_steps=30, seed=3,
                     env=config.env_params.replace(**{field: values[1]}))
    np.testing.assert_array_equal(table.returns[0, 1, 1], alone.returns)


def test_a_trained_policy_scores_in_gymnasium_what_it_scores_in_jaxpg():
    """Pendulum's returns vary continuously: the two backends' means agree within 4 standard
    errors of their difference (other initial states and uniforms, the same policy)."""
    config = TrainConfig(env="Pendulum-v1", loss="baseline", hidden=(16,), iterations=20)
    trained = train(config, seed=0, show_progress=False)
    policy = policies.network_policy(config.network, trained.policy_params, num_actions=None)
    ours = evaluate(policy, episodes=60, max_steps=200, env="Pendulum-v1", seed=1)
    theirs = evaluate(policy, episodes=60, max_steps=200, env="Pendulum-v1", seed=1,
                      backend="gymnasium")
    error = math.hypot(ours.std, theirs.std) / math.sqrt(60)
    assert abs(ours.mean - theirs.mean) < 4 * error


def test_gymnasium_plays_another_environment_in_its_own_physics_only():
    with pytest.raises(ValueError, match="^env: Gymnasium plays Acrobot-v1 with its own physics"):
        evaluate(lambda obs, u: jnp.zeros(obs.shape[:-1], jnp.int32), episodes=2,
                 env=envs.acrobot.V1.replace(link_mass_2=2.0), backend="gymnasium")
