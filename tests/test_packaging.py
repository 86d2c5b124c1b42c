"""The distribution holds every package of jaxpg, as setuptools finds them from pyproject.toml."""

import pathlib
import tomllib

import setuptools

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_every_package_is_in_the_distribution():
    found = (tomllib.loads((ROOT / "pyproject.toml").read_text())
             ["tool"]["setuptools"]["packages"]["find"])
    assert found["namespaces"] is False  # setuptools' find_packages: folders with __init__.py
    included = set(setuptools.find_packages(where=str(ROOT), include=found["include"]))
    # Every folder of modules, with or without an `__init__.py` (which setuptools would skip).
    packages = {".".join(module.parent.relative_to(ROOT).parts)
                for module in (ROOT / "jaxpg").rglob("*.py")}
    assert packages == included, sorted(packages ^ included)
    assert "jaxpg.envs" in included
