"""The `jaxpg` command: train | sweep | evaluate | render | compare | conformance | reproduce.

Every argument is checked before anything compiles; a bad one ends the command with status 2 and
one line on stderr, never a traceback. `main` is the installed command; `run_command` runs one
command in this process and returns its exit status.
"""

import argparse
import atexit
import contextlib
import dataclasses
import fractions
import logging
import os
import pathlib
import re
import signal
import socket
import sys
import tempfile
import threading
import time
import types
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, NoReturn, TextIO, cast

if TYPE_CHECKING:  # (the commands import numpy and jaxpg's modules when they run: `main`)
    import numpy as np

    from jaxpg.evaluation import Robustness
    from jaxpg.train_config import TrainConfig
    from jaxpg.types import Params, Policy

PROG = "jaxpg"  # the command's name, which its messages start with
# The book's figures, which `jaxpg reproduce` prints beside jaxpg's.
BOOK_BASIC_POLICY = (41.698, 8.389445512070509, 24.0, 63.0)  # mean, std, min, max, as printed
BOOK_DISCOUNT = [-22.0, -40.0, -50.0]
BOOK_NORMALIZED = [[-0.28435071, -0.86597718, -1.18910299], [1.26665318, 1.0727777]]
BOOK_LAST_ITERATION = 199.6  # "Iteration: 150/150, mean rewards: 199.6"


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr and exit status 2, no usage.

    A value that starts with a minus and a digit is a value, `--gravity -1e3` included (older
    Pythons' argparse took only `-1` and `-1.5` for numbers, and `-1e3` for an unknown flag).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\.?\d")

    def error(self, message: str) -> NoReturn:
        """Exits with status 2 and `message` on one line."""
        self.exit(2, f"{self.prog}: error: {message}\n")


# --- Argument types: each raises a one-line error naming what is allowed ---------------------


def _int_list(text: str) -> tuple[int, ...]:
    """`32,32` as integers; `''` as none (no hidden layer)."""
    if not text.strip():
        return ()  # `--hidden ''`: no hidden layer
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}") from None


