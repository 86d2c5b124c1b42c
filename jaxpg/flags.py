"""The XLA setting of the processes that jaxpg starts: its command and its benchmarks.

Two parts, both read when JAX starts its backends. First, one option of XLA's CPU backend: LLVM
unrolls no loops. The iteration program compiles 0.2 to 0.3 s sooner, and 8 seeds train in 0.18 to
0.20 s instead of 0.31 to 0.33 s. The trained parameters and every statistic are bit for bit the
same, except the gradient norm, which nothing is computed from: it can differ in its last bit,
since LLVM fuses one of its multiplications and additions into one rounding in one code layout and
not in another.

Second, a process that trains one run at a time (`jaxpg train`) gives XLA's CPU client one thread
(`PJRT_NPROC=1`). The client's pool has one thread per core by default, and XLA then splits the
larger kernels of a program over them (`outer_dimension_partitions` in the compiled HLO: six
kernels of the iteration of one seed, such as its step signals over 3200 floats), handing a part to
another thread each time. One seed trained in a median of 0.056 s that way against 0.040 s on one
thread (six alternating pairs of processes), compiled as fast, bit for bit alike. More runs are the
other way round. Blocks side by side need a thread each: with one thread in XLA's pool, 64 seeds (two
blocks of 32) took 1.08 and 0.96 s instead of 0.51 and 0.51 s. And the kernels of a large block
gain from the split: 63 seeds in one block took 1.94 and 2.01 s on one thread against 1.62 and
1.73 s (`benchmarks/results/train_throughput-20261201-2056*.json`, `-214[56]*.json`).

The setting belongs to the whole process: jaxpg applies it to its own command and its training
benchmark only. Any program can opt in by calling `configure_xla` before JAX computes anything.

Not in the setting: raising `xla_cpu_small_while_loop_byte_threshold`, which compiles the whole
ten-iteration loop into one function (1 seed 0.041 s instead of 0.057 s). A run alone then rounds
differently from the same run beside others (17 of the book's seeds 0 to 63 ended with other
parameters alone, 30 differed in some statistic; `tests/test_flags.py`). Such a loop is emitted by
XLA's older IR emitter, which rounds a program with a run axis of one entry differently from one
with two or more, run kernel by kernel too (`xla_cpu_use_fusion_emitters=False`): by how LLVM fuses
multiplications and additions into FMAs, as far as it was traced.
"""

import os

BACKEND_OPTIONS = {
    "xla_cpu_disable_loop_unrolling": "true",  # XLA reads its presence, whatever the value
}
SETTING = "--xla_backend_extra_options=" + ",".join(
    f"{name}={value}" for name, value in BACKEND_OPTIONS.items())
# Backend options at XLA's own values: in XLA_FLAGS, they keep `configure_xla` from adding SETTING.
XLA_DEFAULTS = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1024"


THREADS = ("PJRT_NPROC", "NPROC")  # what XLA's CPU client reads for the size of its pool
CPU_DEVICES = "JAX_NUM_CPU_DEVICES"  # JAX's count of CPU devices (XLA_FLAGS can also set one)


def configure_xla(runs=None):
    """Adds `SETTING` to `XLA_FLAGS`, unless `XLA_FLAGS` already passes backend options.

    Args:
      runs: how many runs the process trains at most at once. Where that is one, XLA's CPU client
        gets one thread, unless the environment sets its threads (`THREADS`) or asks for several
        CPU devices (`CPU_DEVICES`, or XLA_FLAGS): a sweep pads its runs to a multiple of the
        devices, whose copies then train side by side.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "--xla_backend_extra_options" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {SETTING}".strip()
    if (runs == 1 and not any(name in os.environ for name in (*THREADS, CPU_DEVICES))
            and "--xla_force_host_platform_device_count" not in flags):
        os.environ[THREADS[0]] = "1"
