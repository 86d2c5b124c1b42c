"""Per-iteration progress of training, printed on the host.

`bar` yields the function that training calls once per iteration with every run's mean return;
when progress is off it yields None, so training can skip the work of reporting.
"""

import contextlib
import sys
import time

import numpy as np


class _Bar:
    def __init__(self, total, stream, label):
        self.total = total
        self.stream = stream
        self.label = f"{label}: " if label else ""
        self.interactive = stream.isatty()
        self.start = time.perf_counter()
        self.every = max(1, total // 10)  # in logs, about ten lines per run

    def update(self, iteration, metrics):
        done = iteration + 1
        if not self.interactive and done % self.every and done != self.total:
            return
        mean_returns = np.asarray(metrics.mean_return)
        runs = f" (mean of {mean_returns.size} runs)" if mean_returns.size > 1 else ""
        line = (
            f"{self.label}Iteration: {done}/{self.total}, mean rewards: "
            f"{float(np.mean(mean_returns)):.1f}{runs} [{time.perf_counter() - self.start:.1f}s]"
        )
        self.stream.write(("\r" + line) if self.interactive else line + "\n")
        self.stream.flush()

    def close(self):
        if self.interactive:
            self.stream.write("\n")
            self.stream.flush()


@contextlib.contextmanager
def bar(total, enabled=True, stream=None, label=""):
    """Shows the progress of `total` iterations on stderr while the block runs.

    Args:
      total: iterations of training.
      enabled: False shows nothing.
      stream: where to write; stderr by default.
      label: text before each line, such as which runs are training.

    Yields:
      `on_iteration(iteration, metrics)` to call once per iteration with a `Metrics` of the
      runs training (`[R]` leaves), or None if disabled.
    """
    if not enabled:
        yield None
        return
    current = _Bar(total, stream or sys.stderr, label)
    try:
        yield current.update
    finally:
        current.close()


def together(*hooks):
    """One `on_iteration(iteration, metrics)` that calls each of `hooks` not None, in order; None
    where there is none."""
    hooks = [hook for hook in hooks if hook is not None]
    if not hooks:
        return None

    def on_iteration(iteration, metrics):
        for hook in hooks:
            hook(iteration, metrics)

    return on_iteration
