"""Writing files so that a failure, a kill or a second process never loses or mixes results.

A run's results go to an output folder all or none, and the folder holds one result. They are
written to a staging folder beside it, and the staging folder then takes the output folder's place
in one step, holding the run's files alone: whatever the earlier folder held is gone with it. A
reader sees the earlier folder or the new one, never a mix:

- On Linux the two folders trade places in one system call (`renameat2` with `RENAME_EXCHANGE`,
  through ctypes). A kill at any moment leaves the earlier folder or the new one in place, and
  the output folder stays a real folder (a symbolic link swapped for a new target would also be
  one step, but would turn the user's folder into a link).
- Elsewhere, or on a file system without the exchange, the earlier folder is renamed aside and
  the new one renamed into place. A kill between the two renames leaves no output folder and the
  earlier one aside (`.NAME.old-*`), which the next run into that folder puts back first.

A lock (`fcntl.flock` on `.NAME.lock`, beside the folder) keeps a second process from writing the
same folder while the first trains and writes; the second is refused at once. The lock is
released when the results are in place, or when the process ends, so a killed run leaves nothing
locked (a command run in a process that goes on, `cli.run_command`, releases it when it ends);
whatever it left half done (`.NAME.staging-*` folders, and the `.staging-*` folders that jaxpg
0.1.0 left inside the output folder) is removed by the next run that takes the lock. Once
`cancel` is called (Ctrl-C), no staging folder takes its output folder's place.

Every single file jaxpg writes (checkpoints, animations, plots, kept programs) goes through
`atomic_path`: the content is written to a temporary file in the same directory, flushed to disk,
then renamed over the target, so a crash mid-write leaves the previous file intact (and perhaps a
stray `.NAME.*.tmp*` file beside it, which `remove_stale_temporaries` removes once no process
writes it).
"""

import contextlib
import csv
import ctypes
import errno
import functools
import io
import json
import math
import os
import pathlib
import re
import shutil
import stat
import sys
import tempfile
import threading
import uuid
from collections.abc import Callable, Iterator, Mapping
from typing import IO, Any

import numpy as np
import numpy.typing as npt

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; a second writer is not detected there
    fcntl = None  # type: ignore[assignment]  # (mypy types the name as the module alone)

StrPath = str | os.PathLike[str]  # a path as the caller gives it: a string or a `pathlib.Path`

NAME_MAX = 255  # bytes in a file name (Linux, macOS and Windows file systems alike)


def temporary_name(name: str, tag: str) -> str:
    """The name `.NAME.TAG` of a temporary entry beside `name`, within NAME_MAX bytes.

    NAME is cut short (at a character) so that the whole fits in NAME_MAX bytes as the file system
    encodes it (`os.fsencode`: a byte that is not UTF-8 is one character). The same `name` and
    `tag` length always give the same cut, so that names made with other tags of that length can
    be recognised (`_beside`).

    Args:
      name: the name of the file or folder the entry belongs to.
      tag: what the entry is (`lock`, `staging-<12 hex>`, ...).

    Returns:
      The entry's name.
    """
    room = max(NAME_MAX - len(os.fsencode(tag)) - 2, 0)
    size = kept = 0
    for char in name:  # (a character's bytes do not depend on its neighbours)
        size += len(os.fsencode(char))
        if size > room:
            break
        kept += 1
    return f".{name[:kept]}.{tag}"


def _unique() -> str:
    """Twelve random hex digits, for a name no other process picks."""
    return uuid.uuid4().hex[:12]


# --- Output folders ------------------------------------------------------------------------------


def check_not_replacing(out: StrPath, source: StrPath, what: str, written: str) -> None:
    """Checks that writing the folder `out` (which replaces it whole) keeps `source`.

    Args:
      out: the output folder.
      source: a file or folder the command reads.
      what: `source` in words, for the message ("a folder compared").
      written: what the command writes, for the message ("the report").

    Raises:
      ValueError: naming `out`, where it is `source` or holds it.
    """
    target, read = pathlib.Path(out).resolve(), pathlib.Path(source).resolve()
    if read == target or target in read.parents:
        raise ValueError(f"out: {os.fspath(out)} holds {os.fspath(source)}, {what}, which "
                         f"writing {written} would replace; choose another folder")


