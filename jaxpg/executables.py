"""Compiled programs kept on disk whole, so that a later process neither traces nor compiles them.

JAX's persistent compilation cache saves XLA's compiling, but a process that looks a program up
there still traces and lowers the Python function to find its key: about a second for the
training programs. A `Stored` function keeps the compiled executable itself, under a key of
everything that decides it: the function's name and settings, its arguments' structure, shapes,
dtypes and devices, jaxpg's own source, the versions of jax and jaxlib, the backend, JAX's
configuration and `XLA_FLAGS`.

Nothing is kept until `enable` names a directory, and nothing that JAX's persistent cache supplied:
an executable loaded from a file loses some of its kernels when it is serialised again, so only
programs that XLA compiled in this process are kept, and none while JAX's cache is on. A file that cannot be loaded
is compiled again and replaced; a directory that cannot be written means only that nothing is kept.
"""

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


def _compile(jitted, args):
    """(`jitted` compiled for `args`, whether XLA compiled it now rather than JAX's cache)."""
    thread, hits = threading.get_ident(), []

    def listen(event, **kwargs):
        if event == _CACHE_HIT and threading.get_ident() == thread:
            hits.append(event)

    jax.monitoring.register_event_listener(listen)
    try:
        return jitted.lower(*args).compile(), not hits
    finally:
        jax.monitoring.unregister_event_listener(listen)


class Stored:
    """A jitted function whose compiled programs are kept in the enabled directory.

    Called with concrete arrays while storing is in use, it runs the program kept for their
    shapes, dtypes and devices: found in memory, loaded from disk, or compiled and written there.
    Otherwise (and for anything but calls, such as `lower`) it is the jitted function itself.

    Args:
      jitted: a `jax.jit` function of arrays only.
      name: a name for its files.
      settings: what tells apart the functions that share `name`, by its `repr`.
    """

    def __init__(self, jitted, name, settings):
        self._jitted = jitted
        self._name = name
        self._settings = repr(settings)
        self._compiled = {}  # (directory, argument signature) -> program
        self._lock = threading.Lock()

    def __getattr__(self, name):
        return getattr(self._jitted, name)

    def __call__(self, *args):
        if _directory is None:
            return self._jitted(*args)
        leaves, tree = jax.tree.flatten(args)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves) or not _in_use():
            return self._jitted(*args)
        signature = (_directory, tree, tuple(
            (leaf.shape, leaf.dtype, getattr(leaf, "sharding", None)) for leaf in leaves))
        compiled = self._compiled.get(signature)
        if compiled is None:
            with self._lock:  # one thread compiles; the others wait for its program
                compiled = self._compiled.get(signature) or self._load_or_compile(args, signature)
                self._compiled[signature] = compiled
        return compiled(*args)

    def _load_or_compile(self, args, signature):
        """The program for `args`: loaded, or compiled and kept; the jitted function itself for
        arguments on several devices, whose programs are not kept."""
        directory, tree, arguments = signature
        devices = {device for _, _, sharding in arguments if sharding is not None
                   for device in sharding.device_set} or {jax.devices()[0]}
        if len(devices) > 1:
            return self._jitted
        (device,) = devices
        arguments = [(shape, str(dtype), str(sharding)) for shape, dtype, sharding in arguments]
        key = repr((self._name, self._settings, str(tree), arguments, _environment()))
        path = directory / f"{self._name}-{hashlib.sha256(key.encode()).hexdigest()[:40]}.pickle"
        try:
            compiled = serialize_executable.deserialize_and_load(
                *pickle.loads(path.read_bytes()), execution_devices=[device])
            logger.debug("loaded %s from %s", self._name, path)
            return compiled
        except FileNotFoundError:
            pass
        except Exception as error:  # a damaged file: compile again and replace it
            logger.warning("could not load %s (%s); compiling it again", path, error)
        compiled, fresh = _compile(self._jitted, args)
        if not fresh:
            return compiled
        try:
            directory.mkdir(parents=True, exist_ok=True)
            results.atomic_write(path, pickle.dumps(serialize_executable.serialize(compiled)))
        except (OSError, ValueError) as error:
            logger.warning("could not keep %s in %s (%s)", self._name, directory, error)
        return compiled
