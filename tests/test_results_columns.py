"""The lists of a result file written by columns (format 3): read back as the very objects
that were saved, in a number of HDF5 objects that does not grow with the number of
states, refused in one line naming the member when a file says more than it holds; and
files of format 2 (written value by value) still read.
"""

from __future__ import annotations

import dataclasses
import io
import math
import re

import h5py
import numpy as np
import pytest

from gridstrain import Lattice
from gridstrain.kinematics import Measurement
from gridstrain.phase.lattice import Carrier
from gridstrain.results import _codec, _layout, load, save_result
from gridstrain.results._codec import _Bad, _decode, _encode
from gridstrain.series import measure_series
from independent_grid import camera, scene

LAT = Lattice.from_pitch(5.0)
N = 64


def _measured(n_states: int, seed: int):
    """A record of one-frame states under a growing uniaxial strain."""
    rng = np.random.default_rng(seed)

    def frame(strain):
        level, _ = scene((N, N), pitch=5.0, angle=0.0, hole=False, light=False,
                         displacement=lambda X, Y: (strain * (X - N / 2), 0.0 * Y))
        return camera(level, 1.0, 4.0, rng)[None]

    return measure_series(frame(0.0), [frame(5e-4 * (k + 1)) for k in range(n_states)],
                          lattice=LAT)


@pytest.fixture(scope="module")
def result():
    return _measured(4, 3101)


def _same(a, b, where="result"):
    """``b`` is ``a``: same types (a NumPy scalar comes back as the Python number it
    holds), arrays of the same dtype, shape and values (NaN where NaN), same keys in
    the same order."""
    a = a.item() if isinstance(a, np.generic) else a
    b = b.item() if isinstance(b, np.generic) else b
    assert type(a) is type(b), f"{where}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, np.ndarray):
        assert (a.dtype, a.shape) == (b.dtype, b.shape), where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"), where
    elif dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), where
    else:
        assert a == b, where


def _without_phase_maps(result):
    ms = tuple(dataclasses.replace(m, reference=None, deformed=None)
               for m in result.measurements)
    return dataclasses.replace(result, measurements=ms)


def _census(path) -> tuple[int, int]:
    """HDF5 objects and attributes under ``gridstrain/result``."""
    with h5py.File(path, "r") as h5:
        g = h5["gridstrain/result"]
        names = []
        g.visit(names.append)
        return len(names), len(g.attrs) + sum(len(g[n].attrs) for n in names)


# --------------------------------------------------------------------------- round trip


def test_a_measured_record_comes_back_field_by_field(result, tmp_path):
    path = save_result(result, tmp_path / "r.h5", lossless=True)
    with h5py.File(path, "r") as h5:
        assert h5["gridstrain"].attrs["format_version"] == 3
        assert h5["gridstrain/result/measurements"].attrs["_type"] == "records"
    back = load(path)
    _same(_without_phase_maps(result), back)
    # objects saved once and named from elsewhere come back as one object
    assert all(m.lattice is back.lattice for m in back.measurements)
    assert all(o is m.fringe_order
               for o, m in zip(back.fringe_orders, back.measurements, strict=True))


def test_the_phase_maps_come_back_stacked_by_state(result, tmp_path):
    path = save_result(result, tmp_path / "r.h5", phase_maps=True, lossless=True)
    with h5py.File(path, "r") as h5:
        psi = h5["gridstrain/result/measurements/deformed/psi"]
        assert psi.shape[0] == result.n_states  # one dataset for every state
    _same(result, load(path))


def test_the_objects_of_the_file_do_not_grow_with_the_states(result, tmp_path):
    longer = _measured(9, 3102)
    short = save_result(result, tmp_path / "short.h5")
    long_ = save_result(longer, tmp_path / "long.h5")
    objects, attributes = _census(short)
    assert _census(long_) == (objects, attributes)
    # value by value (format 2), each state adds its groups
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_codec, "_MIN_ROWS", VALUE_BY_VALUE)
        per_item = save_result(longer, tmp_path / "per_item.h5")
    assert _census(per_item)[0] > objects + 10 * longer.n_states