# The files that mark a folder as one of jaxpg's results, one pair per command that writes one
# (train, sweep, evaluate, compare). Nothing else is written inside such a folder: writing it
# again replaces it whole, and a folder holding directories is refused as an output.
RESULT_FILES = (("policy.msgpack", "metrics.json"), ("policies.msgpack", "summary.json"),
                ("robustness.json", "robustness.csv"), ("comparison.json", "improvement.png"))


def check_outside_results(path: StrPath, name: str) -> None:
    """Raises a ValueError naming `name` where a folder above `path` holds jaxpg's results
    (`RESULT_FILES`), which writing them again would lose `path` with."""
    for parent in pathlib.Path(path).resolve().parents:
        if any(all((parent / file).is_file() for file in files) for files in RESULT_FILES):
            raise ValueError(f"{name}: {os.fspath(path)} lies inside {parent}, a folder of "
                             "jaxpg's results, which is replaced whole when written again; give "
                             "a place outside it")


def check_path_names(path: StrPath, name: str) -> pathlib.Path:
    """`path` as a `pathlib.Path`, checked that a file system can name it.

    Args:
      path: a file or folder, existing or not.
      name: the name of the argument that gave it, which the message starts with.

    Returns:
      `path` as a `pathlib.Path`.

    Raises:
      ValueError: naming `name` for characters that no file name can hold (a lone surrogate) or
        a part of the path longer than NAME_MAX bytes.
    """
    try:
        parts = [os.fsencode(part) for part in pathlib.Path(path).parts]
    except UnicodeEncodeError:
        raise ValueError(f"{name}: {os.fspath(path)!r} holds characters that no file name can "
                         "hold") from None
    for part in parts:
        if len(part) > NAME_MAX:
            raise ValueError(f"{name}: the name {os.fsdecode(part)[:40]}... is {len(part)} "
                             f"bytes long; a file name holds at most {NAME_MAX}")
    return pathlib.Path(path)


def check_out_dir(out: StrPath) -> pathlib.Path:
    """Checks that the output directory `out` can hold jaxpg's results; creates nothing.

    Refused: an empty path, one that no file system can name (`check_path_names`), one inside
    another folder of results (`check_outside_results`), an existing file (or a file among its
    parents), the working directory
    or a directory above it, and a directory holding other directories, which jaxpg never writes
    (its results are files only).

    Args:
      out: the output directory, existing or not.

    Returns:
      `out` as a `pathlib.Path`.

    Raises:
      ValueError: `out` is refused; the message names `out` and says why.
    """
    if not os.fspath(out):
        raise ValueError("out: expected a directory, got an empty path")
    out = check_path_names(out, "out")
    check_outside_results(out, "out")
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} is a file; give a directory (it is created if missing)")
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"out: {out.parent} is a file, so {out} cannot be created")
            break
    if out.is_dir():
        real, here = out.resolve(), pathlib.Path.cwd().resolve()
        if real == here or real in here.parents:
            raise ValueError(f"out: {out} holds the working directory; give a directory for "
                             "jaxpg's results alone")
        folders = sorted(p.name for p in out.iterdir()
                         if p.is_dir() and not _LEGACY_STAGING.fullmatch(p.name))
        if folders:
            raise ValueError(f"out: {out} holds directories ({', '.join(folders[:3])}), which "
                             "jaxpg never writes; give a new or empty directory, or one that "
                             "jaxpg wrote")
    return out


_LEGACY_STAGING = re.compile(r"\.staging-[0-9a-f]{12}")  # inside the folder, by jaxpg 0.1.0
_held: dict[pathlib.Path, IO[str]] = {}  # the output folders claimed: real path -> its lock file


