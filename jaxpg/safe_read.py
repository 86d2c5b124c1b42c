"""Reading files that may be damaged or hostile, in bounded size and time.

Every reader opens the path once, without waiting (a FIFO has no writer to wait for), refuses
anything but a regular file (a folder, a FIFO, a device such as /dev/zero), and reads no more
than the caller's bound. What it refuses is a one-line `ValueError` that starts with the path.
"""

import json
import lzma
import math
import os
import stat
import zipfile
import zlib
from collections.abc import Collection
from typing import IO, Any

import numpy as np

from jaxpg.atomic_files import StrPath, file_kind

# Opening a FIFO for reading waits for a writer, unless it is opened without blocking.
_NO_WAIT = getattr(os, "O_NONBLOCK", 0)
# What zipfile and its decompressors raise on a damaged archive, besides ValueError.
_DAMAGED = (zipfile.BadZipFile, zlib.error, lzma.LZMAError, EOFError, OSError,
            NotImplementedError, RuntimeError)
_NPY_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0,
                (2, 0): np.lib.format.read_array_header_2_0}


def open_regular(path: StrPath) -> IO[bytes]:
    """Opens a regular file for reading in binary, refusing anything else before reading a byte.

    Args:
      path: the file.

    Returns:
      The open file, to be closed by the caller (a context manager).

    Raises:
      FileNotFoundError: there is no such file.
      ValueError: starting with `path`, for a folder, a FIFO, a device or a socket.
    """
    fd = os.open(path, os.O_RDONLY | _NO_WAIT)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise ValueError(f"{path}: not a regular file ({file_kind(mode)})")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: StrPath, max_bytes: int) -> bytes:
    """The content of a regular file of at most `max_bytes` bytes.

    Args:
      path: the file.
      max_bytes: the most bytes it may hold; no more are read.

    Returns:
      Its bytes.

    Raises:
      FileNotFoundError: there is no such file.
      ValueError: starting with `path`, for no regular file (`open_regular`), a larger one, or
        one that changed size while it was read.
    """
    with open_regular(path) as file:
        size = os.fstat(file.fileno()).st_size
        if size > max_bytes:
            raise ValueError(f"{path}: {size} bytes, more than the {max_bytes} allowed")
        data = file.read(size + 1)  # one more, to tell a file that grew
    if len(data) != size:
        raise ValueError(f"{path}: changed while it was read")
    return data


def read_json(path: StrPath, max_bytes: int) -> Any:
    """The JSON value of a regular file of at most `max_bytes` bytes.

    Args:
      path: the file.
      max_bytes: the most bytes it may hold.

    Returns:
      The value, as `json.loads` gives it.

    Raises:
      FileNotFoundError: there is no such file.
      ValueError: starting with `path`, as `read_bytes`, or for text that is not JSON, or is
        nested deeper than Python's recursion limit.
    """
    data = read_bytes(path, max_bytes)
    try:
        return json.loads(data)
    except RecursionError:
        raise ValueError(f"{path}: not valid JSON (nested too deeply)") from None
    except ValueError as error:  # JSONDecodeError, UnicodeDecodeError, too many digits
        raise ValueError(f"{path}: not valid JSON ({error})") from None


def read_arrays(path: StrPath, names: Collection[str], max_bytes: int) -> dict[str, np.ndarray]:
    """Arrays of numbers of an `.npz` file, each checked by its header before it is read.

    Args:
      path: the file, as `np.savez` or `np.savez_compressed` writes it.
      names: the arrays to read; those the file lacks are left out.
      max_bytes: the most bytes one array may hold, as its header declares them.

    Returns:
      `{name: array}` for each of `names` that the file holds.

    Raises:
      FileNotFoundError: there is no such file.
      ValueError: starting with `path`, for no regular file (`open_regular`), a damaged or
        truncated archive, or an array that is not of numbers, holds other than its header
        declares, or more than `max_bytes`.
    """
    with open_regular(path) as file:
        try:
            with zipfile.ZipFile(file) as archive:
                held = set(archive.namelist())
                return {name: _read_array(archive, f"{name}.npy", max_bytes)
                        for name in names if f"{name}.npy" in held}
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None
        except _DAMAGED as error:
            raise ValueError(f"{path}: damaged .npz archive ({type(error).__name__}: "
                             f"{error})") from None


def _read_array(archive: zipfile.ZipFile, member: str, max_bytes: int) -> np.ndarray:
    """The array of an `.npy` member of `archive`, read once its header is found to fit.

    Raises:
      ValueError: starting with `member`, for a header that is no `.npy` header of numbers, or
        that declares more than `max_bytes` or another size than the member holds.
    """
    info = archive.getinfo(member)
    with archive.open(info) as file:
        try:
            read_header = _NPY_HEADERS.get(np.lib.format.read_magic(file))
            if read_header is None:
                raise ValueError("a format version this reader does not know")
            shape, _, dtype = read_header(file)
        except ValueError as error:
            raise ValueError(f"{member}: no .npy header ({error})") from None
        data_bytes = info.file_size - file.tell()
    if dtype.kind not in "fiu" or min(shape, default=0) < 0:
        raise ValueError(f"{member}: expected an array of numbers, got shape {shape} of {dtype}")
    declared = math.prod(shape) * dtype.itemsize
    if declared > max_bytes:
        raise ValueError(f"{member}: its header declares shape {shape} of {dtype}, "
                         f"{declared} bytes, more than the {max_bytes} allowed")
    if declared != data_bytes:
        raise ValueError(f"{member}: its header declares {declared} bytes of data, the archive "
                         f"holds {data_bytes}")
    with archive.open(info) as file:
        return np.lib.format.read_array(file, allow_pickle=False)
