"""The compiled fast derivatives (gridstrain.phase._kernels, numba) against the exact ones.

``wft(..., derivatives="fast")`` runs compiled loops when numba is installed (the
``fast`` extra) and ``wft``'s default then takes them. The reference is the exact
spectral path (the analytic derivative of the window, ``derivatives="exact"``) and,
independent of the package, the direct double sum of eq. (22) and a camera image
drawn by ``tests/independent_grid.py``. The numpy implementation of the same filter
is tested on the same cases in ``tests/test_wft.py``; here what only the compiled
loops do: their bounds on images the numpy tests do not hold, the undefined
derivatives, the threads, the fall-back when numba is missing, and that numba is
neither imported nor compiled before a transform needs it.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gridstrain
import gridstrain.phase._maps as phase_maps
import gridstrain.phase._transform as impl
from gridstrain import Lattice, wft
from gridstrain._runtime.fft import name as fft_name
from gridstrain.phase import Window
from independent_grid import camera, scene
from test_wft import _direct, _modulated_grid

SRC = str(Path(gridstrain.__file__).resolve().parents[1])
# bounds of the issue on the phase derivatives, rad/px
BOUND = {np.float64: 1e-7, np.float32: 1e-6}


@pytest.fixture
def compiled():
    """The compiled loops (the tests that need them are skipped without numba)."""
    pytest.importorskip("numba")
    kern = phase_maps.compiled_loops()
    assert kern is not None
    return kern


def _spy(monkeypatch):
    """Count the wave vectors that go through the compiled loops."""
    calls = []
    inner = impl._one_wave_vector_compiled

    def counted(*args, **kwargs):
        calls.append(1)
        return inner(*args, **kwargs)

    monkeypatch.setattr(impl, "_one_wave_vector_compiled", counted)
    return calls


def _camera_frame(dtype):
    """A rotated checkerboard under camera-fixed lighting, with a hole, as a 12-bit
    sensor stores it (x16 in 16 bits): the package's generator plays no part."""
    level, hole = scene((150, 170), pitch=5.0, angle=12.0, amplitude=2500.0)
    frame = camera(level, K=1.0, L=25.0, rng=np.random.default_rng(11)).astype(dtype)
    return frame, ~hole


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_compiled_on_a_camera_frame_is_within_the_bound(compiled, monkeypatch, dtype):
    frame, mask = _camera_frame(dtype)
    lat = Lattice.from_pitch(5.0, angle=12.0)
    exact = wft(frame.astype(np.float64), lat, mask=mask, derivatives="exact")
    calls = _spy(monkeypatch)
    fast = wft(frame, lat, mask=mask, derivatives="fast")
    assert len(calls) == 2  # both wave vectors went through the compiled loops
    assert fast.dphi.dtype == dtype
    assert fast.psi.dtype == np.result_type(dtype, np.complex64)
    # the mask, the border and the faint pixels are judged on the same moduli
    np.testing.assert_array_equal(fast.valid, exact.valid)
    v = exact.valid
    assert v.sum() > 5000
    err = np.max(np.abs(fast.dphi.astype(float) - exact.dphi)[:, :, v])
    # float64: the filter's design error (2e-9 rad/px per unit modulus, x 20 at the
    # faintest valid pixel) -- measured 2e-10; float32: the rounding of Psi through
    # differences of neighbours -- measured 3e-7. Both inside the bounds.
    assert err < (4e-8 if dtype == np.float64 else BOUND[dtype])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_compiled_against_the_direct_sum(compiled, dtype):
    lat, img = _modulated_grid()
    res = wft(img.astype(dtype), lat, sigma=5.0, derivatives="fast")
    rng = np.random.default_rng(3)
    worst = 0.0
    for py, px in rng.integers(40, 88, size=(8, 2)):
        for j, k in enumerate((lat.k1, lat.k2)):
            psi, dx, dy = _direct(img, k, 5.0, px, py)
            worst = max(worst, abs(res.dphi[j, 0, py, px] - dx),
                        abs(res.dphi[j, 1, py, px] - dy))
            # Psi to the rounding of the dtype: float32 holds 6e-8 relative
            tol = 1e-12 if dtype == np.float64 else 2e-6
            assert abs(res.psi[j, py, px] / psi - 1) < tol
    # noise-free grid: float64, the filter's error near the carrier (6e-11 rad/px
    # measured; 1e-9 is the exact path's bound in tests/test_wft.py); float32, the
    # issue's bound (its rounding gives ~3e-7)
    assert worst < (1e-9 if dtype == np.float64 else BOUND[dtype])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_compiled_equals_the_numpy_filter_to_rounding(compiled, monkeypatch, dtype):
    lat, img = _modulated_grid((140, 160), angle=23.0)
    img = img + np.random.default_rng(8).normal(0.0, 20.0, img.shape)
    mine = wft(img.astype(dtype), lat, sigma=6.1, derivatives="fast")
    monkeypatch.setattr(phase_maps, "_COMPILED", False)
    ref = wft(img.astype(dtype), lat, sigma=6.1, derivatives="fast")
    np.testing.assert_array_equal(mine.valid, ref.valid)
    v = ref.valid
    err = np.max(np.abs(mine.dphi.astype(float) - ref.dphi)[:, :, v])
    # the same taps on the same Psi; float64: 1e-13 rad/px is 1e3 roundings of a
    # 0.1 rad/px derivative; float32: its rounding through the filter (~3e-7, both
    # paths), within the float32 bound
    assert err < (1e-13 if dtype == np.float64 else 5e-7)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_no_signal_gives_undefined_derivatives_as_numpy_does(compiled, monkeypatch, dtype):
    # a specimen of uniform grey (a black hole masked out): after mean removal over
    # the mask nothing is left, Psi = 0 everywhere and the derivatives are 0/0,
    # NaN, in both implementations; nothing raises
    img = np.full((64, 80), 812.0, dtype=dtype)
    img[20:30, 30:45] = 0.0
    mask = img > 0
    lat = Lattice.from_pitch(5.0, angle=10.0)
    mine = wft(img, lat, mask=mask, derivatives="fast")
    monkeypatch.setattr(phase_maps, "_COMPILED", False)
    ref = wft(img, lat, mask=mask, derivatives="fast")
    assert np.all(mine.psi == 0)
    assert np.all(np.isnan(mine.dphi))
    assert np.all(np.isnan(ref.dphi))
    np.testing.assert_array_equal(mine.valid, ref.valid)


