"""The reference's maps paged out to a temporary file during the states' passes, and
methods B and C taking their mask from the mean image's moduli alone."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from gridstrain._runtime import paging as _paging
from gridstrain.results import ResultFile
from gridstrain.series import _loop as gp
from gridstrain.series import measure_series
from test_pipeline import LAT, Plate


def _rss_file_kib() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("RssFile:"):
                return int(line.split()[1])
    raise AssertionError("no RssFile line")


def test_paged_arrays_keep_their_values_and_leave_no_file(tmp_path):
    rng = np.random.default_rng(0)
    arrays = {"psi": rng.normal(size=(2, 30, 41)) + 1j * rng.normal(size=(2, 30, 41)),
              "dphi": rng.normal(size=(2, 2, 30, 41)).astype(np.float32),
              "empty": np.zeros((0, 3))}
    before = {k: v.copy() for k, v in arrays.items()}
    paged = _paging.page(arrays, folder=tmp_path)
    assert paged is not None
    assert list(tmp_path.iterdir()) == []  # unlinked at once
    for name, a in arrays.items():
        view = paged.arrays[name]
        assert view.dtype == a.dtype
        assert view.shape == a.shape
        assert not view.flags.writeable
        assert_array_equal(view, before[name])
        assert_array_equal(a, before[name])  # the originals untouched
    paged.page_out()
    for name in arrays:  # read back from the page cache: the same values
        assert_array_equal(paged.arrays[name], before[name])


def test_page_keeps_the_arrays_in_memory_where_no_file_can_be_made(tmp_path):
    assert _paging.page({"a": np.ones(3)}, folder=tmp_path / "missing") is None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RssFile of /proc")
def test_page_out_gives_the_pages_back(tmp_path):
    big = np.ones((64, 2**17))  # 64 MiB
    paged = _paging.page({"big": big}, folder=tmp_path)
    assert paged is not None
    del big
    float(paged.arrays["big"].sum())  # every page resident
    resident = _rss_file_kib()
    paged.page_out()
    # KiB: the 64 MiB mapping leaves the process's resident set at once (madvise is
    # synchronous); other file pages of the process move by far less
    assert resident - _rss_file_kib() > 60 * 1024
    assert float(paged.arrays["big"].sum()) == 64 * 2**17


def _series(n_frames=2):
    p = Plate()
    rng = np.random.default_rng(11)
    ref, _ = p.frames(n_frames, loaded=False, rng=rng)
    cur, _ = p.frames(n_frames, loaded=True, rng=rng)
    return ref, cur


@pytest.mark.parametrize("method", ["B", "C"])
def test_paged_reference_gives_the_same_file(tmp_path, monkeypatch, method):
    ref, cur = _series()
    made = []
    real_page = _paging.page

    def spy(arrays, folder):
        made.append(real_page(arrays, folder=folder))
        return made[-1]

    monkeypatch.setattr(gp._paging, "page", spy)
    paged = measure_series(ref, [cur, cur], lattice=LAT, method=method,
                           output=ResultFile(tmp_path / "paged.h5"))
    assert len(made) == 1
    assert made[0] is not None  # the reference's maps were paged
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paged.h5"]
    monkeypatch.setattr(gp._paging, "page", lambda arrays, folder: None)
    kept = measure_series(ref, [cur, cur], lattice=LAT, method=method,
                          output=ResultFile(tmp_path / "kept.h5"))
    for name in ("u", "strain", "valid"):
        assert_array_equal(np.asarray(getattr(paged, name)), np.asarray(getattr(kept, name)))
    assert paged.uncertainty.keys() == kept.uncertainty.keys()
    for name in paged.uncertainty:
        assert_array_equal(np.asarray(paged.uncertainty[name]),
                           np.asarray(kept.uncertainty[name]))
    assert paged.warnings == kept.warnings


def test_methods_b_and_c_find_the_regions_without_grid_as_method_a():
    # no mask given: the hole is found in the mean image, by method A from its maps
    # and by B and C from the moduli alone
    ref, cur = _series(1)
    masks = {m: measure_series(ref, cur, lattice=LAT, method=m).mask for m in "ABC"}
    p = Plate()
    assert not masks["A"][p.r < p.a - 5.0].any()  # the hole is out
    assert_array_equal(masks["B"], masks["A"])
    assert_array_equal(masks["C"], masks["A"])


def test_nothing_to_page_keeps_the_arrays_in_memory(tmp_path):
    assert _paging.page({"a": np.zeros((0, 3))}, folder=tmp_path) is None
    assert list(tmp_path.iterdir()) == []