@dataclasses.dataclass(frozen=True, eq=False)
class _Annotated(Measurement):
    """A measurement class of a user's program (a subclass the file may name)."""

    note: str = ""


def test_measurements_of_two_classes_get_the_maps_of_their_own_states(result, tmp_path):
    ms = list(result.measurements)
    ms[1] = _Annotated(**{f.name: getattr(ms[1], f.name) for f in dataclasses.fields(ms[1])},
                       note="loaded by hand")
    mixed = dataclasses.replace(result, measurements=tuple(ms))
    path = save_result(mixed, tmp_path / "mixed.h5", lossless=True)
    with h5py.File(path, "r") as h5:
        assert h5["gridstrain/result/measurements"].attrs["_type"] == "union"
    back = load(path)
    # a subclass keeps every field in the group, phase maps included (the fields left
    # to the file's variables are those of the result classes themselves)
    kept = tuple(m if type(m) is _Annotated else
                 dataclasses.replace(m, reference=None, deformed=None) for m in ms)
    _same(dataclasses.replace(mixed, measurements=kept), back)
    # each state's maps are its own, not those of its row within its class
    for i, m in enumerate(back.measurements):
        np.testing.assert_array_equal(m.u, result.u[i])


VALUE_BY_VALUE = 1_000_000  # as _MIN_ROWS: every list written value by value (format 2)


def _through_a_file(value, *, rows=None):
    """``value`` written by the codec into a file in memory and read back."""
    buf = io.BytesIO()
    with pytest.MonkeyPatch.context() as mp:
        if rows is not None:
            mp.setattr(_codec, "_MIN_ROWS", rows)
        with h5py.File(buf, "w") as h5:
            _encode(h5, [("v", {"x": value})], {})
    with h5py.File(buf, "r") as h5:
        return _decode(h5["v"], {}, lambda cls, group, values, row: values)["x"]


def _every_kind_of_column():
    carriers = [Carrier(k1=(0.2, 0.0), k2=(0.0, 0.2 + 1e-3 * i), window_pitch=5.0)
                for i in range(3)]
    shared = np.arange(4.0)
    other = Lattice.from_pitch(6.0)
    rows = [{"i": 1, "f": 2.5, "b": True, "s": "état", "opt": None, "mixed": 1,
             "arr": np.ones((2, 3), np.float32), "ragged": np.zeros(2), "t": (1, 2),
             "l": [], "nested": {"a": 1, "z": np.int16(-3)}, "c": np.array([1 + 2j])},
            {"i": 2, "f": 3.0, "b": False, "s": "b", "opt": 0.5, "mixed": 1.5,
             "arr": np.full((2, 3), np.nan, np.float32), "ragged": np.zeros(3),
             "t": (3,), "l": ["x", None], "nested": {"a": 2, "z": np.int16(4)},
             "c": np.array([3j])},
            {"i": -(2**62), "f": -0.0, "b": True, "s": "", "opt": np.inf, "mixed": True,
             "arr": np.zeros((2, 3), np.float32), "ragged": np.zeros((0, 2)), "t": (),
             "l": [[1.0], (2,)], "nested": {"a": 3, "z": np.int16(0)},
             "c": np.array([0j])}]
    return {
        "rows": rows,
        "keys": [{"a": 1}, {"b": 2}, {"a": 3}],  # two kinds of dict
        "same": [shared, shared, shared],
        "lattices": (LAT, *carriers),  # a class and its subclass
        "again": tuple(carriers),  # the very objects of a column
        "twice": [other, LAT, other],  # one object twice
        "zero_d": [np.array(1.0), np.array(2.0)],
        "bools": (np.array([True, False]), np.array([False, False])),
        "nones": (None, None),
        "empty": [(), ()],
        "one": [LAT],
        "floats_then_none": (1.0, 2.0, None),
    }


def test_every_kind_of_column_comes_back_as_it_was_written():
    value = _every_kind_of_column()
    back = _through_a_file(value)
    _same(value, back, "value")
    assert back["lattices"][0] is not back["lattices"][1]
    assert all(a is b for a, b in zip(back["again"], back["lattices"][1:], strict=True))
    assert back["twice"][0] is back["twice"][2]
    assert all(x is back["same"][0] for x in back["same"])
    # and as the list written value by value does
    _same(value, _through_a_file(value, rows=VALUE_BY_VALUE), "value")


