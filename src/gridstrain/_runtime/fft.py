"""Which FFT implementation the windowed Fourier transform runs on.

``scipy.fft`` (pocketfft) by default. With the ``mkl`` extra installed
(``pip install "gridstrain[mkl]"``: mkl_fft, Intel's MKL, BSD-3 wrapper of a
freely redistributable library), the transforms go through MKL instead, plugged in
with scipy.fft's backend mechanism. The environment variable ``GRIDSTRAIN_FFT``
chooses: ``auto`` (the default: MKL when installed), ``scipy`` or ``mkl``.

Whether MKL is faster depends on the CPU: measure with
``benchmarks/bench_wft.py`` (it prints the implementation in use). The transforms
call the chosen implementation's functions directly (:func:`call`), in whatever
thread runs them: a backend entered with ``scipy.fft.set_backend`` holds in its
thread only, and entering one in every short-lived worker thread crashes scipy's
``uarray`` after a few tens of thousands of threads (a long record's states).
Every transform is asked for one thread (``workers=1``): gridstrain's own
``workers`` options decide how many run at once.
"""

from __future__ import annotations

import os
from functools import cache

from scipy import fft as sfft

__all__: list[str] = []

_CHOICES = ("auto", "scipy", "mkl")


@cache
def _backend():
    """The scipy.fft backend object to use, or None for scipy's own (resolved once)."""
    choice = os.environ.get("GRIDSTRAIN_FFT", "auto").strip().lower() or "auto"
    if choice not in _CHOICES:
        raise ValueError(f"GRIDSTRAIN_FFT must be one of {', '.join(_CHOICES)}, got "
                         f"{choice!r}")
    if choice == "scipy":
        return None
    try:
        from mkl_fft.interfaces import scipy_fft
    except ImportError as err:
        if choice == "mkl":
            raise ImportError("GRIDSTRAIN_FFT=mkl needs mkl_fft and mkl-service: "
                              'pip install "gridstrain[mkl]"') from err
        return None
    return scipy_fft


def name() -> str:
    """``"scipy"`` or ``"mkl"``: the implementation in use."""
    return "scipy" if _backend() is None else "mkl"


def call(name: str, *args, **kwargs):
    """``scipy.fft.<name>(*args, **kwargs)`` on the chosen implementation: its own
    function where it has one (the same computation as through scipy's dispatch),
    else through ``scipy.fft.set_backend`` (a backend that only dispatches)."""
    b = _backend()
    if b is None:
        return getattr(sfft, name)(*args, **kwargs)
    fn = getattr(b, name, None)
    if callable(fn):
        return fn(*args, **kwargs)
    with sfft.set_backend(b, only=True):
        return getattr(sfft, name)(*args, **kwargs)
