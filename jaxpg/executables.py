"""Programs compiled ahead of their first call, and kept on disk whole, so that a later process
neither traces nor compiles them.

XLA compiles without holding Python's lock. `Stored.prepare` traces and lowers a program in the
calling thread and compiles it on another, so that the caller can go on to trace the next program
(`schedule.prepare`: `init` is traced and compiled while `iterate`, the longer, compiles).

JAX's persistent compilation cache saves XLA's compiling, but a process that looks a program up
there still traces and lowers the Python function to find its key: about a second for the
training programs. A `Stored` function keeps the compiled executable itself, under a key of
everything that decides it: the function's name and settings, its arguments' structure, shapes,
dtypes and devices, jaxpg's own source, the versions of jax and jaxlib, the backend, JAX's
configuration and `XLA_FLAGS`.

Nothing is kept until `keep_programs` names a directory, and nothing that JAX's persistent cache supplied:
an executable loaded from a file loses some of its kernels when it is serialised again, so only
programs that XLA compiled in this process are kept, and none while JAX's cache is on. A file
that cannot be loaded is compiled again and replaced; a directory that cannot be written means
only that nothing is kept.

A kept program is read back without running any of the file's code: nothing is unpickled
(`jax.experimental.serialize_executable` pickles, and unpickling runs whatever the file asks).
A file holds

    jaxpg-program 1\n     the format's marker and version
    header\n              JSON: the sha256 of the program's key and of the payload, which of
                          the arguments' leaves the executable takes (XLA drops unused ones), and
                          the outputs: their tree (tuples, lists, dicts, None and named tuples of
                          modules already imported) and each one's shape and dtype
    payload               XLA's executable, as XLA serialises it (`Client.serialize_executable`)

A file of another format, another key (another program's) or another digest is warned about
once, compiled again and replaced. A loaded program (`_Kept`) runs XLA's executable on the call's
arrays and builds the outputs' tree around its results.

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
import sys
import threading

import jax
import jax.numpy as jnp
import jaxlib

# (What jax.experimental.serialize_executable loads with, and the array type its results take.)
from jax._src import array as jax_array
from jax._src.lib import xla_client

from jaxpg import atomic_files

logger = logging.getLogger(__name__)

_directory = None


def cache_home():
    """$XDG_CACHE_HOME, or ~/.cache where it is unset, empty or relative (the XDG base directory
    specification says to ignore such values)."""
    value = os.environ.get("XDG_CACHE_HOME", "")
    return pathlib.Path(value) if os.path.isabs(value) else pathlib.Path.home() / ".cache"


def keep_programs(directory=None):
    """Keeps the programs of every `Stored` function in `directory` from now on, unless the
    directory is another user's or others can write it (then with a warning, none): the next
    process loads them rather than compiling; the `jaxpg` command does this for its own training.

    Args:
      directory: where; by default `cache_home()/jaxpg/programs`, where the command keeps its.

    Temporary files that killed processes left there are removed. Programs of a user's own
    policy, loss or optimizer are not kept: their code can change under the same name.
    """
    directory = cache_home() / "jaxpg" / "programs" if directory is None else directory
    global _directory
    directory = pathlib.Path(directory)
    problem = _unsafe(directory)
    if problem:
        logger.warning("keeping no compiled programs in %s: %s", directory, problem)
        _directory = None
        return
    atomic_files.remove_stale_temporaries(directory)
    _directory = directory


def _unsafe(directory):
    """Why `directory` may not hold programs, which are machine code; None where it may."""
    if os.name != "posix":
        return None
    try:
        status = directory.stat()
    except FileNotFoundError:
        return None  # created for the user alone when a program is kept
    if status.st_uid != os.getuid():
        return "it belongs to another user"
    if status.st_mode & 0o022:
        return "others can write it"
    return None


def stop_keeping_programs():
    global _directory
    _directory = None


def _in_use():
    return (_directory is not None and jax.config.jax_compilation_cache_dir is None
            and jax.process_count() == 1)


@functools.cache
def _source_digest():
    """A digest of jaxpg's modules: a program compiled from other code is never reused."""
    digest = hashlib.sha256()
    for path in sorted(pathlib.Path(__file__).parent.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _environment():
    """What every program depends on besides its function and arguments."""
    backend = jax.devices()[0].client
    config = sorted((name, repr(value)) for name, value in jax.config.values.items()
                    if "cache" not in name)
    return (_source_digest(), jax.__version__, jaxlib.__version__, backend.platform,
            backend.platform_version, os.environ.get("XLA_FLAGS", ""), config)


_CACHE_HIT = "/jax/compilation_cache/cache_hits"


def _compile(lowered):
    """(`lowered` compiled, whether XLA compiled it now rather than JAX's cache)."""
    thread, hits = threading.get_ident(), []

    def listen(event, **kwargs):
        if event == _CACHE_HIT and threading.get_ident() == thread:
            hits.append(event)

    jax.monitoring.register_event_listener(listen)
    try:
        return lowered.compile(), not hits
    finally:
        jax.monitoring.unregister_event_listener(listen)


@functools.cache
def _compiler():
    """The threads that compile the programs prepared ahead of their calls."""
    return concurrent.futures.ThreadPoolExecutor(os.cpu_count(), "jaxpg-compile")


def _done(program):
    future = concurrent.futures.Future()
    future.set_result(program)
    return future


def _placement(leaf):
    """Where an argument is placed: its sharding, or None where JAX places it (a numpy array, or a
    jax array not committed to its device)."""
    return getattr(leaf, "sharding", None) if getattr(leaf, "committed", True) else None


class Stored:
    """A jitted function whose programs can be compiled ahead of their calls, and are kept in the
    enabled directory.

    Called with concrete arrays, it runs the program that `prepare` started for their shapes,
    dtypes and placement (waiting for it to compile), or, while storing is in use, the program kept
    for them: found in memory, loaded from disk, or compiled and written there. Otherwise (and for
    anything but calls, such as `lower`) it is the jitted function itself.

    Args:
      jitted: a `jax.jit` function of arrays only.
      name: a name for its files.
      settings: what tells apart the functions that share `name`, by its `repr`.
      keep: False for a function whose `settings` do not tell all that decides its programs (code
        of the user's, known by name only): its programs are compiled ahead as others, never kept.
    """

    def __init__(self, jitted, name, settings, keep=True):
        self._jitted = jitted
        self._name = name
        self._settings = repr(settings)
        self._may_keep = keep
        self._programs = {}  # (directory, argument signature) -> Future of the program
        self._lock = threading.Lock()

    def __getattr__(self, name):
        return getattr(self._jitted, name)

    def __call__(self, *args):
        leaves, tree = jax.tree.flatten(args)
        if not (self._programs or _in_use()) or any(
                isinstance(leaf, jax.core.Tracer) or not hasattr(leaf, "dtype") for leaf in leaves):
            return self._jitted(*args)  # (Python numbers among the arguments: the jitted function's)
        signature = self._signature(tree, leaves)
        program = self._programs.get(signature)
        if program is None or _failed(program):
            if signature[0] is None:  # storing is not in use, and nothing usable was prepared
                return self._jitted(*args)
            program = self._program(args, signature, ahead=False)
        return program.result()(*args)

    def prepare(self, *args):
        """Starts compiling (or loading) the program for arguments like `args`, and returns the
        `concurrent.futures.Future` of it; a call with such arguments waits for it.

        `args` are arrays, or `jax.ShapeDtypeStruct`s shaped, typed and placed (`sharding`, None
        for the default device) as the call's arrays will be. This thread traces and lowers the
        function; another compiles it, so that this one can go on to trace the next.
        """
        leaves, tree = jax.tree.flatten(args)
        return self._program(args, self._signature(tree, leaves), ahead=True)

    def loaded(self, *args):
        """The program for arguments like `args` (as for `prepare`) where it is at hand without
        compiling: compiled already, or kept on disk (then loaded); otherwise None."""
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

    def _program(self, args, signature, ahead):
        """The Future of the program for `signature`: the one at hand, or one started now where
        there is none or it failed (a failure may have passed: tried again). One thread starts it;
        the others wait for its program."""
        with self._lock:
            program = self._programs.get(signature)
            if program is None or _failed(program):
                program = self._programs[signature] = self._start(args, signature, ahead)
        return program

    def _signature(self, tree, leaves):
        return (_directory if _in_use() else None, tree,
                tuple((leaf.shape, leaf.dtype, _placement(leaf)) for leaf in leaves))

    def _start(self, args, signature, ahead):
        """The Future of the program for `args`: loaded, or lowered now and compiled (on a thread
        when `ahead`) and kept; the jitted function itself for arguments on several devices, whose
        programs are neither compiled ahead nor kept."""
        device, file = _device(signature), self._file(signature)
        if device is None:
            return _done(self._jitted)
        compiled = self._load(device, file)
        if compiled is not None:
            return _done(compiled)
        lowered = self._jitted.lower(*args)

        def compile_and_keep():
            compiled, fresh = _compile(lowered)
            if fresh and file is not None:
                self._keep(compiled, file)
            return compiled

        return _compiler().submit(compile_and_keep) if ahead else _done(compile_and_keep())

    def _file(self, signature):
        """(the file that keeps the program for `signature`, the sha256 of the program's key);
        None while storing is not in use."""
        directory, tree, arguments = signature
        if directory is None or not self._may_keep:
            return None
        arguments = [(shape, str(dtype), str(sharding)) for shape, dtype, sharding in arguments]
        key = repr((self._name, self._settings, str(tree), arguments, _environment()))
        digest = hashlib.sha256(key.encode()).hexdigest()
        return directory / f"{self._name}-{digest[:40]}.xla", digest

    def _load(self, device, file):
        """The program kept in `file` (from `_file`), loaded onto `device`; None where there is
        none that loads, or the file was found unusable before (it is warned about once)."""
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

    def _keep(self, compiled, file):
        path, key = file
        try:
            data = _write(compiled, key)
            atomic_files.private_directory(path.parent)
            atomic_files.atomic_write(path, data)
            _unusable.discard(path)
        except Exception as error:  # the program is compiled all the same
            logger.warning("could not keep %s in %s (%s)", self._name, path.parent, error)


def _failed(program):
    """Whether the Future `program` ended in an error."""
    return program.done() and program.exception() is not None


def _device(signature):
    """The one device that a program for `signature` runs on; None for arguments on several."""
    devices = {device for _, _, sharding in signature[2] if sharding is not None
               for device in sharding.device_set} or {jax.devices()[0]}
    return next(iter(devices)) if len(devices) == 1 else None


# --- Files of kept programs ----------------------------------------------------------------------

_FORMAT = b"jaxpg-program 1\n"
_unusable = set()  # the files this process found it could not load


def _write(compiled, key):
    """The bytes of the file that keeps `compiled`, the program of the key whose sha256 is `key`.

    Raises:
      ValueError: the program is not one that a file can hold: its executable takes parameters
        other than the arguments' leaves (such as effects' tokens), or its outputs hold a node
        that `_describe` does not.
    """
    executable = compiled.runtime_executable()
    # The leaves XLA dropped, being unused, have no sharding.
    shardings = jax.tree.leaves(compiled.input_shardings, is_leaf=lambda sharding: sharding is None)
    taken = [index for index, sharding in enumerate(shardings) if sharding is not None]
    if len(taken) != len(executable.get_parameter_layouts()):
        raise ValueError("its executable takes other parameters than the arguments")
    outputs, tree = jax.tree.flatten(compiled.out_info)
    payload = executable.client.serialize_executable(executable)
    header = {"key": key, "sha256": hashlib.sha256(payload).hexdigest(), "arguments": taken,
              "outputs": _describe(tree),
              "shapes": [[list(leaf.shape), str(leaf.dtype)] for leaf in outputs]}
    return _FORMAT + json.dumps(header).encode() + b"\n" + payload


def _read(data, key, device):
    """The program in a file's `data` (from `_write`), checked against the sha256 `key` of the
    program's key and loaded onto `device`. Raises a ValueError saying what does not match."""
    if not data.startswith(_FORMAT):
        raise ValueError("not a jaxpg program file")
    header, _, payload = data[len(_FORMAT):].partition(b"\n")
    header = json.loads(header)
    if header["key"] != key:
        raise ValueError("it holds another program")
    if header["sha256"] != hashlib.sha256(payload).hexdigest():
        raise ValueError("its contents do not match their digest")
    executable = device.client.deserialize_executable(payload, xla_client.DeviceList((device,)))
    shapes = [jax.ShapeDtypeStruct(tuple(shape), jnp.dtype(dtype))
              for shape, dtype in header["shapes"]]
    return _Kept(executable, device, header["arguments"], header["outputs"], shapes)


class _Kept:
    """A program read from its file, called as the `jax.stages.Compiled` it was: with arguments
    like those it was compiled for. `out_info` gives its outputs' shapes and dtypes, as there."""

    def __init__(self, executable, device, arguments, outputs, shapes):
        self._executable = executable
        self._device = device
        self._arguments = [int(index) for index in arguments]  # the leaves it takes
        self._outputs = outputs  # their tree, from `_describe`
        self.out_info = _unflatten(outputs, shapes)

    def __call__(self, *args):
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


def _describe(tree):
    """A pytree structure (`PyTreeDef`) as JSON: "*" for a leaf, null for None, and
    {"tuple": [...]}, {"list": [...]}, {"dict": [...], "keys": [...]} or
    {"namedtuple": "module:qualname", "fields": [...]} of the children's descriptions.

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


def _named_tuple(name):
    """The named tuple class `module:qualname` of a module already imported; None where there is
    none. Found by the modules' and classes' own dictionaries: nothing is imported, and no code of
    a module (such as its `__getattr__`) runs."""
    module, _, qualname = name.partition(":")
    found = sys.modules.get(module)
    for part in qualname.split("."):
        found = getattr(found, "__dict__", {}).get(part)
    if isinstance(found, type) and issubclass(found, tuple) and hasattr(found, "_fields"):
        return found
    return None


def _unflatten(description, leaves):
    """The pytree that `description` (from `_describe`) describes, with `leaves` in order."""
    leaves = iter(leaves)
    try:
        tree = _build(description, leaves)
    except StopIteration:
        raise ValueError("its outputs have fewer leaves than their tree") from None
    if next(leaves, None) is not None:
        raise ValueError("its outputs have more leaves than their tree")
    return tree


def _build(description, leaves):
    if description == "*":
        return next(leaves)
    if description is None:
        return None
    if "tuple" in description:
        return tuple(_build(child, leaves) for child in description["tuple"])
    if "list" in description:
        return [_build(child, leaves) for child in description["list"]]
    if "dict" in description:
        return dict(zip(description["keys"], [_build(child, leaves) for child in description["dict"]]))
    kind = _named_tuple(description["namedtuple"])
    if kind is None:
        raise ValueError(f"no named tuple {description['namedtuple']} is imported")
    return kind(*[_build(child, leaves) for child in description["fields"]])
