"""The XLA setting of the processes that jaxpg starts: its command and its benchmarks.

Three parts, all read when JAX starts its backends. First, LLVM unrolls no loops (an option of
XLA's CPU backend). The iteration program compiles 0.2 to 0.3 s sooner, and 8 seeds train in 0.18 to
0.20 s instead of 0.31 to 0.33 s. The trained parameters and every statistic are bit for bit the
same, except the gradient norm, which nothing is computed from: it can differ in its last bit,
since LLVM fuses one of its multiplications and additions into one rounding in one code layout and
not in another.

Second, XLA's CPU backend compiles a `while` loop into one function, with its older IR emitter,
rather than kernel by kernel with its fusion emitters (a dozen milliseconds of compiling each,
whatever their size), when its cost model's bytes accessed are under a threshold and nothing in it
calls a library (a custom fusion). At XLA's 1024 bytes that is the discounting loop alone. At
`WHOLE_LOOP_BYTES` it is the whole ten-iteration loop of the training program, of a run alone and of
any block of runs a CPU trains (`schedule.CPU_BLOCK`; 28 MB for 16 runs of the book's settings;
above 64 MiB with the baseline loss's critic, whose 128 seeds then trained 2.3 times as long as the
book's instead of 3.1): each program is one function, which LLVM compiles on one thread in less CPU
time than XLA's kernels on two, and which runs without dispatching kernels. The loop of a block of
more episodes or steps stays kernel by kernel. `rollout.rollout` sums its returns as integers for
this:
XLA handed the float sum of a block's records to YNNPACK, whose call kept the loop kernel by kernel
at any threshold. At 16 MiB, as before, only the loop of a run alone was one function (and the
rollout's loop of a block); with those of blocks too, 64 to 1024 seeds compiled in a median of
1.42 to 1.48 s instead of 1.67 to 1.73 s, trained 3 to 5 % sooner and peaked 65 to 100 MiB lower
(four alternating pairs of benchmark runs), bit for bit as before at 1 to 1024 seeds. At 16 MiB
against XLA's 1024 bytes (an earlier version, on an Intel Xeon), 1 seed compiled in 1.95, 1.85 and
1.82 s instead of 2.38, 1.99 and 2.11 s and 8 seeds trained in 0.13 to 0.14 s instead of 0.23 to
0.25 s; `jaxpg evaluate` reports the same statistics, sooner.
Only as long as a run alone compiles with XLA's own vector width: with 512-bit vectors
(`programs.TOGETHER_OPTIONS`, which blocks use) its rollout compiled whole rounds some episodes
differently (8 of the book's seeds 0 to 15 ended elsewhere), as the older emitter can round a run
axis of one entry differently from two or more, by how LLVM fuses multiplications and additions
into FMAs. While a run alone still had a run axis of one entry, its ten-iteration loop compiled
whole made 17 of seeds 0 to 63 end with other parameters alone. `tests/test_xla_options.py` trains seeds
alone and side by side under the setting (`benchmarks/check_alone.py`) to keep it so. A loop over
very large arrays loses XLA's splitting of kernels over the cores (a stream of 65536 environments
ran 79 M steps/s instead of 105 M); `benchmarks/env_throughput.py` measures XLA's defaults.

Third, a process that trains one run at a time (`jaxpg train`) gives XLA's CPU client one thread
(`PJRT_NPROC=1`). The client's pool has one thread per core by default, and XLA then splits the
larger kernels of a program over them (`outer_dimension_partitions` in the compiled HLO: six
kernels of the iteration of one seed, such as its step signals over 3200 floats), handing a part to
another thread each time. One seed trained in a median of 0.056 s that way against 0.040 s on one
thread (six alternating pairs of processes), compiled as fast, bit for bit alike. More runs are the
other way round. Blocks side by side need a thread each: with one thread in XLA's pool, 64 seeds
(two blocks of 32, as blocks were then) took 1.08 and 0.96 s instead of 0.51 and 0.51 s. And the
kernels of a large block gain from the split: 63 seeds in one block took 1.94 and 2.01 s on one
thread against 1.62 and 1.73 s (`benchmarks/results/train_throughput-20261201-2056*.json`,
`-214[56]*.json`).

The setting belongs to the whole process: jaxpg applies it to its own command and its training
benchmark only. Any program can opt in by calling `configure_xla` before JAX computes anything.
"""

import os

WHOLE_LOOP_BYTES = 1 << 28  # above the ten-iteration loop of CPU_BLOCK runs of any built-in loss
BACKEND_OPTIONS = {
    "xla_cpu_disable_loop_unrolling": "true",  # XLA reads its presence, whatever the value
    "xla_cpu_small_while_loop_byte_threshold": str(WHOLE_LOOP_BYTES),
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
        gets one thread, unless the environment sets its threads (`THREADS`, to anything but an
        empty value) or asks for several CPU devices (`CPU_DEVICES`, or XLA_FLAGS): a sweep pads
        its runs to a multiple of the devices, whose copies then train side by side.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "--xla_backend_extra_options" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {SETTING}".strip()
    # An empty PJRT_NPROC or NPROC is one XLA ignores: as if unset.
    if (runs == 1 and not any(os.environ.get(name) for name in (*THREADS, CPU_DEVICES))
            and "--xla_force_host_platform_device_count" not in flags):
        os.environ[THREADS[0]] = "1"


def configure_unstarted():
    """`configure_xla()` where JAX has not started its backends yet, which read the setting when
    they start; nothing otherwise. `train` and `sweep` call it, so that a Python program trains as
    fast as the command without asking (all but the one thread for a run alone, which would slow
    the process's later sweeps)."""
    from jax._src import xla_bridge  # here: importing this module must not import JAX

    if not xla_bridge.backends_are_initialized():
        configure_xla()
