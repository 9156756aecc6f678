"""One pass over a series (gridstrain.stacks.accumulate) against sums written here.

The frames come from tests/independent_grid.py (numpy only): a rotated
checkerboard under lighting fixed to the camera, with a hole, 12-bit Poisson-
Gaussian noise stored x16, each frame rigidly shifted by a random vibration.
"""

from __future__ import annotations

import itertools
import pickle

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from gridstrain import Lattice, stacks, wft
from gridstrain.phase import Window
from gridstrain.stacks.accumulate import PassPlan, SeriesPass
from gridstrain.stacks.screening import screen_frames
from independent_grid import scene

PITCH, ANGLE = 5.0, 12.0
SHAPE = (96, 112)


def _lattice():
    th = np.deg2rad(ANGLE)
    f = 1 / PITCH
    return Lattice((f * np.cos(th), f * np.sin(th)), (-f * np.sin(th), f * np.cos(th)))


def _series(T, seed=0, vib=0.08):
    rng = np.random.default_rng(seed)
    shifts = rng.normal(0, vib, (T, 2))
    frames = []
    for a in shifts:
        img, _ = scene(SHAPE, pitch=PITCH, angle=ANGLE, over=2,
                       displacement=lambda X, Y, a=a: (a[0] + 0 * X, a[1] + 0 * Y))
        noisy = 2.0 * rng.poisson(img / 2.0) + rng.normal(0, 3.0, img.shape)
        frames.append(np.clip(np.round(noisy), 0, 4095) * 16)
    return np.array(frames), shifts


@pytest.fixture(scope="module")
def data():
    return _series(12)


def _pass(frames, method="A", chunks=1, **kw):
    T = len(frames)
    plan = PassPlan(lattice=_lattice(), n_frames=T, method=method, window=Window(PITCH), **kw)
    bounds = np.linspace(0, T, chunks + 1).round().astype(int)
    parts = []
    for a, b in itertools.pairwise(bounds):
        p = SeriesPass(plan, frames[0])
        for t in range(a, b):
            p.add(t, frames[t])
        parts.append(pickle.loads(pickle.dumps(p)))  # as a Dask worker ships it
    out = parts[0]
    for p in parts[1:]:
        out = out.merge(p)
    return out


def _terms(shifts):
    """The motion regressors by name, written here: the shift (px) and the cosine and
    sine of the harmonics m theta_1 + n theta_2 of the carrier phases theta = 2 pi K a."""
    th = 2 * np.pi * shifts @ _lattice().K.T
    out = {"x": shifts[:, 0], "y": shifts[:, 1]}
    for m, n in ((1, 0), (0, 1), (2, 0), (0, 2), (1, 1), (1, -1)):
        name = {(1, 0): "theta1", (0, 1): "theta2", (2, 0): "2 theta1", (0, 2): "2 theta2",
                (1, 1): "theta1 + theta2", (1, -1): "theta1 - theta2"}[m, n]
        arg = m * th[:, 0] + n * th[:, 1]
        out[f"cos({name})"], out[f"sin({name})"] = np.cos(arg), np.sin(arg)
    return out


def _direct_variance(frames, shifts, names=("x", "y")):
    """Per-pixel residual variance of the least-squares fit v_t = m + sum_k b_k g_k(t)
    on the regressors ``names`` (:func:`_terms`), solved pixel by pixel by numpy's
    least squares (T - 1 - len(names) dof)."""
    T = len(frames)
    terms = _terms(shifts)
    X = np.column_stack([np.ones(T)] + [terms[n] for n in names])
    beta, *_ = np.linalg.lstsq(X, frames.reshape(T, -1), rcond=None)
    r = frames.reshape(T, -1) - X @ beta
    return (r * r).sum(axis=0).reshape(frames.shape[1:]) / (T - 1 - len(names))