def test_compiled_threads_give_the_same_bits(compiled):
    frame, mask = _camera_frame(np.float32)
    lat = Lattice.from_pitch(5.0, angle=12.0)
    one = wft(frame, lat, mask=mask, derivatives="fast", workers=1)
    two = wft(frame, lat, mask=mask, derivatives="fast", workers=2)
    np.testing.assert_array_equal(two.psi, one.psi)
    np.testing.assert_array_equal(two.dphi, one.dphi)
    np.testing.assert_array_equal(two.valid, one.valid)


def _streamed(img, lat, **kwargs):
    """The maps of ``_wft(..., sink=...)`` put back together from its blocks of rows,
    with the rows each wave vector's blocks covered, in the order they came."""
    H, W = img.shape
    cdtype = np.result_type(img.dtype, np.complex64)
    psi = np.full((2, H, W), np.nan, dtype=cdtype)
    dphi = np.full((2, 2, H, W), np.nan, dtype=img.dtype)
    rows = {0: [], 1: []}

    def sink(j, r0, r1, p, d, md):
        assert p.shape == (r1 - r0, W)
        assert d.shape == (2, r1 - r0, W)
        assert md.shape == (r1 - r0, W)
        psi[j, r0:r1] = p
        dphi[j, :, r0:r1] = d
        rows[j].extend(range(r0, r1))

    valid = impl._wft(img, lat, sink=sink, **kwargs)
    return psi, dphi, valid, rows


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("workers", [1, 2])
def test_compiled_sink_hands_over_the_same_maps(compiled, monkeypatch, dtype, workers):
    # the blocks a stack sums (method B) are the rows of the whole maps, bit for bit
    frame, mask = _camera_frame(dtype)
    lat = Lattice.from_pitch(5.0, angle=12.0)
    monkeypatch.setattr(impl, "_COMPILED_CHUNK_BYTES", 2**14)  # several blocks
    whole = impl._wft(frame, lat, mask=mask, derivatives="fast", workers=workers)
    calls = _spy(monkeypatch)
    psi, dphi, valid, rows = _streamed(frame, lat, mask=mask, derivatives="fast",
                                       workers=workers)
    assert len(calls) == 2
    for j in range(2):
        assert rows[j] == list(range(frame.shape[0]))  # each row once, in order
    np.testing.assert_array_equal(psi, whole.psi)
    np.testing.assert_array_equal(dphi, whole.dphi)
    np.testing.assert_array_equal(valid, whole.valid)


