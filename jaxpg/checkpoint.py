"""Saving and loading trained policies with the configuration that trained them.

A checkpoint is one file, by convention `policy.msgpack` (the name `jaxpg train --out DIR` writes
and `load(DIR)` reads), or `policies.msgpack` for every run of a sweep (`jaxpg sweep --out DIR`),
holding a msgpack map written by `flax.serialization.msgpack_serialize`:

    format          "jaxpg-checkpoint": marks the file as a jaxpg checkpoint
    format_version  an integer, bumped when the layout changes; a reader refuses newer versions:
                    3 (earlier ones below)
    sha256          the SHA-256 digest of `content`, as 64 lowercase hex digits
    content         the msgpack bytes of a map of the fields below, checked against `sha256`
                    before they are read: a flipped bit anywhere in the file is refused

The content's fields:

    jaxpg_version   the `jaxpg.__version__` that wrote the file, e.g. "0.1.0"
    config          the `TrainConfig` as a map of its fields; `hidden` is a list, `env` is
                    either a preset name ("CartPole-v1") or a map of `CartPoleParams` fields,
                    and `policy`, `loss` and `optimizer` are nil or a name, or, for a user's
                    module or function, a map {"object": its qualified name, "repr": ...}:
                    `load` then takes the object itself from the caller
    policy_params   the flax state dict of the policy network, e.g.
                    {"params": {"Dense_0": {"kernel": [4, 5], "bias": [5]}, "Dense_1": {...}}},
                    arrays stored as flax's msgpack ndarray extension (dtype, shape, raw bytes),
                    float32 or float64 (a diverged run's hold NaNs)
    metrics         nil, or a map of `Metrics` fields to float32 or float64 arrays (`[I]`
                    per-iteration statistics), `extra` a map of the loss's own metrics
    critic_params   nil, or the flax state dict of the loss's critic (`losses.critic`: the
                    "baseline" and "ppo" losses' value network), stored as `policy_params`;
                    absent from files written before it was added, which load without one
    runs            a sweep's only: {"grid": its G settings (maps of field to number), "seeds":
                    its S seeds, in [0, 2**32)}; every array of `policy_params`, `metrics` and
                    `critic_params` then holds every run's, `[G, S, ...]`, run (g, s) being seed s
                    under setting g

Versions 1 (one run) and 2 (a sweep's runs, with `runs`), written by earlier jaxpg, hold the
content's fields in the file's map itself, beside `format` and `format_version`, with no checksum;
they load unchecked.

Any msgpack reader can open the file, then its content; flax's `msgpack_restore` turns the arrays
back into numpy.

It is written with `atomic_files.atomic_write`: a crash mid-write leaves the previous file intact.
"""

import dataclasses
import functools
import hashlib
import os
import pathlib
import warnings
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, NamedTuple, TypedDict, cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from jaxpg import (
    atomic_files,
    cartpole,
    envs,
    iteration,
    losses,
    policies,
    safe_read,
    train_config,
)
from jaxpg.types import Params
from jaxpg.validation import check_int, check_number, is_int, shown

if TYPE_CHECKING:
    from jaxpg import sweeps

FORMAT = "jaxpg-checkpoint"
FORMAT_VERSION = 3  # the version written, and the newest this reads
_CHECKED_VERSION = 3  # the first version whose content is checked against its sha256
# A bound on the file read: above any sweep's, whose 1,000 seeds x 100 settings x 10,000
# iterations of 6 float32 metrics take 2.4e10 bytes.
_MAX_BYTES = 2**36
FILENAME = "policy.msgpack"
SWEEP_FILENAME = "policies.msgpack"


class Checkpoint(NamedTuple):
    """A loaded checkpoint."""

    policy_params: dict  # the policy network's parameters, as jax arrays
    config: train_config.TrainConfig  # the config that trained it
    version: str  # the jaxpg version that wrote it
    metrics: iteration.Metrics | None  # the run's metrics `[I]`, where they were saved
    # A sweep's G settings {field: value}; its arrays are then `[G, S, ...]`.
    grid: list[dict[str, float]] | None = None
    seeds: np.ndarray | None = None  # a sweep's S seeds, int64
    # The loss's critic's parameters (`losses.critic`), as jax arrays shaped as `policy_params`'s;
    # None for a loss without one, or a file saved without them.
    critic_params: dict | None = None


