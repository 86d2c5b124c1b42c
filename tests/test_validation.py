import warnings

import numpy as np
import pytest

from jaxpg.validation import (
    check_choice,
    check_finite,
    check_int,
    check_number,
    check_representable,
    in_float64,
    shown,
)

F32 = np.finfo(np.float32)


@pytest.mark.parametrize("value", [0, 7, np.int64(7), np.uint32(2**32 - 1)])
def test_integers_in_range_pass_as_python_ints(value):
    got = check_int("seed", value, 0, 2**32)
    assert got == value and type(got) is int


@pytest.mark.parametrize(("value", "minimum", "maximum", "message"), [
    (True, 0, None, r"^seed: must be a non-negative integer, got True$"),
    (1.0, 1, None, r"^seed: must be a positive integer, got 1.0$"),
    ("3", 1, None, r"^seed: must be a positive integer, got '3'$"),
    (-1, 0, 2**32, r"^seed: must be an integer in \[0, 2\*\*32\), got -1$"),
    (2**32, 0, 2**32, r"^seed: must be an integer in \[0, 2\*\*32\), got 4294967296$"),
    (3, 5, None, r"^seed: must be an integer of at least 5, got 3$"),
    (10, 0, 10, r"^seed: must be an integer in \[0, 10\), got 10$"),
])
def test_other_integers_are_one_line_errors_naming_the_argument(value, minimum, maximum, message):
    with pytest.raises(ValueError, match=message):
        check_int("seed", value, minimum, maximum)


@pytest.mark.parametrize("value", [0.5, 3, np.float32(0.25), np.int8(-2)])
def test_finite_real_numbers_pass_as_floats(value):
    got = check_number("discount", value)
    assert got == float(value) and type(got) is float


@pytest.mark.parametrize(("value", "message"), [
    (True, r"^discount: must be a number, got True$"),
    ("0.9", r"^discount: must be a number, got '0.9'$"),
    ([0.9, 0.95], r"^discount: must be a number \(one value; a sweep's grid takes several\)"),
    (float("nan"), r"^discount: must be finite, got NaN or infinity$"),
])
def test_other_numbers_are_one_line_errors_naming_the_argument(value, message):
    with pytest.raises(ValueError, match=message):
        check_number("discount", value)


@pytest.mark.parametrize(("values", "message"), [
    ([1.0, np.inf], r"^scores: must be finite, got NaN or infinity$"),
    (np.array([[0.5], [np.nan]]), r"^scores: must be finite, got NaN or infinity$"),
    (["a"], r"^scores: must be a number, got \['a'\]$"),
])
def test_arrays_with_an_entry_not_finite_are_one_line_errors(values, message):
    np.testing.assert_array_equal(check_finite("scores", [[1, 2]]), [[1, 2]])
    with pytest.raises(ValueError, match=message):
        check_finite("scores", values)


def test_a_choice_outside_the_allowed_names_them_all():
    assert check_choice("backend", "jaxpg", ("jaxpg", "gymnasium")) == "jaxpg"
    with pytest.raises(ValueError, match=r"^env: unknown preset 'v2'; allowed: a, b$"):
        check_choice("env", "v2", ("a", "b"), "preset")
    with pytest.raises(ValueError, match=r"^backend: unknown \['jaxpg'\]; allowed: jaxpg$"):
        check_choice("backend", ["jaxpg"], ("jaxpg",))


@pytest.mark.parametrize(("value", "positive"), [
    (0.02, True), (-3e38, False), (float(F32.max), False), (float(F32.smallest_normal), True),
    (1e-300, False),  # underflows to 0, which a field that may be 0 allows
    (0.0, True), (-1e-300, True),  # not positive: the caller's own range refuses them
    (np.array([[0.5, 2.0]]), True),
])
def test_values_that_float32_holds_pass_converted(value, positive):
    got = check_representable("tau", value, np.float32, positive)
    assert got.dtype == np.float32 and got.shape == np.shape(value)
    np.testing.assert_array_equal(got, np.asarray(value, np.float32))


@pytest.mark.parametrize(("value", "positive", "message"), [
    (1e308, False, r"^tau: must be at most 3\.403e\+38 in magnitude \(the largest float32\), "
     r"got 1e\+308$"),
    (-1e39, False, r"^tau: must be at most .* got -1e\+39$"),
    (np.inf, False, r"^tau: must be at most .* got inf$"),  # a sum that overflowed float64
    (np.array([0.5, 4e38]), False, r"got 4e\+38$"),  # the first value at fault
    (1e-300, True, r"^tau: must be at least 1\.175e-38 \(the smallest normal float32\), "
     r"got 1e-300$"),  # 0 in float32
    (1e-40, True, r"^tau: must be at least 1\.175e-38 .* got 1e-40$"),  # subnormal in float32
])
def test_values_that_overflow_or_underflow_float32_are_one_line_errors(value, positive, message):
    with pytest.raises(ValueError, match=message):
        check_representable("tau", value, np.float32, positive)


def test_the_smallest_normal_float32_is_the_bound_and_float64_holds_what_float32_cannot():
    below = np.nextafter(F32.smallest_normal, np.float32(0))  # the largest subnormal float32
    with pytest.raises(ValueError, match="smallest normal float32"):
        check_representable("lr", below, np.float32, positive=True)
    assert check_representable("lr", 1e-300, np.float64, positive=True) == 1e-300
    assert check_representable("lr", 1e308, np.float64) == 1e308


def test_derived_values_overflow_float64_to_infinity_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        product = in_float64(np.multiply, np.float64(1e200), 1e200)
        difference = in_float64(np.subtract, 3e38, -3e38)
    assert product == np.inf and product.dtype == np.float64
    assert difference == 6e38  # 2 * 3e38: exact in float64, beyond float32's 3.4e38


@pytest.mark.parametrize("check", [
    lambda: check_int("seed", np.ones((3, 3), int)),
    lambda: check_finite("scores", np.zeros((3, 3), bool)),
    lambda: check_choice("backend", np.array([["jaxpg"], ["gymnasium"]]), ("jaxpg",)),
])
def test_an_array_whose_repr_spans_lines_is_shown_on_one(check):
    with pytest.raises(ValueError, match=r" array\(\[\[.*\], \[.*\]\]"):
        check()


def test_a_long_value_is_cut():
    assert shown(np.zeros((2, 2))) == "array([[0., 0.], [0., 0.]])"
    assert shown("a  b\n") == repr("a  b\n")  # a string's own spaces and escapes stay
    long = shown(list(range(1000)))
    assert len(long) == 200 and long.endswith("...") and long.startswith("[0, 1, 2")
