"""jaxpg's XLA setting for its own processes changes how fast they train, not what they train."""

import os
import subprocess
import sys

import numpy as np

# Trains one seed (a run alone) and three (runs side by side) and saves the results, with or
# without the setting, and how many of the iteration program's loops XLA compiled whole.
SCRIPT = """
import sys
import numpy as np
from jaxpg import flags
if sys.argv[2] == "whole":
    flags.configure_xla()
from jaxpg import reinforce
from jaxpg.sweep import check_seeds, expand_grid, run_inputs

config = reinforce.TrainConfig(iterations=12, episodes=3, max_steps=40)
program = reinforce.compiled_program(config)
saved = {}
for num_runs in (1, 3):
    keys, hyperparams = run_inputs(check_seeds(range(num_runs)), expand_grid(config, None))
    (result,) = reinforce.run(program, config.iterations, [(keys, hyperparams)])
    for name, leaf in zip(result.metrics._fields, result.metrics):
        saved[f"{num_runs}-{name}"] = leaf
    for i, leaf in enumerate(reinforce.jax.tree.leaves(result.policy_params)):
        saved[f"{num_runs}-param{i}"] = leaf
    state = program.init(keys, hyperparams)
    compiled = program.iterate.lower(state, hyperparams, np.int32(1)).compile().as_text()
    saved[f"{num_runs}-whole-loops"] = compiled.count("xla_cpu_small_call")
np.savez(sys.argv[1], **saved)
"""


def _train(tmp_path, setting):
    out = tmp_path / f"{setting}.npz"
    env = {**os.environ, "XLA_FLAGS": ""}
    subprocess.run([sys.executable, "-c", SCRIPT, str(out), setting], env=env, check=True)
    return dict(np.load(out))


def test_the_setting_trains_bit_for_bit_alike(tmp_path):
    """Parameters and statistics are the same bit for bit; the gradient norm, which nothing is
    computed from, to one unit in the last place: with loops not unrolled, LLVM fuses one of its
    multiplications and additions into one rounding in one layout and not in the other."""
    whole, default = _train(tmp_path, "whole"), _train(tmp_path, "default")
    for num_runs in (1, 3):
        loops = f"{num_runs}-whole-loops"
        assert whole.pop(loops) > default.pop(loops)  # the setting took effect
        np.testing.assert_array_max_ulp(whole.pop(f"{num_runs}-grad_norm"),
                                        default.pop(f"{num_runs}-grad_norm"), maxulp=1)
    assert whole.keys() == default.keys()
    for name in whole:
        np.testing.assert_array_equal(whole[name], default[name], err_msg=name)