def claim(out: StrPath) -> pathlib.Path:
    """Locks the output directory `out` against other processes, after checking it.

    `out` is checked (`check_out_dir`) and locked until `staged` has replaced it, this process
    ends, or the block of `claims_released` that claimed it ends; then what killed runs left there
    is removed. Claiming a folder this process holds already does nothing more.

    Args:
      out: the output directory, existing or not (its parents are created).

    Returns:
      `out` as a `pathlib.Path`.

    Raises:
      ValueError: `out` cannot hold results, or another process holds it.
    """
    out = check_out_dir(out)
    real = _real(out)
    if real in _held:
        return out
    try:
        real.parent.mkdir(parents=True, exist_ok=True)
        lock = open(real.parent / temporary_name(real.name, "lock"), "a")
    except OSError as error:
        raise ValueError(f"out: cannot write in {real.parent} ({error.strerror})") from None
    try:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise ValueError(f"out: another jaxpg process is writing to {out}; wait for it to end, "
                         "or give another directory") from None
    _held[real] = lock
    _recover(real)
    return out


@contextlib.contextmanager
def claims_released() -> Iterator[None]:
    """Inside the block, output folders may be claimed; when it ends, however it ends, those still
    held are released: a command that failed after `claim` leaves them to other processes, in a
    process that goes on."""
    before = set(_held)
    try:
        yield
    finally:
        for real in set(_held) - before:
            _release(real)


def _release(real: pathlib.Path) -> None:
    """Unlocks the folder `real` if this process holds it."""
    lock = _held.pop(real, None)
    if lock is not None:
        lock.close()


def _real(out: StrPath) -> pathlib.Path:
    """The folder that `out` names, symbolic links followed: the one that is replaced."""
    return pathlib.Path(os.path.realpath(out))


def _beside(real: pathlib.Path, kind: str) -> list[pathlib.Path]:
    """The entries beside the folder `real` named `temporary_name(real.name, KIND-<12 hex>)`."""
    pattern = temporary_name(real.name, f"{kind}-{'0' * 12}")
    prefix = pattern[:-12]
    return [path for path in real.parent.iterdir()
            if len(path.name) == len(pattern) and path.name.startswith(prefix)
            and re.fullmatch(r"[0-9a-f]{12}", path.name[len(prefix):])]


def _recover(real: pathlib.Path) -> None:
    """Undoes what killed runs left beside and in the folder `real`.

    Puts back an earlier folder left aside, and removes staging folders. Only for a folder this
    process holds the lock of.
    """
    aside = _beside(real, "old")
    if aside and not real.exists():
        os.rename(aside.pop(), real)
    for path in aside + _beside(real, "staging"):
        _remove(path)
    if real.is_dir():
        for path in real.iterdir():
            if path.is_dir() and _LEGACY_STAGING.fullmatch(path.name):
                _remove(path)


@contextlib.contextmanager
def staged(out: StrPath) -> Iterator[pathlib.Path]:
    """Replaces the output directory `out` all at once with the files written in the block.

    When the block ends without an error, the staging folder takes the place of `out` in one step,
    holding the files written there alone: `out`'s earlier files are gone. `out` is claimed
    (`claim`) if it was not, and released at the end, whether the block ended in an error or not.
    On an error, or once `cancel` was called, `out` is left as it was.

    Args:
      out: the output directory, existing or not.

    Yields:
      An empty staging folder (a `pathlib.Path`) beside `out`; write the results there.

    Raises:
      ValueError: as `claim`.
      KeyboardInterrupt: `cancel` was called, and `out` is left as it was.
    """
    out = claim(out)
    real = _real(out)
    staging = real.parent / temporary_name(real.name, f"staging-{_unique()}")
    try:
        staging.mkdir()
        yield staging
        if real.is_dir():
            shutil.copymode(real, staging)
        _sync_folder(staging)
        if _cancelled.is_set():
            raise KeyboardInterrupt
        _replace(staging, real)
    finally:
        _remove(staging)  # after an exchange, the earlier folder
        _release(real)


_cancelled = threading.Event()  # set by `cancel`


def cancel() -> None:
    """From now on, no staging folder of `staged` takes its output folder's place (Ctrl-C).

    Safe to call from any thread, and from a signal handler.
    """
    _cancelled.set()


def _sync_folder(folder: pathlib.Path) -> None:
    """Flushes the files of `folder` and the folder itself to disk.

    So that after a power cut the folder that took the output folder's place is whole too.
    """
    for path in folder.iterdir():
        if path.is_file():
            _fsync(path, os.O_RDONLY)
    _fsync_directory(folder)


