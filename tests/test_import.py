"""`import jaxpg` imports neither JAX nor Gymnasium; its names and Gymnasium's ids still work."""

import importlib
import json
import subprocess
import sys

import gymnasium
import pytest

import jaxpg
from jaxpg import cartpole

HEAVY = ("numpy", "jax", "flax", "optax", "gymnasium")


def _python(code):
    """What `code` prints, run by a fresh Python (this one has imported JAX), as JSON."""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.mark.parametrize("module", ["jaxpg", "jaxpg.cli"])  # (jaxpg.cli: the command's start)
def test_importing_the_package_or_the_command_imports_nothing_heavy(module):
    loaded = _python(f"import json, sys, {module}\n"
                     f"print(json.dumps([m for m in {HEAVY} if m in sys.modules]))")
    assert loaded == []


MODULES = {"cartpole": "jaxpg.envs.cartpole", "conformance": "jaxpg.envs.conformance",
           "gym": "jaxpg.envs.gym", "losses": "jaxpg.losses", "render": "jaxpg.animation"}


@pytest.mark.parametrize("name", sorted({*jaxpg.__all__, *MODULES}))
def test_each_public_name_imports_as_before(name):
    namespace = {}
    exec(f"from jaxpg import {name}", namespace)
    value = namespace[name]
    assert name in dir(jaxpg) and getattr(jaxpg, name) is value
    if name in MODULES:  # a module: CartPole's, its adapters' and their harness are in envs
        assert value is importlib.import_module(MODULES[name])
    else:  # a function or class of one of jaxpg's modules
        assert getattr(importlib.import_module(value.__module__), name) is value
        assert value.__module__.startswith("jaxpg.")


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'trian'"):
        jaxpg.trian  # noqa: B018


@pytest.mark.parametrize("imports", [
    "import jaxpg\nimport gymnasium",
    "import gymnasium\nimport jaxpg",
    "import jaxpg\nfrom jaxpg import types, train\nimport gymnasium",  # jaxpg.types: no `types`
])
def test_gymnasium_makes_jaxpgs_ids_whichever_is_imported_first(imports):
    found = _python(imports + """
import json, sys
jax_on_import = "jax" in sys.modules
env = gymnasium.make("jaxpg/CartPole-v0")
envs = gymnasium.make_vec("jaxpg/CartPole-v0", 2)
print(json.dumps({"jax_on_import": jax_on_import, "env": type(env.unwrapped).__module__,
                  "limit": env.spec.max_episode_steps, "vector_limit": envs.max_episode_steps,
                  "vector": type(envs).__module__}))
""")
    # JAX on registration only where the lines above imported it (`train`).
    assert found == {"jax_on_import": "train" in imports, "env": "jaxpg.envs.gym", "limit": 200,
                     "vector_limit": 200, "vector": "jaxpg.envs.gym"}


def test_the_ids_have_jaxpgs_time_limits_and_thresholds():
    for name, env_params in cartpole.PRESETS.items():
        spec = gymnasium.spec(f"jaxpg/{name}")
        assert spec.max_episode_steps == env_params.max_steps
        assert spec.reward_threshold == cartpole.REWARD_THRESHOLDS[name]
