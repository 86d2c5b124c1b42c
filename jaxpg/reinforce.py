"""What training runs share on the host: their keys, starting parameters and divergence checks.

One iteration plays `episodes` episodes of at most `max_steps` steps with the current policy,
discounts the rewards and takes `TrainConfig.updates` optimizer steps on the loss
(`jaxpg.iteration`). Iterations
of many runs together are one compiled program (`jaxpg.programs`), which the host calls for up to
`programs.ITERATIONS_PER_CALL` iterations at a time (`jaxpg.schedule`); `jaxpg.sweeps` trains
every run, one (`train`) or many (`sweep`), that way.
"""

import warnings
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from jaxpg import losses, policies
from jaxpg.iteration import Metrics
from jaxpg.train_config import TrainConfig
from jaxpg.types import ArrayLike, HostArray, Params


def run_keys(seeds: ArrayLike | Sequence[int]) -> HostArray:
    """One PRNG key per seed, made on the host: `jax.random.PRNGKey(seed)` of each.

    Threefry's key of a 32-bit seed is its high word (0) and the seed itself.

    Args:
      seeds: integers `[R]` in [0, 2**32).

    Returns:
      uint32 `[R, 2]`, a numpy array.
    """
    seeds = np.asarray(seeds, dtype=np.uint32)
    return np.stack([np.zeros_like(seeds), seeds], axis=-1)


def check_init_params(config: TrainConfig, init_params: Params, critic: bool = False) -> Params:
    """`init_params` as numpy arrays of the network's dtypes, checked against its shapes.

    Args:
      config: the `TrainConfig` whose policy (`TrainConfig.network`) they are for.
      init_params: one run's policy parameters (with `critic`, its loss's critic's).
      critic: whether they are the parameters of the loss's critic (`losses.critic`).

    Returns:
      The parameters as numpy arrays.

    Raises:
      ValueError: unless they have the tree and shapes of the network's own parameters
        (`jax.eval_shape` of its `init`), or for a critic's where the loss has none.
    """
    name, network = (("init_critic_params", losses.critic(config.loss)) if critic
                     else ("init_params", config.network))
    if network is None:
        raise ValueError(f"{name}: the loss {config.loss!r} has no critic")
    want = jax.eval_shape(lambda key: policies.init_network(key, network,
                                                         config.env_module.OBS_SIZE),
                          jax.ShapeDtypeStruct((2,), np.uint32))
    try:
        params = jax.tree.map(lambda w, leaf: np.asarray(leaf, w.dtype), want, init_params)
        matches = all(w.shape == p.shape for w, p in zip(jax.tree.leaves(want),
                                                         jax.tree.leaves(params)))
    except (TypeError, ValueError):
        matches = False
    if not matches:
        raise ValueError(f"{name}: expected the {'critic' if critic else 'policy'}'s "
                         f"parameters, shaped {jax.tree.map(lambda leaf: leaf.shape, want)}")
    return params


def first_nonfinite(metrics: Metrics) -> HostArray:
    """The first iteration of each run whose loss or gradient norm is not finite.

    The parameters take a non-finite gradient's step, so this is also where they may stop being
    finite.

    Args:
      metrics: `Metrics` with `[..., I]` leaves.

    Returns:
      ints `[...]`: each run's first such iteration, -1 where there is none.
    """
    bad = ~(np.isfinite(metrics.loss) & np.isfinite(metrics.grad_norm))
    return np.where(bad.any(axis=-1), bad.argmax(axis=-1), -1)


def warn_if_diverged(metrics: Metrics, labels: Sequence[Any] | None = None) -> None:
    """Warns, with a `RuntimeWarning`, once per run that diverged (`first_nonfinite`).

    Args:
      metrics: `Metrics` with `[R, I]` leaves.
      labels: optional: how each run's warning names it (` of {label}`).
    """
    for r, first in enumerate(first_nonfinite(metrics)):
        if first >= 0:
            which = "" if labels is None else f" of {labels[r]}"
            warnings.warn(f"training{which} diverged: the loss or its gradient is not finite "
                          f"from iteration {first} on (counted from 0)", RuntimeWarning,
                          stacklevel=3)