def test_arrays_too_large_to_stack_in_memory_are_written_a_chunk_at_a_time(monkeypatch):
    monkeypatch.setattr(_codec, "_STACK_BYTES", 0)
    value = {"maps": [np.arange(12.0).reshape(3, 4) * k for k in range(5)],
             "flags": (np.array([True]), np.array([False]))}
    _same(value, _through_a_file(value), "value")


# --------------------------------------------------------------------------- format 2


def test_a_file_of_format_2_still_loads(result, tmp_path, monkeypatch):
    """A file as the encoder of format 2 wrote it: every list value by value."""
    monkeypatch.setattr(_codec, "_MIN_ROWS", VALUE_BY_VALUE)
    monkeypatch.setattr(_layout, "FORMAT_VERSION", 2)
    path = save_result(result, tmp_path / "v2.h5", lossless=True)
    monkeypatch.undo()
    with h5py.File(path, "r") as h5:
        assert h5["gridstrain"].attrs["format_version"] == 2
        assert h5["gridstrain/result/measurements/1"].attrs["_type"] == "dataclass"
    back = load(path)
    _same(_without_phase_maps(result), back)
    assert back.fringe_orders[1] is back.measurements[1].fringe_order


@pytest.mark.parametrize("version", [1, 4, "3"])
def test_another_format_is_refused_by_its_number(result, tmp_path, version):
    path = save_result(result, tmp_path / "r.h5")
    with h5py.File(path, "a") as h5:
        h5["gridstrain"].attrs["format_version"] = version
    with pytest.raises(ValueError, match=f"format {re.escape(repr(version))}; .* 2, 3"):
        load(path)


# --------------------------------------------------------------------------- hostile files


@pytest.fixture
def saved(result, tmp_path):
    return save_result(result, tmp_path / "r.h5")


def _refused(path, member, *also):
    with pytest.raises(ValueError, match=re.escape(f"{path}: ")) as info:
        load(path)
    text = str(info.value)
    assert len(text.splitlines()) == 1
    assert f"{path}: " in text
    assert member in text
    for word in also:
        assert word in text
    return text


def _edit(path, change):
    with h5py.File(path, "a") as h5:
        change(h5)


def _replace(h5, name, data):
    del h5[name]
    h5[name] = data


M = "gridstrain/result/measurements"


@pytest.mark.parametrize(("change", "member", "word"), [
    # a count that disagrees with the columns
    (lambda h5: h5[M].attrs.__setitem__("_n", np.int64(3)), f"/{M}/sigma", "3 values"),
    (lambda h5: h5[M].attrs.__setitem__("_n", np.int64(-1)), f"/{M}/_n", "whole number"),
    (lambda h5: h5[M].attrs.__setitem__("_n", "4"), f"/{M}/_n", "whole number"),
    # a column of the wrong type, and a column of strings where numbers are stacked
    (lambda h5: h5[M].attrs.__setitem__("iterations", np.array([1.5] * 4)),
     f"/{M}/iterations[0]", "expected int"),
    (lambda h5: _replace(h5, "gridstrain/result/vibration/std",
                         np.array(["a"] * 5, dtype=h5py.string_dtype())),
     "/gridstrain/result/vibration/std", "dtype"),
    # a stacked column whose rows are not the list's
    (lambda h5: _replace(h5, "gridstrain/result/vibration/std", np.zeros((4, 2))),
     "/gridstrain/result/vibration/std", "5 rows"),
    # a class that is not a result class
    (lambda h5: h5[M].attrs.__setitem__("_class", "os.system"), f"/{M}/_class",
     "not a class"),
    (lambda h5: h5[M].attrs.__setitem__("from_the_future", np.zeros(4)), f"/{M}",
     "newer version"),
    # structure that does not hold together
    (lambda h5: h5[M].attrs.__setitem__("_none", np.array([1, 2])), f"/{M}/_none",
     "list of names"),
    (lambda h5: h5[M].attrs.__setitem__("_const", np.array(["nothing"], dtype=object)),
     f"/{M}/_const", "does not hold"),
    (lambda h5: h5[f"{M}/guess"].attrs.__setitem__("lengths", np.array([2, 2, 2, 3])),
     f"/{M}/guess/values", "9 values"),
    (lambda h5: h5[M].attrs.__setitem__("_rows", "set"), f"/{M}/_rows", "'set'"),
    (lambda h5: h5[M].attrs.__setitem__("_type", "pickle"), f"/{M}/_type", "'pickle'"),
    # rows declared by the billion cost memory before anything is built
    (lambda h5: h5["gridstrain/result/systematic/vibration_offset"].attrs.__setitem__(
        "_n", np.int64(2**58)), "/gridstrain/result/systematic/vibration_offset",
     "memory"),
    # a column that loops back to its group
    (lambda h5: _replace(h5, f"{M}/guess", h5py.SoftLink(f"/{M}")), f"/{M}", "cycle"),
])
def test_a_column_that_does_not_hold_together_is_one_line_naming_it(saved, change, member,
                                                                     word):
    _edit(saved, change)
    _refused(saved, member, word)


