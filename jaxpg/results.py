"""Writing files so that a failure never loses or corrupts what was there before.

A run's results go to an output directory all or none: they are first written to a staging
folder inside it and renamed into place only once every one of them is complete, so a run that
fails (or is killed) leaves an earlier run's results as they were.

Every single file jaxpg writes (checkpoints, animations, plots, kept programs) goes through
`atomic_path`: the content is written to a temporary file in the same directory, flushed to disk,
then renamed over the target, so a crash mid-write leaves the previous file intact (and perhaps a
stray `.NAME.*.tmp*` file beside it).
"""

import contextlib
import csv
import io
import json
import os
import pathlib
import shutil
import uuid

import numpy as np


def check_out_dir(out):
    """The output directory as a Path; a ValueError when it names an existing file."""
    out = pathlib.Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} is a file; give a directory (it is created if missing)")
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"out: {parent} is a file, so {out} cannot be created")
            break
    return out


@contextlib.contextmanager
def staged(out):
    """Yields a staging folder; on success its files replace those of the same name in `out`."""
    out = check_out_dir(out)
    out.mkdir(parents=True, exist_ok=True)
    staging = out / f".staging-{uuid.uuid4().hex[:12]}"
    staging.mkdir()
    try:
        yield staging
        for path in sorted(staging.iterdir()):
            path.replace(out / path.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def to_json(value):
    """Arrays and numpy scalars as plain lists and numbers, for `json.dumps`."""
    if isinstance(value, dict):
        return {str(k): to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    if hasattr(value, "tolist"):
        return to_json(np.asarray(value).tolist())
    return value


def write_json(path, value):
    pathlib.Path(path).write_text(json.dumps(to_json(value), indent=2) + "\n")


def write_csv(path, columns):
    """Writes `{name: [N] values}` as a CSV with one row per index."""
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(columns)
    writer.writerows(zip(*(np.asarray(v).tolist() for v in columns.values())))
    pathlib.Path(path).write_text(buffer.getvalue())


# --- Atomic writes -------------------------------------------------------------------------------


@contextlib.contextmanager
def atomic_path(path):
    """Yields a temporary path beside `path`; on success, moves the file written there onto `path`.

    The temporary name ends with the same suffix as `path`, so writers that pick a format from
    the file name (imageio, matplotlib) write the right one. On an exception the temporary file
    is removed and `path` is left as it was.

    Args:
      path: the file to (over)write.

    Yields:
      A `pathlib.Path` that does not yet hold any content; write the whole file there.
    """
    path = pathlib.Path(path)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp{path.suffix}")
    # Created here (honouring the umask, unlike mkstemp's 0600) so the name is ours alone.
    os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
    try:
        yield tmp
        _fsync(tmp, os.O_RDONLY)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    # The rename is durable only once the directory entry is on disk; not possible on Windows.
    with contextlib.suppress(OSError):
        _fsync(path.parent, getattr(os, "O_DIRECTORY", os.O_RDONLY))


def _fsync(path, flags):
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path, data):
    """Writes `data` (bytes, or str as UTF-8) to `path` so that readers see the old or the new file.

    Args:
      path: the file to (over)write.
      data: the whole content.
    """
    if isinstance(data, str):
        data = data.encode()
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