def test_sink_without_the_compiled_loops_streams_the_exact_maps(monkeypatch):
    # the numpy fast path keeps whole maps: asked to stream, it computes the exact
    # derivatives, block by block
    monkeypatch.setattr(phase_maps, "_COMPILED", False)
    lat, img = _modulated_grid((96, 110))
    calls = _spy(monkeypatch)
    fast = _streamed(img, lat, derivatives="fast")
    exact = _streamed(img, lat, derivatives="exact")
    assert calls == []
    for a, b in zip(fast[:3], exact[:3], strict=True):
        np.testing.assert_array_equal(a, b)


def test_default_takes_the_compiled_loops_when_numba_is_there(compiled, monkeypatch):
    lat, img = _modulated_grid((96, 96))
    calls = _spy(monkeypatch)
    default = wft(img, lat)
    assert len(calls) == 2
    np.testing.assert_array_equal(default.dphi, wft(img, lat, derivatives="fast").dphi)


def test_without_numba_the_numpy_paths_run(monkeypatch):
    # numba missing (an import that fails): the default is the exact path and
    # "fast" the numpy filter; the loops of gridstrain.phase._kernels stay uncompiled
    import gridstrain.phase

    monkeypatch.setitem(sys.modules, "numba", None)
    # the compiled module, where this worker imported it already, comes back after the
    # test (monkeypatch restores both); the uncompiled one imported here never stays
    monkeypatch.delitem(sys.modules, "gridstrain.phase._kernels", raising=False)
    monkeypatch.delattr(gridstrain.phase, "_kernels", raising=False)
    phase_maps._load_kernels.cache_clear()
    try:
        assert phase_maps.compiled_loops() is None
        calls = _spy(monkeypatch)
        lat, img = _modulated_grid((96, 96))
        default = wft(img, lat)
        exact = wft(img, lat, derivatives="exact")
        np.testing.assert_array_equal(default.dphi, exact.dphi)
        np.testing.assert_array_equal(default.psi, exact.psi)
        fast = wft(img, lat, derivatives="fast")
        # the numpy filter keeps the transform (bit for bit on pocketfft; MKL's batched
        # and single transforms round differently: a few roundings of |Psi|)
        if fft_name() == "mkl":
            scale = np.max(np.abs(exact.psi))
            assert np.max(np.abs(fast.psi - exact.psi)) < 16 * np.finfo(float).eps * scale
        else:
            np.testing.assert_array_equal(fast.psi, exact.psi)
        # float64 design bound of the filter (see tests/test_wft.py)
        assert np.max(np.abs(fast.dphi - exact.dphi)[:, :, exact.valid]) < 4e-8
        assert calls == []
    finally:
        phase_maps._load_kernels.cache_clear()
        sys.modules.pop("gridstrain.phase._kernels", None)
        if hasattr(gridstrain.phase, "_kernels"):
            delattr(gridstrain.phase, "_kernels")


def _loaded_after(code: str) -> set[str]:
    script = (f"{code}\nimport sys\n"
              "print(' '.join(m for m in ('numba', 'llvmlite') if m in sys.modules))\n")
    env = dict(os.environ, PYTHONPATH=SRC)
    res = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return set(res.stdout.split())


