"""The FFT implementation is chosen once and entered in every thread that transforms."""

from __future__ import annotations

import importlib
import threading
from typing import ClassVar

import numpy as np
import pytest

from gridstrain import Lattice, wft
from gridstrain.models import synthetic
from gridstrain.stacks import method_b

_fft = importlib.import_module("gridstrain._runtime.fft")


class _Spy:
    """A scipy.fft backend that computes with numpy.fft and counts its calls per thread.

    Which pool thread runs which task is up to the scheduler (one idle thread may run
    both), so the tests compare call counts, never the number of distinct threads.
    """

    __ua_domain__ = "numpy.scipy.fft"
    calls: ClassVar[list] = []
    _lock = threading.Lock()

    @staticmethod
    def __ua_function__(method, args, kwargs):
        with _Spy._lock:
            _Spy.calls.append(threading.current_thread().name)
        kwargs = {k: v for k, v in kwargs.items() if k in ("axis", "axes", "s", "n")}
        return getattr(np.fft, method.__name__)(*args, **kwargs)


@pytest.fixture
def spy(monkeypatch):
    _Spy.calls = []
    monkeypatch.setattr(_fft, "_backend", lambda: _Spy)
    return _Spy


def _image(shape=(96, 112)):
    lat = Lattice.from_pitch(5.0, angle=10.0)
    rng = np.random.default_rng(3)
    img = synthetic.grid_image(shape, lat, amplitude=1500.0)
    return lat, synthetic.add_noise(img, rng=rng)


def test_worker_threads_transform_on_the_chosen_implementation(spy):
    lat, img = _image()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_fft, "_backend", lambda: None)
        want = wft(img, lat)
    wft(img, lat, workers=1)
    serial = len(spy.calls)
    spy.calls = []
    got = wft(img, lat, workers=2)
    # every transform of the threaded run went through the backend: as many calls as
    # the serial run (a pool thread that did not enter the backend would call scipy's
    # own pocketfft, unseen here; which thread takes which wave vector is the
    # scheduler's choice, the count is not)
    assert serial > 0
    assert len(spy.calls) == serial
    # numpy.fft and scipy.fft are both pocketfft, with other orders of operations:
    # ~1e-16 relative on the maps, far below the 1e-9 rad/px of the oracle tests
    np.testing.assert_allclose(got.dphi, want.dphi, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.psi, want.psi, rtol=1e-12, atol=1e-9)
    spy.calls = []
    method_b([img, img, img], lat, workers=1)
    serial = len(spy.calls)
    spy.calls = []
    method_b([img, img, img], lat, workers=2)
    assert serial > 0
    assert len(spy.calls) == serial
    assert set(spy.calls) - {threading.current_thread().name}


def test_choice_by_environment(monkeypatch):
    _fft._backend.cache_clear()
    monkeypatch.setenv("GRIDSTRAIN_FFT", "scipy")
    assert _fft.name() == "scipy"
    _fft._backend.cache_clear()
    monkeypatch.setenv("GRIDSTRAIN_FFT", "fftw")
    with pytest.raises(ValueError, match="GRIDSTRAIN_FFT must be one of"):
        _fft.name()
    _fft._backend.cache_clear()
    if importlib.util.find_spec("mkl_fft") is None:
        monkeypatch.setenv("GRIDSTRAIN_FFT", "mkl")
        with pytest.raises(ImportError, match=r"gridstrain\[mkl\]"):
            _fft.name()
    _fft._backend.cache_clear()


def _implementations() -> list[str]:
    return ["scipy", *(["mkl"] if importlib.util.find_spec("mkl_fft") else [])]


def _maps_on(name: str, monkeypatch, img, lat):
    """The transform's maps and method B's mean phase derivatives with the FFT of
    ``name`` (the choice GRIDSTRAIN_FFT makes, resolved afresh)."""
    _fft._backend.cache_clear()
    monkeypatch.setenv("GRIDSTRAIN_FFT", name)
    try:
        assert _fft.name() == name
        maps = wft(img, lat, workers=2)
        stack = method_b([img, img[::-1], img[:, ::-1]], lat, workers=2).maps
        return maps, stack
    finally:
        monkeypatch.delenv("GRIDSTRAIN_FFT")
        _fft._backend.cache_clear()


# Two FFT libraries round differently: double-precision transforms of these sizes
# agree to ~1e-15 relative (1.5e-15 measured between pocketfft and MKL). On the valid
# pixels the modulus is at least a few percent of its largest value, so the phases
# agree to ~1e-13 rad; 1e-11 rad (1e-11 px of displacement at a 6 px pitch) leaves a
# hundredfold margin and is still a million times below the 1e-5 rad of a measurement's
# noise floor. The derivatives, differences of phases over a pixel, likewise.
PHASE_TOL = 1e-11  # rad
DPHI_TOL = 1e-11  # rad/px


@pytest.mark.parametrize("other", _implementations())
def test_every_fft_implementation_gives_the_same_phases_within_rounding(monkeypatch, other):
    """Against scipy.fft (pocketfft): the phases, their derivatives and the moduli on
    the valid pixels, compared with tolerances in radians, never bit for bit."""
    lat, img = _image()
    ref, ref_b = _maps_on("scipy", monkeypatch, img, lat)
    got, got_b = _maps_on(other, monkeypatch, img, lat)
    for a, b in ((ref, got), (ref_b, got_b)):
        v = a.valid
        np.testing.assert_array_equal(b.valid, v)  # a rule on the mask, not on rounding
        assert v.mean() > 0.3  # the margin takes the borders of a 96 x 112 image
        dphase = np.angle(b.psi[:, v] * np.conj(a.psi[:, v]))  # wrapped difference
        assert np.max(np.abs(dphase)) < PHASE_TOL
        np.testing.assert_allclose(b.dphi[..., v], a.dphi[..., v], rtol=0, atol=DPHI_TOL)
        np.testing.assert_allclose(np.abs(b.psi[:, v]), np.abs(a.psi[:, v]), rtol=1e-12)


def test_an_implementation_with_its_own_functions_is_called_without_uarray(monkeypatch):
    """Entering scipy.fft.set_backend in every short-lived worker thread crashes scipy's
    uarray after some tens of thousands of threads (a record of a thousand states):
    an implementation that has the function (mkl_fft's scipy interface) is called
    directly, in any thread."""

    class _Direct:
        @staticmethod
        def ifft(x, **kwargs):
            return np.fft.ifft(x, axis=kwargs.get("axis", -1))

    def refuse(*args, **kwargs):
        raise AssertionError("scipy.fft.set_backend entered")

    monkeypatch.setattr(_fft, "_backend", lambda: _Direct)
    monkeypatch.setattr(_fft.sfft, "set_backend", refuse)
    x = np.arange(8.0) + 1j
    np.testing.assert_array_equal(_fft.call("ifft", x, axis=0), np.fft.ifft(x))