def _replace(new: pathlib.Path, out: pathlib.Path) -> None:
    """Puts the folder `new` at `out`, in one step where the system can.

    Afterwards `new` holds the earlier folder, if there was one.
    """
    if not out.exists():
        os.rename(new, out)
    elif not _exchange(new, out):
        aside = out.parent / temporary_name(out.name, f"old-{_unique()}")
        os.rename(out, aside)
        os.rename(new, out)  # a kill just before this is undone by the next claim (`_recover`)
        os.rename(aside, new)
    _fsync_directory(out.parent)


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


@functools.cache
def _renameat2() -> Callable[..., int] | None:
    """glibc's `renameat2`, or None where there is none (not Linux, or glibc before 2.28)."""
    if not sys.platform.startswith("linux"):
        return None
    function = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if function is not None:
        function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                             ctypes.c_uint]
    return function


def _exchange(a: pathlib.Path, b: pathlib.Path) -> bool:
    """Swaps the entries `a` and `b` in one step.

    Returns:
      True once swapped; False where the system or the file system cannot, and then nothing has
      changed.

    Raises:
      OSError: the system could swap them, but failed.
    """
    renameat2 = _renameat2()
    if renameat2 is None:
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    error = ctypes.get_errno()
    if error in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):  # EINVAL: a file system without
        return False
    raise OSError(error, os.strerror(error), os.fspath(b))


