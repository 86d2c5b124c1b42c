"""The lower bounds pyproject.toml declares, against .ci/lower-bounds.txt, the pins CI installs.

    python .ci/lower_bounds.py              exit 1 with one line per disagreement, else 0
    python .ci/lower_bounds.py --installed  also exit 1 unless the installed versions are the pins

Every runtime dependency must declare a lower bound (`>=`), and the file must pin (`==`) exactly
those packages at exactly those versions, so that CI's lower-bound environment tests what
pyproject promises. Standard library only: it runs before anything is installed.
"""

import pathlib
import re
import sys
import tomllib

ROOT = pathlib.Path(__file__).resolve().parent.parent
PYPROJECT = ROOT / "pyproject.toml"
PINS = ROOT / ".ci" / "lower-bounds.txt"


def _name(name):
    """A distribution name in its normal form (PEP 503): `ML-Dtypes` and `ml_dtypes` are one."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _same(version, other):
    """Whether two release versions are equal, as `0.5` and `0.5.0` are."""
    def release(v):
        parts = v.split(".")
        while len(parts) > 1 and parts[-1] == "0":
            parts.pop()
        return parts
    return release(version) == release(other)


def declared(pyproject_text):
    """{name: lower bound} of the runtime dependencies, and the problems found reading them."""
    bounds, problems = {}, []
    for requirement in tomllib.loads(pyproject_text)["project"]["dependencies"]:
        match = re.fullmatch(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*([^;]*?)\s*(;.*)?", requirement)
        name, specifiers = _name(match[1]), [s.strip() for s in match[2].split(",") if s.strip()]
        lower = [s[2:].strip() for s in specifiers if s.startswith(">=")]
        if len(lower) != 1:
            problems.append(f"pyproject.toml: {requirement!r} needs exactly one '>=' lower bound")
        else:
            bounds[name] = lower[0]
    return bounds, problems


def pinned(pins_text):
    """{name: version} of the `name==version` lines (comments and blank lines ignored)."""
    pins, problems = {}, []
    for line in pins_text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        match = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)\s*==\s*(\S+)", line)
        if match is None:
            problems.append(f"lower-bounds.txt: {line!r} is not 'name==version'")
        else:
            pins[_name(match[1])] = match[2]
    return pins, problems


def disagreements(pyproject_text, pins_text):
    """One line per way the declared lower bounds and the pins differ; empty when they agree."""
    bounds, problems = declared(pyproject_text)
    pins, pin_problems = pinned(pins_text)
    problems += pin_problems
    for name in sorted(bounds.keys() | pins.keys()):
        if name not in pins:
            problems.append(f"{name}: pyproject.toml declares >={bounds[name]}, "
                            "lower-bounds.txt has no pin")
        elif name not in bounds:
            problems.append(f"{name}: lower-bounds.txt pins {pins[name]}, not a runtime dependency "
                            "with a lower bound in pyproject.toml")
        elif not _same(pins[name], bounds[name]):
            problems.append(f"{name}: pyproject.toml declares >={bounds[name]}, "
                            f"lower-bounds.txt pins {pins[name]}")
    return problems


def not_installed(pins_text):
    """One line per pinned package whose installed version is not its pin."""
    from importlib import metadata

    problems = []
    for name, version in pinned(pins_text)[0].items():
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            installed = None
        if installed != version:
            problems.append(f"{name}: lower-bounds.txt pins {version}, installed is {installed}")
    return problems


def main(argv):
    pins_text = PINS.read_text()
    problems = disagreements(PYPROJECT.read_text(), pins_text)
    if "--installed" in argv:
        problems += not_installed(pins_text)
    for problem in problems:
        print(problem, file=sys.stderr)
    if not problems:
        agreed = ", ".join(f"{n}=={v}" for n, v in pinned(pins_text)[0].items())
        print(f"lower bounds agree: {agreed}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
