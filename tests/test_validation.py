import numpy as np
import pytest

from jaxpg.validation import check_choice, check_finite, check_int, check_number


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
