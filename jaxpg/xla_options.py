"""XLA settings for the processes that jaxpg starts: its command and its benchmarks.

`configure_xla` sets environment variables that JAX reads when it starts its backends:

- `SETTING`, added to `XLA_FLAGS`: two options of XLA's CPU backend (`BACKEND_OPTIONS`). LLVM
  unrolls no loops, and a `while` loop whose bytes accessed are under `WHOLE_LOOP_BYTES`, with no
  library call in it, compiles into one function rather than kernel by kernel: the ten-iteration
  loop of the training program, of a run alone and of any block of runs a CPU trains
  (`schedule.CPU_BLOCK`), is one function. A loop of more bytes (a block of many more episodes
  or steps) stays kernel by kernel. And XLA's copy insertion by region analysis
  (`COPY_INSERTION`), which copies a `while` loop's carried array only where its old value is
  still read once its successor is written: `scan(vmap(cartpole.step))` copies 2 arrays a step
  where it copied 7.
- For a process that trains one run at a time (`jaxpg train`), one thread for XLA's CPU client
  (`PJRT_NPROC=1`), so that XLA splits no kernel of a run over threads.

Both make the training programs compile and run sooner on CPU (a loop over very large arrays
loses XLA's splitting of its kernels over the cores); neither changes a result. Trained parameters
and every statistic are bit for bit those of XLA's defaults, except the gradient norm, which
nothing is computed from: it may differ in its last bit. Under the setting, a seed trains alone bit
for bit as it does beside others (`tests/test_xla_options.py`, `benchmarks/check_alone.py`). The
measurements are in docs/performance.md.

The settings belong to the whole process, jaxpg's computations and any other's alike, and take
effect only if made before JAX starts its backends. The `jaxpg` command makes them; `train` and
`sweep` add `SETTING` where JAX has not started yet (`configure_unstarted`), but never the one
thread, which would slow the process's later sweeps. Another program opts in by calling
`configure_xla` before JAX computes anything; `XLA_FLAGS` that pass backend options of their own
(`XLA_DEFAULTS`: XLA's own values) and a thread count already set are left alone.
"""

import os

# Above the ten-iteration loop of CPU_BLOCK runs of any built-in loss.
WHOLE_LOOP_BYTES = 1 << 28
BACKEND_OPTIONS = {
    "xla_cpu_disable_loop_unrolling": "true",  # XLA reads its presence, whatever the value
    "xla_cpu_small_while_loop_byte_threshold": str(WHOLE_LOOP_BYTES),
}
COPY_INSERTION = "--xla_cpu_copy_insertion_use_region_analysis=true"
SETTING = "--xla_backend_extra_options=" + ",".join(
    f"{name}={value}" for name, value in BACKEND_OPTIONS.items()) + " " + COPY_INSERTION
# Backend options at XLA's own values: in XLA_FLAGS, they keep `configure_xla` from adding SETTING.
XLA_DEFAULTS = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1024"


# Options of one program rather than the process: `jax.jit(f, compiler_options=WIDE_VECTORS)`
# compiles `f` with 512-bit vectors where the CPU has them (XLA's default is 256), if that `jit`
# is not inside another (JAX refuses options there: pass them to the outer one). A block of
# several runs trains with them, and a stream of environments steps 1.5x as fast, the same bits.
# Not the process's: a rollout of a few episodes padded to a vector of 16 lanes would round some of
# them otherwise than unpadded (docs/performance.md, "The XLA setting").
WIDE_VECTORS = {"xla_cpu_prefer_vector_width": 512}

THREADS = ("PJRT_NPROC", "NPROC")  # what XLA's CPU client reads for the size of its pool
CPU_DEVICES = "JAX_NUM_CPU_DEVICES"  # JAX's count of CPU devices (XLA_FLAGS can also set one)


def configure_xla(runs: int | None = None) -> None:
    """Adds `SETTING` to `XLA_FLAGS`, unless `XLA_FLAGS` already passes backend options.

    Call it before JAX starts its backends: they read the environment once, when they start.

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


def configure_unstarted() -> None:
    """Calls `configure_xla()` where JAX has not started its backends yet; nothing otherwise.

    `train` and `sweep` call it, so that a Python program gets the command's `SETTING` without
    asking (but not the one thread for a run alone, which would slow the process's later sweeps).
    """
    from jax._src import xla_bridge  # here: importing this module must not import JAX

    if not xla_bridge.backends_are_initialized():
        configure_xla()
