"""Contracts every public function keeps, checked over the whole public API.

- Options are keyword-only: after the data (the image, the frames, the phase maps,
  the lattice they are measured with), every parameter that has a default is
  declared after ``*``, so that a call reads the same in a year and a new option
  never shifts an old one.
- Inputs are never modified: read-only arrays go in and come out untouched.

The precision contract (output dtypes) lives in ``tests/test_dtypes.py``.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import numpy as np
import pytest

import gridstrain
from gridstrain import Lattice

# data-like parameters that have a default, with the reason they stay positional
POSITIONAL_OK = {
    # the lattice is the second operand, as in wft(image, lattice); it is optional
    # only because it can be detected from the frames
    ("uncertainty", "estimate_noise", "lattice"),
    ("uncertainty", "estimate_noise_image", "lattice"),
    # the attributes are content written to the file, like the datasets before them
    ("io", "write_hdf5", "attrs"),
    # the frame is the clean grid seen through this rigid vibration: an operand
    ("paper", "clean_frame", "shift"),
    # the options as one object (a MeasureOptions, e.g. a result's replayed): the
    # keywords beside it override its fields
    ("series", "measure_series", "options"),
}


def _public_functions():
    out = []
    for info in pkgutil.iter_modules(gridstrain.__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"gridstrain.{info.name}")
        for name in getattr(mod, "__all__", ()):
            obj = getattr(mod, name)
            if inspect.isfunction(obj):
                out.append((info.name, name, obj))
    return out


FUNCTIONS = _public_functions()


def test_the_api_is_walked():
    # the walk reaches the entry points a user calls first
    names = {name for _, name, _ in FUNCTIONS}
    assert {"wft", "measure", "measure_series", "method_a", "method_b", "method_c",
            "estimate_noise", "load"} <= names


@pytest.mark.parametrize(("module", "name", "func"), FUNCTIONS,
                         ids=[f"{m}.{n}" for m, n, _ in FUNCTIONS])
def test_options_are_keyword_only(module, name, func):
    params = inspect.signature(func).parameters.values()
    positional_defaults = [p.name for p in params
                           if p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD
                           and p.default is not inspect.Parameter.empty
                           and (module, name, p.name) not in POSITIONAL_OK]
    # the first parameter is the data even when it has a default (a profile name)
    first = next(iter(inspect.signature(func).parameters), None)
    positional_defaults = [p for p in positional_defaults if p != first]
    assert not positional_defaults, (f"{module}.{name}: options {positional_defaults} "
                                     "must be keyword-only (after *)")


def test_the_check_catches_a_positional_option():
    def f(image, lattice, sigma=None):  # the shape this test exists to refuse
        return image, lattice, sigma

    params = inspect.signature(f).parameters.values()
    assert [p.name for p in params if p.default is not inspect.Parameter.empty
            and p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD] == ["sigma"]


# ----------------------------------------------------------------- inputs untouched

LAT = Lattice.from_pitch(5.0)


def _grid(shape=(80, 96), shift=0.0, seed=0):
    """A sine grid of pitch 5 px (k1 = (1/5, 0), k2 = (0, 1/5)) with a little noise,
    written out here so that the check does not rest on the package's generator."""
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    img = 1000 * (1 + 0.4 * np.cos(2 * np.pi * (x - shift) / 5) + 0.4 * np.cos(2 * np.pi * y / 5))
    return img + np.random.default_rng(seed).normal(0, 3, shape)


def _frozen(a):
    a = np.array(a)
    a.flags.writeable = False
    return a


def _entry_points():
    from gridstrain import (
        estimate_noise_image,
        frame_shifts,
        measure,
        measure_series,
        method_a,
        method_b,
        wft,
    )
    from gridstrain.stacks import method_c

    ref = _frozen(_grid())
    cur = _frozen(_grid(shift=0.3, seed=1))
    stack = _frozen(np.stack([_grid(seed=s) for s in range(4)]))
    mask = _frozen(np.ones(ref.shape, bool))
    big = _frozen(_grid((176, 176)))  # the one-image noise estimate needs 160 px
    return [
        ("wft", lambda: wft(ref, LAT, mask=mask), (ref, mask)),
        ("measure", lambda: measure(ref, cur, lattice=LAT, mask=mask), (ref, cur, mask)),
        ("method_a", lambda: method_a(stack, LAT, mask=mask), (stack, mask)),
        ("method_b", lambda: method_b(stack, LAT, mask=mask), (stack, mask)),
        ("method_c", lambda: method_c(stack, LAT, mask=mask), (stack, mask)),
        ("frame_shifts", lambda: frame_shifts(stack, LAT), (stack,)),
        ("estimate_noise_image", lambda: estimate_noise_image(big, LAT), (big,)),
        ("measure_series", lambda: measure_series(stack, [cur], lattice=LAT, mask=mask),
         (stack, cur, mask)),
    ]


@pytest.mark.parametrize("index", range(8))
def test_read_only_inputs_are_accepted_and_left_untouched(index):
    name, call, inputs = _entry_points()[index]
    before = [a.copy() for a in inputs]
    call()
    for a, b in zip(inputs, before, strict=True):
        assert not a.flags.writeable, name
        np.testing.assert_array_equal(a, b, err_msg=name)
