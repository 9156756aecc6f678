"""A result written state by state while measuring (measure_series(output=...)).

Checked against the same measurement held in memory and saved afterwards: the file
and the maps must be the same, and a failure must leave nothing behind.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from gridstrain import Lattice, stacks
from gridstrain.kinematics import deformation
from gridstrain.models import synthetic
from gridstrain.phase import coupling_corrected, demodulated_at, finite_derivatives, wft
from gridstrain.phase.lattice import reference_carrier as _reference_carrier
from gridstrain.phase.lattice import state_carrier as _state_carrier
from gridstrain.results import ResultFile, StoredMaps, load, save_result
from gridstrain.series import measure_series

LAT = Lattice.from_pitch(5.0)
SHAPE = (96, 112)


def _series(T, strain, seed):
    rng = np.random.default_rng(seed)
    img = synthetic.grid_image(SHAPE, LAT, displacement=lambda X, Y: (
        strain * X + 0.3, -0.5 * strain * Y))
    return np.array([img + rng.normal(0, 0.01, SHAPE) for _ in range(T)])


@pytest.fixture(scope="module")
def data():
    ref = _series(4, 0.0, 0)
    states = [_series(3, e, k + 1) for k, e in enumerate((1e-3, 2e-3, 3e-3))]
    return ref, states


@pytest.fixture(scope="module")
def pair(data, tmp_path_factory):
    ref, states = data
    path = tmp_path_factory.mktemp("streamed") / "r.h5"
    held = measure_series(ref, states, lattice=LAT, guess=None)
    streamed = measure_series(ref, states, lattice=LAT, guess=None,
                              output=ResultFile(path, lossless=True))
    return held, streamed, path


def test_streamed_maps_are_those_held_in_memory(pair):
    held, streamed, _path = pair
    assert isinstance(streamed.u, StoredMaps)
    assert streamed.u.shape == held.u.shape
    assert streamed.n_states == 3
    assert streamed.shape == SHAPE
    # the same numbers, stored losslessly in float64
    assert_array_equal(np.asarray(streamed.u), held.u)
    assert_array_equal(np.asarray(streamed.strain), held.strain)
    assert_array_equal(np.asarray(streamed.valid), held.valid)
    for k, v in held.uncertainty.items():
        assert_array_equal(np.asarray(streamed.uncertainty[k]), v)
    for a, b in zip(streamed.measurements, held.measurements, strict=True):
        assert_array_equal(np.asarray(a.rotation), b.rotation)
        assert a.iterations == b.iterations
    assert streamed.warnings == held.warnings
    assert_array_equal(streamed.noise.theory_u, held.noise.theory_u)


def test_indexing_reads_like_an_array(pair):
    held, streamed, _ = pair
    for key in (1, -1, (2, 0), (slice(None), 1), (slice(0, 2), 0, 5), (0, 1, 7, 9)):
        assert_array_equal(np.asarray(streamed.u[key]), held.u[key])
    assert_array_equal(streamed.get_map("exy"), held.get_map("exy"))
    assert [s.shape for s in streamed.strain] == [(3, *SHAPE)] * 3
    with pytest.raises(IndexError, match="state 3 out of range for 3 states"):
        streamed.u[3]
    # NumPy's operators, functions and an array's methods work on the whole
    assert_array_equal(streamed.u * 2.0, held.u * 2.0)
    assert float(streamed.valid.mean()) == float(held.valid.mean())
    assert_array_equal(np.nonzero(streamed.valid)[2], np.nonzero(held.valid)[2])
    assert_array_equal(streamed.measurements[1].rotation.reshape(-1),
                       held.measurements[1].rotation.reshape(-1))


def test_the_file_is_the_one_save_result_writes(pair, tmp_path):
    held, _streamed, path = pair
    saved = save_result(held, tmp_path / "held.h5", lossless=True)
    a, b = load(path), load(saved)
    for name in ("u", "strain", "valid", "mask", "reference_image"):
        assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.names == b.names
    # NaN fields (no correlation with guess=None) compare by their text
    assert repr(a.fringe_orders) == repr(b.fringe_orders)
    assert repr(a.metrology) == repr(b.metrology)
    assert repr(a.noise) == repr(b.noise)


def test_float32_keeps_what_it_says(data, tmp_path):
    ref, states = data
    held = measure_series(ref, states, lattice=LAT, guess=None)
    small = measure_series(ref, states, lattice=LAT, guess=None,
                           output=ResultFile(tmp_path / "f.h5", lossless=True),
                           dtype="float32")
    u = np.asarray(small.u)
    assert u.dtype == np.float32
    assert small.parameters["dtype"] == "float32"
    v = held.valid
    # rounding to float32: half the spacing of float32 numbers at |u| < 1 px, 2^-25
    # (the displacements here stay below 1 px), and 2^-25 of |e| < 0.01 for strain
    err = np.abs(u - held.u)[:, :, v[0]]
    assert float(err.max()) <= 2.0**-25
    assert float(np.abs(np.asarray(small.strain) - held.strain)[:, :, v[0]].max()) \
        <= 0.01 * 2.0**-24


def test_a_failing_state_leaves_no_file(data, tmp_path):
    ref, states = data
    bad = np.zeros_like(states[1])  # a state without a grid: refused
    with pytest.raises(ValueError, match="state 1"):
        measure_series(ref, [states[0], bad, states[2]], lattice=LAT, guess=None,
                       output=tmp_path / "r.h5")
    assert list(tmp_path.iterdir()) == []  # neither the file nor its temporary file


def test_an_existing_file_is_kept_without_overwrite(data, tmp_path):
    ref, states = data
    (tmp_path / "r.h5").write_bytes(b"mine")
    with pytest.raises(FileExistsError):
        measure_series(ref, states[:1], lattice=LAT, guess=None, output=tmp_path / "r.h5")
    assert (tmp_path / "r.h5").read_bytes() == b"mine"
    res = measure_series(ref, states[:1], lattice=LAT, guess=None,
                         output=ResultFile(tmp_path / "r.h5", overwrite=True,
                                           pixel_size=0.05, unit="mm"))
    assert load(tmp_path / "r.h5").n_states == 1
    assert_array_equal(np.asarray(res.u[0]), load(tmp_path / "r.h5").u[0])


@pytest.mark.parametrize("method", ["A", "B"])
def test_each_state_is_the_direct_measurement_of_its_frames(data, tmp_path, method):
    """The pipeline frees each series' sums, statistics and maps as soon as nothing
    needs them (method B's maps computed in its sums' buffers, the state's mean
    dropped once its image features are taken, the previous state's field once the
    next state is guessed). Each state's maps must still be those of
    kinematics.deformation on the two series' phase maps computed here from the
    frames: method A from the mean image, method B from one transform per frame
    averaged (stacks.method_b), their vibration offset about the frames' mean position
    removed and the window's phase-modulus coupling taken out
    (gridstrain.phase.coupling_corrected), both on the pixels whose mean image shows a grid
    (modulus at least a quarter of its median at both wave vectors, the documented
    rule for holes and edges: here a few pixels of the borders' band). The guess is
    automatic (the previous state's field from the second state on): the
    displacements stay below 0.7 px, well within half a period (2.5 px), so every
    guess gives the same fringe order. A state is transformed at its own carrier,
    found on its first frame (gridstrain.phase.follow_lattice), and its maps then
    brought to the reference's lattice."""
    ref, states = data
    full = np.ones(SHAPE, dtype=bool)

    def maps(frames, lat=LAT):
        mean = frames.mean(axis=0)
        pm = wft(mean, lat, mask=full)
        mod = np.abs(pm.psi)
        grid = ~np.any([mod[j] < 0.25 * np.median(mod[j][pm.valid]) for j in range(2)],
                       axis=0)
        # both with their vibration offset about the frames' mean position removed
        # (stacks.correct_phases, about="mean"), from the frames' measured shifts
        shifts = stacks.vibration.frame_shifts(frames, lat)
        if method == "A":
            pm = wft(mean, lat, mask=grid)
        else:
            pm = stacks.method_b(frames, lat, mask=grid).maps
        # and the window's phase-modulus coupling taken out at the transform's carrier
        return coupling_corrected(
            finite_derivatives(stacks.correct_phases(pm, shifts, about="mean")))

    def state_maps(frames):
        own = _state_carrier(frames[0], LAT, _reference_carrier(ref[0], LAT))
        return demodulated_at(maps(frames, own), LAT)

    res = measure_series(ref, states, lattice=LAT, method=method,
                         output=ResultFile(tmp_path / "r.h5", lossless=True))
    m_ref = maps(ref)
    for k, frames in enumerate(states):
        want = deformation(m_ref, state_maps(frames), guess=None)
        assert_array_equal(np.asarray(res.valid[k]), want.valid)
        # method A's mean is the pass's origin plus the frames' differences, not
        # numpy's sum: ~1e-16 relative in the image, 1e-12 px and 1e-12 strain are far
        # above what that changes and far below any physical effect
        assert_allclose(np.asarray(res.u[k]), want.u, rtol=0, atol=1e-12)
        assert_allclose(np.asarray(res.strain[k]), want.strain, rtol=0, atol=1e-12)
        assert_allclose(np.asarray(res.measurements[k].rotation), want.rotation, rtol=0,
                        atol=1e-12)
    # the previous state's field, read back from the file for the next state's guess
    # and step, is the one held in memory without a file: the same records, bit for bit
    held = measure_series(ref, states, lattice=LAT, method=method)
    # (the first state within 0.1 period of the reference is followed from it)
    assert [r.source for r in res.fringe_orders] == ["previous state"] * 3
    assert repr(res.fringe_orders) == repr(held.fringe_orders)
    assert_array_equal(np.asarray(res.u), held.u)


def test_the_previous_field_read_back_from_the_file_gives_the_same_states(data, tmp_path,
                                                                          monkeypatch, spy):
    """Each state's guess is the previous state's field: kept in memory when it is
    small, read back from the result file when it is large (the bits the file holds,
    u in float64). Both ways must give the same maps and fringe order records; the
    threshold is set to 0 here to read back fields this small."""
    from gridstrain.results import _file
    from gridstrain.series import _loop

    ref, states = data
    kept = measure_series(ref, states, lattice=LAT,
                          output=ResultFile(tmp_path / "kept.h5", lossless=True))
    calls = spy(_file.StreamedResult, "reader")
    monkeypatch.setattr(_loop, "_FOLLOW_IN_MEMORY", 0)
    read = measure_series(ref, states, lattice=LAT,
                          output=ResultFile(tmp_path / "read.h5", lossless=True))
    assert calls == [0, 1]  # every state but the last is followed from the file
    assert_array_equal(np.asarray(read.u), np.asarray(kept.u))
    assert_array_equal(np.asarray(read.strain), np.asarray(kept.strain))
    assert_array_equal(np.asarray(read.valid), np.asarray(kept.valid))
    assert [r.source for r in read.fringe_orders] == [r.source for r in kept.fringe_orders]
    assert [r.detail for r in read.fringe_orders] == [r.detail for r in kept.fringe_orders]
    assert read.fringe_orders[1].source == "previous state"


def test_a_record_that_cannot_fit_on_its_disk_is_refused_after_its_first_state(
        data, tmp_path, monkeypatch):
    # the disk's free space as the file system would report it, once the first state
    # is written: room for that one, not for the two others
    import collections

    import gridstrain.results._file as rf

    ref, states = data
    usage = collections.namedtuple("usage", "total used free")
    one_state = 8 * SHAPE[0] * SHAPE[1] * 11  # float64 maps: u, strain, rotation, stds
    seen = []

    def disk_usage(path):
        seen.append(path)
        return usage(10 * one_state, 9 * one_state, one_state)

    monkeypatch.setattr(rf.shutil, "disk_usage", disk_usage)
    with pytest.raises(OSError, match=r"r\.h5: the maps of its 2 other states need about "
                                      r".* more on that disk, and .* are free; nothing was "
                                      r"written; .*write elsewhere, or .*leave out "
                                      r"--lossless"):
        measure_series(ref, states, lattice=LAT, guess=None,
                       output=ResultFile(tmp_path / "r.h5", lossless=True))
    assert seen == [tmp_path.resolve()]
    assert list(tmp_path.iterdir()) == []
    # a rounded file is counted by what its first state took compressed: refused
    # where even that does not fit, and the rounding is not offered again
    monkeypatch.setattr(rf.shutil, "disk_usage", lambda p: usage(10, 10, 1000))
    with pytest.raises(OSError, match=r"write elsewhere$"):
        measure_series(ref, states, lattice=LAT, guess=None, output=tmp_path / "r.h5")
    assert list(tmp_path.iterdir()) == []
    # a single state needs no more room than it took: never refused
    monkeypatch.setattr(rf.shutil, "disk_usage", lambda p: usage(1, 1, 0))
    measure_series(ref, states[:1], lattice=LAT, guess=None, output=tmp_path / "one.h5")
    assert (tmp_path / "one.h5").is_file()
