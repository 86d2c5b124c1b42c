"""Programs compiled ahead of their first call, and kept on disk whole.

A later process that finds a program kept neither traces nor compiles it.

XLA compiles without holding Python's lock. `Stored.prepare` traces and lowers a program in the
calling thread and compiles it on another, so that the caller can go on to trace the next program
(`schedule.prepare`: `init` is traced and compiled while `iterate`, the longer, compiles).

JAX's persistent compilation cache saves XLA's compiling, but a process that looks a program up
there still traces and lowers the Python function to find its key. A `Stored` function keeps the
compiled executable itself, under a key of everything that decides it: the function's name and
settings, its arguments' structure, shapes, dtypes and devices, jaxpg's own source, the versions
of jax and jaxlib, the backend, JAX's configuration and `XLA_FLAGS`.

Nothing is kept until `keep_programs` names a directory, and nothing that JAX's persistent cache
supplied: an executable loaded from a file loses some of its kernels when it is serialised again,
so only programs that XLA compiled in this process are kept, and none while JAX's cache is on. A
file that cannot be loaded is compiled again and replaced; a directory that cannot be created or
written (a cache home that is a file, or read-only) means only that nothing is kept, with one
warning.

A kept program is read back without running any of the file's code: nothing is unpickled
(`jax.experimental.serialize_executable` pickles, and unpickling runs whatever the file asks).
A file holds

    jaxpg-program 2\n     the format's marker and version
    digest\n              the sha256, in hex, of every byte that follows it: header and payload
    header\n              JSON: the sha256 of the program's key, which of the arguments' leaves
                          the executable takes (XLA drops unused ones), and the outputs: their
                          tree (tuples, lists, dicts, None and named tuples of modules already
                          imported) and each one's shape and dtype
    payload               XLA's executable, as XLA serialises it (`Client.serialize_executable`)

Every byte that decides what runs is under the digest: a header edited (its arguments or outputs)
is as damaged as a payload. A file of another format, another key (another program's) or another
digest, or something other than a file in its place, is warned about once, compiled again and
replaced: the results are those of a process that found no file. A loaded program (`_Kept`) runs
XLA's executable on the call's arrays and builds the outputs' tree around its results.

The executable is machine code: whoever can write the directory can make the user run code. The
directories are created for the user alone (0700), and one that is another user's, or that others
can write, is not used.
"""

import concurrent.futures
import functools
import hashlib
import json
import logging
import os
import pathlib
import shutil
import sys
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, cast

import jax
import jax.numpy as jnp
import jaxlib
import numpy as np

# (What jax.experimental.serialize_executable loads with, and the array type its results take.)
from jax._src import array as jax_array
from jax._src.lib import xla_client

from jaxpg import atomic_files

logger = logging.getLogger(__name__)

# A compiled program: a `jax.stages.Compiled`, a `_Kept` one, or (for arguments on several
# devices) the jitted function itself.
Program = Callable[..., Any]
# What tells programs apart: (the directory that keeps them, or None where none is in use; the
# arguments' tree; each leaf's shape, dtype and placement).
Signature = tuple[pathlib.Path | None, jax.tree_util.PyTreeDef,
                  tuple[tuple[tuple[int, ...], np.dtype, jax.sharding.Sharding | None], ...]]
ProgramFile = tuple[pathlib.Path, str]  # (the file that keeps a program, its key's sha256)
# A pytree structure as JSON (`_describe`).
TreeDescription = str | dict[str, Any] | None

_directory: pathlib.Path | None = None  # where programs are kept; None: nowhere


def cache_home() -> pathlib.Path:
    """The user's cache directory: $XDG_CACHE_HOME, or ~/.cache.

    ~/.cache where $XDG_CACHE_HOME is unset, empty or relative: the XDG base directory
    specification says to ignore such values. Such a value is removed from the environment too,
    so that the libraries that read it later (matplotlib, for its cache) ignore it as well, and
    nothing is created in the working directory.
    """
    value = os.environ.get("XDG_CACHE_HOME", "")
    if os.path.isabs(value):
        return pathlib.Path(value)
    os.environ.pop("XDG_CACHE_HOME", None)
    return pathlib.Path.home() / ".cache"