def test_numba_is_loaded_only_by_a_transform(compiled):
    help_code = ("import contextlib, io\nimport gridstrain.phase._transform\n"
                 "from gridstrain.cli import main\n"
                 "with contextlib.redirect_stdout(io.StringIO()):\n"
                 "    try:\n        main(['--help'])\n    except SystemExit:\n        pass")
    assert _loaded_after(help_code) == set()
    transform = ("import numpy as np\nfrom gridstrain import Lattice, wft\n"
                 "wft(np.random.default_rng(0).random((48, 48)), Lattice.from_pitch(5.0))")
    assert "numba" in _loaded_after(transform)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_compiled_sums_of_method_b_are_the_numpy_sums(compiled, monkeypatch, dtype):
    # method B's sums of unit phasors, moduli and derivatives, added block by block in
    # one compiled pass, bit for bit those of the numpy path: with a hole (Psi = 0
    # deep inside it adds nothing), several blocks, and a frame taken out again
    import gridstrain.stacks._accumulators as gs

    frame, mask = _camera_frame(dtype)
    lat = Lattice.from_pitch(5.0, angle=12.0)
    rng = np.random.default_rng(12)
    frames = [(frame + rng.normal(0, 20, frame.shape)).astype(dtype) for _ in range(3)]
    monkeypatch.setattr(impl, "_COMPILED_CHUNK_BYTES", 2**14)

    def sums(kernels):
        monkeypatch.setattr(gs, "compiled_loops", kernels)
        acc = gs.PhaseMean()
        window = Window.for_lattice(lat)
        for f in frames:
            acc.add_frame(f, lat, window, mask=mask)
        acc.add_frame(frames[1], lat, window, mask=mask, remove=True)
        return acc

    loops, plain = sums(lambda: compiled), sums(lambda: None)
    assert loops.n == plain.n == 2
    for name in ("unit", "mod", "dphi", "invalid"):
        np.testing.assert_array_equal(getattr(loops, name), getattr(plain, name))


def test_compiled_sums_skip_the_direction_where_psi_is_zero(compiled):
    # where Psi = 0 there is no phase: its phasor and derivatives (0/0) add nothing,
    # its modulus adds 0; elsewhere psi / |psi| and the derivatives as they are
    rng = np.random.default_rng(13)
    psi = rng.normal(size=(3, 4)) + 1j * rng.normal(size=(3, 4))
    psi[1, 2] = 0
    mod = np.abs(psi)
    dphi = rng.normal(size=(2, 3, 4))
    dphi[:, 1, 2] = np.nan
    unit, msum, dsum = np.ones((3, 8)), np.ones((3, 4)), np.ones((2, 3, 4))
    compiled.add_unit_sums(psi.view(np.float64), mod, dphi, unit, msum, dsum, 1.0, 1.0)
    phasor = np.where(mod > 0, psi / np.where(mod > 0, mod, 1), 0)
    np.testing.assert_allclose(unit.view(np.complex128), 1 + 1j + phasor, rtol=1e-15)
    np.testing.assert_allclose(msum, 1 + mod, rtol=1e-15)
    np.testing.assert_allclose(dsum, 1 + np.where(mod > 0, dphi, 0), rtol=1e-15)
    compiled.add_unit_sums(psi.view(np.float64), mod, dphi, unit, msum, dsum, 1.0, -1.0)
    np.testing.assert_allclose(unit, 1, rtol=1e-15)  # taken out again
    np.testing.assert_allclose(dsum, 1, rtol=1e-15)


def test_the_phase_folders_compiled_loops_have_one_switch(monkeypatch):
    """The transform, the coupling correction and the carrier's move ask one switch
    (``gridstrain.phase._maps._COMPILED``): turned off there, none of them sees the
    compiled loops, and no other module holds a switch of its own that a test could
    patch while the loops it meant to turn off still ran."""
    import gridstrain.phase._coupling as coupling

    pytest.importorskip("numba")
    for module in (impl, coupling, phase_maps):
        assert module.compiled_loops() is not None
    assert not hasattr(impl, "_COMPILED")
    assert not hasattr(coupling, "_COMPILED")
    monkeypatch.setattr(phase_maps, "_COMPILED", False)
    for module in (impl, coupling, phase_maps):
        assert module.compiled_loops() is None
