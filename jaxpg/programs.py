"""The compiled training programs: `init` and `iterate` of a `TrainConfig`, kept by `executables`."""

import dataclasses
import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg import cartpole, executables, policies
from jaxpg.iteration import (
    Metrics,
    check_config,
    evaluate_runs,
    init_runs,
    is_run_alone,
    iterate,
)
from jaxpg.train_config import TrainConfig

ITERATIONS_PER_CALL = 10  # iterations a call of the program runs at most


class Program(NamedTuple):
    """The compiled training of R runs at once, for one `TrainConfig`: `executables.Stored`
    functions (`iterate` an `AloneOrTogether` of two), which `run` prepares before it calls them."""

    config: TrainConfig
    physics_in_runs: bool  # whether the runs' `Hyperparams` carry their physics (`env`)
    extra: tuple[str, ...]  # the names of the loss's metrics, `Metrics.extra`, in leaf order
    # (keys [R, 2], Hyperparams [R], optional policy_params of one run) -> TrainState [R]
    init: Callable
    # (TrainState [R], Hyperparams [R], count: int32 scalar) -> (TrainState [R], the metrics'
    # leaves stacked [ITERATIONS_PER_CALL, fields, R]): `count` iterations (at most
    # ITERATIONS_PER_CALL), whose metrics fill the first `count` rows; one array per call.
    iterate: Callable  # an `AloneOrTogether`
    # (TrainState [R], Hyperparams [R], episodes: static int) -> `iteration.Evaluation` [R, N]
    evaluate: Callable

    def metrics(self, rows):
        """`Metrics` from `iterate`'s stacked metrics `[fields, ...]`: leaves `[...]`."""
        rows = np.asarray(rows)
        fields = len(Metrics._fields) - 1
        return Metrics(*rows[:fields], extra=dict(zip(self.extra, rows[fields:])))

    def hyperparams(self, runs):
        """`Hyperparams` of `runs` runs as the program takes them (the config's values)."""
        hyperparams = self.config.hyperparams
        env = self.config.env_params if self.physics_in_runs else None
        return hyperparams._replace(env=env).per_run(runs)

    def policy_params(self, params):
        """The policy's parameters (leaves `[..., R]`) of a `TrainState`'s `params`."""
        if self.config.hand_gradient:
            return policies.unflatten(params, self.config.network)
        return params["policy"]


def compiled_program(config, physics_in_runs=False):
    """The jitted `Program` of `config`; `iterate` consumes (donates) the state it is given.

    Its functions keep their compiled programs on disk while `executables.keep_programs` is in effect.

    Configs that differ only in how many iterations run, what counts as solved, or the values of
    their hyperparameters (but for whether the entropy coefficient is 0: only then can the fast
    path serve, `TrainConfig.hand_gradient`) share one: those values are the runs' `Hyperparams`,
    arguments of the program. So do configs that differ in their physics, where
    `physics_in_runs`: the runs' `Hyperparams` then carry it (`env`), rather than the program
    (`train_config.compiled_physics`).
    """
    env = config.env_params
    if physics_in_runs:  # the values come with the runs' `Hyperparams`; only static fields count
        env = cartpole.V1.replace(integrator=env.integrator,
                                  sutton_barto_reward=env.sutton_barto_reward)
    return _program(dataclasses.replace(
        config, iterations=1, solved_return=0.0, learning_rate=0.01, discount=0.95,
        entropy_coef=float(config.entropy_coef != 0), env=env), physics_in_runs)


# Initialising runs once: it is compiled for speed of compilation, not of running, without
# XLA's CPU fusion emitters (about 0.1 s sooner).
INIT_OPTIONS = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
# The iteration of a block of several runs asks for 512-bit vectors (XLA's default is 256), for
# speed: 1024 seeds trained in 3.70 and 4.30 s instead of 5.50 and 5.69 s, the same bits. A block
# of one run does not, for its bits: with its loop compiled whole (`jaxpg.xla_options`), 512-bit vectors
# round some of its episodes differently from the same run's beside others (8 of the book's seeds
# 0 to 15).
TOGETHER_OPTIONS = {"xla_cpu_prefer_vector_width": 512}


class AloneOrTogether(NamedTuple):
    """A function whose first argument is a `TrainState`, as two `executables.Stored` functions
    compiled with different options: `alone` for a run alone (a block of one run), `together` for
    several runs. It calls, prepares, lowers or traces the one for its arguments."""

    alone: executables.Stored
    together: executables.Stored

    def _for(self, train_state):
        return self.alone if is_run_alone(train_state) else self.together

    def __call__(self, *args):
        return self._for(args[0])(*args)

    def prepare(self, *args):
        return self._for(args[0]).prepare(*args)

    def lower(self, *args):
        return self._for(args[0]).lower(*args)

    def eval_shape(self, *args):
        return self._for(args[0]).eval_shape(*args)


@functools.lru_cache(maxsize=32)
def _program(config, physics_in_runs):
    extra = check_config(config)
    # A user's module, loss or optimizer is known by name only, not by its code: not kept.
    stored = functools.partial(executables.Stored, settings=config, keep=config.built_in)

    def jit_iterate(options):
        return jax.jit(functools.partial(_iterate_stacked, config, extra), donate_argnums=0,
                       compiler_options=options)

    return Program(
        config, physics_in_runs, extra,
        stored(jax.jit(functools.partial(init_runs, config), compiler_options=INIT_OPTIONS),
               "init"),
        AloneOrTogether(stored(jit_iterate(None), "iterate_alone"),
                        stored(jit_iterate(TOGETHER_OPTIONS), "iterate")),
        jax.jit(functools.partial(evaluate_runs, config), static_argnames="episodes"),
    )


def _iterate_stacked(config, extra, train_state, hyperparams, count):
    def one(i, carry):
        train_state, history = carry
        train_state, metrics = iterate(config, train_state, hyperparams)
        return train_state, jax.lax.dynamic_update_index_in_dim(
            history, jnp.stack(jax.tree.leaves(metrics)), i, 0)

    history = jnp.zeros((ITERATIONS_PER_CALL, len(Metrics._fields) - 1 + len(extra),
                         *hyperparams.learning_rate.shape), jnp.result_type(float))
    return jax.lax.fori_loop(0, jnp.minimum(count, ITERATIONS_PER_CALL), one,
                             (train_state, history))