def _remove(path: pathlib.Path) -> None:
    """Removes the file, link or folder (with its contents) `path`, if there is one."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


# --- Writing files -------------------------------------------------------------------------------


def to_json(value: Any) -> Any:
    """`value` with arrays and numpy scalars as plain lists and numbers, for `json.dumps`.

    NaN and infinities (a diverged run's) become None, JSON's null, for strict JSON has no such
    numbers.

    Args:
      value: dicts (keys become strings), lists and tuples (become lists), arrays, numbers and
        whatever else `json.dumps` takes, nested.

    Returns:
      The same tree of Python dicts, lists, numbers, strings and None.
    """
    if isinstance(value, dict):
        return {str(k): to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    if hasattr(value, "tolist"):
        return to_json(np.asarray(value).tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: StrPath, value: Any) -> None:
    """Writes `value` as strict JSON (`to_json`), which every JSON reader reads.

    Args:
      path: the file to (over)write.
      value: what `to_json` takes.
    """
    pathlib.Path(path).write_text(json.dumps(to_json(value), indent=2, allow_nan=False) + "\n")


def write_csv(path: StrPath, columns: Mapping[str, npt.ArrayLike]) -> None:
    """Writes columns as a CSV file: a header of their names, then one row per index.

    Args:
      path: the file to (over)write.
      columns: `[N]` values by name, each an array or a list.
    """
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(columns)
    writer.writerows(zip(*(np.asarray(v).tolist() for v in columns.values())))
    pathlib.Path(path).write_text(buffer.getvalue())


# --- Atomic writes -------------------------------------------------------------------------------


_KINDS = ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def file_kind(mode: int) -> str:
    """What a file of `mode` (`os.stat`'s `st_mode`) is, in words: "a FIFO", "a folder", ..."""
    return next((name for test, name in _KINDS if test(mode)), "no file")


def check_replaceable(path: StrPath, name: str) -> None:
    """Checks that writing the file `path` (`atomic_path`) replaces at most a regular file.

    A rename onto a device, a FIFO or a socket would replace it with a file (`/dev/null`, had it
    been given); onto a folder, it fails only once the content is written.

    Args:
      path: the file to write; a link is judged by what it points to.
      name: the name of the argument that gave it, which the message starts with.

    Raises:
      ValueError: naming `name`, where `path` exists as something else than a regular file.
    """
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return  # a new file (or a path that the write itself refuses)
    if not stat.S_ISREG(mode):
        raise ValueError(f"{name}: {os.fspath(path)} is {file_kind(mode)}, not a regular file; "
                         "give a file's path (it is created if missing)")


@contextlib.contextmanager
def atomic_path(path: StrPath) -> Iterator[pathlib.Path]:
    """Yields a temporary path beside `path`; on success, moves the file written there onto `path`.

    The temporary name ends with the same suffix as `path`, so writers that pick a format from
    the file name (imageio, matplotlib) write the right one, and fits in NAME_MAX bytes for any
    `path` whose own name does. The file is locked while it is written, so that
    `remove_stale_temporaries` leaves it. On an exception the temporary file is removed and
    `path` is left as it was.

    Args:
      path: the file to (over)write: a regular file, or a new one.

    Yields:
      A `pathlib.Path` that does not yet hold any content; write the whole file there.

    Raises:
      ValueError: naming `path`, where it exists as something else than a regular file
        (`check_replaceable`), before anything is written.
      OSError: of the kind the system gave, naming `path`'s folder, where no file can be created
        there (a read-only or virtual file system such as /proc, no permission).
    """
    check_replaceable(path, "path")
    path = pathlib.Path(path)
    tmp = path.with_name(temporary_name(path.name, f"{_unique()}.tmp{path.suffix}"))
    # Created here (honouring the umask, unlike mkstemp's 0600) so the name is ours alone.
    try:
        fd = os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
    except OSError as error:  # named by `path`'s folder, not by the temporary file's name
        raise type(error)(error.errno, error.strerror, str(path.parent)) from None
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield tmp
        _fsync(tmp, os.O_RDONLY)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        os.close(fd)
    # The rename is durable only once the directory entry is on disk; not possible on Windows.
    with contextlib.suppress(OSError):
        _fsync_directory(path.parent)


_TEMPORARY = re.compile(r"\..*\.[0-9a-f]{12}\.tmp.*", re.DOTALL)


def remove_stale_temporaries(directory: StrPath) -> None:
    """Removes the temporary files that killed processes' `atomic_path` left in `directory`.

    Files that a process is writing (and so holds locked) stay. Nothing happens where `directory`
    does not exist, or where the system has no advisory locks (Windows).
    """
    if fcntl is None or not pathlib.Path(directory).is_dir():
        return
    for path in pathlib.Path(directory).iterdir():
        if not _TEMPORARY.fullmatch(path.name):
            continue
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:  # renamed into place or removed meanwhile
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            path.unlink(missing_ok=True)
        except BlockingIOError:
            pass  # being written
        finally:
            os.close(fd)


def check_writable(folder: StrPath, what: str) -> None:
    """Checks that a file can be created in the directory `folder`.

    A file is created and removed, for permissions alone do not tell (a read-only file system,
    /proc, root).

    Args:
      folder: an existing directory.
      what: the name of the argument that gave it, which the message starts with.

    Raises:
      ValueError: no file can be created there.
    """
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as error:
        raise ValueError(f"{what}: cannot write in {folder} ({error.strerror})") from None


def private_directory(path: StrPath) -> pathlib.Path:
    """Creates the directory `path` and its missing parents, each for the user alone (0700).

    As the XDG base directory specification asks of cache directories. Existing ones are left
    as they are.

    Args:
      path: the directory.

    Returns:
      `path` as a `pathlib.Path`.

    Raises:
      OSError: a directory cannot be created.
    """
    path = pathlib.Path(path)
    for folder in [*reversed(path.parents), path]:
        if not folder.is_dir():
            with contextlib.suppress(FileExistsError):  # made meanwhile by another process
                folder.mkdir(mode=0o700)
    return path


def _fsync(path: StrPath, flags: int) -> None:
    """Flushes the file `path`, opened with `flags`, to disk."""
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_directory(path: StrPath) -> None:
    """Flushes the directory `path`'s entries to disk (where the system can open a directory)."""
    _fsync(path, getattr(os, "O_DIRECTORY", os.O_RDONLY))


def atomic_write(path: StrPath, data: bytes | str) -> None:
    """Writes `data` (bytes, or str as UTF-8) to `path` so that readers see the old or the new file.

    Args:
      path: the file to (over)write.
      data: the whole content.
    """
    if isinstance(data, str):
        data = data.encode()
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
