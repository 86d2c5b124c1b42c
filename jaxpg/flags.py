"""The XLA setting of the processes that jaxpg starts: its command and its benchmarks.

XLA's CPU runtime runs a loop's body one kernel at a time, and for one run's training, whose
kernels are tiny, starting them costs more than their arithmetic. Its small-while-loop pass
compiles a loop whose body accesses fewer bytes than a threshold (1 kB by default) into one
function instead. `compile_loops_whole` raises the threshold above every loop of training: one
seed trains in 0.05 s instead of 0.055 s, larger sweeps as fast as before, with results bit for
bit the same. A loop over very large arrays loses XLA's splitting of its kernels over the cores
(a stream of 65536 environments steps 25 % slower), and the setting belongs to the whole process,
read when JAX starts its backends: jaxpg applies it to its own command and training benchmark
only. Any program can opt in by calling it before JAX computes anything.
"""

import os

SMALL_LOOP_BYTES = 10**9
SETTING = f"--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold={SMALL_LOOP_BYTES}"


def compile_loops_whole():
    """Adds `SETTING` to `XLA_FLAGS`, unless `XLA_FLAGS` already passes backend options."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "--xla_backend_extra_options" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {SETTING}".strip()
