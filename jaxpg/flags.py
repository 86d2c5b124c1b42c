"""The XLA setting of the processes that jaxpg starts: its command and its benchmarks.

One option of XLA's CPU backend, read when JAX starts its backends: LLVM unrolls no loops. The
iteration program compiles 0.2 to 0.3 s sooner, and 8 seeds train in 0.18 to 0.20 s instead of
0.31 to 0.33 s.

The trained parameters and every statistic are bit for bit the same, except the gradient norm,
which nothing is computed from: it can differ in its last bit, since LLVM fuses one of its
multiplications and additions into one rounding in one code layout and not in another. The
setting belongs to the whole process: jaxpg applies it to its own command and its training
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


def configure_xla():
    """Adds `SETTING` to `XLA_FLAGS`, unless `XLA_FLAGS` already passes backend options."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "--xla_backend_extra_options" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {SETTING}".strip()