def test_mean_halves_and_variance_are_the_direct_sums(data):
    frames, _ = data
    acc = _pass(frames, chunks=3)
    st = acc.statistics()
    # float64 sums of 12 grey levels of ~3e4: rounding ~1e-11 grey levels
    assert_allclose(st.mean, frames.mean(axis=0), rtol=0, atol=1e-9)
    h = acc.half_means()
    assert_allclose(h[0], frames[:6].mean(axis=0), rtol=0, atol=1e-9)
    assert_allclose(h[1], frames[6:].mean(axis=0), rtol=0, atol=1e-9)
    assert acc.half_counts() == (6, 6)
    # the regressors are the shifts the pass measured on the carriers; the direct
    # fit uses the same ones (the pass's claim is the algebra, the shifts are tested
    # in test_vibration), so they agree to rounding: 1e-9 of a variance of ~1e3
    a = screen_frames(frames, _lattice()).shifts()
    assert st.n_frames == 12
    # 0.08 px of vibration at pitch 5: the first harmonics lower the residual by more
    # than the 1 % a group must gain; the second ones (4 dof of 9) do not
    assert st.regressors == ("x", "y", "cos(theta1)", "sin(theta1)", "cos(theta2)",
                             "sin(theta2)")
    assert st.dof == 5
    assert "regressed out (5 dof)" in st.method
    want = _direct_variance(frames, a, st.regressors)
    assert_allclose(st.variance, want, rtol=1e-9, atol=1e-6)
    # the plain first-order fit, for the record: the second-order term of the
    # vibrations is in it (a few % at 0.08 px on this sharp checkerboard)
    first = _direct_variance(frames, a)
    assert np.mean(first) > np.mean(want)


def test_chunking_does_not_change_the_sums(data):
    frames, _ = data
    one, four = _pass(frames, "B", chunks=1), _pass(frames, "B", chunks=4)
    # sums added in another order: relative rounding of float64, 1e-12 of the values
    s1, s4 = one.statistics(), four.statistics()
    assert_allclose(s4.mean, s1.mean, rtol=1e-13)
    assert_allclose(s4.variance, s1.variance, rtol=1e-9, atol=1e-9)
    b1, b4 = one.method_b().maps, four.method_b().maps
    assert_array_equal(b1.valid, b4.valid)
    v = b1.valid
    # phases of unit-phasor sums: 1e-12 rad is rounding
    assert_allclose(b4.phase[:, v], b1.phase[:, v], rtol=0, atol=1e-12)
    assert_array_equal(one.screen().coefficients, four.screen().coefficients)


def test_method_b_and_c_are_those_of_stacks(data):
    frames, _ = data
    lat = _lattice()
    b = _pass(frames, "B", chunks=2).method_b().maps
    want = stacks.method_b(frames, lat, sigma=PITCH).maps
    assert_array_equal(b.valid, want.valid)
    assert_allclose(b.phase[:, b.valid], want.phase[:, want.valid], rtol=0, atol=1e-12)
    assert_allclose(b.dphi[:, :, b.valid], want.dphi[:, :, want.valid], rtol=0, atol=1e-15)
    acc = _pass(frames, "C", chunks=3)
    c = acc.method_c()
    shifts = screen_frames(frames, lat).shifts()
    wc = stacks.method_c(frames, lat, shifts=shifts, sigma=PITCH)
    assert_array_equal(c.maps.valid, wc.maps.valid)
    v = c.maps.valid
    # the same realigned sums, one complex turn apart at most: 1e-12 rad
    assert_allclose(c.maps.phase[:, v], wc.maps.phase[:, v], rtol=0, atol=1e-12)
    assert_allclose(c.shifts, wc.shifts, rtol=0, atol=1e-12)
    half = acc.method_c(halves=(1,))
    wh = stacks.method_c(frames[6:], lat, shifts=shifts[6:], sigma=PITCH)
    assert_allclose(half.maps.phase[:, v], wh.maps.phase[:, v], rtol=0, atol=1e-12)


