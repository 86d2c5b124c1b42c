"""The Python API refuses values that would answer wrongly without a word, in one line naming the
argument, before anything compiles."""

import numpy as np
import pytest
from conftest import xla_compiles

from jaxpg import TrainConfig, evaluate, policies, sweep, train


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
    with xla_compiles() as compiled, pytest.raises(
            ValueError, match="^on_iteration: must be a function .* or None, got int$"):
        trainer(TrainConfig(iterations=1), on_iteration=5)
    assert not compiled