class SweepRuns(TypedDict):
    """The runs of a sweep's checkpoint (its `runs` entry): run (g, s) is seed s under setting g."""

    grid: list[dict[str, float]]  # the G settings, maps of field to number
    seeds: list[int]  # the S seeds


# --- Saving --------------------------------------------------------------------------------------


def save(
    path: str | pathlib.Path,
    policy_params: Params,
    config: train_config.TrainConfig,
    metrics: iteration.Metrics | None = None,
    runs: SweepRuns | None = None,
    critic_params: Params | None = None,
) -> pathlib.Path:
    """Saves a policy with its `TrainConfig` (and optionally its metrics) as one file, atomically.

    Args:
      path: the file to write, or a directory to write `policy.msgpack` in (for a sweep,
        `policies.msgpack`): an existing one, or a path ending in a separator (`"runs/best/"`).
        Missing directories are created.
      policy_params: the policy network's parameters (`TrainResult.policy_params` of one run).
      config: the `TrainConfig` that describes the network.
      metrics: optional `Metrics` of the run.
      runs: for a sweep's runs (`save_sweep`), `{"grid": G settings, "seeds": S seeds}`;
        `policy_params`, `metrics` and `critic_params` then hold every run's, `[G, S, ...]`.
      critic_params: optional parameters of the loss's critic (`TrainResult.critic_params`),
        which `load` gives back to warm-start it (`train(..., init_critic_params=...)`).

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for an empty `path`, one of something else than a regular file (a device, a
        FIFO: `atomic_files.check_replaceable`) or one inside a folder of jaxpg's results (a
        `jaxpg train` or `sweep` folder: `atomic_files.check_outside_results`), a `config` that is
        no `TrainConfig`, `metrics` that are no `Metrics` or of other iterations than
        `config.iterations`, a whole `TrainResult` given as parameters, parameters of other
        shapes than `config`'s network's (or its loss's critic's) or not float32 or float64
        (which `load` refuses), critic parameters for a loss without a critic, or a config field
        that cannot be saved.
      OSError: where the file cannot be created (`atomic_files.atomic_path`).
    """
    if not isinstance(config, train_config.TrainConfig):
        raise ValueError(f"config: expected a TrainConfig, got {type(config).__name__}")
    if metrics is not None and not isinstance(metrics, iteration.Metrics):
        raise ValueError(f"metrics: expected a Metrics or None, got {type(metrics).__name__}")
    lengths = sorted({np.shape(leaf)[-1] if np.ndim(leaf) else 0
                      for leaf in jax.tree.leaves(metrics)})
    if lengths and lengths != [config.iterations]:
        raise ValueError(f"metrics: expected {config.iterations} iterations (config's) in every "
                         f"field, got {', '.join(map(str, lengths))}")
    _check_params_match(policy_params, config, "policy_params", _grid_shape(runs))
    _check_floats(_state_dict(policy_params), "policy_params")  # what `load` reads back
    if critic_params is not None:
        _check_params_match(critic_params, config, "critic_params", _grid_shape(runs))
        _check_floats(_state_dict(critic_params), "critic_params")
    path = _target(path, FILENAME if runs is None else SWEEP_FILENAME)
    atomic_files.check_outside_results(path, "path")  # one folder, one result
    content = serialization.msgpack_serialize({
        "jaxpg_version": _jaxpg_version(),
        "config": config_to_dict(config),
        "policy_params": _state_dict(policy_params),
        "metrics": None if metrics is None else jax.tree.map(np.asarray, metrics._asdict()),
        "critic_params": None if critic_params is None else _state_dict(critic_params),
        **({} if runs is None else {"runs": runs}),
    })
    payload = {"format": FORMAT, "format_version": FORMAT_VERSION,
               "sha256": hashlib.sha256(content).hexdigest(), "content": content}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_files.atomic_write(path, serialization.msgpack_serialize(payload))
    return path


