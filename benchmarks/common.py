"""Helpers shared by the benchmark scripts: machine and versions, timing, tables, JSON, charts."""

import datetime
import importlib
import importlib.metadata
import json
import math
import os
import pathlib
import platform
import resource
import statistics
import sys
import time

from jaxpg.schedule import usable_cores

RESULTS_DIR = pathlib.Path(__file__).resolve().parent / "results"

PACKAGES = ("jax", "jaxlib", "numpy", "gymnasium", "flax", "optax", "chex", "gymnax")


# ---------------------------------------------------------------- machine and versions


def _cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory_gib():
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    return round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return None


def machine_info():
    """Cores, CPU model, memory and OS of this machine, and the load when the run started."""
    return {
        "cpu_model": _cpu_model(),
        "cores": os.cpu_count(),
        "usable_cores": usable_cores(),
        "memory_gib": _memory_gib(),
        "os": platform.platform(),
        "load_average_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def library_versions():
    """Python and the installed version of each library that matters here (None if absent)."""
    versions = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    try:
        import jax

        versions["jax_backend"] = jax.default_backend()
        versions["jax_devices"] = [str(d) for d in jax.devices()]
        versions["xla_flags"] = os.environ.get("XLA_FLAGS", "")
    except ImportError:
        pass
    return versions


def optional_import(name, hint=""):
    """The module, or None with a message saying what is skipped."""
    try:
        return importlib.import_module(name)
    except ImportError as error:
        print(f"{name} is not importable ({error}); skipping it. {hint}".rstrip())
        return None


def peak_rss_mib():
    """Peak resident memory of this process so far (Linux reports ru_maxrss in KiB)."""
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    scale = 1 / 2**20 if sys.platform == "darwin" else 1 / 2**10
    return round(kib * scale, 1)


# ---------------------------------------------------------------- timing


def compile_jitted(jitted, *args):
    """Traces and compiles a jitted function for `args`, timed apart from running it.

    Returns:
      (compiled function, {"lower_s": tracing and lowering, "compile_s": XLA compilation})
    """
    start = time.perf_counter()
    lowered = jitted.lower(*args)
    lowered_at = time.perf_counter()
    compiled = lowered.compile()
    done = time.perf_counter()
    return compiled, {"lower_s": lowered_at - start, "compile_s": done - lowered_at}


def time_calls(fn, *args, repeats=3):
    """Runs `fn(*args)` `repeats` (at least 1) times, waiting for its result each time.

    Returns:
      ({"median_s", "min_s", "times_s"} in seconds, the last call's result)
    """
    import jax

    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        result = jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return {"median_s": statistics.median(times), "min_s": min(times), "times_s": times}, result


def scaled_length(length, elapsed, target_s, lowest=1, highest=2**24):
    """A new loop length so that a run that took `elapsed` seconds takes about `target_s`.

    Rounded to a power of two so that repeated runs of this script compile the same programs.
    """
    wanted = length * target_s / max(elapsed, 1e-9)
    power = 2 ** round(max(0.0, math.log2(max(wanted, 1))))
    return int(min(max(power, lowest), highest))


# ---------------------------------------------------------------- output


def format_value(value):
    if isinstance(value, float):
        if value == 0 or 1e-3 <= abs(value) < 1e6:
            return f"{value:,.3f}" if abs(value) < 100 else f"{value:,.0f}"
        return f"{value:.3e}"
    if value is None:
        return "-"
    return str(value)


def print_table(rows, columns, title=None):
    """Prints `rows` (dicts) as an aligned text table of the given columns."""
    cells = [[format_value(row.get(c)) for c in columns] for row in rows]
    widths = [max([len(c)] + [len(r[i]) for r in cells]) for i, c in enumerate(columns)]
    if title:
        print(f"\n{title}")
    print("  ".join(c.rjust(w) for c, w in zip(columns, widths)))
    print("  ".join("-" * w for w in widths))
    for r in cells:
        print("  ".join(v.rjust(w) for v, w in zip(r, widths)))


def timestamp():
    return datetime.datetime.now().strftime("%Y%m%d-%H%M%S")


def write_results(name, args, rows, **extra):
    """Writes `benchmarks/results/<name>-<timestamp>.json` with machine, versions, args and rows.

    Returns:
      the path written.
    """
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}-{timestamp()}.json"
    record = {
        "benchmark": name,
        "created": datetime.datetime.now().isoformat(timespec="seconds"),
        "command": [sys.executable] + sys.argv,
        "machine": machine_info(),
        "versions": library_versions(),
        "args": vars(args) if hasattr(args, "__dict__") else args,
        "rows": rows,
        "peak_rss_mib": peak_rss_mib(),
        **extra,
    }
    path.write_text(json.dumps(record, indent=2, default=_jsonable) + "\n")
    print(f"\nwrote {path}")
    return path


def _jsonable(value):
    if hasattr(value, "tolist"):  # numpy and jax arrays and scalars
        return value.tolist()
    return str(value)


def write_chart(rows, json_path, title, **kwargs):
    """A throughput PNG beside the JSON, via `jaxpg.plots.throughput_chart` when it exists.

    `rows` are dicts {"impl": str, "n": int, "steps_per_s": float}; `kwargs` go to the chart.
    """
    try:
        from jaxpg.plots import throughput_chart
    except ImportError as error:
        print(f"no chart: jaxpg.plots.throughput_chart is not available ({error})")
        return None
    path = pathlib.Path(json_path).with_suffix(".png")
    throughput_chart(rows, path, title, **kwargs)
    print(f"wrote {path}")
    return path


def print_header(title):
    """The machine and versions, printed before the measurements."""
    machine, versions = machine_info(), library_versions()
    print(title)
    print(f"machine: {machine['cpu_model']}, {machine['usable_cores']} usable of "
          f"{machine['cores']} cores, {machine['memory_gib']} GiB, {machine['os']}, "
          f"load {machine['load_average_1_5_15']}")
    print("versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()
                                    if k != "jax_devices" and v is not None))
