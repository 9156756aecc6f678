"""Which FFT implementation the windowed Fourier transform runs on.

``scipy.fft`` (pocketfft) by default. With the ``mkl`` extra installed
(``pip install "gridstrain[mkl]"``: mkl_fft, Intel's MKL, BSD-3 wrapper of a
freely redistributable library), the transforms go through MKL instead, plugged in
with scipy.fft's backend mechanism. The environment variable ``GRIDSTRAIN_FFT``
chooses: ``auto`` (the default: MKL when installed), ``scipy`` or ``mkl``.

Whether MKL is faster depends on the CPU: measure with
``benchmarks/bench_wft.py`` (it prints the implementation in use). A backend set
with ``scipy.fft.set_backend`` holds in the calling thread only, so gridstrain
enters its own choice in every thread that transforms, including its worker
threads. Every transform is asked for one thread (``workers=1``): gridstrain's
own ``workers`` options decide how many run at once.
"""

from __future__ import annotations

import contextlib
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


def backend():
    """Context in which ``scipy.fft`` calls run on the chosen implementation."""
    b = _backend()
    return contextlib.nullcontext() if b is None else sfft.set_backend(b, only=True)