def keep_programs(directory: atomic_files.StrPath | None = None) -> None:
    """Keeps the programs of every `Stored` function in `directory` from now on.

    The next process loads them rather than compiling; the `jaxpg` command does this for its own
    training. A directory that is another user's, or that others can write, keeps none (with a
    warning): its programs are machine code that the process would run. So does one that cannot
    be created or written (one warning; training goes on without kept programs). Temporary files
    that killed processes left there are removed. Programs of a user's own policy, loss or
    optimizer are kept under the digest of their lowered code (`Stored`'s `by_code`).

    Args:
      directory: where; by default `cache_home()/jaxpg/programs`, where the command keeps its.
        Created now, with its missing parents, for the user alone (0700).
    """
    directory = cache_home() / "jaxpg" / "programs" if directory is None else directory
    global _directory
    directory = pathlib.Path(directory)
    problem = _unsafe(directory) or _unwritable(directory)
    if problem:
        logger.warning("keeping no compiled programs in %s: %s", directory, problem)
        _directory = None
        return
    atomic_files.remove_stale_temporaries(directory)
    _directory = directory


def _unsafe(directory: pathlib.Path) -> str | None:
    """Why `directory` may not hold programs, which are machine code; None where it may."""
    if os.name != "posix":
        return None
    try:
        status = directory.stat()
    except FileNotFoundError:
        return None  # created for the user alone (`_unwritable`)
    except OSError as error:  # a parent is a file, or cannot be searched
        return f"it cannot be used ({error.strerror})"
    if status.st_uid != os.getuid():
        return "it belongs to another user"
    if status.st_mode & 0o022:
        return "others can write it"
    return None


def _unwritable(directory: pathlib.Path) -> str | None:
    """Why no file can be written in `directory`, created now where missing; None where one can."""
    try:
        atomic_files.private_directory(directory)
        with tempfile.TemporaryFile(dir=directory):
            pass  # permissions alone do not tell (a read-only file system, root)
    except OSError as error:
        return f"it cannot be written ({error.strerror})"
    return None


def stop_keeping_programs() -> None:
    """Keeps no more programs, and loads none kept, from now on (until `keep_programs`)."""
    global _directory
    _directory = None


def _in_use() -> bool:
    """Whether programs are kept: a directory is named, JAX's cache is off, one process computes."""
    # (JAX's stubs declare none of its flags as attributes of `jax.config`.)
    return (_directory is not None
            and jax.config.jax_compilation_cache_dir is None  # type: ignore[attr-defined]
            and jax.process_count() == 1)


@functools.cache
def _source_digest() -> str:
    """A digest of jaxpg's modules, its subpackages' too: a program compiled from other code is
    never reused."""
    digest = hashlib.sha256()
    package = pathlib.Path(__file__).parent
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0" + path.read_bytes()
                      + b"\0")
    return digest.hexdigest()


def _environment() -> tuple[Any, ...]:
    """What every program depends on besides its function and arguments."""
    backend = jax.devices()[0].client
    config = sorted((name, repr(value)) for name, value in jax.config.values.items()
                    if "cache" not in name)
    return (_source_digest(), jax.__version__, jaxlib.__version__, backend.platform,
            backend.platform_version, os.environ.get("XLA_FLAGS", ""), config)


_CACHE_HIT = "/jax/compilation_cache/cache_hits"


def _compile(lowered: jax.stages.Lowered) -> tuple[jax.stages.Compiled, bool]:
    """Compiles `lowered`.

    Returns:
      (`lowered` compiled, whether XLA compiled it now rather than JAX's cache supplied it).
    """
    thread, hits = threading.get_ident(), []

    def listen(event: str, **kwargs: Any) -> None:
        if event == _CACHE_HIT and threading.get_ident() == thread:
            hits.append(event)

    jax.monitoring.register_event_listener(listen)
    try:
        return lowered.compile(), not hits
    finally:
        jax.monitoring.unregister_event_listener(listen)


