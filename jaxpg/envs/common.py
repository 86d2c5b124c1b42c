"""What the classic-control environments share: checks of their settings and actions, and states
as arrays.

Every check reads concrete values only and skips values under a trace (inside jit, vmap or grad),
so a sweep can vmap over any number of an environment's settings.
"""

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Protocol, Self, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg.types import ArrayLike
from jaxpg.validation import check_choice, check_finite, check_representable

MAX_STEPS_LIMIT = 2**31  # episodes count their steps in int32


class EnvParams(Protocol):
    """What the checks read of an environment's settings: a `flax.struct` dataclass.

    Attributes:
      max_steps: Gymnasium's TimeLimit: an episode is truncated once this many steps were taken.
    """

    __dataclass_fields__: ClassVar[dict[str, Any]]
    max_steps: Any

    def replace(self, **updates: Any) -> Self: ...


Params = TypeVar("Params", bound=EnvParams)


def concrete(value: ArrayLike) -> np.ndarray | None:
    """The value as numpy, or None when it is traced (inside jit, vmap or grad)."""
    if isinstance(value, jax.core.Tracer):
        return None
    return np.asarray(value)


def check_numbers(env_params: EnvParams, kind: type, positive: tuple[str, ...]) -> None:
    """Checks the numbers (the pytree fields) of `env_params`.

    Args:
      env_params: the settings.
      kind: the dataclass `env_params` must be an instance of.
      positive: the names of the fields that must be above 0.

    Raises:
      ValueError: naming the first invalid field: `env_params` not a `kind`, a value that is not
        finite, one of `positive` at or below 0, a `max_steps` that is not an integer in
        [1, MAX_STEPS_LIMIT), or a float that JAX's default float cannot hold
        (`check_representable`: 1e39 overflows float32, and a positive 1e-300 is 0 there).
    """
    if not isinstance(env_params, kind):
        raise ValueError(f"env_params: expected a {kind.__name__}, got "
                         f"{type(env_params).__name__}")
    floats = jax.dtypes.canonicalize_dtype(float)  # what `step` computes in
    for field in dataclasses.fields(env_params):
        value = concrete(getattr(env_params, field.name))
        if field.metadata.get("pytree_node", True) and value is not None:
            check_finite(field.name, value)
            if value.dtype.kind == "f":
                check_representable(field.name, value, floats, field.name in positive)
    steps = concrete(env_params.max_steps)
    if steps is not None and not (steps.dtype.kind in "iu" and np.all(steps < MAX_STEPS_LIMIT)):
        raise ValueError(f"max_steps: must be an integer in [1, 2**31), got {steps}")
    for name in ("max_steps", *positive):
        value = concrete(getattr(env_params, name))
        if value is not None and not np.all(value > 0):
            raise ValueError(f"{name}: must be positive, got {value}")


def check_below(env_params: EnvParams, low: str, high: str) -> None:
    """A ValueError naming `low` unless the field `low` of `env_params` is below field `high`."""
    low_value = concrete(getattr(env_params, low))
    high_value = concrete(getattr(env_params, high))
    if low_value is not None and high_value is not None and not np.all(low_value < high_value):
        raise ValueError(f"{low}: must be below {high}, got {low_value} >= {high_value}")


def make_params(presets: Mapping[str, Params], check: Callable[[Params], None], env: str,
                overrides: Mapping[str, Any]) -> Params:
    """A preset by name, with any field overridden, validated.

    Args:
      presets: the settings of each environment id.
      check: the environment's `check_params`.
      env: an id of `presets`.
      overrides: values of fields of the preset.

    Returns:
      The settings.

    Raises:
      ValueError: for an unknown preset or field, or an invalid value (`check`).
    """
    check_choice("env", env, presets, "preset")
    preset = presets[env]
    unknown = set(overrides) - {field.name for field in dataclasses.fields(preset)}
    if unknown:
        raise ValueError(f"env_params: unknown field(s) {', '.join(sorted(unknown))}")
    env_params = preset.replace(**overrides)
    check(env_params)
    return env_params


def check_discrete_action(action: ArrayLike, num_actions: int, meaning: str) -> None:
    """In eager use, a ValueError unless every action is an integer in [0, num_actions).

    Args:
      action: the actions, of any shape.
      num_actions: how many actions there are.
      meaning: what each action does, for the message.
    """
    value = concrete(action)
    if value is not None and not np.all(np.isin(value, np.arange(num_actions))):
        raise ValueError(f"action: must be {meaning}, got {value}")


def centred_action(action: ArrayLike, dtype: Any) -> jax.Array:
    """Actions 0, 1, 2 as -1, 0, +1 in `dtype`, the direction each pushes, of any integer dtype.

    The action is converted before 1 is taken away: an unsigned 0 less 1 would wrap round to its
    dtype's largest value (255 for uint8), a push of that size the other way.
    """
    return jnp.asarray(action).astype(dtype) - 1


def check_continuous_action(action: ArrayLike) -> None:
    """In eager use, a ValueError unless every action is a finite number (any finite value is
    clipped to the action's range)."""
    value = concrete(action)
    if value is not None:
        check_finite("action", value)


class ArrayState:
    """A state's physical values as one array; a mixin of the environments' state dataclasses.

    Attributes:
      VALUES: the names of the physical fields, in the order of the array's last axis.
    """

    VALUES: ClassVar[tuple[str, ...]]

    @classmethod
    def from_array(cls, values: ArrayLike, time: ArrayLike = 0) -> Self:
        """Builds a state from values in the order of `VALUES`, e.g. Gymnasium's state.

        Args:
          values: `[..., K]` values, K = len(VALUES); integers become the default float dtype.
          time: int steps taken, broadcast to `[...]`.

        Returns:
          A state with `[...]` leaves.

        Raises:
          ValueError: if `values` is not shaped `[..., K]`.
        """
        return cls(**array_fields(cls.VALUES, values, time))

    def to_array(self, axis: int = -1) -> jax.Array:
        """The physical values as `[..., K]`, or with the K values on another `axis`."""
        return jnp.stack([getattr(self, name) for name in self.VALUES], axis=axis)


def array_fields(names: tuple[str, ...], values: ArrayLike, time: ArrayLike) -> dict[str, Any]:
    """The fields `names` and `time` of a state, from `values` `[..., K]` (`ArrayState`)."""
    values = jnp.asarray(values)
    if values.ndim == 0 or values.shape[-1] != len(names):
        raise ValueError(
            f"state: expected an array of shape [..., {len(names)}] ({', '.join(names)}), "
            f"got shape {tuple(values.shape)}"
        )
    if not jnp.issubdtype(values.dtype, jnp.floating):
        values = values.astype(jnp.result_type(float))
    fields = {name: values[..., i] for i, name in enumerate(names)}
    fields["time"] = jnp.broadcast_to(jnp.asarray(time, jnp.int32), values.shape[:-1])
    return fields


def float32_values(value: jax.Array) -> jax.Array:
    """`value` rounded to float32 and kept in its own dtype, as Gymnasium stores some states."""
    return value.astype(jnp.float32).astype(value.dtype)
