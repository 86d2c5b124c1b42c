"""Progress of training, per iteration, and of other work done in parts, printed on the host.

`bar` yields the function that training calls once per iteration with every run's mean return;
when progress is off it yields None, so training can skip the work of reporting. `count` yields
one that work in parts (`evaluation.evaluate`'s chunks) calls with how much is done.
"""

import contextlib
import sys
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, TextIO

import numpy as np

if TYPE_CHECKING:
    from jaxpg.iteration import Metrics

# Called on the host once per iteration: (iteration, `Metrics` of the runs training) -> None.
OnIteration = Callable[[int, "Metrics"], None]


class _Bar:
    """The progress of one piece of work: a line per step, rewritten in place on a terminal."""

    def __init__(self, total: int, stream: TextIO, label: str) -> None:
        """A bar for `total` steps written to `stream`, each line after `label`."""
        self.total = total
        self.stream = stream
        self.label = f"{label}: " if label else ""
        self.interactive = stream.isatty()
        self.start = time.perf_counter()
        self.every = max(1, total // 10)  # in logs, about ten lines per run

    def show(self, text: str, due: bool) -> None:
        """Shows `text`: each time on a terminal, in a log where `due`."""
        if not (self.interactive or due):
            return
        line = f"{self.label}{text} [{time.perf_counter() - self.start:.1f}s]"
        self.stream.write(("\r" + line) if self.interactive else line + "\n")
        self.stream.flush()

    def update(self, iteration: int, metrics: "Metrics") -> None:
        """Shows iteration `iteration` (from 0) of training."""
        mean_returns = np.asarray(metrics.mean_return)
        runs = f" (mean of {mean_returns.size} runs)" if mean_returns.size > 1 else ""
        done = iteration + 1
        self.show(f"Iteration: {done}/{self.total}, mean rewards: "
                  f"{float(np.mean(mean_returns)):.1f}{runs}",
                  not done % self.every or done == self.total)

    def close(self) -> None:
        """Ends the line rewritten on a terminal."""
        if self.interactive:
            self.stream.write("\n")
            self.stream.flush()


@contextlib.contextmanager
def bar(total: int, enabled: bool = True, stream: TextIO | None = None, label: str = ""
        ) -> Iterator[OnIteration | None]:
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


@contextlib.contextmanager
def count(total: int, what: str) -> Iterator[Callable[[int], None]]:
    """Shows how many of `total` things are done on stderr while the block runs.

    Args:
      total: how many things the work does, such as episodes.
      what: their name, such as "episodes".

    Yields:
      `on_done(done)` to call with how many are done so far; shown as "what: done/total".
    """
    current = _Bar(total, sys.stderr, "")
    shown = [0]  # in a log, a line each time another tenth is done

    def on_done(done: int) -> None:
        """Shows `done` of `total`."""
        due = done // current.every > shown[0] // current.every or done == total
        shown[0] = done
        current.show(f"{what}: {done}/{total}", due)

    try:
        yield on_done
    finally:
        current.close()


def together(*hooks: OnIteration | None) -> OnIteration | None:
    """One `on_iteration(iteration, metrics)` that calls each of `hooks` not None, in order.

    Returns:
      That function, or None where every hook is None.
    """
    called = [hook for hook in hooks if hook is not None]
    if not called:
        return None

    def on_iteration(iteration: int, metrics: "Metrics") -> None:
        """Calls every hook with `iteration` and `metrics`."""
        for hook in called:
            hook(iteration, metrics)

    return on_iteration