@functools.cache
def _compiler() -> concurrent.futures.ThreadPoolExecutor:
    """The threads that compile the programs prepared ahead of their calls."""
    return concurrent.futures.ThreadPoolExecutor(os.cpu_count(), "jaxpg-compile")


def _done(program: Program) -> concurrent.futures.Future[Program]:
    """A Future already holding `program`."""
    future: concurrent.futures.Future[Program] = concurrent.futures.Future()
    future.set_result(program)
    return future


def _placement(leaf: Any) -> jax.sharding.Sharding | None:
    """Where an argument is placed: its sharding, or None where JAX places it.

    None for a numpy array, or a jax array not committed to its device.
    """
    return getattr(leaf, "sharding", None) if getattr(leaf, "committed", True) else None


class Stored:
    """A jitted function whose programs can be compiled ahead of their calls, and kept on disk.

    Called with concrete arrays, it runs the program that `prepare` started for their shapes,
    dtypes and placement (waiting for it to compile), or, while programs are kept
    (`keep_programs`), the program kept for them: found in memory, loaded from disk, or compiled
    and written there. Otherwise (and for anything but calls, such as `lower`) it is the jitted
    function itself. Its results are those of the jitted function, bit for bit.

    Args:
      jitted: a `jax.jit` function of arrays only.
      name: a name for its files.
      settings: what tells apart the functions that share `name`, by its `repr`.
      by_code: True for a function whose `settings` do not tell all that decides its programs
        (code of the user's, known by name only): its programs are kept under the digest of
        their lowered code too, so a later process traces and lowers them to find them.
    """

    def __init__(self, jitted: jax.stages.Wrapped, name: str, settings: object,
                 by_code: bool = False) -> None:
        self._jitted = jitted
        self._name = name
        self._settings = repr(settings)
        self._by_code = by_code
        # (directory, argument signature) -> Future of the program
        self._programs: dict[Signature, concurrent.futures.Future[Program]] = {}
        self._lock = threading.Lock()

    def __getattr__(self, name: str) -> Any:
        """The jitted function's attribute `name` (`lower`, `eval_shape`, ...)."""
        return getattr(self._jitted, name)

    def __call__(self, *args: Any) -> Any:
        """Runs the program for `args` (see the class); returns the jitted function's outputs."""
        leaves, tree = jax.tree.flatten(args)
        if not (self._programs or _in_use()) or any(
                isinstance(leaf, jax.core.Tracer) or not hasattr(leaf, "dtype") for leaf in leaves):
            # (Python numbers among the arguments: the jitted function's)
            return self._jitted(*args)
        signature = self._signature(tree, leaves)
        program = self._programs.get(signature)
        if program is None or _failed(program):
            if signature[0] is None:  # storing is not in use, and nothing usable was prepared
                return self._jitted(*args)
            program = self._program(args, signature, ahead=False)
        return program.result()(*args)

    def prepare(self, *args: Any) -> concurrent.futures.Future[Program]:
        """Starts compiling (or loading) the program for arguments like `args`.

        This thread traces and lowers the function; another compiles it, so that this one can go
        on to trace the next. A call with such arguments waits for it.

        Args:
          *args: arrays, or `jax.ShapeDtypeStruct`s shaped, typed and placed (`sharding`, None for
            the default device) as the call's arrays will be.

        Returns:
          The `concurrent.futures.Future` of the program.
        """
        leaves, tree = jax.tree.flatten(args)
        return self._program(args, self._signature(tree, leaves), ahead=True)

    def loaded(self, *args: Any) -> Program | None:
        """The program for arguments like `args`, where it is at hand without compiling.

        Args:
          *args: as for `prepare`.

        Returns:
          The program compiled already, or kept on disk (then loaded); None where there is none,
          it is still compiling, or it failed.
        """
        leaves, tree = jax.tree.flatten(args)
        signature = self._signature(tree, leaves)
        with self._lock:
            program = self._programs.get(signature)
            if program is None:
                compiled = self._load(_device(signature), self._file(signature))
                if compiled is None:
                    return None
                program = self._programs[signature] = _done(compiled)
        if not program.done() or _failed(program):
            return None
        return None if program.result() is self._jitted else program.result()

    def _program(self, args: tuple[Any, ...], signature: Signature,
                 ahead: bool) -> concurrent.futures.Future[Program]:
        """The Future of the program for `signature`: the one at hand, or one started now.

        One is started where there is none or it failed (a failure may have passed: tried again).
        One thread starts it; the others wait for its program.
        """
        with self._lock:
            program = self._programs.get(signature)
            if program is None or _failed(program):
                program = self._programs[signature] = self._start(args, signature, ahead)
        return program

    def _signature(self, tree: jax.tree_util.PyTreeDef, leaves: Sequence[Any]) -> Signature:
        """What tells apart the programs for arguments of structure `tree` and leaves `leaves`."""
        return (_directory if _in_use() else None, tree,
                tuple((leaf.shape, leaf.dtype, _placement(leaf)) for leaf in leaves))

    def _start(self, args: tuple[Any, ...], signature: Signature,
               ahead: bool) -> concurrent.futures.Future[Program]:
        """The Future of the program for `args`: loaded, or lowered now, compiled and kept.

        Compiled on a thread when `ahead`. For arguments on several devices, the jitted function
        itself, whose programs are neither compiled ahead nor kept.
        """
        device = _device(signature)
        if device is None:
            return _done(self._jitted)
        lowered = self._jitted.lower(*args) if self._by_code else None
        file = self._file(signature, None if lowered is None else lowered.as_text())
        compiled = self._load(device, file)
        if compiled is not None:
            return _done(compiled)
        lowered = lowered or self._jitted.lower(*args)

        def compile_and_keep() -> jax.stages.Compiled:
            compiled, fresh = _compile(lowered)
            if fresh and file is not None:
                self._keep(compiled, file)
            return compiled

        return _compiler().submit(compile_and_keep) if ahead else _done(compile_and_keep())

    def _file(self, signature: Signature, code: str | None = None) -> ProgramFile | None:
        """The file that keeps the program for `signature`, and the sha256 of the program's key.

        None while no programs are kept, or for a function kept `by_code` without its `code`
        (its lowered text).
        """
        directory, tree, leaves = signature
        if directory is None or (self._by_code and code is None):
            return None
        arguments = [(shape, str(dtype), str(sharding)) for shape, dtype, sharding in leaves]
        # Kept by code, the settings' text is left out: it may name objects by their addresses.
        decides = code if self._by_code else self._settings
        key = repr((self._name, decides, str(tree), arguments, _environment()))
        digest = hashlib.sha256(key.encode()).hexdigest()
        return directory / f"{self._name}-{digest[:40]}.xla", digest

    def _load(self, device: jax.Device | None, file: ProgramFile | None) -> "_Kept | None":
        """The program kept in `file` (from `_file`), loaded onto `device`.

        None where there is none that loads, or the file was found unusable before (it is warned
        about once).
        """
        if device is None or file is None or file[0] in _unusable:
            return None
        path, key = file
        try:
            kept = _read(path.read_bytes(), key, device)
        except FileNotFoundError:
            return None
        except Exception as error:  # damaged, or another program's: compiled again and replaced
            _unusable.add(path)
            logger.warning("could not load %s (%s); compiling it again", path, error)
            return None
        logger.debug("loaded %s from %s", self._name, path)
        return kept

    def _keep(self, compiled: jax.stages.Compiled, file: ProgramFile) -> None:
        """Writes `compiled` to `file`; warns, and keeps nothing, where it cannot."""
        path, key = file
        try:
            data = _write(compiled, key)
            atomic_files.private_directory(path.parent)
            if path.is_dir() and not path.is_symlink():  # found in the file's place: replaced too
                shutil.rmtree(path)
            atomic_files.atomic_write(path, data)
            _unusable.discard(path)
        except Exception as error:  # the program is compiled all the same
            logger.warning("could not keep %s in %s (%s)", self._name, path.parent, error)


