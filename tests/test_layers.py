"""The layout's one-way flow of imports: envs <- core <- host <- analysis <- cli
(docs/api.md, "Layout")."""

import ast
import pathlib

import pytest

import jaxpg

PACKAGE = pathlib.Path(jaxpg.__file__).parent
# Helpers every layer may use: jaxpg's types, argument checks, random numbers and fixed-order sums.
SHARED = {"types", "validation", "rng", "sums", "fastmath"}
LAYERS = {
    "envs": {"envs", "_register_ids"},  # every module of jaxpg/envs, and the ids' registration
    "core": {"distributions", "policies", "losses", "returns", "rollout", "runwise", "replay",
             "hand_gradient", "iteration", "train_config"},
    "host": {"reinforce", "atomic_files", "safe_read", "executables", "programs", "schedule",
             "budget", "progress", "sweeps", "xla_options", "checkpoint"},
    "analysis": {"evaluation", "stats", "report", "plots", "results", "animation"},
    "cli": {"cli", "__main__"},  # the command, and its entry point
}
ORDER = list(LAYERS)
# The harness that plays whole episodes in jaxpg and in Gymnasium through `evaluate`: it checks the
# environments with the rest of the library, and nothing of the library imports it.
HARNESS = "envs.conformance"


def _name(path):
    """The module's name inside the package: `iteration`, `envs.cartpole`, `envs`."""
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


PATHS = {_name(p): p for p in PACKAGE.rglob("*.py") if _name(p)}  # (the package's own: left out)
MODULES = sorted(PATHS)


def _layer(name):
    """The layer of a module of jaxpg's, or None for a shared helper."""
    top = name.split(".")[0]
    if top in SHARED:
        return None
    return next(layer for layer, members in LAYERS.items() if top in members)


def _imports(path):
    """The modules of jaxpg's that `path` imports, anywhere in it (inside functions too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("jaxpg"):
            base = node.module.removeprefix("jaxpg").lstrip(".")
            for alias in node.names:  # `from jaxpg import envs`, `from jaxpg.envs import gym`
                name = f"{base}.{alias.name}".lstrip(".") if base in ("", "envs") else base
                # a public name of the package's (`from jaxpg import cartpole`): its module
                found.add(jaxpg._MODULES.get(name, jaxpg._DEFINED_IN.get(name, name)))
        elif isinstance(node, ast.Import):
            found |= {a.name.removeprefix("jaxpg.") for a in node.names
                      if a.name.startswith("jaxpg.")}
    return {name for name in found if name in PATHS}  # (a module's names: its module)


def test_every_module_has_a_layer():
    unplaced = [name for name in MODULES
                if name.split(".")[0] not in SHARED | set().union(*LAYERS.values())]
    assert unplaced == []


@pytest.mark.parametrize("name", [m for m in MODULES if m != HARNESS])
def test_a_module_imports_nothing_of_the_layers_after_its_own(name):
    own = _layer(name)
    later = [imported for imported in _imports(PATHS[name]) if imported != HARNESS
             and _layer(imported) is not None
             and (own is None or ORDER.index(_layer(imported)) > ORDER.index(own))]
    assert later == []


def test_nothing_imports_the_command_or_the_harness():
    importers = {name for name in MODULES
                 if _layer(name) != "cli" and {"cli", HARNESS} & _imports(PATHS[name])}
    assert importers == set()
