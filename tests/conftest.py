"""Fixtures and helpers shared by the tests."""

import contextlib

import jax
import pytest

from jaxpg import TrainConfig
from jaxpg.sweep import sweep

# Ten short runs: five seeds by two learning rates. The device tests run the same sweep as
# `jaxpg sweep --iterations 3 --episodes 3 --max-steps 20 --seeds 5 --lr 0.01,0.02`.
SMALL_CONFIG = TrainConfig(iterations=3, episodes=3, max_steps=20)
SMALL_SEEDS = range(5)
SMALL_GRID = {"learning_rate": [0.01, 0.02]}


@pytest.fixture(scope="session")
def small_sweep():
    """The small sweep in one chunk on one device, the reference for chunked and sharded runs."""
    return sweep(SMALL_CONFIG, SMALL_SEEDS, SMALL_GRID, show_progress=True)


@contextlib.contextmanager
def xla_compiles():
    """The names of the programs XLA compiles inside the block, one entry per compile."""
    names = []

    def listen(event, duration, fun_name=None, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            names.append(fun_name)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
