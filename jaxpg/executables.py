"""Programs compiled ahead of their first call, and kept on disk whole, so that a later process
neither traces nor compiles them.

XLA compiles without holding Python's lock. `Stored.prepare` traces and lowers a program in the
calling thread and compiles it on another, so that the caller can go on to trace the next program
(`reinforce.prepare`: `init` is traced and compiled while `iterate`, the longer, compiles).

JAX's persistent compilation cache saves XLA's compiling, but a process that looks a program up
there still traces and lowers the Python function to find its key: about a second for the
training programs. A `Stored` function keeps the compiled executable itself, under a key of
everything that decides it: the function's name and settings, its arguments' structure, shapes,
dtypes and devices, jaxpg's own source, the versions of jax and jaxlib, the backend, JAX's
configuration and `XLA_FLAGS`.

Nothing is kept until `enable` names a directory, and nothing that JAX's persistent cache supplied:
an executable loaded from a file loses some of its kernels when it is serialised again, so only
programs that XLA compiled in this process are kept, and none while JAX's cache is on. A file
that cannot be loaded is compiled again and replaced; a directory that cannot be written means
only that nothing is kept.
"""

import concurrent.futures
import functools
import hashlib
import logging
import os
import pathlib
import pickle
import threading

import jax
import jaxlib
from jax.experimental import serialize_executable

from jaxpg import results

logger = logging.getLogger(__name__)

_directory = None


def enable(directory):
    """Keeps the programs of every `Stored` function in `directory` from now on."""
    global _directory
    _directory = pathlib.Path(directory)


def disable():
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
    """

    def __init__(self, jitted, name, settings):
        self._jitted = jitted
        self._name = name
        self._settings = repr(settings)
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
                compiled = self._load(_device(signature), self._path(signature))
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
        device, path = _device(signature), self._path(signature)
        if device is None:
            return _done(self._jitted)
        compiled = self._load(device, path)
        if compiled is not None:
            return _done(compiled)
        lowered = self._jitted.lower(*args)

        def compile_and_keep():
            compiled, fresh = _compile(lowered)
            if fresh and path is not None:
                self._keep(compiled, path)
            return compiled

        return _compiler().submit(compile_and_keep) if ahead else _done(compile_and_keep())

    def _path(self, signature):
        """The file that keeps the program for `signature`; None while storing is not in use."""
        directory, tree, arguments = signature
        if directory is None:
            return None
        arguments = [(shape, str(dtype), str(sharding)) for shape, dtype, sharding in arguments]
        key = repr((self._name, self._settings, str(tree), arguments, _environment()))
        return directory / f"{self._name}-{hashlib.sha256(key.encode()).hexdigest()[:40]}.pickle"

    def _load(self, device, path):
        """The program kept in `path` (from `_path`), loaded onto `device`; None where there is
        none that loads."""
        if device is None or path is None:
            return None
        try:
            compiled = serialize_executable.deserialize_and_load(
                *pickle.loads(path.read_bytes()), execution_devices=[device])
        except FileNotFoundError:
            return None
        except Exception as error:  # a damaged file: compiled again and replaced
            logger.warning("could not load %s (%s); compiling it again", path, error)
            return None
        logger.debug("loaded %s from %s", self._name, path)
        return compiled

    def _keep(self, compiled, path):
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            results.atomic_write(path, pickle.dumps(serialize_executable.serialize(compiled)))
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
