"""The Python API refuses values that would answer wrongly without a word, in one line naming the
argument, before anything compiles."""

import numpy as np
import pytest
from conftest import xla_compiles

from jaxpg import evaluate, policies


@pytest.mark.parametrize("value, match", [
    (np.nan, "must be finite"),  # a NaN state never falls: every episode would last 200 steps
    (1e39, r"must be at most 3\.403e\+38 in magnitude"),  # infinite in float32
])
def test_initial_states_that_the_episodes_cannot_start_from_are_refused(value, match):
    states = [[0.0, 0.0, 0.01, 0.0], [0.0, 0.0, 0.0, value]]
    with xla_compiles() as compiled, pytest.raises(ValueError, match=f"^init_states: {match}"):
        evaluate(policies.basic_policy, episodes=2, init_states=states)
    assert not compiled