def test_a_removed_frame_is_as_if_never_added(data):
    frames, _ = data
    # a frame of another grey level and another position: what the screening excludes
    bad = frames.copy()
    bad[4] = np.roll(bad[4], 2, axis=1) * 0.5
    acc = _pass(bad, "B", chunks=2)
    acc.remove(4, bad[4])
    keep = [t for t in range(12) if t != 4]
    want = _pass(frames[keep], "B")
    st, sw = acc.statistics(), want.statistics()
    assert acc.kept == keep
    assert acc.half_counts() == (5, 6)
    # a subtraction of grey levels of ~3e4: rounding well under 1e-8 grey levels
    assert_allclose(st.mean, sw.mean, rtol=0, atol=1e-8)
    assert_allclose(st.variance, sw.variance, rtol=1e-7, atol=1e-6)
    mb, mw = acc.method_b().maps, want.method_b().maps
    assert_array_equal(mb.valid, mw.valid)
    assert_allclose(mb.phase[:, mb.valid], mw.phase[:, mw.valid], rtol=0, atol=1e-10)
    # the halves: frame 4 was in the first half
    assert_allclose(acc.half_means()[0], frames[[0, 1, 2, 3, 5]].mean(axis=0), atol=1e-8)


def test_bad_use_is_refused(data):
    frames, _ = data
    plan = PassPlan(lattice=_lattice(), n_frames=3)
    p = SeriesPass(plan, frames[0])
    p.add(0, frames[0])
    with pytest.raises(ValueError, match="frame 0 was added twice"):
        p.add(0, frames[0])
    with pytest.raises(ValueError, match="shape"):
        p.add(1, frames[0][:50])
    with pytest.raises(ValueError, match="lacks frames"):
        p.screen()
    with pytest.raises(ValueError, match="frame 2 is not in the sums"):
        p.remove(2, frames[2])
    other = SeriesPass(plan, frames[1])
    with pytest.raises(ValueError, match="origin"):
        p.merge(other)
    with pytest.raises(ValueError, match="method"):
        PassPlan(lattice=_lattice(), n_frames=3, method="D")
    with pytest.raises(ValueError, match="method B"):
        p.method_b()


def _direct_method_b(frames, lat):
    """Method B written here from one gridstrain.wft per frame: the circular mean of
    the phases (unit phasors summed), the mean modulus and the mean derivatives
    (paper §2.3, eqs. 32-33), valid where every frame is."""
    maps = [wft(f, lat, sigma=PITCH) for f in frames]
    unit = np.mean([m.psi / np.abs(m.psi) for m in maps], axis=0)
    psi = unit / np.abs(unit) * np.mean([np.abs(m.psi) for m in maps], axis=0)
    dphi = np.mean([m.dphi for m in maps], axis=0)
    valid = np.all([m.valid for m in maps], axis=0)
    return psi, dphi, valid


def test_released_sums_give_the_direct_results(data):
    """The pass frees its sums as the pipeline goes (release, method_b(release=True));
    what is still asked for afterwards is what the full sums and the frames give."""
    frames, _ = data
    lat = _lattice()
    acc, kept = _pass(frames, "B", chunks=2), _pass(frames, "B", chunks=2)
    st = acc.statistics()
    acc.release(keep_halves=True)
    with pytest.raises(ValueError, match="released"):
        acc.statistics()
    b = acc.method_b(release=True)
    # the maps computed in the sums' buffers are those of a pass that keeps them, bit
    # for bit (same operations in the same order)
    full = kept.method_b()
    assert_array_equal(b.maps.psi, full.maps.psi)
    assert_array_equal(b.maps.dphi, full.maps.dphi)
    assert_array_equal(b.maps.valid, full.maps.valid)
    assert_array_equal(b.resultant, full.resultant)
    assert b.n_frames == full.n_frames == 12
    with pytest.raises(ValueError, match="method B's sums were released"):
        acc.method_b()
    # and those of the frames' transforms averaged here: float64 sums of 12 unit
    # phasors added in another order, rounding ~1e-15; 1e-12 rad and 1e-12 rad/px
    psi, dphi, valid = _direct_method_b(frames, lat)
    assert_array_equal(b.maps.valid, valid)
    v = valid
    assert_allclose(np.angle(b.maps.psi[:, v] * np.conj(psi[:, v])), 0, atol=1e-12)
    assert_allclose(np.abs(b.maps.psi[:, v]), np.abs(psi[:, v]), rtol=1e-12)
    assert_allclose(b.maps.dphi[:, :, v], dphi[:, :, v], rtol=0, atol=1e-12)
    # the halves' sums were kept: 1e-9 grey levels of ~3e4 is float64 rounding
    h0, h1 = acc.half_means()
    assert_allclose(h0, frames[:6].mean(axis=0), rtol=0, atol=1e-9)
    assert_allclose(acc.half_means((1,))[0], h1, rtol=0, atol=0)
    assert_allclose(st.mean, frames.mean(axis=0), rtol=0, atol=1e-9)
    acc.release()
    with pytest.raises(ValueError, match="halves' sums were released"):
        acc.half_means()


