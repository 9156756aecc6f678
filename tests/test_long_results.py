"""A long record's result file looked at state by state: ``load(in_memory=False)`` and
the commands that read a result (gauge, history, plot, report), in the memory of a
few states rather than of the whole record.

Checked against the same file read into memory: the same numbers, the same tables,
the same figures byte for byte, under a memory budget that reading the whole refuses.
The percentiles of the colour limits, read in passes, against ``np.percentile``.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from numpy.testing import assert_array_equal

from gridstrain import Lattice
from gridstrain._runtime.memory import memory_budget
from gridstrain._stats import streamed_percentiles
from gridstrain.cli import main
from gridstrain.models import synthetic
from gridstrain.results import StoredMaps, load
from gridstrain.series import measure_series

LAT = Lattice.from_pitch(5.0)
SHAPE = (64, 80)
N_STATES = 16


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """A record's result file: one reference frame and 16 one-frame states of a
    growing strain, and the bytes its per-state maps hold once read."""
    rng = np.random.default_rng(3)

    def frame(e):
        img = synthetic.grid_image(SHAPE, LAT, amplitude=1000.0,
                                   displacement=lambda X, Y: (e * X, -0.3 * e * Y))
        return img + rng.normal(0, 2.0, SHAPE)

    path = tmp_path_factory.mktemp("record") / "rec.h5"
    measure_series(frame(0.0), [frame(2e-4 * (k + 1)) for k in range(N_STATES)],
                   lattice=LAT, guess=(0.0, 0.0), output=path, noise_model=(0.004, 4.0))
    with h5py.File(path, "r") as h5:
        maps = sum(h5[k].size * h5[k].dtype.itemsize for k in h5
                   if isinstance(h5[k], h5py.Dataset) and h5[k].ndim == 3)
    return path, maps


def test_maps_left_in_the_file_read_as_those_loaded(record):
    path, _ = record
    held, lazy = load(path), load(path, in_memory=False)
    assert isinstance(lazy.u, StoredMaps)
    assert isinstance(lazy.valid, StoredMaps)
    for name in ("u", "strain", "valid"):
        assert_array_equal(np.asarray(getattr(lazy, name)), getattr(held, name))
    for k, v in held.uncertainty.items():
        assert_array_equal(np.asarray(lazy.uncertainty[k]), v)
        assert_array_equal(lazy.uncertainty[k][[5, 0, 5]], v[[5, 0, 5]])
    for a, b in zip(lazy.measurements, held.measurements, strict=True):
        for name in ("u", "strain", "rotation", "valid"):
            assert_array_equal(np.asarray(getattr(a, name)), getattr(b, name))
    # a component of every state is a view of the file, read state by state
    assert isinstance(lazy.ux, StoredMaps)
    assert lazy.ux.shape == (N_STATES, *SHAPE)
    assert_array_equal(lazy.exy[3], held.exy[3])
    assert_array_equal(lazy.get_map("uy")[-1], held.get_map("uy")[-1])
    # chosen states, in any order, repeated or not
    assert_array_equal(lazy.u[[7, 2, 7]], held.u[[7, 2, 7]])
    assert_array_equal(lazy.strain[np.array([15, 0])], held.strain[[15, 0]])
    assert lazy.u[[]].shape == (0, 2, *SHAPE)
    st, yy, xx = np.nonzero(held.valid)  # pointwise, as a CSV export reads it
    assert_array_equal(lazy.ux[st, yy, xx], held.ux[st, yy, xx])
    with pytest.raises(IndexError, match="out of range for 16 states"):
        lazy.u[[3, 16]]
    with pytest.raises(IndexError, match="component 2 out of range"):
        lazy.u[:, 2]
    # the rest is the file's, as loaded
    assert lazy.names == held.names
    assert repr(lazy.noise) == repr(held.noise)
    assert_array_equal(lazy.mask, held.mask)
    with pytest.raises(TypeError, match="in_memory"):
        load(path, in_memory="no")
    # a record's repr names its first and last states, not every one
    assert repr(lazy) == repr(held)
    assert repr(held).endswith(
        f"frames reference 1, states 1 each, valid {held.valid[0].mean():.1%} (first) to "
        f"{held.valid[-1].mean():.1%} (last))")


def test_maps_left_in_the_file_fit_a_memory_reading_them_does_not(record):
    path, maps = record
    with memory_budget(maps // 2):
        with pytest.raises(ValueError, match=r"rec\.h5: its datasets need"):
            load(path)
        lazy = load(path, in_memory=False)
        assert lazy.u[N_STATES - 1].shape == (2, *SHAPE)


def test_a_file_changed_under_its_views_is_refused_not_misread(record, tmp_path):
    path, _ = record
    copy = tmp_path / "rec.h5"
    copy.write_bytes(path.read_bytes())
    lazy = load(copy, in_memory=False)
    with h5py.File(copy, "r+") as h5:  # ux cut to fewer states
        ux = h5["ux"][:4]
        del h5["ux"]
        h5["ux"] = ux
    # nothing of a changed file is read, not even what is unchanged in it
    with pytest.raises(ValueError, match=r"rec\.h5: the result file was replaced or "
                                         r"changed since it was opened"):
        lazy.u[0]
    with pytest.raises(ValueError, match="replaced or changed"):
        lazy.strain[0]
    # a view that does not know the file it was made from (the maps of a file being
    # written) still checks each variable's layout before reading it
    view = StoredMaps(copy, "ux", layout=(N_STATES, *SHAPE, np.dtype(np.float32)))
    with pytest.raises(ValueError, match=r"rec\.h5: /ux is no longer the \(16, 64, 80\)"):
        view[0]
    assert StoredMaps(copy, "uy", layout=(N_STATES, *SHAPE, np.dtype(np.float32)))[0].shape \
        == SHAPE


def test_reads_in_a_kept_open_block_share_one_handle_per_file(record, tmp_path,
                                                               monkeypatch):
    import gridstrain.results._file as rf
    from gridstrain.results import kept_open

    path, _ = record
    copy = tmp_path / "rec.h5"
    copy.write_bytes(path.read_bytes())
    lazy = load(copy, in_memory=False)
    opened = []
    real = rf.h5py.File

    def counting(*args, **kwargs):
        f = real(*args, **kwargs)
        opened.append(f)
        return f

    valid3 = load(path).valid[3]
    monkeypatch.setattr(rf.h5py, "File", counting)
    first = [np.asarray(lazy.ux[i]) for i in range(N_STATES)]  # a file a read
    assert len(opened) == N_STATES
    opened.clear()
    with kept_open():
        again = [np.asarray(lazy.ux[i]) for i in range(N_STATES)]
        assert_array_equal(lazy.valid[3], valid3)
        assert len(opened) == 1
        # the file replaced under the block (another inode): refused, not opened
        with real(tmp_path / "other.h5", "w") as h5:
            h5["ux"] = np.zeros((2, *SHAPE))
        (tmp_path / "other.h5").replace(copy)
        with pytest.raises(ValueError, match="replaced"):
            lazy.ux[0]
        assert len(opened) == 1
    assert not any(f.id.valid for f in opened)  # every kept handle closed at the end
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(first, again,
                                                                    strict=True))


def _run(args):
    assert main([str(a) for a in args]) == 0


def _outputs_under_budgets(record, tmp_path, capsys, commands):
    """The files ``commands(path, times, d)`` write, with no memory budget and with one
    that reading the whole file refuses, each run in its own folder ``d``."""
    path, maps = record
    times = tmp_path / "times.csv"
    times.write_text("load [kN],time [s]\n"
                     + "".join(f"{0.1 * k},{0.5 * k}\n" for k in range(N_STATES)))
    outputs = {}
    for where, budget in (("free", None), ("tight", maps // 2)):
        d = tmp_path / where
        d.mkdir()
        with memory_budget(budget):
            for args in commands(path, times, d):
                _run(args)
        outputs[where] = {p.relative_to(d): p.read_bytes() for p in sorted(d.rglob("*"))
                          if p.is_file() and p.name != ".gridstrain"}
    capsys.readouterr()
    return outputs


def test_the_commands_read_a_record_state_by_state(record, tmp_path, capsys):
    """gauge, history and plot give the same tables and figures under a memory budget
    that reading the whole file refuses as with no budget."""
    outputs = _outputs_under_budgets(record, tmp_path, capsys, lambda path, times, d: [
        ["gauge", path, "--region", 20, 16, 60, 48, "-o", d / "gauge.csv"],
        ["history", path, "--loads", times, "-o", d / "history.csv"],
        # a map and its std map: the limits of each read in passes over the states
        ["plot", path, "--maps", "exx,exx_std", "--limits", "robust", "-o", d / "figures"]])
    assert len(outputs["free"]) == 5  # the two tables, two maps and the history figure
    assert outputs["tight"] == outputs["free"]


@pytest.mark.slow
def test_the_report_reads_a_record_state_by_state(record, tmp_path, capsys):
    """The report too (its figures cost most of its time, whatever the budget); the
    plot of every kind of map with it."""
    outputs = _outputs_under_budgets(record, tmp_path, capsys, lambda path, times, d: [
        ["plot", path, "--maps", "exx,ux,rotation,exx_std", "--limits", "robust",
         "-o", d / "figures"],
        ["report", path, "-o", d / "report.html"]])
    assert len(outputs["free"]) == 6
    assert outputs["tight"] == outputs["free"]


def _chunks(data, size):
    parts = [data[i:i + size] for i in range(0, data.size, size)]
    calls = []

    def chunks():
        calls.append(1)
        return iter(parts)
    return chunks, calls


_RNG = np.random.default_rng(11)
_DATA = {
    "normal": _RNG.normal(size=20001),
    "one value": np.array([0.25]),
    "two values": np.array([3.0, -1.0]),
    "all equal": np.full(5000, -2.5),
    "rounded (ties)": np.round(_RNG.normal(size=60000), 1),
    "Cauchy (far outliers)": _RNG.standard_cauchy(80001),
    "mostly zeros": np.concatenate([np.zeros(40000), _RNG.normal(size=300)]),
    "span beyond the largest float": np.concatenate([_RNG.normal(size=3000),
                                                     [1.7e308, -1.7e308] * 20]),
    "subnormals": _RNG.normal(size=4000) * 1e-310,
}


@pytest.mark.parametrize("name", list(_DATA))
@pytest.mark.parametrize("gather", [50, 2**22])
def test_streamed_percentiles_are_numpy_percentiles(name, gather):
    data = _DATA[name]
    chunks, calls = _chunks(data, 777)
    n, lo, hi, p = streamed_percentiles(chunks, (0.5, 50.0, 99.5), gather=gather)
    assert (n, lo, hi) == (data.size, data.min(), data.max())
    with np.errstate(over="ignore", invalid="ignore"):
        # the same order statistics and interpolation: the same bits
        assert_array_equal(p, np.percentile(data, (0.5, 50.0, 99.5)))
    # a pass or two while what is left fits; each further one narrows a bin 4096-fold,
    # so that even 50 values gathered at a time take a few passes, not dozens
    assert len(calls) <= (2 if gather > data.size else 8)


def test_streamed_percentiles_of_nothing_are_nan():
    chunks, _ = _chunks(np.array([]), 10)
    n, lo, hi, p = streamed_percentiles(chunks, (0.5, 99.5))
    assert n == 0
    assert np.isnan([lo, hi, *p]).all()


def test_the_report_reads_each_map_once_when_it_fits(record, spy):
    """A record whose maps fit the memory is read once into memory for its report (one
    read of each map's dataset, one per state for the rotation), not once per figure,
    table and history (each state's maps a dozen times): the same page."""
    from gridstrain.post import render_report
    from gridstrain.results import _file

    path, _ = record
    page = render_report(load(path), title="r")
    reads = spy(_file.StoredMaps, "_read")
    assert render_report(load(path, in_memory=False), title="r") == page
    # u, strain, valid and 5 std maps whole, 16 rotations
    assert len(reads) <= 8 + N_STATES


def test_the_report_reads_state_by_state_where_the_memory_is_unknown(record, monkeypatch):
    """Where the system tells no available memory (no cgroup, no /proc: macOS,
    Windows), the report takes a 4-GiB machine's share, not an unbounded one: a
    record larger than that is read state by state, never whole."""
    from gridstrain.post import _report

    path, _ = record
    monkeypatch.setattr(_report, "available_memory", lambda: (2**63 - 1, "unknown"))
    lazy = load(path, in_memory=False)
    assert _report._maps_read_once(lazy) is not lazy  # this small record fits 1 GiB
    monkeypatch.setattr(_report, "_UNKNOWN_MEMORY", 1024)  # a record over the share
    assert _report._maps_read_once(lazy) is lazy