def _failed(program: concurrent.futures.Future[Program]) -> bool:
    """Whether the Future `program` ended in an error."""
    return program.done() and program.exception() is not None


def _device(signature: Signature) -> jax.Device | None:
    """The one device that a program for `signature` runs on; None for arguments on several."""
    devices = {device for _, _, sharding in signature[2] if sharding is not None
               for device in sharding.device_set} or {jax.devices()[0]}
    return next(iter(devices)) if len(devices) == 1 else None


# --- Files of kept programs ----------------------------------------------------------------------

_FORMAT = b"jaxpg-program 2\n"
_unusable: set[pathlib.Path] = set()  # the files this process found it could not load


def _write(compiled: jax.stages.Compiled, key: str) -> bytes:
    """The bytes of the file that keeps `compiled`, the program of the key whose sha256 is `key`.

    Raises:
      ValueError: the program is not one that a file can hold: its executable takes parameters
        other than the arguments' leaves (such as effects' tokens), or its outputs hold a node
        that `_describe` does not.
    """
    executable: Any = compiled.runtime_executable()  # (None where a backend has none: not kept)
    # The leaves XLA dropped, being unused, have no sharding.
    shardings = jax.tree.leaves(compiled.input_shardings, is_leaf=lambda sharding: sharding is None)
    taken = [index for index, sharding in enumerate(shardings) if sharding is not None]
    if len(taken) != len(executable.get_parameter_layouts()):
        raise ValueError("its executable takes other parameters than the arguments")
    outputs, tree = jax.tree.flatten(compiled.out_info)
    payload = executable.client.serialize_executable(executable)
    header = {"key": key, "arguments": taken, "outputs": _describe(tree),
              "shapes": [[list(leaf.shape), str(leaf.dtype)] for leaf in outputs]}
    signed = json.dumps(header).encode() + b"\n" + payload
    return _FORMAT + _digest(signed) + b"\n" + signed