def _state_dict(params: Params) -> dict[str, Any]:
    """A network's parameters as flax's state dict of numpy arrays, as the file holds them."""
    return jax.tree.map(np.asarray, serialization.to_state_dict(params))


def _target(path: str | os.PathLike[str], name: str) -> pathlib.Path:
    """The file `save` writes: `path`, or `path/name` for a directory, an existing one or one
    named with a final separator (which `pathlib.Path` would drop)."""
    text = _path_text(path)
    separators = tuple(sep for sep in (os.sep, os.altsep) if sep)
    if text.endswith(separators) or pathlib.Path(text).is_dir():
        return pathlib.Path(text) / name
    return pathlib.Path(text)


def _path_text(path: Any) -> str:
    """`path` as text; a ValueError naming `path` unless it is a non-empty `str` or
    `os.PathLike` of one (an empty one would name the working directory)."""
    text = os.fspath(path) if isinstance(path, str | os.PathLike) else None
    if not isinstance(text, str):
        raise ValueError(f"path: expected a file or a directory, got {type(path).__name__}")
    if not text:
        raise ValueError("path: expected a file or a directory, got an empty path")
    return text


def save_sweep(
    path: str | pathlib.Path, swept: "sweeps.SweepResult",
    config: train_config.TrainConfig | None = None,
) -> pathlib.Path:
    """Saves every run of a sweep (`SweepResult`) in one file, `[G, S, ...]` (`save`'s `runs`),
    with its critic's parameters where its loss has a critic.

    Args:
      path: the file to write, or an existing directory to write `policies.msgpack` in.
      swept: the sweep's result.
      config: the `TrainConfig` that the sweep shared; by default the result's own.

    Returns:
      The `pathlib.Path` written: `path`, or `path/policies.msgpack` for a directory.

    Raises:
      ValueError: naming `config` where neither it nor the result has one.
    """
    config = swept.config if config is None else config
    if config is None:
        raise ValueError("config: the sweep's result carries none; pass its TrainConfig")
    runs = SweepRuns(grid=[{name: float(value) for name, value in setting.items()}
                           for setting in swept.grid],
                     seeds=[int(seed) for seed in swept.seeds])
    return save(path, swept.policy_params, config, swept.metrics, runs, swept.critic_params)


def _grid_shape(runs: SweepRuns | None) -> tuple[int, ...]:
    """The leading axes `(G, S)` of a sweep's arrays (`save`'s `runs`), `()` for one run."""
    return () if runs is None else (len(runs["grid"]), len(runs["seeds"]))


def _jaxpg_version() -> str:
    """The version of jaxpg that writes the file."""
    import jaxpg  # (the package of this module: imported by now)

    return jaxpg.__version__


def config_to_dict(config: train_config.TrainConfig) -> dict[str, Any]:
    """A `TrainConfig` as plain msgpack-able values (the `config` entry of a checkpoint).

    Args:
      config: the config.

    Returns:
      Its fields by name, as the module's docstring lays out the `config` entry.

    Raises:
      ValueError: naming the field, for a number that is an array rather than a scalar.
    """
    fields: dict[str, Any] = {}
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if field.name == "hidden":
            value = [int(size) for size in value]
        elif field.name == "randomize":
            value = {name: list(bounds) for name, bounds in value}
        elif field.name in _OBJECTS:
            value = _describe(value)
        elif field.name == "env" and not isinstance(value, str):
            # CartPole's physics by their fields alone, another environment's with its id.
            module = envs.module_of(value)
            value = {
                **({} if module is cartpole else {"id": module.NAME}),
                **{name: _scalar(getattr(value, name), f"config.env.{name}")
                   for name in type(value).__dataclass_fields__},
            }
        else:
            value = _scalar(value, f"config.{field.name}")
        fields[field.name] = value
    return fields