def test_stacks_method_b_is_the_direct_average(data):
    """stacks.method_b computes its maps in its sums' buffers: the frames' transforms
    averaged here (rounding of 12-term float64 sums: 1e-12 rad, 1e-12 rad/px)."""
    frames, _ = data
    lat = _lattice()
    res = stacks.method_b(frames, lat, sigma=PITCH, workers=2)
    psi, dphi, valid = _direct_method_b(frames, lat)
    assert_array_equal(res.maps.valid, valid)
    assert res.maps.psi.dtype == np.complex128  # integer-valued float64 frames
    assert_allclose(np.angle(res.maps.psi[:, valid] * np.conj(psi[:, valid])), 0,
                    atol=1e-12)
    assert_allclose(res.maps.dphi[:, :, valid], dphi[:, :, valid], rtol=0, atol=1e-12)
    # float32 frames: float32 maps from float64 sums (gridstrain.conventions)
    r32 = stacks.method_b(frames.astype(np.float32), lat, sigma=PITCH)
    assert r32.maps.psi.dtype == np.complex64
    assert r32.maps.dphi.dtype == np.float32


@pytest.mark.parametrize("compiled", [True, False])
def test_integer_frames_as_read_give_the_direct_sums(data, compiled, monkeypatch):
    from gridstrain.phase import _maps as phase_maps

    if compiled and phase_maps._load_kernels() is None:
        pytest.skip("the compiled loops need numba (the fast extra)")
    monkeypatch.setattr(phase_maps, "_COMPILED", compiled)
    frames, _ = data
    raw = frames.astype(np.uint16)  # 12-bit levels stored x16: exact in uint16
    bad = raw.copy()
    bad[4] = np.roll(bad[4], 2, axis=1) // 2  # taken out again, as the screening does
    acc = _pass(bad, chunks=2)
    # the batch holds the frames as read where the compiled loops sum them
    assert acc._buf.dtype == (np.uint16 if compiled else np.float64)
    acc.remove(4, bad[4])
    keep = [t for t in range(12) if t != 4]
    st = acc.statistics()
    # float64 sums of grey levels of ~3e4, one frame taken out: rounding ~1e-11
    assert_allclose(st.mean, frames[keep].mean(axis=0), rtol=0, atol=1e-9)
    assert_allclose(acc.half_means()[0], frames[[0, 1, 2, 3, 5]].mean(axis=0), atol=1e-9)
    assert_allclose(acc.half_means()[1], frames[6:].mean(axis=0), atol=1e-9)
    a = screen_frames(frames, _lattice()).shifts()[keep]
    assert_allclose(st.variance, _direct_variance(frames[keep], a, st.regressors),
                    rtol=1e-9, atol=1e-6)


