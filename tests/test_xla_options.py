"""jaxpg's XLA setting for its own processes changes how fast they train, not what they train."""

import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import check_alone

from jaxpg import schedule, xla_options

# Trains one seed (a run alone) and three (one block, padded to four: the blocks of one core) and
# saves the results, with or without the setting.
SCRIPT = """
import sys
import numpy as np
from jaxpg import xla_options
if sys.argv[2] == "set":
    xla_options.configure_xla()
if sys.argv[2] == "one thread":
    xla_options.configure_xla(runs=1)
from jaxpg import train_config, programs, reinforce, schedule
from jaxpg.sweeps import check_seeds, expand_grid, run_inputs

schedule.usable_cores = lambda: 1  # on more cores, three runs would train alone
config = train_config.TrainConfig(iterations=12, episodes=3, max_steps=40)
program = programs.compiled_program(config)
saved = {}
for num_runs in (1, 3):
    keys, hyperparams = run_inputs(config, check_seeds(range(num_runs)), expand_grid(config, None))
    (result,) = schedule.train_blocks(program, config.iterations, [(keys, hyperparams)])
    for name, leaf in result.metrics.columns().items():
        saved[f"{num_runs}-{name}"] = leaf
    for i, leaf in enumerate(reinforce.jax.tree.leaves(result.policy_params)):
        saved[f"{num_runs}-param{i}"] = leaf
np.savez(sys.argv[1], **saved)
"""

# Compiles a small program with XLA's dumps on, with or without the setting; XLA ignores a
# backend option it does not know, so only its code shows whether the setting arrived.
DUMPED = """
import os, sys
from jaxpg import xla_options
if sys.argv[2] == "set":
    xla_options.configure_xla()
os.environ["XLA_FLAGS"] = f"{os.environ['XLA_FLAGS']} --xla_dump_to={sys.argv[1]}".strip()
import jax, jax.numpy as jnp
jax.block_until_ready(jax.jit(lambda x: jnp.cumsum(x * 2.0 + 1.0))(jnp.arange(37.0)))
"""


def _run(*args):
    env = {name: value for name, value in os.environ.items() if name not in xla_options.THREADS}
    env["XLA_FLAGS"] = ""
    return subprocess.run([sys.executable, "-c", *args], env=env, capture_output=True, text=True)


def _train(tmp_path, setting):
    out = tmp_path / f"{setting}.npz"
    result = _run(SCRIPT, str(out), setting)
    assert result.returncode == 0, result.stderr
    return dict(np.load(out))


def test_the_setting_trains_the_same_parameters_and_statistics(tmp_path):
    """Parameters and statistics are the same bit for bit; the gradient norm, which nothing is
    computed from, to one unit in the last place: with loops not unrolled, LLVM fuses one of its
    multiplications and additions into one rounding in one layout and not in the other."""
    tuned, default = _train(tmp_path, "set"), _train(tmp_path, "default")
    for num_runs in (1, 3):
        np.testing.assert_array_max_ulp(tuned.pop(f"{num_runs}-grad_norm"),
                                        default.pop(f"{num_runs}-grad_norm"), maxulp=1)
    assert tuned.keys() == default.keys()
    for name in tuned:
        np.testing.assert_array_equal(tuned[name], default[name], err_msg=name)


def test_one_thread_for_xla_trains_bit_for_bit_alike(tmp_path):
    """A process that trains one run at a time gives XLA's CPU client one thread: XLA no longer
    splits kernels over threads, and every parameter and statistic is as with one per core (for
    one run and, in the same process, three)."""
    one_thread, per_core = _train(tmp_path, "one thread"), _train(tmp_path, "set")
    assert one_thread.keys() == per_core.keys()
    for name in one_thread:
        np.testing.assert_array_equal(one_thread[name], per_core[name], err_msg=name)


def test_under_the_setting_seeds_train_alone_as_side_by_side():
    """The book's seeds 0 to 20 train alone (in a process of one thread, as `jaxpg train`) as in
    two blocks of 10 and 11 runs padded to 16, by `benchmarks/check_alone.py`.

    The programs of one run and of several are compiled apart, each into one function
    (`xla_cpu_small_while_loop_byte_threshold`, in the setting), and XLA can round them
    differently: it did when a run alone asked for 512-bit vectors, or still had a run axis of one
    entry (docs/performance.md).
    """
    result = check_alone("--seeds", "21")
    assert result.returncode == 0, result.stdout + result.stderr


# Compiles the iteration of a run alone and of a block of CPU_BLOCK runs with the book's settings,
# under the setting, and prints for each how many `while` loops its entry computation runs kernel by
# kernel and how many it calls as one function.
WHOLE = """
from jaxpg import xla_options
xla_options.configure_xla()
import numpy as np
from jaxpg import train_config, programs, reinforce, schedule
from jaxpg.sweeps import check_seeds, expand_grid, run_inputs

config = train_config.TrainConfig()
program = programs.compiled_program(config)
for runs in (1, schedule.CPU_BLOCK):
    keys, hyperparams = run_inputs(config, check_seeds(range(runs)), expand_grid(config, None))
    state = program.init(keys, hyperparams)
    text = program.iterate.lower(state, hyperparams, np.int32(1)).compile().as_text()
    entry = text[text.index("ENTRY"):]
    entry = entry[:entry.index("\\n}")]
    print(runs, entry.count(" while("), entry.count('xla_cpu_small_call="true"'))
"""


