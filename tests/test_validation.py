"""The shared argument checks: what they accept, what they refuse, and that every
refusal names the parameter, the expected and the received."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from gridstrain._validation import (
    as_float_array,
    as_pair,
    as_shifts,
    check_finite,
    check_fraction,
    check_frequency,
    check_int,
    check_nonnegative,
    check_range,
    check_same_shape,
    check_shape,
    check_type,
)
from gridstrain.phase import Lattice

NON_NUMBERS = [True, False, None, "3", b"3", [1.0], np.array([1.0]), 1 + 0j]
NUMPY_SCALARS = [np.float32(2.5), np.float64(2.5), np.int16(3), np.uint8(3), np.int64(3)]


# ------------------------------------------------------------------ real numbers

@pytest.mark.parametrize("check", [check_finite, check_nonnegative, check_fraction,
                                   check_frequency])
@pytest.mark.parametrize("value", NON_NUMBERS)
def test_non_numbers_and_bools_are_type_errors_naming_the_parameter(check, value):
    with pytest.raises(TypeError, match=r"^gain must be .* got "):
        check(value, "gain")


@pytest.mark.parametrize("check", [check_finite, check_nonnegative, check_fraction,
                                   check_frequency])
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, np.float32("nan")])
def test_nan_and_infinity_are_value_errors(check, value):
    with pytest.raises(ValueError, match=r"^gain must be .*, got (nan|inf|-inf|np\.float32)"):
        check(value, "gain")


@pytest.mark.parametrize("value", [*NUMPY_SCALARS, Fraction(1, 4), 7])
def test_numpy_scalars_and_rationals_are_numbers(value):
    v = check_finite(value, "x")
    assert type(v) is float
    assert v == float(value)
    assert check_nonnegative(value, "x") == float(value)


def test_finite_accepts_negatives_and_zero():
    assert check_finite(-3, "offset") == -3.0
    assert check_finite(0, "offset") == 0.0
    with pytest.raises(ValueError, match="offset must be a finite number, got nan"):
        check_finite(float("nan"), "offset")


def test_nonnegative_bounds():
    assert check_nonnegative(0.0, "variance") == 0.0
    with pytest.raises(ValueError, match="variance must be a finite non-negative number, "
                                         "got -1e-300"):
        check_nonnegative(-1e-300, "variance")


def test_range_ends_open_and_closed():
    assert check_range(-1, "x", -1, 1) == -1.0
    assert check_range(1, "x", -1, 1) == 1.0
    with pytest.raises(ValueError, match=r"nu must be a number in \(-1, 0.5\], got -1"):
        check_range(-1, "nu", -1, 0.5, include_low=False)
    with pytest.raises(ValueError, match=r"nu must be a number in \[-1, 0.5\), got 0.5"):
        check_range(0.5, "nu", -1, 0.5, include_high=False)
    with pytest.raises(ValueError, match=r"angle must be an angle in \[0, 90\] deg, got 91"):
        check_range(91, "angle", 0, 90, what="an angle", unit="deg")


def test_fraction_is_the_closed_unit_interval():
    assert check_fraction(0, "contrast") == 0.0
    assert check_fraction(np.float32(1.0), "contrast") == 1.0
    with pytest.raises(ValueError, match=r"contrast must be a number in \[0, 1\], got 1.01"):
        check_fraction(1.01, "contrast")


def test_frequency_is_below_nyquist():
    assert check_frequency(0.2) == 0.2
    for bad in (0.0, 0.5, -0.1):
        with pytest.raises(ValueError, match=r"frequency must be a carrier frequency in "
                                             r"\(0, 0.5\) cycles/px"):
            check_frequency(bad)


# ------------------------------------------------------------------ integers

@pytest.mark.parametrize("value", [np.int8(3), np.uint16(3), np.int64(3), 3])
def test_int_accepts_python_and_numpy_integers(value):
    n = check_int(value, "n_bins", minimum=3)
    assert type(n) is int
    assert n == 3


@pytest.mark.parametrize("value", [True, None, "3", [3], np.array([3])])
def test_int_refuses_non_numbers_with_type_error(value):
    with pytest.raises(TypeError, match=r"^T must be a positive integer, got "):
        check_int(value, "T")


@pytest.mark.parametrize("value", [2.5, 3.0, np.float64(3.0), math.nan, math.inf, 0, -2])
def test_int_refuses_fractions_floats_and_small_values_with_value_error(value):
    with pytest.raises(ValueError, match=r"^T must be a positive integer, got "):
        check_int(value, "T")


def test_int_minimum_is_in_the_message():
    assert check_int(0, "order", minimum=0) == 0
    with pytest.raises(ValueError, match="n_bins must be an integer of at least 3, got 2"):
        check_int(2, "n_bins", minimum=3)


def test_shape_is_two_positive_integers():
    assert check_shape((np.int64(4), 5)) == (4, 5)
    for bad in [(0, 8), (8,), (8, 8, 1), 8, (8.0, 8), (True, 8), "ab", None]:
        with pytest.raises(ValueError, match="size must be two positive integers, got "):
            check_shape(bad, "size")


# ------------------------------------------------------------------ objects and arrays

def test_type_names_the_class_and_what_was_received():
    lat = Lattice.from_pitch(5)
    assert check_type(lat, "lattice", Lattice) is lat
    assert check_type(None, "lattice", Lattice, allow_none=True) is None
    with pytest.raises(TypeError, match=r"^lattice must be a Lattice, got NoneType$"):
        check_type(None, "lattice", Lattice)
    with pytest.raises(TypeError, match=r"^lattice must be a Lattice or None, got tuple$"):
        check_type((0.2, 0.2), "lattice", Lattice, allow_none=True)
    with pytest.raises(TypeError, match=r"^n must be an int, got str$"):
        check_type("3", "n", int)


def test_float_array_dtype_policy_and_no_copy_of_input():
    f32 = np.arange(6, dtype=np.float32).reshape(2, 3)
    assert as_float_array(f32, "a").dtype == np.float32
    assert as_float_array(f32, "a") is f32  # no copy when nothing to convert
    assert as_float_array(np.arange(3, dtype=np.uint16), "a").dtype == np.float64
    assert as_float_array([1, 2], "a").dtype == np.float64
    assert as_float_array(f32, "a", dtype=np.float64).dtype == np.float64
    assert as_float_array(np.float32(2), "a").shape == ()


@pytest.mark.parametrize("value", [np.array([True]), ["a"], [1 + 2j], [None]])
def test_float_array_refuses_non_real_data(value):
    with pytest.raises(TypeError, match=r"^image must be a real numeric array, got dtype"):
        as_float_array(value, "image")


def test_float_array_refuses_ragged_sequences():
    with pytest.raises(ValueError, match=r"^d must be a regular array of real numbers, got a "
                                         r"ragged list$"):
        as_float_array([[1.0], [1.0, 2.0]], "d")


def test_pair():
    p = as_pair((1, np.float32(2.5)), "centre")
    assert p.dtype == np.float64
    assert p.tolist() == [1.0, 2.5]
    src = np.array([1.0, 2.0])
    assert as_pair(src, "centre") is not src  # a new array: the caller's is never aliased
    with pytest.raises(ValueError, match=r"^centre must be a finite \(x, y\) pair in px, "
                                         r"got \(1.0,\)$"):
        as_pair((1.0,), "centre", unit="px")
    with pytest.raises(ValueError, match=r"phase_shift must be a finite \(u_x, u_y\) pair"):
        as_pair((0.0, math.nan), "phase_shift", labels="(u_x, u_y)")
    with pytest.raises(TypeError, match=r"^centre must be a finite \(x, y\) pair, got 'ab'$"):
        as_pair("ab", "centre")
    with pytest.raises(TypeError, match="centre"):
        as_pair((True, False), "centre")


def test_shifts():
    a = as_shifts([[0.1, 0.2], [0.3, 0.4]])
    assert a.shape == (2, 2)
    assert a.dtype == np.float64
    assert as_shifts(np.float32([0.1, 0.2]), "alphas", ndim=1).dtype == np.float64
    for bad in ([0.1, 0.2], np.zeros((0, 2)), [[0.1, 0.2, 0.3]]):
        with pytest.raises(ValueError, match=r"^shifts must be a finite \(T, 2\) array of px "
                                             r"with T >= 1, got shape"):
            as_shifts(bad)
    with pytest.raises(ValueError, match=r"alphas must be a finite \(T,\) array .* NaN"):
        as_shifts([0.1, math.inf], "alphas", ndim=1)
    with pytest.raises(TypeError, match="shifts must be a real numeric array"):
        as_shifts([["a", "b"]])


def test_same_shape_names_both_shapes():
    check_same_shape((4, 5), np.zeros((4, 5)).shape, "deformed", "reference")
    with pytest.raises(ValueError, match=r"^deformed must have the shape of reference "
                                         r"\(4, 5\), got \(4, 6\)$"):
        check_same_shape((4, 6), (4, 5), "deformed", "reference")
