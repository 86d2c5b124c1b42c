"""The parity harness: passes on jaxpg as it is, fails on a wrong constant."""

import jax
import numpy as np
import pytest
from flax import struct

from jaxpg import cartpole, conformance
from jaxpg.train_config import PHYSICS


@struct.dataclass
class Phys2dParams(cartpole.CartPoleParams):
    """Gymnasium's phys2d CartPole's mistake: masspole + length (0.6) instead of their product."""

    @property
    def polemass_length(self):
        return self.masspole + self.length


def test_default_run_is_ok():
    report = conformance.compare_with_gymnasium()
    assert report.ok, report.format()
    assert [v.name for v in report.variants] == list(conformance.VARIANTS)
    for variant in report.variants:
        # The episodes reach every ending: a fall and the step limit.
        assert variant.stats.terminated > 0 and variant.stats.truncated > 0, variant
        assert max(variant.stats.max_error) <= 1e-6
    v0, v1 = report.variants[:2]
    assert v0.stats.steps < v1.stats.steps  # v0 truncates at 200, v1 at 500
    assert report.format().endswith("conformance: OK")


def test_three_physics_settings_play_identical_episodes():
    """Every physical field set apart from its default, and 100 episodes of the basic policy with
    identical returns in jaxpg and in Gymnasium's CartPoleEnv with the same attributes."""
    physics = {name: value for name, value in conformance.VARIANTS.items()
               if set(value) & set(PHYSICS)}
    assert len(physics) == 3 and set().union(*physics.values()) == set(PHYSICS)
    assert all(getattr(cartpole.V1, field) != value
               for setting in physics.values() for field, value in setting.items())
    report = conformance.compare_with_gymnasium(variants=list(physics))
    assert report.ok, report.format()
    for variant in report.variants:
        assert variant.episodes == variant.equal_returns == 100
        assert f"{variant.name} " in report.format() and "100/100" in report.format()
    in_jaxpg, in_gymnasium = conformance.episode_returns(
        cartpole.V1.replace(**physics["long-heavy-pole"]), 100, 0)
    np.testing.assert_array_equal(in_jaxpg, in_gymnasium)
    assert len(np.unique(in_jaxpg)) > 10  # episodes of many lengths, not one


def test_float64_run_is_ok():
    with jax.enable_x64(True):
        report = conformance.compare_with_gymnasium(episodes=20, variants=["v1", "semi-implicit"])
    assert report.dtype == "float64" and report.tolerance == 1e-12
    assert report.ok, report.format()


def test_wrong_polemass_length_is_flagged():
    report = conformance.compare_with_gymnasium(episodes=10, env_params=Phys2dParams(),
                                                variants="v1")
    assert not report.ok
    (variant,) = report.variants
    # polemass_length enters temp and xacc: 0.6 instead of 0.05 changes the accelerations by far
    # more than 1e-6 at the first step of every episode.
    assert variant.stats.max_error[1] > 1e-3  # x_dot
    assert variant.first_divergence == 1
    assert variant.equal_returns < variant.episodes
    assert report.format().endswith("conformance: FAILED")


@pytest.mark.parametrize("kwargs, match", [
    ({"episodes": 0}, "episodes"),
    ({"seed": -1}, "seed"),
    ({"variants": ["v2"]}, "variants"),
    ({"variants": []}, "variants"),
    ({"env_params": "CartPole-v1"}, "env_params"),
])
def test_bad_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=f"^{match}:"):
        conformance.compare_with_gymnasium(**kwargs)