def test_a_column_in_another_file_is_refused(saved, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as h5:
        h5["std"] = np.zeros((5, 2))
    _edit(saved, lambda h5: _replace(h5, "gridstrain/result/vibration/std",
                                     h5py.ExternalLink(str(other), "std")))
    _refused(saved, "/gridstrain/result/vibration/std", "another file")


def test_a_stacked_column_larger_than_the_memory_is_refused_before_reading():
    buf = io.BytesIO()
    with h5py.File(buf, "w") as h5:
        _encode(h5, [("v", {"x": [np.zeros(3), np.ones(3)]})], {})
        del h5["v/x/values"]
        # 2 x 2**46 float64: 2 PiB declared, a few bytes on disk
        h5["v/x"].create_dataset("values", shape=(2, 2**46), dtype="f8",
                                 chunks=(1, 2**20), compression="gzip")
    with h5py.File(buf, "r") as h5, pytest.raises(_Bad) as info:
        _decode(h5["v"], {}, lambda cls, group, values, row: values)
    text = str(info.value)
    assert "/v/x/values: its values need" in text
    assert "memory" in text
    assert len(text.splitlines()) == 1


def _random_value(rng, depth=0):
    """A value of any kind the codec stores, nested up to three levels."""
    kinds = ["none", "bool", "int", "float", "str", "array", "lattice"]
    if depth < 3:
        kinds += ["tuple", "list", "dict", "rows"]
    kind = kinds[rng.integers(len(kinds))]
    if kind == "none":
        return None
    if kind == "bool":
        return bool(rng.integers(2))
    if kind == "int":
        return int(rng.integers(-5, 5))
    if kind == "float":
        return float(rng.choice([0.5, -1.0, np.nan, np.inf]))
    if kind == "str":
        return str(rng.choice(["", "a", "état", "0"]))
    if kind == "array":
        shape = tuple(rng.integers(0, 3, rng.integers(0, 3)))
        return rng.normal(size=shape).astype(rng.choice(["f4", "f8", "i2", "?", "c16"]))
    if kind == "lattice":
        return Lattice.from_pitch(float(rng.choice([4.0, 5.0, 6.0])))
    if kind in ("tuple", "list"):
        items = [_random_value(rng, depth + 1) for _ in range(rng.integers(0, 4))]
        return tuple(items) if kind == "tuple" else items
    if kind == "dict":
        return {k: _random_value(rng, depth + 1) for k in ("a", "b", "c")[:rng.integers(4)]}
    # rows: records that share their keys, their values of a kind or two
    keys = ("x", "y", "z")[:rng.integers(1, 4)]
    return [{k: _random_value(rng, 2) for k in keys} for _ in range(rng.integers(2, 6))]


@pytest.mark.parametrize("seed", range(40))
def test_any_nesting_of_values_comes_back_as_it_was_written(seed):
    rng = np.random.default_rng(seed)
    value = [_random_value(rng) for _ in range(6)]
    _same(value, _through_a_file(value), "value")
