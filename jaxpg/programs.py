"""The compiled training programs of a `TrainConfig`: `init`, `iterate`, kept by `executables`."""

import concurrent.futures
import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg import envs, executables, policies, rollout, xla_options
from jaxpg.iteration import (
    Evaluation,
    Metrics,
    TrainState,
    check_config,
    evaluate_runs,
    init_runs,
    initial_records,
    is_run_alone,
    iterate,
)
from jaxpg.train_config import Hyperparams, TrainConfig
from jaxpg.types import Array, ArrayLike, Params

ITERATIONS_PER_CALL = 10  # iterations a call of the program runs at most


class Program(NamedTuple):
    """The compiled training of R runs at once, for one `TrainConfig`.

    Its functions are `executables.Stored` (`iterate` an `AloneOrTogether` of two), which
    `schedule.train_blocks` prepares before it calls them.

    Attributes:
      config: the `TrainConfig` compiled (`compiled_program`).
      extra: the names of the loss's metrics, `Metrics.extra`, in leaf order.
      init: `(keys [R, 2], Hyperparams [R], optional policy_params and critic_params of one run)
        -> TrainState`.
      iterate: `(TrainState, Hyperparams [R], count: int32 scalar) -> (TrainState, metrics)`:
        `count` iterations (at most `ITERATIONS_PER_CALL`), whose metrics' leaves, stacked
        `[ITERATIONS_PER_CALL, fields, R]` in one array, fill its first `count` rows. It consumes
        (donates) the state it is given.
      evaluate: `(TrainState, Hyperparams [R], episodes: static int, randomized: static bool)
        -> Evaluation [R, N]` (`iteration.evaluate_runs`).
    """

    config: TrainConfig
    extra: tuple[str, ...]
    init: executables.Stored
    iterate: "AloneOrTogether"
    evaluate: Callable[..., Evaluation]

    def metrics(self, rows: ArrayLike) -> Metrics:
        """`Metrics` from `iterate`'s stacked metrics.

        Args:
          rows: `[fields, ...]`, a row per field of `Metrics` and per name of `extra`.

        Returns:
          `Metrics` with numpy leaves `[...]`.
        """
        rows = np.asarray(rows)
        fields = len(Metrics._fields) - 1
        return Metrics(*rows[:fields],  # type: ignore[misc]  # (mypy lets *rows reach `extra`)
                       extra=dict(zip(self.extra, rows[fields:])))

    def hyperparams(self, runs: int) -> Hyperparams:
        """`Hyperparams` of `runs` runs as the program takes them, the config's values: `[runs]`."""
        return self.config.hyperparams.per_run(runs)

    def policy_params(self, params: Params) -> Params:
        """The policy's parameters, leaves `[..., R]`, of a `TrainState`'s `params`."""
        if self.config.hand_gradient:
            return policies.unflatten(params, cast(policies.PolicyNetwork, self.config.network))
        return params["policy"]

    def critic_params(self, params: Params) -> Params | None:
        """A loss's critic's parameters, leaves `[..., R]`, of a `TrainState`'s `params`; None
        for a loss without one."""
        return None if self.config.hand_gradient else params.get("critic")


def compiled_program(config: TrainConfig) -> Program:
    """The jitted `Program` of `config`; `iterate` consumes (donates) the state it is given.

    Its functions keep their compiled programs on disk while `executables.keep_programs` is in
    effect.

    Configs that differ only in how many iterations run, what counts as solved, the values of
    their hyperparameters (but for whether the entropy coefficient is 0: only then can the fast
    path serve, `TrainConfig.hand_gradient`) or of their physics share one: those values are the
    runs' `Hyperparams`, arguments of the program. Only the physics' static fields (the
    integrator, the reward scheme, Acrobot's equations) are the program's.

    Args:
      config: the `TrainConfig`.

    Returns:
      The `Program`, the same object for every config that shares it (up to a cache's size).
    """
    return _program(dataclasses.replace(
        config, iterations=1, solved_return=0.0, learning_rate=0.01, discount=0.95,
        entropy_coef=float(config.entropy_coef != 0),
        env=envs.program_params(config.env_params)))