def _digest(signed: bytes) -> bytes:
    """The sha256 of a file's header and payload, `signed`, in hex."""
    return hashlib.sha256(signed).hexdigest().encode()


def _read(data: bytes, key: str, device: jax.Device) -> "_Kept":
    """The program in a file's `data` (from `_write`), checked and loaded onto `device`.

    Args:
      data: the file's bytes.
      key: the sha256 of the program's key, which the file must hold.
      device: where the program runs.

    Raises:
      ValueError: the file is not one of a program of this format, its header and payload do
        not match their digest, or it holds another program; the message says which.
    """
    if not data.startswith(_FORMAT):
        raise ValueError(f"not a jaxpg program file of format {_FORMAT.split()[-1].decode()}")
    digest, _, signed = data[len(_FORMAT):].partition(b"\n")
    if digest != _digest(signed):
        raise ValueError("its contents do not match their digest")
    header, _, payload = signed.partition(b"\n")
    header = json.loads(header)
    if header["key"] != key:
        raise ValueError("it holds another program")
    executable = device.client.deserialize_executable(payload, xla_client.DeviceList((device,)))
    shapes = [jax.ShapeDtypeStruct(tuple(shape), jnp.dtype(dtype))
              for shape, dtype in header["shapes"]]
    return _Kept(executable, device, header["arguments"], header["outputs"], shapes)


