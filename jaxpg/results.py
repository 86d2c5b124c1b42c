"""Writing a run's results to an output directory: all files or none.

Files are first written to a staging folder inside the output directory and renamed into place
only once every one of them is complete, so a run that fails (or is killed) leaves an earlier
run's results as they were.
"""

import contextlib
import csv
import io
import json
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
