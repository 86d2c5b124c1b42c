"""The XLA setting of the processes that jaxpg starts: its command and its benchmarks.

Two options of XLA's CPU backend, read when JAX starts its backends:

- XLA's CPU runtime runs a loop's body one kernel at a time, and for one run's training, whose
  kernels are tiny, starting them costs more than their arithmetic. Its small-while-loop pass
  compiles a loop whose body accesses fewer bytes than a threshold (1 kB by default) into one
  function instead; the setting raises the threshold above every loop of training. One seed
  trains in 0.05 s instead of 0.055 s.
- LLVM unrolls no loops. The iteration program compiles about 0.25 s sooner (1.1 s), and 8 seeds
  train in 0.12 s instead of 0.24 s.

The trained parameters and every statistic are bit for bit the same, except the gradient norm,
which nothing is computed from: it can differ in its last bit, since LLVM fuses one of its
multiplications and additions into one rounding in one code layout and not in another. A loop
over very large arrays loses XLA's splitting of its kernels over the cores (a stream of 65536
environments steps 25 % slower), and the setting belongs to the whole process: jaxpg applies it
to its own command and training benchmarks only. Any program can opt in by calling
`configure_xla` before JAX computes anything.
"""

import os

BACKEND_OPTIONS = {
    "xla_cpu_small_while_loop_byte_threshold": 10**9,
    "xla_cpu_disable_loop_unrolling": "true",
}
SETTING = "--xla_backend_extra_options=" + ",".join(
    f"{name}={value}" for name, value in BACKEND_OPTIONS.items())


def configure_xla():
    """Adds `SETTING` to `XLA_FLAGS`, unless `XLA_FLAGS` already passes backend options."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "--xla_backend_extra_options" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {SETTING}".strip()
