"""Checks of arguments, shared by every module that takes them.

Each check returns the value it accepts, converted, or raises a one-line `ValueError` that names the
argument and says what is allowed. They use numpy only, so that a check runs before JAX starts or
compiles anything.
"""

import re
from collections.abc import Callable, Collection
from typing import Any

import numpy as np
import numpy.typing as npt

MAX_SHOWN = 200  # characters of a value that a message shows, at most


def shown(value: Any) -> str:
    """`repr(value)` on one line, cut to `MAX_SHOWN` characters, for a one-line message.

    An array's repr spans several lines, each after the first indented, and a large one's runs
    long (a string's repr holds no line break: it escapes them).
    """
    text = re.sub(r"\n\s*", " ", repr(value))
    return text if len(text) <= MAX_SHOWN else f"{text[:MAX_SHOWN - 3]}..."


def check_bool(name: str, value: Any) -> bool:
    """`value` as a `bool`; a ValueError naming `name` unless it is True or False (numpy's too),
    not any value that is truthy."""
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"{name}: must be True or False, got {shown(value)}")
    return bool(value)


def is_int(value: Any) -> bool:
    """Whether `value` is a Python or numpy integer (a bool is not one)."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def check_int(name: str, value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """`value` as an `int`; a ValueError naming `name` unless it is an integer in range.

    Args:
      name: the argument's name, which the message starts with.
      value: a Python or numpy integer (a bool is not one).
      minimum: the smallest value allowed.
      maximum: optional: the first value not allowed above `minimum` (`[minimum, maximum)`).

    Returns:
      `value` as a Python `int`.
    """
    if not is_int(value) or value < minimum or (maximum is not None and value >= maximum):
        raise ValueError(f"{name}: must be {_int_range(minimum, maximum)}, got {shown(value)}")
    return int(value)


def _int_range(minimum: int, maximum: int | None) -> str:
    """How `check_int` words its range."""
    if maximum is not None:
        power = maximum.bit_length() - 1
        top = f"2**{power}" if maximum == 2**power >= 1024 else str(maximum)
        return f"an integer in [{minimum}, {top})"
    return {0: "a non-negative integer", 1: "a positive integer"}.get(
        minimum, f"an integer of at least {minimum}")


def check_callback(name: str, callback: Any, signature: str) -> None:
    """A ValueError naming `name` unless `callback` is None or a function (`signature` says which,
    as the message does)."""
    if callback is not None and not callable(callback):
        raise ValueError(f"{name}: must be a function {signature} or None, got "
                         f"{type(callback).__name__}")


def check_number(name: str, value: Any) -> float:
    """`value` as a float; a ValueError naming `name` unless it is one finite real number.

    Args:
      name: the argument's name, which the message starts with.
      value: an int or a float of Python, numpy or JAX (not a bool, a string or a list, which a
        sweep's grid holds).

    Returns:
      `value` as a Python `float`.
    """
    array = np.asarray(value)
    if array.ndim != 0 or array.dtype.kind not in "iuf":
        hint = " (one value; a sweep's grid takes several)" if array.ndim else ""
        raise ValueError(f"{name}: must be a number{hint}, got {shown(value)}")
    return float(check_finite(name, array))


def check_finite(name: str, values: Any) -> np.ndarray:
    """`values` as a numpy array; a ValueError naming `name` unless every entry is finite.

    Args:
      name: the argument's name, which the message starts with.
      values: a number or an array of them, of any shape (not bools or strings).

    Returns:
      `values` as a numpy array.
    """
    try:
        array = np.asarray(values)
    except ValueError:  # numpy's word for nested lists of other lengths
        raise ValueError(f"{name}: must be numbers in rows of one length, got {shown(values)}"
                         ) from None
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{name}: must be a number, got {shown(values)}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: must be finite, got NaN or infinity")
    return array


def check_representable(name: str, values: Any, dtype: npt.DTypeLike,
                         positive: bool = False) -> np.ndarray:
    """`values` in `dtype`; a ValueError naming `name` unless each value means there what it says.

    A number finite as given can overflow to infinity in a narrower float (1e308 in float32).
    Where it must be positive, it must also be at least the dtype's smallest normal number: below
    it a value rounds to 0 (1e-300 in float32) or to a subnormal one (1e-40), which keeps a few
    bits or none, so a time step freezes the cart and a learning rate stops learning.

    Args:
      name: the argument's name, which the message starts with.
      values: finite numbers (`check_finite`), of any shape; `inf` for a derived value that
        overflowed float64 already (`in_float64`).
      dtype: the float dtype that the computation uses.
      positive: whether the values are positive ones (0 and negative values pass: the caller
        refuses them with its own range).

    Returns:
      `values` in `dtype`.
    """
    array = np.asarray(values)
    info = np.finfo(dtype)
    with np.errstate(over="ignore", under="ignore"):
        cast = array.astype(dtype)
    overflows = ~np.isfinite(cast)
    if overflows.any():
        raise ValueError(f"{name}: must be at most {info.max:.4g} in magnitude (the largest "
                         f"{info.dtype}), got {float(array[overflows].flat[0])!r}")
    if positive:
        underflows = (array > 0) & (cast < info.smallest_normal)
        if underflows.any():
            raise ValueError(f"{name}: must be at least {info.smallest_normal:.4g} (the smallest "
                             f"normal {info.dtype}), got {float(array[underflows].flat[0])!r}")
    return cast


def in_float64(operation: Callable[..., Any], *operands: Any) -> np.ndarray:
    """`operation` of `operands` taken in float64: infinite, without a warning, where it overflows.

    Args:
      operation: a numpy function or operator, such as `np.multiply`.
      *operands: numbers or arrays.

    Returns:
      The result, a float64 array, for `check_representable` to check in a narrower dtype.
    """
    with np.errstate(over="ignore"):
        return np.asarray(operation(*(np.asarray(x, np.float64) for x in operands)))


def check_choice(name: str, value: Any, allowed: Collection[str], what: str = "") -> str:
    """`value`; a ValueError naming `name` and listing `allowed` unless it is one of them.

    Args:
      name: the argument's name, which the message starts with.
      value: the value given.
      allowed: the values allowed, in the order the message lists them.
      what: optional: a word for the kind of value (`"preset"`), put before it in the message.
    """
    if not isinstance(value, str) or value not in allowed:
        kind = f"{what} " if what else ""
        raise ValueError(f"{name}: unknown {kind}{shown(value)}; allowed: {', '.join(allowed)}")
    return value
