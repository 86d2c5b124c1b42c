"""Per-iteration progress of a compiled training program, printed from a host callback.

The compiled program calls `report` once per iteration; the callback forwards to the bar opened by
`bar`, so the program itself does not depend on which bar (or none) is showing.
"""

import contextlib
import sys
import time

import jax
import numpy as np

_current = None


class _Bar:
    def __init__(self, total, stream):
        self.total = total
        self.stream = stream
        self.interactive = stream.isatty()
        self.start = time.perf_counter()
        self.every = max(1, total // 10)  # in logs, about ten lines per run

    def update(self, iteration, mean_returns):
        done = iteration + 1
        if not self.interactive and done % self.every and done != self.total:
            return
        runs = f" (mean of {mean_returns.size} runs)" if mean_returns.size > 1 else ""
        line = (
            f"Iteration: {done}/{self.total}, mean rewards: {float(np.mean(mean_returns)):.1f}"
            f"{runs} [{time.perf_counter() - self.start:.1f}s]"
        )
        self.stream.write(("\r" + line) if self.interactive else line + "\n")
        self.stream.flush()

    def close(self):
        if self.interactive:
            self.stream.write("\n")
            self.stream.flush()


def _on_iteration(iteration, mean_returns):
    if _current is not None:
        _current.update(int(iteration), np.asarray(mean_returns))


def report(iteration, mean_returns):
    """Inside a traced program: send this iteration's mean returns `[R]` to the open bar."""
    jax.debug.callback(_on_iteration, iteration, mean_returns)


@contextlib.contextmanager
def bar(total, enabled=True, stream=None):
    """Shows the progress of `total` iterations on stderr while the block runs."""
    global _current
    if not enabled:
        yield
        return
    _current = _Bar(total, stream or sys.stderr)
    try:
        yield
    finally:
        _current.close()
        _current = None
