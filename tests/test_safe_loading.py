"""Opening a result file from someone else: nothing in it is run, imported or trusted.

Each test edits one field of a file written by :func:`gridstrain.results.save_result`
and checks that :func:`gridstrain.load` (and the commands reading files) refuse it with
one message naming the file and the field, instead of importing, executing, reading
another file or computing with a value of the wrong kind.
"""

from __future__ import annotations

import re
import sys

import h5py
import numpy as np
import pytest

from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.pipeline import measure_series
from gridstrain.results import _nan_equal, load, read_attrs, save_result
from independent_grid import camera, scene

LAT = Lattice.from_pitch(5.0)
N = 64


@pytest.fixture(scope="module")
def result():
    rng = np.random.default_rng(2611)

    def frames(strain):
        level, _ = scene((N, N), pitch=5.0, angle=0.0, hole=False, light=False,
                         displacement=lambda X, Y: (strain * (X - N / 2), 0.0 * Y))
        return np.array([camera(level, 1.0, 4.0, rng) for _ in range(3)])

    return measure_series(frames(0.0), [frames(1e-3), frames(2e-3)], lattice=LAT)


@pytest.fixture
def saved(result, tmp_path):
    return save_result(result, tmp_path / "r.h5", pixel_size=0.02, unit="mm",
                       attrs={"config": 'method = "A"\n'})


def _refused(path, field, read=load):
    with pytest.raises(ValueError, match=re.escape(str(path))) as info:
        read(path)
    text = str(info.value)
    assert str(path) in text
    assert field in text
    assert len(text.splitlines()) == 1
    return text


def test_a_class_name_is_never_imported(saved, tmp_path, monkeypatch):
    """A module next to the file, named by ``_class``, is neither imported nor run."""
    marker = tmp_path / "ran"
    (tmp_path / "evilmod.py").write_text(f"open({str(marker)!r}, 'w').close()\n"
                                         "class Evil:\n    pass\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("evilmod.Evil", "this.s", "os.system", "gridstrain.cli.main"):
        with h5py.File(saved, "a") as h5:
            h5["gridstrain/result/noise"].attrs["_class"] = name
        text = _refused(saved, "/gridstrain/result/noise/_class")
        assert name in text
    assert not marker.exists()
    assert "evilmod" not in sys.modules
    assert "this" not in sys.modules


def test_the_file_round_trips_with_the_registry(result, saved):
    assert _nan_equal(load(saved), _without_phase_maps(result))


def _without_phase_maps(result):
    import dataclasses

    ms = tuple(dataclasses.replace(m, reference=None, deformed=None)
               for m in result.measurements)
    return dataclasses.replace(result, measurements=ms)


@pytest.mark.parametrize(("edit", "field"), [
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("sigma", "six"),
     "/gridstrain/result/sigma"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("sigma", np.nan),
     "/gridstrain/result/sigma"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("method", "<script>"),
     "/gridstrain/result/method"),
    (lambda h5: h5["gridstrain/result/measurements/0"].attrs.__setitem__("iterations",
                                                                        "<b>3</b>"),
     "/gridstrain/result/measurements/0/iterations"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("_type", "module"),
     "/gridstrain/result/_type"),
    (lambda h5: _replace(h5, "exx", np.zeros((2, N, N + 1))), "/exx"),
    (lambda h5: _replace(h5, "valid", np.zeros((2, N, N))), "/valid"),
    (lambda h5: _replace(h5, "mask", np.zeros((N, 3), bool)), "/mask"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__(
        "n_frames", np.array([3, 3], np.int64)), "/gridstrain/result/n_frames"),
    (lambda h5: h5.attrs.__setitem__("pixel_size", "0.02<script>"), "/pixel_size"),
])
def test_a_wrong_field_is_one_line_naming_the_file_and_the_field(saved, edit, field):
    with h5py.File(saved, "a") as h5:
        edit(h5)
    _refused(saved, field, read_attrs if field == "/pixel_size" else load)


def _replace(h5, name, data):
    del h5[name]
    h5[name] = data


def test_links_out_of_the_file_are_refused(saved, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as h5:
        h5["noise"] = np.zeros(3)
    with h5py.File(saved, "a") as h5:
        del h5["gridstrain/result/noise"]
        h5["gridstrain/result/noise"] = h5py.ExternalLink(str(other), "noise")
    text = _refused(saved, "/gridstrain/result/noise")
    assert "another file" in text


def test_a_link_cycle_is_refused(saved):
    with h5py.File(saved, "a") as h5:
        h5["gridstrain/result/noise/loop"] = h5py.SoftLink("/gridstrain/result/noise")
    _refused(saved, "/gridstrain/result/noise/loop")


def test_a_file_declaring_more_than_the_memory_is_refused_before_reading(saved):
    # a chunked, compressed dataset declaring 2**50 bytes takes a few bytes on disk
    with h5py.File(saved, "a") as h5:
        h5["gridstrain/result"].create_dataset("huge", shape=(2**47,), dtype="f8",
                                               chunks=(2**20,), compression="gzip")
    text = _refused(saved, "GiB")
    assert "memory" in text


def test_the_commands_say_one_line(saved, capsys):
    with h5py.File(saved, "a") as h5:
        h5["gridstrain/result/noise"].attrs["_class"] = "os.system"
    for argv in (["report", str(saved), "-o", str(saved.with_suffix(".html"))],
                 ["plot", str(saved), "-o", str(saved.parent / "figs")]):
        assert main(argv) != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert str(saved) in err[0]
        assert "_class" in err[0]
    assert not saved.with_suffix(".html").exists()