def test_under_the_setting_the_iteration_compiles_into_one_function():
    """The ten-iteration loop of a run alone and of a block of runs is one function: compiled
    sooner than kernel by kernel, and run sooner. A float sum that XLA hands to a library, a
    library call anywhere in the loop, or a loop of more bytes than
    `xla_options.WHOLE_LOOP_BYTES` would keep it kernel by kernel."""
    result = _run(WHOLE)
    assert result.returncode == 0, result.stderr
    counts = {int(runs): (int(loops), int(calls))
              for runs, loops, calls in (line.split() for line in result.stdout.splitlines())}
    assert counts == {1: (0, 1), schedule.CPU_BLOCK: (0, 1)}


def _optimized_ir_lines(tmp_path, setting):
    dump = tmp_path / setting
    result = _run(DUMPED, str(dump), setting)
    assert result.returncode == 0, result.stderr
    files = list(dump.glob("*jit__lambda*.ir-with-opt.ll"))
    assert files
    return sum(len(path.read_text().splitlines()) for path in files)


def test_the_setting_reaches_llvm_which_then_unrolls_no_loops(tmp_path):
    assert _optimized_ir_lines(tmp_path, "set") < 0.75 * _optimized_ir_lines(tmp_path, "default")


# Compiles a kernel of a million sines with or without one thread for XLA's CPU client, and prints
# how many pieces the compiled program splits it into.
SPLIT = """
import re, sys
from jaxpg import xla_options
xla_options.configure_xla(runs=1 if sys.argv[1] == "one thread" else None)
import jax, jax.numpy as jnp
text = jax.jit(lambda x: jnp.sin(x) * 2.0).lower(jnp.zeros(2**20)).compile().as_text()
print(max([int(n) for n in re.findall(r'outer_dimension_partitions":\\["(\\d+)', text)] or [1]))
"""


@pytest.mark.skipif(schedule.usable_cores() < 2, reason="XLA splits kernels over two cores or more")
def test_one_thread_reaches_xla_which_then_splits_no_kernel():
    pieces = {}
    for setting in ("one thread", "per core"):
        result = _run(SPLIT, setting)
        assert result.returncode == 0, result.stderr
        pieces[setting] = int(result.stdout)
    assert pieces["one thread"] == 1 and pieces["per core"] > 1


def test_xla_gets_one_thread_for_a_process_that_trains_one_run(monkeypatch):
    # Absent now, and again after the test.
    for name in (*xla_options.THREADS, xla_options.CPU_DEVICES):
        monkeypatch.setenv(name, "")
        monkeypatch.delenv(name)
    monkeypatch.setenv("XLA_FLAGS", "")
    for runs in (None, 2, schedule.CPU_BLOCK - 1):  # nothing trained; two runs; a large block
        xla_options.configure_xla(runs=runs)
        assert xla_options.THREADS[0] not in os.environ
    xla_options.configure_xla(runs=1)
    assert os.environ[xla_options.THREADS[0]] == "1"
    for name in xla_options.THREADS:  # an empty variable is no choice: XLA ignores it
        monkeypatch.setenv(xla_options.THREADS[0], "")
        monkeypatch.setenv(name, "")
        xla_options.configure_xla(runs=1)
        assert os.environ[xla_options.THREADS[0]] == "1"
        monkeypatch.delenv(name)
    for name in xla_options.THREADS:  # the environment's own choice stays
        monkeypatch.delenv(xla_options.THREADS[0], raising=False)
        monkeypatch.setenv(name, "3")
        xla_options.configure_xla(runs=1)
        assert os.environ.get(xla_options.THREADS[0], "3") == "3"
        monkeypatch.delenv(name)
    # A sweep's copies of its one run train side by side on several devices, which need threads.
    for name, value in (("XLA_FLAGS", "--xla_force_host_platform_device_count=2"),
                        (xla_options.CPU_DEVICES, "2")):
        monkeypatch.setenv(name, value)
        xla_options.configure_xla(runs=1)
        assert xla_options.THREADS[0] not in os.environ
        monkeypatch.delenv(name)


def test_the_setting_is_added_to_xla_flags_unless_backend_options_are_given(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    xla_options.configure_xla()
    assert os.environ["XLA_FLAGS"] == (
        f"--xla_force_host_platform_device_count=2 {xla_options.SETTING}")
    monkeypatch.setenv("XLA_FLAGS", xla_options.XLA_DEFAULTS)
    xla_options.configure_xla()
    assert os.environ["XLA_FLAGS"] == xla_options.XLA_DEFAULTS


def test_the_package_names_its_xla_options_module():
    """As the README writes it: `jaxpg.xla_options.WIDE_VECTORS`, after `import jaxpg`."""
    import jaxpg

    assert jaxpg.xla_options is xla_options
    assert "xla_options" in dir(jaxpg)