def _float_list(text: str) -> list[float]:
    """`0.003,0.01` as floats."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}") from None


_BYTES = re.compile(r"(\d+(?:\.\d+)?)\s*([KMGT]?)(?:I?B)?", re.IGNORECASE)
_BYTE_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def _bytes(text: str) -> int:
    """`2G`, `512MB`, `1.5GiB` or plain bytes, as a number of bytes (K, M, G, T: powers of 1024)."""
    match = _BYTES.fullmatch(text.strip())
    # Exactly, as a fraction: a float would overflow to infinity on a long number.
    size = fractions.Fraction(match[1]) * _BYTE_UNITS[match[2].upper()] if match else 0
    if size < 1 or size.denominator != 1:  # (not 1000000.9 bytes cut to 1000000)
        raise argparse.ArgumentTypeError(
            f"expected a positive whole number of bytes such as 2G, 512M or 1000000, got {text!r}")
    return int(size)


def _physics(text: str) -> tuple[float, float] | list[float]:
    """`0.5,1,2` (values: a sweep's axis) or `0.25:2.0` (a range to draw from per episode)."""
    low, colon, high = text.partition(":")
    if colon:
        try:
            return float(low), float(high)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a range LOW:HIGH, got {text!r}") from None
    return _float_list(text)


def _add_physics_args(parser: argparse.ArgumentParser, ranges: bool = True) -> None:
    """Adds a flag per physics field of any environment (`--length`, ...): values, and ranges
    where `ranges`; `_physics_settings` refuses one that `--env` does not have."""
    for name in _physics_fields():
        if ranges:
            parser.add_argument(f"--{name.replace('_', '-')}", type=_physics,
                                metavar="V[,V...]|LOW:HIGH",
                                help=f"{name}: values, or a range drawn per episode")
        else:
            parser.add_argument(f"--{name.replace('_', '-')}", type=_float_list,
                                metavar="V[,V...]",
                                help=f"{name}: values; every combination of the flags' values "
                                "is a setting")


def _env_names() -> list[str]:
    """The names `--env` takes."""
    from jaxpg import envs

    return list(envs.MODULES)


def _physics_fields() -> dict[str, None]:
    """The physics fields of every environment, CartPole's first, each once."""
    from jaxpg import envs

    return dict.fromkeys(name for module in envs.MODULES.values()
                         for name in envs.physics(module))


def _physics_settings(
        args: argparse.Namespace, env_params: Any = None,
) -> tuple[dict[str, list[float]], dict[str, tuple[float, float]]]:
    """({field: values} of the physics flags, {field: (low, high)} of their ranges).

    Raises:
      ValueError: naming the flag of a field that the environment (`env_params`, by default
        that of `--env`) does not have.
    """
    from jaxpg import envs

    given = {name: getattr(args, name) for name in _physics_fields()
             if getattr(args, name, None) is not None}
    module = envs.module_of(envs.resolve(args.env if env_params is None else env_params))
    physics = envs.physics(module)
    for name in given:
        if name not in physics:
            raise ValueError(f"--{name.replace('_', '-')}: {module.NAME} has no field {name}; "
                             f"its fields: {', '.join(physics)}")
    return ({name: v for name, v in given.items() if isinstance(v, list)},
            {name: v for name, v in given.items() if isinstance(v, tuple)})


def _add_training_args(parser: argparse.ArgumentParser) -> None:
    """Adds the flags that `train` and `sweep` share, with `TrainConfig`'s defaults."""
    from jaxpg.losses import BUILT_IN
    from jaxpg.train_config import TrainConfig

    d = TrainConfig()
    parser.add_argument("--iterations", type=int, default=d.iterations,
                        help="updates (default %(default)s)")
    parser.add_argument("--episodes", type=int, default=d.episodes,
                        help="episodes per update (default %(default)s)")
    parser.add_argument("--max-steps", type=int, default=None,
                        help="steps per episode (default: the environment's time limit; 200 on "
                        "CartPole, the book's)")
    parser.add_argument("--optimizer", default=d.optimizer,
                        help="an optax optimizer (default %(default)s)")
    parser.add_argument("--hidden", type=_int_list, default=d.hidden,
                        help="hidden layer sizes, e.g. 5 or 32,32; '' for a linear policy "
                        "(default 5)")
    parser.add_argument("--loss", choices=list(BUILT_IN), default=d.loss,
                        help="(default %(default)s)")
    parser.add_argument("--epochs", type=int, default=d.epochs,
                        help="passes over each update's episodes (default %(default)s)")
    parser.add_argument("--minibatches", type=int, default=d.minibatches,
                        help="minibatches of whole episodes per pass (default %(default)s)")
    parser.add_argument("--activation", default=d.activation,
                        help="hidden activation (default %(default)s)")
    parser.add_argument("--env", default=d.env,
                        help=f"{', '.join(_env_names())} (default %(default)s)")
    parser.add_argument("--solved-return", type=float, default=None,
                        help="mean return that counts as solved (default: the environment's; "
                        "195 on CartPole, the book's)")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    parser.add_argument("--no-cache", action="store_true",
                        help="compile afresh; keep no compiled programs")
    _add_physics_args(parser)


def _config(args: argparse.Namespace, **hyperparams: Any) -> "TrainConfig":
    """The `TrainConfig` of the training flags and the ranges of the physics flags."""
    from jaxpg.train_config import TrainConfig

    return TrainConfig(
        iterations=args.iterations,
        episodes=args.episodes,
        max_steps=args.max_steps,
        hidden=args.hidden,
        activation=args.activation,
        optimizer=args.optimizer,
        loss=args.loss,
        epochs=args.epochs,
        minibatches=args.minibatches,
        env=args.env,
        randomize=_physics_settings(args)[1],
        solved_return=args.solved_return,
        **hyperparams,
    )


def _enable_compilation_cache(disabled: bool, whole_programs: bool = False) -> None:
    """Keeps compiled programs in the user's cache directory, unless `disabled` (`--no-cache`).

    The next process then skips compiling them. `train` and `sweep` compile nothing but the
    training programs and keep them whole (`whole_programs`, `executables`): a later process
    neither traces nor compiles them. `reproduce` uses JAX's persistent compilation cache.
    One process never uses both (`executables` says why).
    """
    if disabled:
        return
    from jaxpg import executables

    cache = executables.cache_home() / "jaxpg"
    if whole_programs:
        executables.keep_programs(cache / "programs")
        return
    import jax

    from jaxpg import atomic_files

    try:
        with tempfile.TemporaryFile(dir=atomic_files.private_directory(cache / "xla")):
            pass  # permissions alone do not tell (a read-only file system, root)
    except OSError as error:  # JAX would warn of each entry, as if damaged
        print(f"{PROG}: warning: keeping no compiled programs in {cache / 'xla'}: it cannot be "
              f"used ({error.strerror})", file=sys.stderr)
        return
    jax.config.update("jax_compilation_cache_dir", str(cache / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def _run_index(text: str) -> tuple[int, int]:
    """`g,s`: run (g, s) of a sweep, seed s under grid setting g (both counted from 0)."""
    try:
        g, s = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected g,s (two integers), got {text!r}") from None
    return g, s


def _load_policies(
        spec: str, run: tuple[int, int] | None = None,
) -> tuple["Policy | Params", "TrainConfig | None", str]:
    """The policies of `--policy` (and `--run`).

    Args:
      spec: `basic`, or a directory or file written by `jaxpg train` or `jaxpg sweep`.
      run: optional: (g, s), one run of a sweep's.

    Returns:
      (the basic policy, or parameters stacked `[G, S, ...]` (`[1, 1, ...]` for one run); the
      config they were trained with (their module and environment), or None for the basic
      policy; a description for the output).

    Raises:
      ValueError: `spec` names no checkpoint that loads, or `run` is given for the basic policy
        or names no run of the sweep's.
    """
    import jax

    from jaxpg import checkpoint, policies

    expected = "expected 'basic' or a checkpoint written by jaxpg train or sweep"
    if not spec:
        raise ValueError(f"policy: {expected}, got an empty path")
    if spec == "basic":
        if run is not None:
            raise ValueError("run: only for a sweep's policies, not for basic")
        return policies.basic_policy, None, "the basic angle policy"
    if not pathlib.Path(spec).exists():
        raise ValueError(f"policy: {expected}, {spec} does not exist")
    loaded = checkpoint.load(spec)
    if loaded.grid is not None and run is None:
        seeds = cast("np.ndarray", loaded.seeds)  # (a sweep's: given with its grid)
        return (loaded.policy_params, loaded.config,
                f"the {len(loaded.grid)} x {len(seeds)} policies in {spec}")
    if run is not None:
        loaded = checkpoint.select_run(loaded, *run)
        spec = f"run {run[0]},{run[1]} of {spec}"
    return (jax.tree.map(lambda leaf: leaf[None, None], loaded.policy_params),
            loaded.config, f"the policy in {spec}")


def _one_policy(policies: "Policy | Params", config: "TrainConfig | None") -> "Policy | None":
    """The policy of `_load_policies`'s parameters of one run; None where they hold several."""
    import jax

    from jaxpg.policies import network_policy

    if config is None:
        return policies
    if jax.tree.leaves(policies)[0].shape[:2] != (1, 1):
        return None
    return network_policy(config.network, jax.tree.map(lambda leaf: leaf[0, 0], policies),
                          num_actions=config.num_actions)


def _load_policy(spec: str, run: tuple[int, int] | None = None
                 ) -> tuple["Policy", "TrainConfig | None", str]:
    """One policy of `_load_policies`: (policy, config, description).

    Raises:
      ValueError: as `_load_policies`, or `spec` holds a sweep's runs and `run` is None.
    """
    policies, config, description = _load_policies(spec, run)
    policy = _one_policy(policies, config)
    if policy is None:
        raise ValueError(f"run: {spec} holds a sweep's runs; choose one with --run g,s")
    return policy, config, description


def _policy_env(env: str | None, config: "TrainConfig | None", spec: str) -> Any:
    """The environment to play: `--env`, else the policy's own (CartPole-v1 for basic).

    Raises:
      ValueError: naming `env` where it is another environment than the policy's.
    """
    from jaxpg import envs

    if env is None:
        return config.env if config else "CartPole-v1"
    own = config.env_module if config else envs.MODULES["CartPole-v1"]
    if envs.module_of(envs.resolve(env)) is not own:
        raise ValueError(f"env: {spec} plays {config.env_name if config else 'CartPole'}, "
                         f"got {env}")
    return env


# --- Commands --------------------------------------------------------------------------------


def cmd_train(args: argparse.Namespace) -> None:
    """`jaxpg train`: trains one policy and writes its checkpoint, metrics and learning curve.

    Writes `policy.msgpack`, `metrics.json`, `metrics.csv` and `learning_curve.png` into
    `args.out`, all at once (`atomic_files.staged`).

    Args:
      args: the parsed arguments of `build_parser`.

    Raises:
      ValueError: a bad argument, before anything is written or compiled.
    """
    import numpy as np

    from jaxpg import atomic_files, budget, checkpoint, plots
    from jaxpg.reinforce import first_nonfinite
    from jaxpg.sweeps import last_mean, train
    from jaxpg.validation import check_int

    config = _config(args, learning_rate=args.lr, discount=args.discount,
                     entropy_coef=args.entropy_coef)
    values = _physics_settings(args)[0]
    for name, given in values.items():
        if len(given) != 1:
            raise ValueError(f"{name}: train takes one value (a sweep takes several), got {given}")
    if values:
        config = dataclasses.replace(config, env=config.env_params.replace(
            **{name: given[0] for name, given in values.items()}))
    check_int("seed", args.seed, 0, 2**32)
    budget.check(config)  # before anything is written, traced or allocated
    # Held until the results are in place: a second run is refused.
    out = atomic_files.claim(args.out)
    _enable_compilation_cache(args.no_cache, whole_programs=True)
    plots.load_in_background()
    start = time.perf_counter()
    result = train(config, seed=args.seed, show_progress=not args.quiet)
    seconds = time.perf_counter() - start
    metrics = {name: np.asarray(v) for name, v in result.metrics.columns().items()}
    final = float(last_mean(result.metrics.mean_return))
    diverged = int(first_nonfinite(result.metrics))  # train() has warned of it
    with atomic_files.staged(out) as stage:
        checkpoint.save(stage / checkpoint.FILENAME, result.policy_params, config, result.metrics,
                        critic_params=result.critic_params)
        summary = {"seed": args.seed, "config": checkpoint.config_to_dict(config),
                   "last_10_mean_return": final, "seconds": seconds,
                   "first_nonfinite_iteration": diverged if diverged >= 0 else None,
                   "metrics": metrics}
        atomic_files.write_json(stage / "metrics.json", summary)
        atomic_files.write_csv(stage / "metrics.csv",
                               {"iteration": np.arange(config.iterations), **metrics})
        plots.learning_curve(result.metrics, stage / "learning_curve.png",
                             title=f"REINFORCE on {_env_name(config)}, seed {args.seed}")
    print(f"mean return over the last 10 iterations: {final:.1f} "
          f"(final iteration {metrics['mean_return'][-1]:.1f}); {seconds:.1f} s")
    print(f"wrote {out}/: {checkpoint.FILENAME}, metrics.json, metrics.csv, learning_curve.png")


def _join_processes(args: argparse.Namespace) -> bool:
    """Joins the other processes of a sweep over several hosts; JAX must not have started yet.

    Args:
      args: the parsed arguments of `jaxpg sweep`: `--coordinator`, `--num-processes` and
        `--process-id`, all given or none, and `--coordinator-timeout`.

    Returns:
      True when this process writes the results: the only one, or process 0 of several.

    Raises:
      ValueError: the three flags are not given together, or one is out of range, or (process
        1 and up) nothing answers at the coordinator's address within the timeout. Process 0,
        whose wait for the others happens inside JAX, ends with status 2 and one line when they
        have not all joined within the timeout (JAX itself would abort with a C++ dump).
    """
    from jaxpg.validation import check_int

    check_int("coordinator_timeout", args.coordinator_timeout, 1, 2**31)  # (given alone too)
    flags = (args.coordinator, args.num_processes, args.process_id)
    if all(flag is None for flag in flags):
        return True
    if any(flag is None for flag in flags):
        raise ValueError(
            "coordinator: give --coordinator, --num-processes and --process-id together, or none")
    host, _, port = args.coordinator.rpartition(":")
    # ASCII digits alone: int() reads others too ("١٢٣٤"), which JAX's server cannot bind.
    if not host or not (port.isascii() and port.isdigit()) or not 0 < int(port) < 2**16:
        raise ValueError(f"coordinator: expected HOST:PORT with PORT in [1, 65535], "
                         f"got {args.coordinator!r}")
    check_int("num_processes", args.num_processes)
    if not 0 <= args.process_id < args.num_processes:
        raise ValueError(f"process_id: must be in [0, {args.num_processes}), got {args.process_id}")
    if args.process_id > 0:  # JAX would wait, then abort with a C++ dump
        _reach(host.strip("[]"), int(port), args.coordinator_timeout)
    import jax

    # JAX's own timeout, later than ours, never comes: a thread ends the process in one line.
    watcher = threading.Timer(args.coordinator_timeout, _give_up_joining, (args,))
    watcher.daemon = True
    watcher.start()
    jax.distributed.initialize(coordinator_address=args.coordinator,
                               num_processes=args.num_processes, process_id=args.process_id,
                               initialization_timeout=args.coordinator_timeout + 30)
    watcher.cancel()
    return args.process_id == 0


def _give_up_joining(args: argparse.Namespace) -> NoReturn:
    """Ends the process with status 2 and one line: the processes did not all join in time."""
    print(f"{PROG} {args.command}: error: coordinator: the {args.num_processes} processes did not "
          f"all join at {args.coordinator} within {args.coordinator_timeout} s "
          f"(--coordinator-timeout)", file=sys.stderr, flush=True)
    os._exit(2)


def _reach(host: str, port: int, timeout: int) -> None:
    """Waits until a TCP connection to `host:port` opens, for at most `timeout` seconds.

    Raises:
      ValueError: in one line naming the address, when none opened in time.
    """
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        try:
            socket.create_connection((host, port), timeout=max(left, 0.1)).close()
            return
        except OSError as error:
            if left <= 0:
                raise ValueError(f"coordinator: nothing answered at {host}:{port} within "
                                 f"{timeout} s ({error.strerror or error})") from None
        time.sleep(min(1.0, max(left, 0.0)))


def cmd_sweep(args: argparse.Namespace) -> None:
    """`jaxpg sweep`: trains seeds 0 to N-1 under every grid setting, and compares the settings.

    Writes `metrics.npz`, `runs.csv`, `summary.json`, `sweep.png`, `policies.msgpack` and, where
    there are two seeds or more, the comparison report (`report.write`) into `args.out`, all at
    once (`atomic_files.staged`). Over several processes (`--coordinator`), process 0 alone writes.

    Args:
      args: the parsed arguments of `build_parser`.

    Raises:
      ValueError: a bad argument, before anything is written or compiled.
    """
    writes_results = _join_processes(args)  # first: it must come before JAX computes anything
    import numpy as np

    from jaxpg import atomic_files, checkpoint, plots
    from jaxpg.sweeps import check_arguments, sweep
    from jaxpg.validation import check_int

    check_int("seeds", args.seeds)
    config = _config(args, learning_rate=args.lr[0], discount=args.discount[0],
                     entropy_coef=args.entropy_coef[0])
    grid = {"learning_rate": args.lr, "discount": args.discount, "entropy_coef": args.entropy_coef,
            **_physics_settings(args)[0]}
    # Before anything is written, traced or allocated.
    check_arguments(config, range(args.seeds), grid, args.memory_budget, args.eval_episodes,
                    args.eval_physics)
    # After the checks: they import scipy, which is slow to import.
    from jaxpg import report, results
    out = (atomic_files.claim if writes_results else atomic_files.check_out_dir)(args.out)
    _enable_compilation_cache(args.no_cache, whole_programs=True)
    if writes_results:
        plots.load_in_background()
    start = time.perf_counter()
    swept = sweep(config, seeds=range(args.seeds), grid=grid, show_progress=not args.quiet,
                  memory_budget=args.memory_budget, eval_episodes=args.eval_episodes,
                  eval_physics=args.eval_physics)
    seconds = time.perf_counter() - start
    if not writes_results:
        return
    # The folder is in place before a failing report (a diverged run's scores) is raised.
    comparison: dict[str, Any] | ValueError | None
    try:
        comparison = results.save_sweep(swept, out, seconds)
    except results.ReportRefused as error:
        comparison = error
    s = swept.summary
    held_out = {name: np.median(returns.mean(axis=-1), axis=1)
                for name, returns in results.held_out(swept).items()}
    for g, (label, solved, final) in enumerate(
            zip(map(report.setting_label, swept.grid), s.fraction_solved,
                np.median(s.final_return, axis=1))):
        beside = "".join(f", {name.replace('_', ' ')} {medians[g]:.1f}"
                         for name, medians in held_out.items())
        print(f"{label}: median last-10 mean return {final:.1f}{beside}, solved {solved:.0%} of "
              f"{args.seeds} seeds")
    print(f"{s.final_return.size} runs in {seconds:.1f} s; wrote {out}/: metrics.npz, runs.csv, "
          f"summary.json, sweep.png, {checkpoint.SWEEP_FILENAME}")
    if comparison is None:
        print("no comparison report: its confidence intervals need at least 2 seeds")
        return
    if isinstance(comparison, ValueError):  # the runs are written: the report is what is missing
        print(f"no comparison report: {comparison}")
        return
    print(report.format_report(comparison))
    print(f"wrote {out}/: {', '.join((report.COMPARISON_FILE, *report.PLOT_FILES))}")


def cmd_compare(args: argparse.Namespace) -> None:
    """`jaxpg compare`: compares the settings of sweep folders, with bootstrap confidence intervals.

    Prints the comparison and writes it, with its plots, into `args.out` (`report.write`).

    Args:
      args: the parsed arguments of `build_parser`.

    Raises:
      ValueError: a bad argument, or a folder that holds no sweep's results.
    """
    from jaxpg import report

    comparison = report.write(args.folders, args.out, args.confidence, args.reps, args.seed)
    print(report.format_report(comparison))
    print(f"wrote {args.out}/: {', '.join((report.COMPARISON_FILE, *report.PLOT_FILES))}")


def cmd_evaluate(args: argparse.Namespace) -> None:
    """`jaxpg evaluate`: plays policies' episodes and prints the statistics of their returns.

    One policy in one physics setting, without `--out`, plays in jaxpg or Gymnasium
    (`evaluation.evaluate`); otherwise every policy in every setting of the physics flags plays in
    jaxpg (`evaluation.robustness`), and `--out` gets robustness.json, .csv and .png.

    Args:
      args: the parsed arguments of `build_parser`.

    Raises:
      ValueError: a bad argument, before anything is written or compiled.
    """
    import numpy as np

    from jaxpg import atomic_files, envs
    from jaxpg.evaluation import evaluate, physics_label, physics_settings, robustness

    policies, config, description = _load_policies(args.policy, args.run)
    args.env = _policy_env(args.env, config, args.policy)
    env_params = envs.resolve(args.env)
    if not isinstance(args.env, str):  # the checkpoint's own physics
        args.env = f"{config.env_name if config else 'CartPole-v1'} (the policy's physics)"
    values = _physics_settings(args, env_params)[0]
    settings = physics_settings(values, env_params)
    if args.max_steps is None:
        args.max_steps = envs.max_steps(env_params)
    # Every episode ends at the time limit: the steps played, said and recorded.
    args.max_steps = min(args.max_steps, int(env_params.max_steps))
    policy = _one_policy(policies, config)
    if policy is not None and len(settings) == 1 and args.out is None:
        with _chunk_progress(args) as on_chunk:
            stats = evaluate(policy, episodes=args.episodes, max_steps=args.max_steps,
                             env=env_params.replace(**settings[0]), seed=args.seed,
                             backend=args.backend, on_chunk=on_chunk)
        print(f"{description} over {args.episodes} episodes of at most {args.max_steps} steps "
              f"in {args.backend} {args.env} ({physics_label(settings[0])}):")
        print(f"mean {stats.mean:.3f}  std {stats.std:.3f}  min {stats.min:g}  "
              f"max {stats.max:g}")
        return
    if args.backend != "jaxpg":
        raise ValueError("backend: gymnasium plays one policy in one physics setting; several "
                         "policies, settings or --out are played in jaxpg")
    if args.out is not None:
        _check_not_replaced(args.out, args.policy)
        atomic_files.claim(args.out)  # held until the results are in place: a second is refused
    with _chunk_progress(args) as on_chunk:
        result = robustness(policies, values, episodes=args.episodes, max_steps=args.max_steps,
                            seed=args.seed, network=config.network if config else None,
                            env=env_params, on_chunk=on_chunk)
    print(f"{description} over {args.episodes} episodes of at most {args.max_steps} steps in "
          f"jaxpg {args.env}, median (mean) return over every policy's episodes:")
    for label, returns in zip(result.labels, result.pooled):
        print(f"  {label}: {np.median(returns):g} ({returns.mean():.1f})")
    if args.out is not None:
        with atomic_files.staged(args.out) as stage:
            _write_robustness(stage, result, values, args)
        print(f"wrote {args.out}/: robustness.json, robustness.csv, robustness.png")


def _check_not_replaced(out: str, policy: str) -> None:
    """A ValueError naming `out` where it holds the checkpoint `policy`, which writing `out` would
    replace (nothing for the basic policy)."""
    from jaxpg import atomic_files

    if policy != "basic":
        atomic_files.check_not_replacing(out, policy, "the policies evaluated", "the results")


def _chunk_progress(args: argparse.Namespace
                    ) -> contextlib.AbstractContextManager[Callable[[int], None] | None]:
    """The progress of `evaluate`'s (or `robustness`'s) chunks where the episodes play in
    several, unless --quiet; otherwise None."""
    from jaxpg import progress
    from jaxpg.evaluation import chunk_episodes

    if (args.quiet or args.backend != "jaxpg" or min(args.episodes, args.max_steps) < 1
            or chunk_episodes(args.episodes, args.max_steps) == args.episodes):
        return contextlib.nullcontext()
    return progress.count(args.episodes, "episodes")


def _write_robustness(folder: pathlib.Path, result: "Robustness",
                      values: Mapping[str, Sequence[float]], args: argparse.Namespace) -> None:
    """Writes the `result` of `jaxpg evaluate` into `folder`.

    robustness.json holds the arguments and the statistics, robustness.csv a row per policy and
    setting, and robustness.png the median return per setting (`_median_table`).

    Args:
      folder: an existing directory.
      result: the returns of every policy in every setting.
      values: the physics flags' values, as `evaluation.robustness` took them.
      args: the parsed arguments of `jaxpg evaluate`.
    """
    import numpy as np

    from jaxpg import atomic_files, plots

    median = np.median(result.pooled, axis=1)
    atomic_files.write_json(folder / "robustness.json", {
        "policy": args.policy, "run": args.run, "env": args.env, "episodes": args.episodes,
        "max_steps": args.max_steps, "seed": args.seed, "settings": result.settings,
        "median_per_setting": median, "mean_per_setting": result.pooled.mean(axis=1),
        "median": result.median, "mean": result.mean,  # [G, S, P]
    })
    cells = np.indices(result.mean.shape).reshape(3, -1)  # (g, s, p) of every cell, in order
    atomic_files.write_csv(folder / "robustness.csv", {
        "g": cells[0], "s": cells[1],
        **{name: [result.settings[p][name] for p in cells[2]] for name in result.settings[0]},
        **{name: getattr(result, name).ravel() for name in ("mean", "median", "std", "min", "max")},
    })
    table, rows, columns, across = _median_table(median, result.settings, values)
    num_policies = result.returns.shape[0] * result.returns.shape[1]
    plots.return_heatmap(table, rows, columns, folder / "robustness.png", args.max_steps,
                         xlabel=across, title=f"median return of {num_policies} policies x "
                         f"{args.episodes} episodes")


def _median_table(
        median: "np.ndarray", settings: Sequence[Mapping[str, float]],
        values: Mapping[str, Sequence[float]],
) -> tuple["np.ndarray", list[str], list[str], str | None]:
    """The median return per physics setting as a table, for a heatmap.

    The last flag's values go across, the combinations of the others down (one cell without
    flags).

    Args:
      median: float `[P]` medians, one per setting, in the order of `settings`.
      settings: the `P` settings, `{field: value}`, the last flag's values varying fastest.
      values: the physics flags' values by field.

    Returns:
      (the medians `[rows, columns]`, row labels, column labels, the field the columns vary or
      None).
    """
    from jaxpg.evaluation import physics_label

    across = list(values)[-1] if values else None
    # (`across` names a flag wherever `values` holds one.)
    columns = values[across] if values else [None]  # type: ignore[index]
    rows = [physics_label({name: value for name, value in setting.items() if name != across},
                          "all")
            for setting in settings[::len(columns)]]
    labels = [f"{value:g}" if across else "default physics" for value in columns]
    return median.reshape(len(rows), len(columns)), rows, labels, across


def cmd_render(args: argparse.Namespace) -> None:
    """`jaxpg render`: draws one episode of a policy in its environment as an animation (GIF or
    MP4).

    Args:
      args: the parsed arguments of `build_parser`.

    Raises:
      ValueError: a bad argument, before anything is drawn.
    """
    from jaxpg import animation, envs
    from jaxpg.validation import check_int

    animation.check_animation_path(args.out, "out")
    policy, config, description = _load_policy(args.policy, args.run)
    check_int("seed", args.seed, 0, 2**32)
    env_params = envs.resolve(_policy_env(args.env, config, args.policy))
    max_steps = envs.max_steps(env_params) if args.max_steps is None else args.max_steps
    frames = animation.render_episode(policy, seed=args.seed, env_params=env_params,
                                      max_steps=max_steps)
    animation.save_animation(frames, args.out)
    print(f"wrote {args.out}: {description}, {len(frames) - 1} steps")


def cmd_conformance(args: argparse.Namespace) -> int:
    """`jaxpg conformance`: steps one task in jaxpg and Gymnasium, compares every step, prints it.

    Args:
      args: the parsed arguments of `build_parser`.

    Returns:
      0 where the comparison passes (`ok` of `conformance.check`'s report), 1 otherwise.
    """
    from jaxpg.envs import conformance

    report = conformance.check(args.env, args.episodes, args.states, args.seed)
    print(report.format())
    return 0 if report.ok else 1


def cmd_reproduce(args: argparse.Namespace) -> None:
    """`jaxpg reproduce`: prints the book's numbers beside jaxpg's (`BOOK_*`).

    The basic policy's returns, the discounting examples, and REINFORCE with the book's settings.

    Args:
      args: the parsed arguments of `build_parser`.

    Raises:
      ValueError: a bad seed, before anything compiles.
    """
    import numpy as np

    from jaxpg import policies, returns
    from jaxpg.evaluation import evaluate, gymnasium_reset_states
    from jaxpg.sweeps import last_mean, train
    from jaxpg.train_config import TrainConfig
    from jaxpg.validation import check_int

    check_int("seed", args.seed, 0, 2**32)
    _enable_compilation_cache(args.no_cache)
    print("Basic policy, 500 episodes of 200 steps from Gymnasium's reset(seed=episode):")
    states = gymnasium_reset_states(500)
    stats = evaluate(policies.basic_policy, 500, 200, init_states=states)
    _beside("mean, std, min, max", (stats.mean, stats.std, stats.min, stats.max), BOOK_BASIC_POLICY)
    print("Discounting:")
    _beside("discount_rewards([10, 0, -50], 0.8)", returns.discount_rewards([10, 0, -50], 0.8),
            BOOK_DISCOUNT)
    normalized = returns.discount_and_normalize_rewards([[10, 0, -50], [10, 20]], 0.8)
    _beside("discount_and_normalize_rewards([[10, 0, -50], [10, 20]], 0.8)",
            [np.round(np.asarray(n), 8).tolist() for n in normalized], BOOK_NORMALIZED)
    print(f"REINFORCE with the book's settings, seed {args.seed}:")
    result = train(TrainConfig(), seed=args.seed, show_progress=not args.quiet)
    mean_return = np.asarray(result.metrics.mean_return)
    _beside("mean rewards at the last iteration", round(float(mean_return[-1]), 1),
            BOOK_LAST_ITERATION)
    print(f"  mean over the last 10 iterations: {last_mean(mean_return):.1f}")


def _beside(what: str, ours: Any, book: Any) -> None:
    """Prints `what` jaxpg gives and what the book gives, one under the other."""
    print(f"  {what}:\n    jaxpg: {_fmt(ours)}\n    book:  {_fmt(book)}")


def _fmt(value: Any) -> str:
    """`value` as text; an array as a list."""
    import numpy as np

    return str(np.asarray(value).tolist() if hasattr(value, "shape") else value)


def _env_name(config: "TrainConfig") -> str:
    """The environment's name for a title."""
    return config.env if isinstance(config.env, str) else f"{config.env_name} (custom)"


# --- Parser ----------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The parser of the `jaxpg` command line: a subcommand and its flags.

    Returns:
      A parser whose namespaces hold `command` (the subcommand's name), `handler` (its `cmd_*`
      function) and the subcommand's flags. A bad command line exits with status 2 and one line.
    """
    parser = _Parser(prog=PROG,
                     description="Policy gradients on CartPole, exact and fast, in JAX.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = commands.add_parser("train", help="train one policy with REINFORCE")
    _add_training_args(p)
    p.add_argument("--seed", type=int, default=42, help="(default %(default)s)")
    p.add_argument("--lr", type=float, default=0.01, help="learning rate (default %(default)s)")
    p.add_argument("--discount", type=float, default=0.95, help="(default %(default)s)")
    p.add_argument("--entropy-coef", type=float, default=0.0,
                   help="weight of the entropy bonus (default %(default)s)")
    p.add_argument("--out", default="runs/train", help="output directory (default %(default)s)")
    p.set_defaults(handler=cmd_train)

    p = commands.add_parser("sweep", help="train many seeds and hyperparameters at once")
    _add_training_args(p)
    p.add_argument("--seeds", type=int, default=64, help="seeds 0..N-1 (default %(default)s)")
    p.add_argument("--lr", type=_float_list, default=[0.01],
                   help="learning rates, e.g. 0.003,0.01")
    p.add_argument("--discount", type=_float_list, default=[0.95],
                   help="discounts, e.g. 0.9,0.95")
    p.add_argument("--entropy-coef", type=_float_list, default=[0.0],
                   help="entropy bonus weights, e.g. 0,0.01")
    p.add_argument("--out", default="runs/sweep", help="output directory (default %(default)s)")
    p.add_argument("--eval-episodes", type=int, default=0, help="held-out episodes each run's "
                   "final policy plays, sampled and greedy (default none)")
    p.add_argument("--eval-physics", choices=["training", "base"], default="training",
                   help="held-out episodes in each run's training physics, ranges drawn as in "
                   "training, or in its base physics without them (default %(default)s)")
    p.add_argument("--memory-budget", type=_bytes, help="memory per device for training, e.g. 2G; "
                   "the runs train in chunks that fit it (default: all at once)")
    p.add_argument("--coordinator", help="HOST:PORT of process 0, to sweep over several hosts")
    p.add_argument("--num-processes", type=int, help="processes taking part, one per host")
    p.add_argument("--process-id", type=int,
                   help="this process's number, 0 to N-1; 0 writes the results")
    p.add_argument("--coordinator-timeout", type=int, default=60,
                   help="seconds to wait for the other processes (default %(default)s)")
    p.set_defaults(handler=cmd_sweep)

    p = commands.add_parser("evaluate", help="evaluate a policy in jaxpg or in Gymnasium, or many "
                            "policies in many physics settings")
    p.add_argument("--policy", default="basic", help="basic, or a directory written by jaxpg train "
                   "or jaxpg sweep (all its runs, or one with --run)")
    p.add_argument("--run", type=_run_index, help="g,s: one run of a sweep, seed s of setting g")
    p.add_argument("--out", help="a directory for robustness.json, .csv and .png (median return "
                   "per physics setting)")
    p.add_argument("--episodes", type=int, default=500)
    p.add_argument("--max-steps", type=int, help="the longest an episode runs, at most the "
                   "environment's time limit (default: that limit; 200 on CartPole, the book's)")
    p.add_argument("--backend", default="jaxpg", help="jaxpg or gymnasium (default %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env", help="an environment of the policy's kind (default: the policy's own; "
                   "CartPole-v1 for basic)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress output (shown where the episodes play in chunks)")
    _add_physics_args(p, ranges=False)
    p.set_defaults(handler=cmd_evaluate)

    p = commands.add_parser("render", help="draw an episode as a GIF (or MP4)")
    p.add_argument("--policy", default="basic", help="basic, or a directory written by jaxpg train "
                   "or jaxpg sweep (with --run)")
    p.add_argument("--run", type=_run_index, help="g,s: one run of a sweep, seed s of setting g")
    p.add_argument("--out", default="cartpole.gif",
                   help="a .gif or .mp4 path (default %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-steps", type=int, help="the most steps drawn (default: the "
                   "environment's time limit; 200 on CartPole, the book's)")
    p.add_argument("--env", help="an environment of the policy's kind (default: the policy's own; "
                   "CartPole-v1 for basic)")
    p.set_defaults(handler=cmd_render)

    p = commands.add_parser("compare", help="compare the settings of sweep folders, with "
                            "confidence intervals")
    p.add_argument("folders", nargs="+", metavar="DIR",
                   help="folders written by jaxpg sweep --out")
    p.add_argument("--out", default="runs/compare", help="output directory (default %(default)s)")
    p.add_argument("--confidence", type=float, default=0.95,
                   help="interval coverage (default %(default)s)")
    p.add_argument("--reps", type=int, default=2000,
                   help="bootstrap resamples, 50 to 100000 (default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="seeds the bootstrap (default %(default)s)")
    p.set_defaults(handler=cmd_compare)

    p = commands.add_parser("conformance",
                            help="compare jaxpg with Gymnasium's environment step by step")
    p.add_argument("--env", default="CartPole-v1",
                   help="the environment's Gymnasium id (default %(default)s)")
    p.add_argument("--episodes", type=int, default=None,
                   help="CartPole: episodes per variant, below 65536 (default 100)")
    p.add_argument("--states", type=int, default=None,
                   help="the other environments: states drawn per variant, below 2**24 "
                        "(default 10000)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(handler=cmd_conformance)

    p = commands.add_parser("reproduce", help="the book's numbers beside jaxpg's")
    p.add_argument("--seed", type=int, default=42)
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--no-cache", action="store_true",
                   help="compile afresh; keep no compiled programs")
    p.set_defaults(handler=cmd_reproduce)
    return parser


def run_command(argv: Sequence[str] | None = None) -> int:
    """Runs one `jaxpg` command in this process and returns its exit status.

    Unlike `main`, it leaves the process's XLA setting, warnings and signals as they are.

    Args:
      argv: the command line after `jaxpg` (`["train", "--seed", "1"]`); by default `sys.argv[1:]`.

    Returns:
      0 on success; 2 for a bad argument (one line on stderr); 130 where interrupted; or the
      command's own status (`cmd_conformance`).

    Raises:
      SystemExit: with status 2, for a command line the parser refuses; with status 0 for `--help`.
    """
    return _execute(build_parser().parse_args(argv))


def _execute(args: argparse.Namespace) -> int:
    """Runs the command of `args`: its status, 2 after a one-line error, 130 where interrupted."""
    from jaxpg import atomic_files

    try:
        with atomic_files.claims_released():
            return args.handler(args) or 0
    except (ValueError, OSError) as error:
        print(f"{PROG} {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        with _saying:  # one line, whether this thread or `_watch_ctrl_c`'s says it
            print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
            _said.set()
        return 130


def _runs_at_once(args: argparse.Namespace) -> int | None:
    """How many runs the command trains in this process at most at once.

    None where it trains none, or shares them with other processes.
    """
    if args.command in ("train", "reproduce"):
        return 1
    if args.command == "sweep" and args.num_processes is None and args.seeds >= 1:
        return args.seeds * len(args.lr) * len(args.discount)
    return None


def _interrupt(signum: int, frame: types.FrameType | None) -> NoReturn:
    """Ctrl-C: stops the command once, and ignores any later one while it ends.

    During an import it ends the process at once (`_end`): raised there, a KeyboardInterrupt can
    fail a compiled extension's initialisation, which then raises an ImportError or aborts.

    Raises:
      KeyboardInterrupt: which `schedule.train_blocks` passes on only when its workers have
        stopped.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if _importing(frame):
        _end(130, f"{' '.join(_command)}: interrupted")
    raise KeyboardInterrupt


def _importing(frame: types.FrameType | None) -> bool:
    """Whether `frame` or one of its callers runs Python's import machinery."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib."):
            return True
        frame = frame.f_back
    return False


def _unraisable(unraisable: "sys.UnraisableHookArgs") -> None:  # (a name of the stubs alone)
    """Reports an exception that Python could not raise as Python does, unless a KeyboardInterrupt.

    A KeyboardInterrupt raised where exceptions are only reported (a garbage collector's callback,
    seen during tracing) is dropped without a word: raised again from this hook, it would be
    reported, traceback and all. The command then ends `_GRACE` seconds after Ctrl-C
    (`_watch_ctrl_c`).
    """
    if not issubclass(unraisable.exc_type, KeyboardInterrupt):
        sys.__unraisablehook__(unraisable)


_UNREADABLE_CACHE = "Error reading persistent compilation cache entry"


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: TextIO | None = None, line: str | None = None) -> None:
    """Shows a warning as one line on stderr (`warnings.showwarning`).

    JAX warns of each unreadable entry of its compilation cache; the command warns once, of the
    cache.
    """
    text = str(message)
    if text.startswith(_UNREADABLE_CACHE):
        import jax

        warnings.filterwarnings("ignore", message=_UNREADABLE_CACHE)
        # (JAX's stubs declare none of its flags as attributes of `jax.config`.)
        cache_dir = jax.config.jax_compilation_cache_dir  # type: ignore[attr-defined]
        text = (f"the compilation cache in {cache_dir} holds "
                f"unreadable entries, compiled afresh each time; delete it to rebuild it "
                f"(first: {text})")
    print(f"{PROG}: warning: {text}", file=sys.stderr)


# How matplotlib's log starts the lines of a cache directory it cannot use: it then keeps a
# temporary one, and the command has said already that the cache cannot be used (`executables`).
_MATPLOTLIB_CACHE = ("mkdir -p failed for path ", "%s is not a writable directory",
                     "Matplotlib created a temporary cache directory ")


def _not_of_matplotlibs_cache(record: logging.LogRecord) -> bool:
    """Whether matplotlib's log shows `record`: any but its lines of an unusable cache."""
    return not str(record.msg).startswith(_MATPLOTLIB_CACHE)


_GRACE = 1.0  # seconds the command has to end itself after Ctrl-C, before it is ended
_ending = threading.Lock()  # held by whichever thread ends the process
_command = [PROG]  # how the "interrupted" line names the command, once it is parsed
_saying = threading.Lock()  # held while the "interrupted" line is said
_said = threading.Event()  # set once the command has said it


def _end(status: int, line: str | None = None) -> NoReturn:
    """Ends the process at once with `status`, after `line` on stderr; once, from any thread.

    At once: threads still compiling would be waited for at exit.
    """
    _ending.acquire()  # never released: a second caller waits for the end
    if line is not None:
        print(line, file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


def _watch_ctrl_c() -> None:
    """Ends the process `_GRACE` seconds after Ctrl-C, if the command has not ended itself.

    A thread reads the signal from the wakeup file of the signal module, which it receives even
    while the main thread runs a compiled program and cannot run the Python handler. From then on
    no output folder is replaced (`atomic_files.cancel`), so the one given stays as it was even
    where the KeyboardInterrupt was lost. Only from the main thread, before any other import of
    jaxpg's.
    """
    read, write = os.pipe()
    os.set_blocking(write, False)
    signal.set_wakeup_fd(write, warn_on_full_buffer=False)

    def watch() -> None:
        while os.read(read, 1) != bytes([signal.SIGINT]):
            pass
        from jaxpg import atomic_files

        atomic_files.cancel()
        time.sleep(_GRACE)
        with _saying:
            _end(130, None if _said.is_set() else f"{' '.join(_command)}: interrupted")

    threading.Thread(target=watch, daemon=True, name="jaxpg-ctrl-c").start()


def main(argv: Sequence[str] | None = None) -> NoReturn:
    """The installed `jaxpg` command: runs one command, then exits with its status.

    As `run_command`, in a process given jaxpg's XLA setting for the runs the command trains
    (`xla_options.configure_xla`), one-line warnings, and Ctrl-C, at any moment, ending it within
    `_GRACE` seconds with status 130 and one line, its output folder left as it was.

    Args:
      argv: the command line after `jaxpg`; by default `sys.argv[1:]`.

    Raises:
      SystemExit: with the command's exit status (as `run_command`). After Ctrl-C the process
        ends at once instead (`os._exit`, status 130), waiting for no thread still compiling.
    """
    try:  # (a Ctrl-C even before the handler is in place raises KeyboardInterrupt here)
        signal.signal(signal.SIGINT, _interrupt)  # first: Ctrl-C during the imports too
        # Python's shutdown, after the last exit handler (this one, registered first), gives
        # Ctrl-C its default action, which would end the finished command by the signal.
        atexit.register(signal.signal, signal.SIGINT, signal.SIG_IGN)
        _watch_ctrl_c()
        from jaxpg import xla_options

        sys.unraisablehook = _unraisable
        warnings.showwarning = _show_warning
        logging.getLogger("matplotlib").addFilter(_not_of_matplotlibs_cache)
        args = build_parser().parse_args(argv)
        _command[1:] = [args.command]
        xla_options.configure_xla(runs=_runs_at_once(args))
        status = _execute(args)  # (it says "interrupted" itself)
    except KeyboardInterrupt:
        _end(130, f"{' '.join(_command)}: interrupted")
    if status == 130:
        _end(status)
    sys.exit(status)


if __name__ == "__main__":
    main()