def _scalar(value: Any, name: str) -> str | bool | int | float:
    """A Python scalar from a number, or a 0-d numpy/jax array."""
    if isinstance(value, (str, bool, int, float)):
        return value
    value = np.asarray(value)
    if value.ndim != 0:
        raise ValueError(f"{name}: must be a scalar to be saved, got shape {value.shape}")
    return value.item()


# Fields that may hold a user's object (a module, a function): saved as a description, given back
# to `load` by the caller, whose code defines them.
_OBJECTS = ("policy", "loss", "optimizer")


def _describe(value: Any) -> str | dict[str, str] | None:
    """A config field's value as saved: None or a name as it is; an object as its description.

    The description is the class or function's qualified name, and its repr (with its fields, for
    a flax module).
    """
    if value is None or isinstance(value, str):
        return value
    # A function or class is named itself; anything else (a module, a partial) by its type.
    is_named = hasattr(value, "__qualname__") and not hasattr(value, "__dataclass_fields__")
    kind = value if is_named else type(value)
    return {"object": f"{kind.__module__}.{kind.__qualname__}", "repr": repr(value)}


def _require_objects(fields: object, objects: Mapping[str, Any]) -> None:
    """Raises a ValueError naming a field saved as a user's object that `objects` lacks, or gives
    as another class or function (by qualified name), or a field saved as jaxpg's own that
    `objects` gives (it would be ignored)."""
    for name in _OBJECTS:
        saved = fields.get(name) if isinstance(fields, dict) else None
        given = objects.get(name)
        if not isinstance(saved, dict):
            # (a config without the field is damaged: `config_from_dict` says so)
            if given is not None and given != saved and isinstance(fields, dict) and name in fields:
                built_in = "the built-in network" if saved is None else repr(saved)
                raise ValueError(f"{name}: the checkpoint was trained with {built_in}, not a "
                                 f"user's {name}; pass no {name}")
            continue
        expected = saved.get("object")
        if given is None:
            raise ValueError(f"{name}: the checkpoint was trained with {expected}; pass it: "
                             f"checkpoint.load(path, {name}=...)")
        described = _describe(given)
        got = described["object"] if isinstance(described, dict) else repr(described)
        if got != expected:
            raise ValueError(f"{name}: the checkpoint was trained with {expected}, got {got}")


def check_config_dict(fields: Any) -> None:
    """Raises a ValueError unless `fields` is a config entry that `config_from_dict` takes, each
    user's object (saved as its description, `_describe`) aside: a `TrainConfig`'s fields."""
    if not isinstance(fields, Mapping):
        raise ValueError(f"expected the config's fields, got {type(fields).__name__}")
    try:
        config_from_dict({name: value for name, value in fields.items()
                          if not (name in _OBJECTS and isinstance(value, dict))})
    except (TypeError, KeyError) as error:  # a field of the wrong kind, deep down
        raise ValueError(f"{type(error).__name__}: {error}") from None


def config_from_dict(
    fields: Mapping[str, Any], objects: Mapping[str, Any] | None = None
) -> train_config.TrainConfig:
    """The `TrainConfig` of a checkpoint's `config` entry.

    Args:
      fields: the entry.
      objects: the policy module, loss or optimizer function by field name, for the fields saved
        as a description of the user's object; a ValueError names the field where one is missing.

    Returns:
      The config.

    Raises:
      ValueError: for a user's object missing from `objects`, an unknown field, or a field that
        `TrainConfig` refuses.
    """
    fields = dict(fields)
    objects = objects or {}
    _require_objects(fields, objects)
    for name in _OBJECTS:
        if isinstance(fields.get(name), dict):
            fields[name] = objects[name]
    unknown = set(fields) - {f.name for f in dataclasses.fields(train_config.TrainConfig)}
    if unknown:
        raise ValueError(f"unknown config field(s) {', '.join(sorted(unknown))}")
    if isinstance(fields.get("env"), dict):
        env = dict(fields["env"])
        preset = envs.resolve(env.pop("id", "CartPole-v1"))
        fields["env"] = type(preset)(**env)
    if "hidden" in fields:
        fields["hidden"] = tuple(fields["hidden"])
    return train_config.TrainConfig(**fields)


