"""Argument checks: one shared set (gridstrain._validation), whose every refusal names
the parameter, what was expected and what was received; the reading, writing,
plotting and paper modules route their arguments through it instead of keeping
private copies."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
import tifffile

import gridstrain
from gridstrain import _validation as v
from gridstrain.io import (
    check_saturation,
    check_saturation_limit,
    open_series,
    read_mask,
    write_csv,
    write_hdf5,
    write_tiff_series,
)
from gridstrain.paper.dataset import clean_frame, draw_shifts, mean_image_bias, paper_phases
from gridstrain.post import plot_map

# (check, arguments, error, what the message must hold: the parameter, the
# expectation, the value received)
REFUSALS = [
    (v.check_finite, ("x", "offset"), TypeError, ("offset", "finite number", "'x'")),
    (v.check_finite, (math.inf, "offset"), ValueError, ("offset", "finite", "inf")),
    (v.check_finite, (True, "offset"), TypeError, ("offset", "number", "True")),
    (v.check_int, (2.5, "T"), ValueError, ("T", "integer", "2.5")),
    (v.check_int, (True, "T"), TypeError, ("T", "integer", "True")),
    (v.check_int, (0, "T"), ValueError, ("T", "positive integer", "0"), {"minimum": 1}),
    (v.check_fraction, (1.5, "max_fraction"), ValueError, ("max_fraction", "[0, 1]", "1.5")),
    (v.check_fraction, ("1", "max_fraction"), TypeError, ("max_fraction", "[0, 1]", "'1'")),
    (v.as_pair, (0.5, "shift"), ValueError, ("shift", "pair", "0.5")),
    (v.as_pair, ((1, 2, 3), "shift"), ValueError, ("shift", "pair", "(1, 2, 3)")),
    (v.as_pair, ((1, math.nan), "shift"), ValueError, ("shift", "finite", "nan")),
    (v.check_shape, ("big", "shape"), ValueError, ("shape", "two positive integers", "'big'")),
    (v.check_shape, ((4, 100), "shape"), ValueError, ("shape", "8 x 8", "(4, 100)"),
     {"minimum": 8}),
    (v.check_shape, ((8.0, 8), "shape"), ValueError, ("shape", "integers", "(8.0, 8)")),
    (v.as_int_tuple, (5, "T"), TypeError, ("T", "list of integers", "5")),
    (v.as_int_tuple, ("12", "T"), TypeError, ("T", "list of integers", "'12'")),
    (v.as_int_tuple, ([], "T"), ValueError, ("T", "at least one", "[]")),
    (v.as_int_tuple, ([3, 0], "T"), ValueError, ("T values", "positive integer", "0"),
     {"minimum": 1}),
    (v.check_name, ("", "name"), TypeError, ("name", "non-empty string", "''")),
    (v.as_path, (3, "path"), TypeError, ("path", "str or os.PathLike", "int")),
    (v.check_mapping, ([1], "attrs"), TypeError, ("attrs", "dict", "list")),
    (v.check_type, ("r", "result", dict), TypeError, ("result", "dict", "str")),
    (v.check_callable, (3, "progress"), TypeError, ("progress", "callable", "3")),
    (v.check_float_dtype, ("int8", "dtype"), ValueError, ("dtype", "float32", "'int8'")),
    (v.check_float_dtype, (None, "dtype"), ValueError, ("dtype", "float32 or float64", "None"),
     {"allow_none": False}),
]


@pytest.mark.parametrize("case", REFUSALS, ids=lambda c: f"{c[0].__name__}-{c[1][0]!r}")
def test_every_refusal_names_parameter_expectation_and_value(case):
    check, args, error, pieces, *kw = case
    with pytest.raises(error) as info:
        check(*args, **(kw[0] if kw else {}))
    for piece in pieces:
        assert piece in str(info.value), (piece, str(info.value))


def test_accepted_values_come_back_converted():
    assert v.check_int(np.int64(3), "T", minimum=1) == 3
    assert type(v.check_int(np.int64(3), "T")) is int
    assert v.check_finite(np.float32(-2.5), "offset") == -2.5
    assert v.check_fraction(0, "max_fraction") == 0.0
    assert tuple(v.as_pair(np.array([1, 2]), "shift")) == (1.0, 2.0)
    assert v.check_shape(np.array([16, 24]), "shape") == (16, 24)
    assert v.as_int_tuple((5, np.int32(2)), "T") == (5, 2)  # order kept
    assert v.check_mapping(None, "attrs", allow_none=True) == {}
    assert v.check_float_dtype(None, "dtype") is None
    assert v.check_float_dtype("float32", "dtype") == np.float32
    assert v.as_path("~/x", "path") == Path("~/x").expanduser()


# --------------------------------------------------------------- the modules use them


def test_reading_refusals(tmp_path):
    frame = (np.arange(24 * 32).reshape(24, 32) % 200).astype(np.uint8)
    tifffile.imwrite(tmp_path / "a.tif", frame)
    with pytest.raises(TypeError, match="name must be a non-empty string"):
        open_series(tmp_path / "a.tif", name="")
    s = open_series(tmp_path / "a.tif")
    with pytest.raises(ValueError, match=r"frame index must be an integer, got 0\.5"):
        s.read(0.5)
    with pytest.raises(TypeError, match="start must be an integer"):
        s.frames(start="0")
    with pytest.raises(ValueError, match="dtype must be float32, float64 or None"):
        s.read(0, dtype=np.int16)
    with pytest.raises(TypeError, match="progress must be callable"):
        s.mean(progress="bar")
    with pytest.raises(ValueError, match=r"max_fraction must be a number in \[0, 1\], got 2"):
        check_saturation_limit(frame, s, max_fraction=2)
    with pytest.raises(TypeError, match="series must be a FrameSeries, got str"):
        check_saturation(frame, "a.tif")
    with pytest.raises(ValueError, match="mask selects no pixel"):
        check_saturation(frame, s, mask=np.zeros(frame.shape, bool))
    with pytest.raises(ValueError, match="shape must be two positive integers"):
        read_mask(tmp_path / "a.tif", 24)


def test_writing_refusals(tmp_path):
    with pytest.raises(ValueError, match=r"chunk_rows must be a positive integer, got 2\.0"):
        write_csv(tmp_path / "a.csv", {"u": np.zeros(3)}, chunk_rows=2.0)
    with pytest.raises(ValueError, match=r"digits must be an integer in \[1, 17\]"):
        write_csv(tmp_path / "a.csv", {"u": np.zeros(3)}, digits=30)
    with pytest.raises(ValueError, match="start must be an integer of at least 0, got -1"):
        write_tiff_series(tmp_path / "f", [np.zeros((8, 8))], start=-1)
    with pytest.raises(TypeError, match="units must be a dict, got list"):
        write_hdf5(tmp_path / "a.h5", {"u": np.zeros(3)}, units=["px"])
    with pytest.raises(TypeError, match="attrs keys must be a non-empty string, got 3"):
        write_hdf5(tmp_path / "a.h5", {"u": np.zeros(3)}, {3: "x"})
    # refused before anything was written
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_paper_and_plotting_refusals():
    phases, _ = paper_phases((16, 16))
    with pytest.raises(ValueError, match=r"T must be a positive integer, got 2\.5"):
        draw_shifts(2.5, 1)
    with pytest.raises(TypeError, match=r"case must be 1, 2, 3, 4 or a \(sigma_alpha"):
        draw_shifts(3, True)
    with pytest.raises(ValueError, match="shift must be a finite"):
        clean_frame(phases, (0.1, math.nan))
    with pytest.raises(ValueError, match=r"phases\[0\] must be finite"):
        clean_frame(np.where(np.eye(16, dtype=bool), np.nan, phases))
    with pytest.raises(ValueError, match="variance must be finite and >= 0"):
        mean_image_bias(phases, (-1.0, 0.0))
    with pytest.raises(ValueError, match="offset must be a finite number, got nan"):
        plot_map(np.zeros((8, 8)), offset=math.nan)
    with pytest.raises(ValueError, match="limit must be a finite positive number, got -1"):
        plot_map(np.zeros((8, 8)), limit=-1)


# The shared checks' names, and the private names a copy of one would take.
_SHARED = {n for n in dir(v) if n.startswith(("check_", "as_"))}
_EDGE = ("io/_series.py", "io/_files.py", "paper/dataset.py", "paper/experiment.py",
         "results/_file.py", "results/_codec.py", "results/_layout.py", "results/_csv.py",
         "results/_mat.py", "post/_report.py", "post/_plotting.py", "cli/demo.py", "cli/noise.py",
         "cli/_common.py", "cli/plot.py", "cli/report.py", "cli/reproduce.py")


@pytest.mark.parametrize("module", _EDGE)
def test_no_private_copy_of_a_shared_check(module):
    root = Path(gridstrain.__file__).parent
    tree = ast.parse((root / module).read_text(encoding="utf-8"))
    defined = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    copies = sorted(d for d in defined if d.lstrip("_") in _SHARED)
    assert not copies, f"{module} defines {copies}; use gridstrain._validation"
