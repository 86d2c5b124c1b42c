"""Names for the types that jaxpg's functions take and return.

Shapes are written in docstrings: `[T, E]` is time by episodes, `[S, ...]` runs (seeds) first,
`[G, S, ...]` grid settings by seeds.
"""

from collections.abc import Callable
from typing import Any

import jax
import numpy as np

Array = jax.Array
ArrayLike = jax.typing.ArrayLike
PRNGKey = jax.Array  # a key of `jax.random.PRNGKey`: uint32 `[2]`, or `[..., 2]` for several
Params = Any  # a pytree of arrays: a flax module's parameters, an optimizer's state
Observation = jax.Array  # float32 `[..., 4]`: cart position and velocity, pole angle and velocity
Action = jax.Array  # int32 `[...]`: 0 pushes the cart left, 1 right
# A policy as rollouts call it: (observations `[E, 4]`, uniforms `[E]` in [0, 1)) -> actions `[E]`.
Policy = Callable[[Observation, jax.Array], Action]
HostArray = np.ndarray  # an array on the host, as numpy gives it