def _check_params_match(
    params: Params, config: train_config.TrainConfig, where: str, lead: tuple[int, ...] = ()
) -> None:
    """Raises a ValueError unless `params` has the shapes of `config`'s policy's own, or for
    `where="critic_params"`, of its loss's critic's (`losses.critic`).

    The shapes are compared after the leading axes `lead` (a sweep's `(G, S)`).
    """
    if hasattr(params, "policy_params"):  # a `TrainResult` given whole
        raise ValueError(f"{where}: expected parameters, got a {type(params).__name__}; pass "
                         f"its .{where}")
    critic = where == "critic_params"
    network = losses.critic(config.loss) if critic else config.network
    if network is None:
        raise ValueError(f"{where}: the loss {config.loss!r} has no critic")
    shapes = jax.tree.map(np.shape, serialization.to_state_dict(params))
    want = jax.tree.map(lambda leaf: (*lead, *leaf.shape), jax.eval_shape(
        lambda key: policies.init_network(key, network, config.env_module.OBS_SIZE),
        jax.ShapeDtypeStruct((2,), np.uint32)))
    if shapes != want:
        raise ValueError(
            f"{where}: parameters do not fit the {'critic' if critic else 'policy'} "
            f"{type(network).__name__}; expected shapes {want}, got {shapes}"
        )


# --- Loading -------------------------------------------------------------------------------------


def resolve(path: str | pathlib.Path) -> pathlib.Path:
    """The checkpoint file that `path` names.

    Args:
      path: a file, or a directory.

    Returns:
      The path itself, or `DIR/policy.msgpack`, or where that is missing, a sweep's
      `DIR/policies.msgpack` (which `load` reads only if it is a regular file).

    Raises:
      FileNotFoundError: there is no such file.
      ValueError: naming `path`, for an empty path (not the working directory) or one that is
        no `str` or `os.PathLike`.
    """
    path = pathlib.Path(_path_text(path))
    if path.is_dir():
        path = path / (SWEEP_FILENAME if (path / SWEEP_FILENAME).exists()
                       and not (path / FILENAME).exists() else FILENAME)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such checkpoint file")
    return path


