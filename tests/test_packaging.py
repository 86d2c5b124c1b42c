"""The distribution holds every package of jaxpg, as setuptools finds them from pyproject.toml."""

import pathlib
import tomllib

import setuptools

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_every_package_is_in_the_distribution():
    found = (tomllib.loads((ROOT / "pyproject.toml").read_text())
             ["tool"]["setuptools"]["packages"]["find"])
    included = set(setuptools.find_packages(where=str(ROOT), **found))
    packages = {".".join(init.parent.relative_to(ROOT).parts)
                for init in (ROOT / "jaxpg").rglob("__init__.py")}
    assert packages == included, sorted(packages ^ included)
    assert "jaxpg.envs" in included