def test_compiled_and_numpy_sums_agree_for_method_c(data, monkeypatch):
    from gridstrain.phase import _maps as phase_maps

    if phase_maps._load_kernels() is None:
        pytest.skip("the compiled loops need numba (the fast extra)")
    frames, _ = data
    raw = frames.astype(np.uint16)
    out = {}
    for compiled in (True, False):
        monkeypatch.setattr(phase_maps, "_COMPILED", compiled)
        acc = _pass(raw, "C", chunks=3)
        acc.remove(7, raw[7])
        acc._flush()
        out[compiled] = acc
    # the same 16 weighted sums (2 halves, 8 realigning rows, the 6 motion regressors
    # 12 frames can fit) added in another order: float64 rounding, 1e-13 of the
    # largest sum
    assert out[True].lin.shape[0] == 16
    for name in ("lin", "sq"):
        x, y = getattr(out[True], name), getattr(out[False], name)
        assert_allclose(x, y, rtol=0, atol=1e-13 * np.abs(y).max())


def _pending_raw_pass(raw):
    """A pass with every frame of ``raw`` added: 11 wait in the batch as read (the
    origin adds nothing), none summed yet."""
    acc = SeriesPass(PassPlan(lattice=_lattice(), n_frames=len(raw)), raw[0])
    for t in range(len(raw)):
        acc.add(t, raw[t])
    return acc


def _assert_direct_sums(st, frames, keep):
    # grey levels of ~3e4 summed in float64, a frame taken out: rounding ~1e-11
    assert_allclose(st.mean, frames[keep].mean(axis=0), rtol=0, atol=1e-9)
    a = screen_frames(frames, _lattice()).shifts()[keep]
    assert_allclose(st.variance, _direct_variance(frames[keep], a, st.regressors),
                    rtol=1e-9, atol=1e-6)


def test_a_frame_read_as_float_leaves_the_raw_batch_exact(data):
    # integer frames wait in the batch as read; a frame given as float64 (taken out
    # again here) flushes them and is summed as its difference: the same sums
    frames, _ = data
    raw = frames.astype(np.uint16)
    acc = _pending_raw_pass(raw)
    acc.remove(4, raw[4].astype(np.float64))
    keep = [t for t in range(12) if t != 4]
    _assert_direct_sums(acc.statistics(), frames, keep)


def test_raw_frames_pending_when_the_compiled_loops_are_switched_off(data, monkeypatch):
    from gridstrain.phase import _maps as phase_maps

    if phase_maps._load_kernels() is None:
        pytest.skip("the compiled loops need numba (the fast extra)")
    frames, _ = data
    acc = _pending_raw_pass(frames.astype(np.uint16))
    monkeypatch.setattr(phase_maps, "_COMPILED", False)
    # flushed by numpy instead: the same sums
    _assert_direct_sums(acc.statistics(), frames, list(range(12)))


@pytest.mark.parametrize(("n_frames", "terms"), [(3, 0), (4, 2), (7, 2), (8, 6), (16, 14),
                                                 (27, 14), (28, 26), (500, 26)])
def test_a_pass_keeps_the_sums_of_the_terms_its_frames_can_fit(n_frames, terms):
    # a group of the variance's regressors (2 shifts, then 4, 8 and 12 harmonic terms)
    # is summed only when T - 1 exceeds the terms fitted with it: its fit keeps a
    # degree of freedom; the budget counts those beyond the shifts, 8 bytes a pixel
    shape = (40, 48)
    yy, xx = np.mgrid[0:40, 0:48]
    img = 1000 + 500 * np.cos(2 * np.pi * (_lattice().K @ np.array([xx.ravel(),
                                                                  yy.ravel()]))).sum(0)
    img = img.reshape(shape)
    for method, first in (("A", 2), ("C", 10)):  # C: its 8 realigning rows first
        acc = SeriesPass(PassPlan(lattice=_lattice(), n_frames=n_frames, method=method), img)
        assert acc.lin.shape == (first + terms, img.size)
    assert stacks.accumulate.motion_sums_bytes(shape, n_frames) == \
        8 * img.size * max(terms - 2, 0)