def load(
    path: str | pathlib.Path,
    policy: nn.Module | None = None,
    loss: losses.LossFn | None = None,
    optimizer: train_config.OptimizerFactory | None = None,
) -> Checkpoint:
    """Loads a checkpoint written by `save`.

    Args:
      path: a checkpoint file, or a directory holding `policy.msgpack` or a sweep's
        `policies.msgpack`.
      policy, loss, optimizer: the objects that trained it where they were a user's own (a flax
        module, functions), which the checkpoint names but cannot hold: the same module class
        with the same fields (its parameters are checked against it), and the functions, of the
        qualified names the checkpoint holds.

    Returns:
      `Checkpoint(policy_params, config, version, metrics, grid, seeds, critic_params)`: for a
      sweep's file, the arrays `[G, S, ...]` and its grid and seeds (`select_run` takes one run);
      else grid and seeds are None. `critic_params` are the loss's critic's where they were
      saved (`train(config, init_params=..., init_critic_params=...)` starts from both), else
      None.

    Raises:
      FileNotFoundError: there is no such file.
      ValueError: `path` is empty or no path (`resolve`); the file is no regular file, truncated,
        damaged (its content does not match its checksum), not a jaxpg checkpoint, from a newer
        format version, trained with another class or function than the one given (or with
        jaxpg's own network, loss or optimizer where one is given), or holds
        weights or metrics that are not float32 or float64 arrays, or seeds out of [0, 2**32);
        the message names the path and the field.

    Warns:
      RuntimeWarning: naming the path, where the weights of a run hold NaN or infinity (a
        diverged run's: its policy's actions mean nothing).
    """
    path = resolve(path)
    payload = _unpack(safe_read.read_bytes(path, _MAX_BYTES), path)
    if payload.get("format") != FORMAT:
        raise ValueError(f"{path}: not a jaxpg checkpoint (no {FORMAT!r} format marker)")
    format_version = payload.get("format_version")
    if type(format_version) is not int or format_version < 1:  # (not a bool, an int subclass)
        raise ValueError(
            f"{path}: not a jaxpg checkpoint (bad format_version {format_version!r})"
        )
    if format_version > FORMAT_VERSION:
        writer = payload.get("jaxpg_version")  # (in the file's map up to version 2)
        raise ValueError(
            f"{path}: checkpoint format version {format_version} is newer than this jaxpg reads "
            f"(up to {FORMAT_VERSION}); upgrade jaxpg"
            + ("" if writer is None else f" (the file was written by jaxpg {writer})"))
    fields = _unseal(payload, path) if format_version >= _CHECKED_VERSION else payload
    objects = {"policy": policy, "loss": loss, "optimizer": optimizer}
    _require_objects(fields.get("config"), objects)
    try:
        version = str(fields["jaxpg_version"])
        config = config_from_dict(fields["config"], objects)
        grid, seeds = _read_runs(fields.get("runs"), config)
        lead = () if grid is None else (len(grid), len(cast(np.ndarray, seeds)))
        policy_params = _read_params(fields["policy_params"], config, "policy_params", lead)
        critic_params = None if fields.get("critic_params") is None else _read_params(
            fields["critic_params"], config, "critic_params", lead)
        metrics = fields.get("metrics")
        if metrics is not None:
            _check_floats(metrics, "metrics")
            metrics = iteration.Metrics(**{k: jax.tree.map(jnp.asarray, v)
                                           for k, v in metrics.items()})
    except (AttributeError, KeyError, RecursionError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: damaged jaxpg checkpoint ({type(e).__name__}: {e})") from None
    _warn_if_diverged(fields["policy_params"], lead, path)
    return Checkpoint(policy_params, config, version, metrics, grid, seeds, critic_params)


def _read_params(params: object, config: train_config.TrainConfig, where: str,
                 lead: tuple[int, ...]) -> dict:
    """A network's parameters as a file holds them (`where`: "policy_params" or
    "critic_params"), as jax arrays, once their types and shapes are checked (`_check_floats`,
    `_check_params_match`)."""
    _check_floats(params, where)
    loaded = jax.tree.map(jnp.asarray, params)
    _check_params_match(loaded, config, where, lead)
    return loaded


def _unpack(data: bytes, path: pathlib.Path) -> dict[Any, Any]:
    """The msgpack map of `data`; a ValueError naming `path` for anything else."""
    try:
        payload = serialization.msgpack_restore(data)
    except Exception as e:  # msgpack raises several unrelated types on bad input
        reason = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__  # (some say nothing)
        raise ValueError(f"{path}: not a jaxpg checkpoint (unreadable msgpack, {reason})") from None
    if not isinstance(payload, dict):
        raise ValueError(f"{path}: not a jaxpg checkpoint (no msgpack map)")
    return payload


def _unseal(payload: dict[Any, Any], path: pathlib.Path) -> dict[Any, Any]:
    """The content's fields of a checked version's file, once they match its checksum."""
    content, digest = payload.get("content"), payload.get("sha256")
    if not isinstance(content, bytes) or not isinstance(digest, str):
        raise ValueError(f"{path}: damaged jaxpg checkpoint (its content or sha256 is missing)")
    if hashlib.sha256(content).hexdigest() != digest:
        raise ValueError(f"{path}: damaged jaxpg checkpoint (the content does not match its "
                         f"sha256 checksum)")
    return _unpack(content, path)


def _read_runs(runs: Any, config: train_config.TrainConfig
               ) -> tuple[list[dict[str, float]] | None, np.ndarray | None]:
    """A sweep's `runs` entry as (its G settings, its `[S]` int64 seeds); (None, None) for none.

    Raises:
      ValueError: naming the entry, for a setting's value that is not a finite number, settings
        that a sweep of `config` would not train (`sweeps.expand_grid`: an unknown field, a
        repeated setting, a value out of range), or seeds that are not distinct, in [0, 2**32).
    """
    from jaxpg import sweeps

    if runs is None:
        return None, None
    grid = [{name: check_number(f"runs.grid[{g}].{name}", value)
             for name, value in dict(setting).items()} for g, setting in enumerate(runs["grid"])]
    seeds = np.array([check_int("runs.seeds", seed, 0, 2**32) for seed in runs["seeds"]],
                     np.int64)
    sweeps.expand_grid(config, grid)
    sweeps.check_seeds(seeds)
    return grid, seeds


def _warn_if_diverged(policy_params: dict, lead: tuple[int, ...], path: pathlib.Path) -> None:
    """Warns, naming `path`, where the weights of a run (of `[*lead, ...]` arrays) are not all
    finite."""
    diverged = np.zeros(lead, bool)
    for leaf in jax.tree.leaves(policy_params):
        diverged |= ~np.isfinite(leaf).all(axis=tuple(range(len(lead), leaf.ndim)))
    if diverged.any():
        whose = "the weights" if not lead else (
            f"the weights of {diverged.sum()} of {diverged.size} runs")
        warnings.warn(f"{path}: {whose} hold NaN or infinity (training diverged); such a "
                      f"policy's actions mean nothing", RuntimeWarning, stacklevel=3)


def select_run(loaded: Checkpoint, g: int, s: int) -> Checkpoint:
    """Run (g, s) of a sweep's checkpoint: seed `loaded.seeds[s]` under setting `loaded.grid[g]`.

    Args:
      loaded: a sweep's checkpoint, as `load` gives it.
      g: the index of the setting, in [0, G).
      s: the index of the seed, in [0, S).

    Returns:
      A `Checkpoint` of that one run (its policy's, metrics and critic's), its config with the
      run's own hyperparameters and physics.

    Raises:
      ValueError: naming `loaded` for anything but a `Checkpoint`, naming `run` for a checkpoint
        of one run or a run outside the sweep.
    """
    if not isinstance(loaded, Checkpoint):
        raise ValueError(f"loaded: expected a Checkpoint (checkpoint.load's), got "
                         f"{type(loaded).__name__}")
    if loaded.grid is None:
        raise ValueError("run: the checkpoint holds one run, not a sweep's")
    grid_shape = (len(loaded.grid), len(cast(np.ndarray, loaded.seeds)))  # a sweep's: both set
    if not all(is_int(i) and 0 <= i < n for i, n in zip((g, s), grid_shape)):
        raise ValueError(f"run: expected g in [0, {grid_shape[0]}) and s in "
                         f"[0, {grid_shape[1]}), integers, got g={shown(g)}, s={shown(s)}")
    setting = loaded.grid[g]
    physics = {name: setting[name] for name in loaded.config.physics if name in setting}
    hyperparams: dict[str, Any] = {
        name: setting[name] for name in train_config.HYPERPARAMETERS if name in setting}
    config = dataclasses.replace(
        loaded.config,
        **hyperparams,
        env=loaded.config.env_params.replace(**physics) if physics else loaded.config.env)
    run = functools.partial(jax.tree.map, lambda leaf: leaf[g, s])
    return Checkpoint(run(loaded.policy_params), config, loaded.version,
                      None if loaded.metrics is None else run(loaded.metrics),
                      critic_params=None if loaded.critic_params is None
                      else run(loaded.critic_params))


_FLOAT_DTYPES = (np.float32, np.float64)


def _check_floats(tree: object, name: str) -> None:
    """Raises a ValueError naming the first leaf of `tree` that is not a float32 or float64 array.

    NaNs and infinities are allowed: a diverged run's parameters and metrics hold them.
    """
    if not isinstance(tree, dict):
        raise ValueError(f"{name}: expected a map, got {type(tree).__name__}")
    for key, leaf in tree.items():
        where = f"{name}.{key}"
        if isinstance(leaf, dict):
            _check_floats(leaf, where)
        elif not isinstance(leaf, np.ndarray) or leaf.dtype not in _FLOAT_DTYPES:
            got = leaf.dtype if isinstance(leaf, np.ndarray) else type(leaf).__name__
            raise ValueError(f"{where}: expected float32 or float64 values, got {got}")