# Runs are initialised once: compiled for speed of compiling, not of running (docs/performance.md).
INIT_OPTIONS: dict[str, Any] = {
    "xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}


class AloneOrTogether(NamedTuple):
    """A function whose first argument is a `TrainState`, as two functions compiled differently.

    It calls, prepares, lowers or traces the one for its arguments (`is_run_alone`).

    Attributes:
      alone: the function for a run alone (a block of one run).
      together: the function for several runs (`xla_options.WIDE_VECTORS`).
    """

    alone: executables.Stored
    together: executables.Stored

    def _for(self, train_state: TrainState) -> executables.Stored:
        """The function for `train_state`'s runs."""
        return self.alone if is_run_alone(train_state) else self.together

    def __call__(self, *args: Any) -> Any:
        """Calls the function for `args[0]`'s runs."""
        return self._for(args[0])(*args)

    def prepare(self, *args: Any) -> concurrent.futures.Future[executables.Program]:
        """Starts compiling the function for `args` (`executables.Stored.prepare`)."""
        return self._for(args[0]).prepare(*args)

    def lower(self, *args: Any) -> jax.stages.Lowered:
        """The lowered function for `args` (`jax.jit`'s `lower`)."""
        return self._for(args[0]).lower(*args)

    def eval_shape(self, *args: Any) -> Any:
        """The shapes of the function's outputs for `args` (`jax.jit`'s `eval_shape`)."""
        return self._for(args[0]).eval_shape(*args)


@functools.lru_cache(maxsize=32)
def _program(config: TrainConfig) -> Program:
    """The `Program` of a config as `compiled_program` normalises it, checked (`check_config`)."""
    extra = check_config(config)
    # A user's module, loss or optimizer is known by name only: kept by its code too.
    stored = functools.partial(executables.Stored, settings=config, by_code=not config.built_in)

    def jit_iterate(options: dict[str, Any] | None) -> jax.stages.Wrapped:
        """`_iterate_stacked` jitted with XLA's `options`, donating the state."""
        return jax.jit(functools.partial(_iterate_stacked, config, extra), donate_argnums=0,
                       compiler_options=options)

    return Program(
        config, extra,
        stored(jax.jit(functools.partial(init_runs, config), compiler_options=INIT_OPTIONS),
               "init"),
        # A block of several runs iterates with 512-bit vectors: faster, the same bits
        # (docs/performance.md). A block of one run must not: with its loop compiled whole,
        # 512-bit vectors round some of its episodes otherwise than the same run's beside others.
        AloneOrTogether(stored(jit_iterate(None), "iterate_alone"),
                        stored(jit_iterate(xla_options.WIDE_VECTORS), "iterate")),
        jax.jit(functools.partial(evaluate_runs, config),
                static_argnames=("episodes", "randomized")),
    )


def _iterate_stacked(config: TrainConfig, extra: tuple[str, ...], train_state: TrainState,
                     hyperparams: Hyperparams, count: Array) -> tuple[TrainState, Array]:
    """Up to `ITERATIONS_PER_CALL` iterations, `count` of them, with their metrics stacked.

    Returns:
      (TrainState, float `[ITERATIONS_PER_CALL, fields, R]`: the first `count` rows hold each
      iteration's metrics' leaves, the rest zeros).
    """

    def one(i: Array, carry: tuple[TrainState, Array, rollout.Records | None]
            ) -> tuple[TrainState, Array, rollout.Records | None]:
        """Iteration `i`, its metrics written into row `i` of the history, its records over the
        last iteration's, if any."""
        train_state, history, records = carry
        train_state, metrics, records = iterate(config, train_state, hyperparams, records)
        return train_state, jax.lax.dynamic_update_index_in_dim(
            history, jnp.stack(jax.tree.leaves(metrics)), i, 0), records

    history = jnp.zeros((ITERATIONS_PER_CALL, len(Metrics._fields) - 1 + len(extra),
                         *jnp.shape(hyperparams.learning_rate)), jnp.result_type(float))
    # A block's records are cleared once a call, each iteration writing over the last one's; a
    # run alone's, small, each iteration, which compiles sooner (docs/performance.md).
    records = None if is_run_alone(train_state) else initial_records(config, train_state,
                                                                     hyperparams)
    train_state, history, _ = jax.lax.fori_loop(0, jnp.minimum(count, ITERATIONS_PER_CALL), one,
                                                (train_state, history, records))
    return train_state, history