class _Kept:
    """A program read from its file, called as the `jax.stages.Compiled` it was.

    Called with arguments like those it was compiled for. `out_info` gives its outputs' shapes and
    dtypes (a tree of `jax.ShapeDtypeStruct`), as there.
    """

    def __init__(self, executable: Any, device: jax.Device, arguments: Iterable[int],
                 outputs: TreeDescription, shapes: Sequence[jax.ShapeDtypeStruct]) -> None:
        self._executable = executable
        self._device = device
        self._arguments = [int(index) for index in arguments]  # the leaves it takes
        self._outputs = outputs  # their tree, from `_describe`
        self.out_info = _unflatten(outputs, shapes)

    def __call__(self, *args: Any) -> Any:
        """Runs the executable on `args`; returns its outputs' tree."""
        # None counted as a leaf, as `_write` counts the input shardings (None for a None leaf).
        leaves = jax.tree.leaves(args, is_leaf=lambda leaf: leaf is None)
        arrays = [leaves[index] if isinstance(leaves[index], jax.Array)
                  else jax.device_put(leaves[index], self._device) for index in self._arguments]
        results = self._executable.execute_sharded(arrays).disassemble_into_single_device_arrays()
        # As JAX's own call: results are committed to the device only where an argument was.
        committed = any(_placement(leaf) is not None for leaf in leaves)
        return _unflatten(self._outputs, [
            array if committed else jax_array.ArrayImpl(array.aval, array.sharding, [array],
                                                        committed=False)
            for [array] in results])


def _describe(tree: jax.tree_util.PyTreeDef) -> TreeDescription:
    """A pytree structure (`PyTreeDef`) as JSON.

    "*" for a leaf, null for None, and {"tuple": [...]}, {"list": [...]},
    {"dict": [...], "keys": [...]} or {"namedtuple": "module:qualname", "fields": [...]} of the
    children's descriptions.

    Raises:
      ValueError: a node of another kind (registered pytree nodes such as flax's dataclasses).
    """
    node = tree.node_data()
    if node is None:
        return "*"
    kind, data = node
    children = [_describe(child) for child in tree.children()]
    if kind is type(None):
        return None
    if kind in (tuple, list):
        return {kind.__name__: children}
    if kind is dict and all(isinstance(key, str) for key in data):
        return {"dict": children, "keys": list(data)}
    name = f"{kind.__module__}:{kind.__qualname__}"
    if _named_tuple(name) is kind:
        return {"namedtuple": name, "fields": children}
    raise ValueError(f"its outputs hold a {kind.__name__}, which its file cannot describe")


def _named_tuple(name: str) -> type | None:
    """The named tuple class `module:qualname` of a module already imported; None where none is.

    Found by the modules' and classes' own dictionaries: nothing is imported, and no code of a
    module (such as its `__getattr__`) runs.
    """
    module, _, qualname = name.partition(":")
    found = sys.modules.get(module)
    for part in qualname.split("."):
        found = getattr(found, "__dict__", {}).get(part)
    if isinstance(found, type) and issubclass(found, tuple) and hasattr(found, "_fields"):
        return found
    return None


def _unflatten(description: TreeDescription, leaves: Iterable[Any]) -> Any:
    """The pytree that `description` (from `_describe`) describes, with `leaves` in order."""
    leaves = iter(leaves)
    try:
        tree = _build(description, leaves)
    except StopIteration:
        raise ValueError("its outputs have fewer leaves than their tree") from None
    if next(leaves, None) is not None:
        raise ValueError("its outputs have more leaves than their tree")
    return tree


def _build(description: TreeDescription, leaves: Iterator[Any]) -> Any:
    """The subtree that `description` describes, taking its leaves from `leaves`."""
    if description == "*":
        return next(leaves)
    if description is None:
        return None
    description = cast(dict[str, Any], description)
    if "tuple" in description:
        return tuple(_build(child, leaves) for child in description["tuple"])
    if "list" in description:
        return [_build(child, leaves) for child in description["list"]]
    if "dict" in description:
        return dict(zip(description["keys"],
                        [_build(child, leaves) for child in description["dict"]]))
    kind = _named_tuple(description["namedtuple"])
    if kind is None:
        raise ValueError(f"no named tuple {description['namedtuple']} is imported")
    return kind(*[_build(child, leaves) for child in description["fields"]])
