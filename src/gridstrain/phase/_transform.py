"""Windowed Fourier transform of grid images: phases and phase derivatives.

The implementation behind the public module :mod:`gridstrain.phase`: the paper's
eqs. (22)-(25) for any two wave vectors, with the conventions (absolute carrier,
centred unit-sum Gaussian, mean removal and zero extension) of
:mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import as_strided
from scipy import fft as sfft

from .._runtime import fft as _fft
from .._runtime.threads import map_leaves
from .._validation import (
    as_image,
    check_choice,
    check_mask,
    check_positive,
    check_sigma,
    check_type,
    check_workers,
)
from ._exact import _ifft, _one_wave_vector
from ._maps import PhaseMaps, compiled_loops
from ._spectrum import _axis_band, spectrum_block, transfer_function
from ._validity import _gaps, _region, _shows_grid
from .lattice import Lattice
from .window import DEFAULT_MARGIN, MIN_MODULUS, Window

__all__ = ["DEFAULT_MARGIN", "PhaseMaps", "transfer_function", "wft", "wft_complex"]

# Spatial padding, in window standard deviations, added before the circular FFT
# convolution: the wrapped-around tail of the Gaussian then weighs exp(-8^2/2) ~ 1e-14.
_PAD_SIGMAS = 8.0
# Bytes of one block of rows of the final inverse FFTs (three transforms): small
# enough for the block and its products to stay in cache between the FFT and the
# products instead of streaming through memory.
_CHUNK_BYTES = 2**21




def wft(image, lattice: Lattice, *, sigma: float | None = None, mask=None,
        margin: float = DEFAULT_MARGIN, min_modulus: float = MIN_MODULUS,
        workers: int | None = 1, derivatives: str = "auto") -> PhaseMaps:
    """Windowed Fourier transform of a grid image for the lattice's two wave vectors.

    Parameters
    ----------
    image : (H, W) array_like
        Grid image, grey levels. float32 input is computed in float32, anything
        else in float64. Not modified.
    lattice : Lattice
        The grid's wave vectors (see :func:`detect_lattice`).
    sigma : float, optional
        Standard deviation of the Gaussian window, px. Default: the lattice's
        largest pitch, the paper's choice; smaller values are refused since the
        window must hold at least one period (paper ref. [23]).
    mask : (H, W) bool array_like, optional
        True on the specimen. Masked pixels are replaced by the mean grey level.
    margin : float
        Width, in units of ``sigma``, of the band along the border and around
        masked pixels that is declared invalid (default 4, see Notes).
    min_modulus : float
        Pixels whose modulus, for either wave vector, is below this fraction of its
        median over the pixels at least ``margin`` sigmas inside the image and the
        mask are invalid (no grid there).
    workers : int or None
        Threads (default 1; None: the usable cores). From 2 on, the two wave
        vectors are transformed at once, each on its own scratch arrays (about
        1.7x faster on two cores); the result is the same, bit for bit.
    derivatives : {"auto", "exact", "fast"}
        How the phase derivatives are computed. ``"exact"``: from the analytic
        derivative of the window, two more inverse transforms per wave vector
        (the reference). ``"fast"``: from ``Psi`` alone, by a short least-squares
        differentiator of the demodulated map, within 1e-7 rad/px of the exact
        ones in float64 and 1e-6 rad/px in float32 (see Notes); in compiled
        loops when numba is installed (``pip install "gridstrain[fast]"``), in
        numpy otherwise. ``"auto"`` (default): ``"fast"`` when the compiled
        loops are available, ``"exact"`` otherwise. ``Psi`` and its moduli are
        the same to rounding (bit for bit on the numpy path), hence ``valid``
        too but for a pixel whose modulus sits on the threshold to the last bit.

    Returns
    -------
    PhaseMaps

    Notes
    -----
    ``Psi_k(x) = sum_xi v(xi) g_sigma(xi - x) exp(-2 i pi k.xi)`` is computed as
    ``exp(-2 i pi k.x)`` times the correlation of the image with the Gabor kernel
    ``g_sigma(d) exp(-2 i pi k.d)``, whose transfer function ``G(f - k)`` is known
    in closed form. The window is never truncated. The phase derivatives are
    ``Im(conj(Psi) dPsi) / |Psi|^2``, exact for the sampled window and free of
    unwrapping. The FFTs are padded by ``8 sigma`` so that the circular convolution
    equals the linear one.

    Cost: one real FFT of the image; then, per wave vector, inverse FFTs along y of
    only the columns where ``G`` is non-zero (a band of about ``2.7 / sigma`` cycle/px)
    for the window and its y-derivative, and three inverse FFTs along x of the
    image's rows, for ``Psi``, ``dPsi/dx`` and ``dPsi/dy``, by blocks of rows that
    stay in cache. The window being separable, this equals the three 2-D inverse
    FFTs of the filtered spectra at about half their cost. At 1040 x 1376 px,
    sigma = 5 px, one call with the exact derivatives takes about 2.6 times one
    rfft2 and two complex ifft2 of the padded size, the least any FFT method needs
    for the two phase maps alone (``benchmarks/bench_wft.py``); with ``workers=2``,
    the two wave vectors run at once (about 1.6x faster on two cores). The FFTs run
    on the implementation :mod:`gridstrain._runtime.fft` chooses (scipy.fft, or MKL with
    the ``mkl`` extra).

    ``derivatives="fast"`` transforms only ``Psi``, one inverse per wave vector,
    and differentiates the demodulated map, whose spectrum is ``G`` times the
    image's: smooth and band-limited, so that an antisymmetric filter of 2m + 1
    taps, fitted to the exact derivative filter ``dG/G`` by least squares weighted
    by ``G``, matches it closely. m is the fewest taps whose error, on a tone or on
    white noise as large as ``Psi``, stays below 2e-9 rad/px (float64; 2e-8 in
    float32): 5 at sigma = 5 px, 7 at 3.5 px. A valid pixel's modulus is at least
    ``min_modulus`` times the median, so the error there stays below ~4e-8 rad/px
    even on pure noise (measured: 1e-8), and measures 2e-10 to 5e-10 rad/px on
    noisy grid images (tests/test_wft.py). In float32, differences of neighbouring
    samples amplify the rounding of ``Psi``: 3e-7 rad/px on a grid image, against
    3e-8 for the exact float32 path. A window narrower than about 3.5 px would need
    more taps than the exact path costs: the exact derivatives are then computed.
    In numpy, 14 to 19 % faster than the exact path at 1040 x 1376 px, sigma =
    5 px. Compiled (numba), the inverse FFT along x of each block of rows is
    followed at once, while the block is in cache, by one pass that demodulates it
    and one that writes ``Psi``, its modulus and both derivatives, in the frame's
    precision: about 1.5 times the FFT floor above in float64 and 1.4 times in
    float32 (1040 x 1376 and 2048 x 2048 px, one thread), 0.6 to 0.65 of the exact
    path's time (``benchmarks/bench_wft.py``). The differentiator is the same;
    only the rounding differs from the numpy path (1e-13 rad/px in float64, 5e-7
    in float32 on valid pixels). numba compiles the loops on the first call that
    needs them (about 5 s, once: the machine code is cached on disk and loads in
    a quarter of a second in later processes), never on ``import gridstrain``.
    The phases are left to :attr:`PhaseMaps.phase` (``np.angle``, vectorised):
    an arctangent in the compiled loops costs 3 to 8 times as much.

    Near the border or a mask edge the window is cut: results there are biased
    (for a noise-free grid at sigma = pitch, phase errors of 3e-3 rad at 2 sigma
    from the edge, 3e-4 rad at 3 sigma, 7e-6 rad at 4 sigma, falling as a Gaussian)
    and are flagged invalid within ``margin`` sigmas.
    """
    check_choice(derivatives, "derivatives", ("auto", "exact", "fast"))
    return _wft(image, lattice, sigma=sigma, mask=mask, margin=margin,
                min_modulus=min_modulus, derivatives=derivatives,
                workers=check_workers(workers))


def transform(image, lattice: Lattice, window: Window, *, mask=None,
              workers: int | None = 1, **options):
    """The transform of ``image`` through a checked :class:`~gridstrain.phase.Window`: the
    one entry of the series measurement. ``options`` are :func:`_wft`'s
    (``derivatives``, ``sink``, ``work``, ``checked``); returns what it returns."""
    check_type(window, "window", Window)
    return _wft(image, lattice, mask=mask, workers=check_workers(workers),
                **window.options(), **options)


def _wft(image, lattice: Lattice, *, sigma: float | None = None, mask=None,
         margin: float = DEFAULT_MARGIN, min_modulus: float = MIN_MODULUS,
         derivatives: str = "auto", sink=None, work=None, workers: int = 1,
         checked: bool = False):
    """:func:`wft`, with a choice of phase derivatives.

    ``derivatives="auto"`` (the default, here as in :func:`wft`): ``"fast"`` when the
    compiled loops are available, ``"exact"`` otherwise. A stack's frames (method B,
    through ``sink``) thus take the same derivatives as :func:`wft`'s maps.

    ``derivatives="exact"``:
    ``Im(conj(Psi) dPsi)/|Psi|^2`` with ``dPsi`` from the analytic derivative of the
    window, two more inverse FFTs along x and one more along y per wave vector; the
    reference the other two are tested against.

    ``derivatives="fast"``: ``Psi`` alone, differentiated by a least-squares filter
    (:func:`wft`'s Notes, :func:`_differentiator`), in the compiled loops of
    :mod:`gridstrain.phase._kernels` when numba is there
    (:func:`~gridstrain.phase.compiled_loops`), in numpy otherwise; the exact path
    where the window is too narrow for a short filter.

    ``sink`` (exact derivatives, or fast ones in the compiled loops; the numpy fast
    path computes the exact ones instead): instead of keeping the maps, hand each
    block of rows to ``sink(j, r0, r1, psi, dphi, mod)`` as soon as it is computed -- the
    wave vector's index, the rows ``r0:r1``, and views of ``psi`` (h, W),
    ``dphi`` (2, h, W) and the modulus (h, W) that are overwritten by the next
    block -- and return only the validity map. Method B sums the frames that way,
    while the blocks are still in cache, without a frame's maps ever being whole.
    ``work`` (a :class:`Workspace`) lends the scratch arrays, so that a caller
    transforming many frames reuses the same pages. ``checked``: ``image`` already
    went through :func:`~gridstrain._validation.as_image` (a stack's frames do).
    """
    check_choice(derivatives, "derivatives", ("auto", "exact", "fast"))
    if derivatives == "auto":
        derivatives = "fast" if compiled_loops() is not None else "exact"
    if not isinstance(lattice, Lattice):
        raise TypeError(f"lattice must be a Lattice, got {type(lattice).__name__}")
    img = image if checked else as_image(image)
    m = check_mask(mask, img.shape)
    sigma = check_sigma(sigma, lattice.pitch)
    margin = check_positive(margin, "margin")
    if not 0 <= min_modulus < 1:
        raise ValueError(f"min_modulus must be in [0, 1), got {min_modulus!r}")

    dtype = img.dtype
    H, W = img.shape
    full = bool(m.all())
    pad = math.ceil(_PAD_SIGMAS * sigma)
    ny = sfft.next_fast_len(H + pad, real=True)
    nx = sfft.next_fast_len(W + pad, real=True)
    # scratch arrays shared by the two wave vectors (and by the frames of a caller
    # that lends its workspace): fresh pages cost a page fault each
    work = Workspace() if work is None else work
    V = _padded_rfft2(img, m, full, ny, nx, work)
    cdtype = V.dtype
    # rows per block of the final inverse FFTs (three transforms of nx points each)
    chunk = max(8, _CHUNK_BYTES // (3 * nx * cdtype.itemsize))
    valid, box = _region(m, full, margin * sigma)
    fast = _differentiator(float(sigma), dtype) if derivatives == "fast" else None
    kern = compiled_loops() if fast is not None else None
    if sink is not None and kern is None:
        fast = None  # the numpy fast path keeps whole maps: the exact one streams
    psi = dphi = None  # the compiled loops stream to a sink from blocks of their own
    if sink is None:
        psi = np.empty((2, H, W), dtype=cdtype)
        dphi = np.empty((2, 2, H, W), dtype=dtype)
    elif kern is None:
        h = min(chunk, H)
        psi = work.get("psi", (2, h, W), cdtype)
        dphi = work.get("dphi", (2, 2, h, W), dtype)
    # the moduli, for the validity threshold only: in float32 where the compiled loops
    # stream blocks to a sink (a threshold at a fraction of the median does not need
    # more digits, and a stack's threads each keep two)
    mdtype = np.float32 if sink is not None and kern is not None else dtype
    mods = [work.get(f"mod{j}", (H, W), mdtype) for j in range(2)]
    # with two threads, one wave vector each, and scratch arrays of its own
    works = [work, Workspace()] if workers > 1 else [work, work]

    def one(j):
        k = (lattice.k1, lattice.k2)[j]
        # where Psi = 0 (no signal at all) the derivatives are 0/0: NaN, silently
        with np.errstate(invalid="ignore", divide="ignore"):
            if fast is not None and kern is not None:
                out = None if sink is None else (
                    lambda r0, r1, p, d, md: sink(j, r0, r1, p, d, md))
                _one_wave_vector_compiled(V, k, sigma, H, W, nx,
                                          None if psi is None else psi[j],
                                          None if dphi is None else dphi[j],
                                          mods[j], works[j], taps=fast[0], kern=kern,
                                          sink=out)
            elif fast is not None:
                _one_wave_vector_fast(V, k, sigma, H, W, nx, psi[j], dphi[j], mods[j],
                                      works[j], taps=fast[0],
                                      chunk=max(8, _FAST_CHUNK_BYTES // (nx * cdtype.itemsize)))
            else:
                out = None if sink is None else (
                    lambda r0, r1, p, d, md: sink(j, r0, r1, p, d, md))
                _one_wave_vector(V, k, sigma, H, W, nx, psi[j], dphi[j], mods[j], works[j],
                                 chunk=chunk, sink=out)

    map_leaves(one, range(2), min(workers, 2))
    valid &= _shows_grid(mods, valid, box, m, min_modulus)
    if sink is not None:
        return valid
    return PhaseMaps(psi=psi, dphi=dphi, valid=valid, lattice=lattice, sigma=float(sigma))



def wft_complex(images, lattice: Lattice, *, sigma: float | None = None, mask=None,
                margin: float = DEFAULT_MARGIN, min_modulus: float = MIN_MODULUS,
                dtype=np.float64) -> PhaseMaps:
    """Windowed Fourier transform of one complex image per wave vector.

    ``Psi_kj`` is the transform of ``images[j]`` at ``k_j``, with the window, the
    carrier, the mean removal, the zero extension and the exact derivatives of
    :func:`wft` (:mod:`gridstrain.conventions`). The transform is linear, so
    ``wft_complex([v, v])`` equals ``wft(v)`` for a real image ``v``; a complex
    image arises as a weighted sum of real frames, ``z_j = sum_t w_tj v_t``
    (:func:`gridstrain.stacks.method_c`), whose transform is ``sum_t w_tj
    Psi_kj(v_t)``.

    Parameters
    ----------
    images : (2, H, W) complex array_like
        One image per wave vector, grey levels.
    lattice : Lattice
        The wave vectors.
    sigma, mask, margin, min_modulus
        As in :func:`wft`.
    dtype : numpy dtype
        Real dtype of the returned derivatives (float32 or float64); ``psi`` is the
        matching complex type. Computed in complex128 either way.

    Returns
    -------
    PhaseMaps

    Notes
    -----
    Cost: one complex FFT of the padded image per wave vector (the spectrum of a
    complex image has no Hermitian symmetry to halve it), then the band-limited
    inverse transforms of :func:`wft`.
    """
    if not isinstance(lattice, Lattice):
        raise TypeError(f"lattice must be a Lattice, got {type(lattice).__name__}")
    z = np.asarray(images)
    if z.ndim != 3 or z.shape[0] != 2 or min(z.shape[1:]) < 2:
        raise ValueError(f"images must be a (2, H, W) complex array, one image per wave "
                         f"vector, got shape {z.shape}")
    if not np.all(np.isfinite(z)):
        raise ValueError("images must be finite")
    H, W = z.shape[1:]
    m = check_mask(mask, (H, W))
    sigma = lattice.pitch if sigma is None else check_positive(sigma, "sigma")
    if sigma < lattice.pitch * (1 - 1e-9):
        raise ValueError(f"sigma must be at least the pitch ({lattice.pitch:.4g} px) so that "
                         f"the window holds one period, got {sigma:.4g}")
    margin = check_positive(margin, "margin")
    if not 0 <= min_modulus < 1:
        raise ValueError(f"min_modulus must be in [0, 1), got {min_modulus!r}")
    full = bool(m.all())
    pad = math.ceil(_PAD_SIGMAS * sigma)
    ny = sfft.next_fast_len(H + pad)
    nx = sfft.next_fast_len(W + pad)
    chunk = max(8, _CHUNK_BYTES // (3 * nx * 16))
    psi = np.empty((2, H, W), dtype=np.complex128)
    dphi = np.empty((2, 2, H, W), dtype=np.float64)
    mods = [np.empty((H, W), dtype=np.float64) for _ in range(2)]
    work = Workspace()
    for j, k in enumerate((lattice.k1, lattice.k2)):
        padded = np.zeros((ny, nx), dtype=np.complex128)
        zj = z[j].astype(np.complex128, copy=False)
        # the mean carries no phase (conventions); for a weighted sum of frames it is
        # the mean grey level times the mean weight
        if full:
            np.subtract(zj, zj.mean(), out=padded[:H, :W])
        else:
            padded[:H, :W] = np.where(m, zj - zj[m].mean(), 0)
        V = _fft.call("fft2", padded, overwrite_x=True, workers=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            _one_wave_vector(V, k, sigma, H, W, nx, psi[j], dphi[j], mods[j], work,
                             chunk=chunk)
    valid, box = _region(m, full, margin * sigma)
    valid &= _shows_grid(mods, valid, box, m, min_modulus)
    dtype = np.dtype(dtype)
    return PhaseMaps(psi=psi.astype(np.result_type(dtype, np.complex64), copy=False),
                     dphi=dphi.astype(dtype, copy=False), valid=valid, lattice=lattice,
                     sigma=float(sigma))



class Workspace:
    """Scratch arrays reused from one wave vector to the next (named flat buffers)."""

    def __init__(self):
        self._buffers: dict[str, np.ndarray] = {}

    def get(self, name: str, shape, dtype) -> np.ndarray:
        """An uninitialised C-contiguous array of ``shape``, sharing ``name``'s buffer."""
        dtype = np.dtype(dtype)
        size = math.prod(shape)
        buf = self._buffers.get(name)
        if buf is None or buf.dtype != dtype or buf.size < size:
            buf = self._buffers[name] = np.empty(size, dtype=dtype)
        return buf[:size].reshape(shape)


def _padded_rfft2(img: np.ndarray, m: np.ndarray, full: bool, ny: int, nx: int,
                  work: Workspace | None = None) -> np.ndarray:
    """rfft2 of the mean-removed image, zero-extended to ``(ny, nx)`` (conventions).

    The same two passes as ``scipy.fft.rfft2`` of the zero-extended image (a real
    transform along x, then a complex one along y), without the extended image:
    the image's rows are transformed by blocks straight into the spectrum, the
    rows of the extension are zeros there, and the pass along y runs in place.
    With ``work``, the spectrum is the workspace's buffer ``"V"`` (a caller that
    transforms frame after frame reuses its pages).
    """
    dtype = img.dtype
    H = img.shape[0]
    cdtype = np.result_type(dtype, np.complex64)
    shape = (ny, nx // 2 + 1)
    V = np.empty(shape, dtype=cdtype) if work is None else work.get("V", shape, cdtype)
    mean = float(np.mean(img if full else img[m], dtype=np.float64))
    mean = dtype.type(mean)
    rows = max(1, _CHUNK_BYTES // (nx * dtype.itemsize))
    for r0 in range(0, H, rows):
        r1 = min(r0 + rows, H)
        block = img[r0:r1] - mean
        if not full:
            block[~m[r0:r1]] = 0
        V[r0:r1] = _fft.call("rfft", block, n=nx, axis=1, overwrite_x=True, workers=1)
    V[H:] = 0
    return _fft.call("fft", V, axis=0, overwrite_x=True, workers=1)



# Phase derivatives from Psi alone ("fast"): a least-squares differentiator of a few
# taps applied to the demodulated map, whose spectrum is the window's G(nu) times the
# image's, so smooth and band-limited. Its error, on a tone of Psi's amplitude at any
# frequency or on white noise (rms), is kept below this many rad/px by the choice of
# the number of taps; the valid pixels' moduli are at least a quarter of the median
# (MIN_MODULUS) and a noise peak may reach 5 rms, so the worst error on a valid pixel
# stays ~20 times this, 4e-8 rad/px in float64 against the 1e-7 bound, and far less
# on a real grid (measured in tests/test_wft.py). float32: its own rounding of Psi
# already gives ~1e-7 rad/px (the exact path's too), so 2e-8 rad/px x 20 suffices.
_FAST_TOL = {np.dtype(np.float64): 2e-9, np.dtype(np.float32): 2e-8}
# More taps than this (a window narrower than about 3.5 px in float64) and the
# differentiator costs more than the extra inverse FFTs of the exact derivatives.
_FAST_MAX_TAPS = 7
# Output columns per block of the x differentiator's matrix products, and image rows
# per product along y: small Toeplitz blocks keep the flops near those of the direct
# filter, and each product under OpenBLAS's threshold for going multi-threaded.
_TILE = 8
_YROWS = 4
_BLAS_ONE_THREAD = 2**18
# Bytes of one block of the transposed inverse FFT along x of the fast path.
_FAST_CHUNK_BYTES = 2**19


@functools.lru_cache(maxsize=32)
def _differentiator(sigma: float, dtype: np.dtype):
    """Taps ``a_1..a_m`` of the antisymmetric filter ``D psi[x] = sum_n a_n (psi[x+n] -
    psi[x-n])`` that best matches, weighted by the window's transfer function, the
    exact derivative filter ``dG/G`` of :func:`_one_wave_vector`; the fewest taps
    whose errors meet ``_FAST_TOL[dtype]``, or None beyond ``_FAST_MAX_TAPS``.

    Returns ``(taps, sup, rms)``: the worst error on a tone (``max |D - dG/G| G``)
    and the rms error on white noise, rad/px per unit of ``|Psi|``.
    """
    nu = np.linspace(-0.5, 0.5, 4001)
    g = transfer_function(nu, sigma)
    r = np.zeros_like(nu)
    np.divide(transfer_function(nu, sigma, derivative=True).imag, g, out=r, where=g > 0)
    for m in range(1, _FAST_MAX_TAPS + 1):
        # D's response is 2 i sum_n a_n sin(2 pi n nu); dG/G is i r(nu)
        basis = 2 * np.sin(2 * math.pi * np.outer(nu, np.arange(1, m + 1)))
        taps = np.linalg.lstsq(basis * g[:, None], r * g, rcond=None)[0]
        err = (basis @ taps - r) * g
        sup = float(np.max(np.abs(err)))
        rms = float(np.sqrt(np.sum(err**2) / np.sum(g**2)))
        if max(sup, rms) <= _FAST_TOL[np.dtype(dtype)]:
            return taps, sup, rms
    return None


def _banded(taps: np.ndarray, n: int, dtype) -> np.ndarray:
    """(n, n + 2m) matrix applying the differentiator ``taps`` to n + 2m samples."""
    m = taps.size
    T = np.zeros((n, n + 2 * m), dtype=dtype)
    for i in range(n):
        T[i, i + m + 1:i + 2 * m + 1] = taps
        T[i, i:i + m] = -taps[::-1]
    return T


def _filter_rows(T: np.ndarray, src: np.ndarray, out: np.ndarray):
    """``out[g*n:(g+1)*n] = T @ src[g*n : g*n + n + 2m]`` for every group g of n rows.

    ``src`` (n_groups*n + 2m, L) and ``out`` (n_groups*n, L) real and row-contiguous;
    one batched matrix product per piece of at most ``_BLAS_ONE_THREAD / (n (n + 2m))``
    columns, so that OpenBLAS runs each on the calling thread.
    """
    n, k = T.shape
    groups = out.shape[0] // n
    L = out.shape[1]
    width = max(64, _BLAS_ONE_THREAD // (n * k))
    it = src.itemsize
    for c0 in range(0, L, width):
        c1 = min(c0 + width, L)
        s = as_strided(src[:, c0:], shape=(groups, k, c1 - c0),
                       strides=(n * src.strides[0], src.strides[0], it), writeable=False)
        o = as_strided(out[:, c0:], shape=(groups, n, c1 - c0),
                       strides=(n * out.strides[0], out.strides[0], it))
        np.matmul(T, s, out=o)


def _psi_rows(psi, halo, buf, m: int, lo: int, hi: int):
    """Rows ``lo .. hi - 1`` (``-m <= lo``) of ``psi`` (H, W) contiguous: ``psi``'s own,
    the ``halo``'s (2m, W: rows -m .. -1, then H .. H + m - 1) and zeros beyond,
    copied into ``buf`` where they are not a slice of ``psi``."""
    H = psi.shape[0]
    if lo >= 0 and hi <= H:
        return psi[lo:hi]
    out = buf[:hi - lo]
    for r in range(lo, hi):
        out[r - lo] = (halo[m + r] if r < 0 else psi[r] if r < H
                       else halo[m + r - H] if r < H + m else 0)
    return out


def _along_y(V, k, sigma, H, nx, m, work):
    """The first half of :func:`_one_wave_vector_fast`'s inverse transform: the band of
    wave vector ``k`` windowed and transformed back along y, demodulated by the
    carrier's residual along y, rows -m .. H + m - 1 of the periodic transform (the y
    differentiator's reach beyond the image) as ``A[0 : H + 2m]`` (the band's
    columns); and the x band's runs and shift (:func:`_axis_band`)."""
    ny = V.shape[0]
    cdtype = V.dtype
    rows, yruns, _, sy, gy = _axis_band(ny, k[1], sigma)
    cols, xruns, _, sx, gx = _axis_band(nx, k[0], sigma)
    block = V[np.ix_(rows, cols)] if V.shape[1] == nx else spectrum_block(V, rows, cols, nx)
    # the window along x applied on the small band, so that the blocks after are copies
    block *= gx.astype(cdtype)
    gy = gy.astype(cdtype)
    Y = work.get("Y", (m + ny, cols.size), cdtype)
    for gap in _gaps(yruns, ny):
        Y[m + gap.start:m + gap.stop] = 0
    for dst, src in yruns:
        np.multiply(block[src], gy[src, None], out=Y[m + dst.start:m + dst.stop])
    _ifft_into(Y[m:], 0)
    Y[:m] = Y[ny:ny + m]
    A = Y[:H + 2 * m]
    ry = sy / ny - k[1]
    if ry != 0:
        A *= np.exp(2j * math.pi * ry * np.arange(-m, H + m)).astype(cdtype)[:, None]
    return A, (xruns, sx)


def _one_wave_vector_fast(V, k, sigma, H, W, nx, psi, dphi, mod, work, *, taps,
                          chunk: int):
    """:func:`_one_wave_vector` with the derivatives from ``Psi`` alone (see :func:`_wft`).

    One inverse transform per wave vector: along y for the band's columns, then along
    x by blocks of rows, transposed (x along the rows of the block) so that the
    differentiator along x is a matrix product over rows, as the one along y is on
    the finished rows of ``psi``, a block behind. The transform is demodulated (the
    carrier's residual too) before it is differentiated, and rows and columns just
    outside the image come from the periodic transform, as the exact path's do.
    """
    cdtype = V.dtype
    rdtype = mod.dtype
    m = taps.size
    A, (xruns, sx) = _along_y(V, k, sigma, H, nx, m, work)

    # along x, by blocks of (extended) rows, transposed: XT[m + x, i] for x = -m ..
    Wt = -(-W // _TILE) * _TILE  # whole tiles of the x differentiator
    nrow = m + max(nx, Wt + m)
    rx = sx / nx - k[0]
    ex = (np.exp(2j * math.pi * rx * np.arange(-m, Wt + m)).astype(cdtype)[:, None]
          if rx != 0 else None)
    gaps = _gaps(xruns, nx)
    Tx = _banded(taps.astype(rdtype), _TILE, rdtype)
    Ty = _banded(taps.astype(rdtype), _YROWS, rdtype)
    halo = work.get("halo", (2 * m, W), cdtype)  # psi rows -m..-1, then H..H+m-1
    h_max = min(chunk, H + 2 * m)
    src_buf = work.get("ysrc", (h_max + 2 * m + _YROWS, W), cdtype)
    dy = work.get("dy", (h_max + m + _YROWS, W), cdtype)
    cc = work.get("cc", ((h_max + m + _YROWS) * W,), cdtype)
    rinv = work.get("rinv", ((h_max + m + _YROWS) * W,), rdtype)
    it = np.dtype(rdtype).itemsize

    def along_y(y0, y1):
        # rows y0..y1: d phi/dy = Im(conj(psi) D psi) / |psi|^2
        n = -(-(y1 - y0) // _YROWS) * _YROWS
        src = _psi_rows(psi, halo, src_buf, m, y0 - m, y0 + n + m)
        _filter_rows(Ty, src.view(rdtype), dy[:n].view(rdtype))
        c = cc[:(y1 - y0) * W].reshape(y1 - y0, W)
        np.conjugate(psi[y0:y1], out=c)
        np.multiply(dy[:y1 - y0], c, out=c)
        inv = rinv[:(y1 - y0) * W].reshape(y1 - y0, W)
        np.square(mod[y0:y1], out=inv)
        np.reciprocal(inv, out=inv)  # inf where Psi = 0: d phi is NaN there, as 0/0
        np.multiply(c.imag, inv, out=dphi[1, y0:y1])

    done = 0  # rows whose y derivative is computed
    Ne = H + 2 * m
    for e0 in range(0, Ne, chunk):
        e1 = min(e0 + chunk, Ne)
        h = e1 - e0
        XT = work.get("XT", (nrow, h), cdtype)
        for gap in gaps:
            XT[m + gap.start:m + gap.stop] = 0
        XT[m + nx:] = 0
        for dst, src in xruns:
            np.copyto(XT[m + dst.start:m + dst.stop], A[e0:e1, src].T)
        _ifft_into(XT[m:m + nx], 0)
        XT[:m] = XT[nx:nx + m]  # columns -m..-1 of the periodic transform
        P = XT[:Wt + 2 * m]
        if ex is not None:
            P *= ex
        for e in range(e0, e1):  # the rows beyond the image, for the y differentiator
            y = e - m
            if y < 0 or y >= H:
                halo[m + y if y < 0 else m + y - H] = P[m:m + W, e - e0]
        y0, y1 = max(e0 - m, 0), min(e1 - m, H)
        if y1 > y0:
            i0, i1 = y0 - e0 + m, y1 - e0 + m
            np.copyto(psi[y0:y1], P[m:m + W, i0:i1].T)
            np.abs(psi[y0:y1], out=mod[y0:y1])
            inv = rinv[:(y1 - y0) * W].reshape(y1 - y0, W)
            np.square(mod[y0:y1], out=inv)
            np.reciprocal(inv, out=inv)  # inf where Psi = 0: d phi is NaN there, as 0/0
            # along x: a matrix product per tile of _TILE output rows of the block
            Pf = P.view(rdtype)
            s = as_strided(Pf, shape=(Wt // _TILE, _TILE + 2 * m, 2 * h),
                           strides=(_TILE * Pf.strides[0], Pf.strides[0], it),
                           writeable=False)
            DT = work.get("DT", (Wt, 2 * h), rdtype)
            np.matmul(Tx, s, out=DT.reshape(Wt // _TILE, _TILE, 2 * h))
            c = cc[:W * (i1 - i0)].reshape(W, i1 - i0)
            np.conjugate(P[m:m + W, i0:i1], out=c)
            np.multiply(DT.view(cdtype)[:W, i0:i1], c, out=c)
            np.multiply(c.imag.T, inv, out=dphi[0, y0:y1])
        # along y, a block behind: the rows whose reach is computed, by whole groups of
        # _YROWS (a group's product reads all its rows: 0 x NaN would be NaN)
        ylim = H if e1 == Ne else done + max(y1 - m - done, 0) // _YROWS * _YROWS
        if ylim > done:
            along_y(done, ylim)
            done = ylim


# Bytes of one block of rows of the compiled path's inverse FFT along x: the block,
# and the rows of the demodulated planes it fills, stay in cache until the compiled
# loop reads them.
_COMPILED_CHUNK_BYTES = 2**19


def _one_wave_vector_compiled(V, k, sigma, H, W, nx, psi, dphi, mod, work, *, taps,
                              kern, sink=None):
    """:func:`_one_wave_vector_fast` in compiled loops (:mod:`gridstrain.phase._kernels`).

    The same transform and differentiator: one inverse FFT along y of the band's
    columns (rows -m .. H + m - 1 of the periodic transform), then, by blocks of
    rows, one inverse FFT along x and one compiled pass that demodulates the block
    by the carrier's residual into planes of real and imaginary parts (with m
    columns beyond each side), and, as soon as the rows within the y
    differentiator's reach are there, one compiled pass that writes ``psi``, its
    modulus and both derivatives. Every loop runs in the frame's precision.

    With ``sink`` (``psi`` and ``dphi`` None), each block of finished rows is written
    to scratch arrays and handed to ``sink(r0, r1, psi, dphi, mod)``; the whole
    ``mod`` (H, W) is filled too, in its own precision (float32 for a sink), for the
    validity threshold.
    """
    ny = V.shape[0]
    cdtype = V.dtype
    rdtype = np.finfo(cdtype).dtype  # the frame's precision (mod may be float32)
    m = taps.size
    b = _compiled_band(ny, nx, H, W, (float(k[0]), float(k[1])), float(sigma), m,
                       rdtype.str)
    rows, cols = b.rows, b.cols
    # along y: rows -m .. H + m - 1 of the periodic transform, as Y[0 : H + 2m]
    Y = work.get("Y", (m + ny, cols.size), cdtype)
    for gap in b.ygaps:
        Y[m + gap.start:m + gap.stop] = 0
    kern.band_columns(V, rows, b.dst, cols, nx, b.gx, b.gy, m, Y)
    _ifft_into(Y[m:], 0)
    Y[:m] = Y[ny:ny + m]
    A = Y[:H + 2 * m]
    ey_re, ey_im, ex_re, ex_im = b.ey_re, b.ey_im, b.ex_re, b.ex_im
    taps = taps.astype(rdtype)
    tmp = work.get("tmp", (4, W), rdtype)
    # a block holds at least the y differentiator's reach, 2m + 1 rows
    chunk = max(8, 2 * m + 1, _COMPILED_CHUNK_BYTES // (nx * cdtype.itemsize))
    X = work.get("Xc", (min(chunk, H + 2 * m), nx), cdtype)
    # the demodulated rows of one block, after the 2m rows of the block before that the
    # y differentiator still reaches: small enough to stay in cache
    planes = work.get("planes", (2, X.shape[0] + 2 * m, W + 2 * m), rdtype)
    runs, gaps = b.runs, b.gaps
    full_mod = mod
    if sink is not None:  # one block of finished rows at a time
        psi = work.get("psi_blk", (X.shape[0], W), cdtype)
        dphi = work.get("dphi_blk", (2, X.shape[0], W), rdtype)
        mod = work.get("mod_blk", (X.shape[0], W), rdtype)
    flat = psi.view(rdtype)  # real and imaginary parts side by side
    done = 0  # rows of the image finished
    Ne = H + 2 * m
    for e0 in range(0, Ne, chunk):
        e1 = min(e0 + chunk, Ne)
        Xh = X[:e1 - e0]
        kern.spread_rows(A, e0, runs, gaps, Xh)
        out = _ifft(Xh, 1)
        # planes row i holds the extended row e0 - 2m + i
        kern.demodulate_rows(out.view(rdtype), e0, ey_re, ey_im, ex_re, ex_im, m,
                             planes[0], planes[1], 2 * m)
        # image row y needs the extended rows y .. y + 2m: all up to e1 - 2m - 1 are
        # there (the rows before done were finished with the block before)
        ylim = H if e1 == Ne else e1 - 2 * m
        out0 = 0 if sink is None else done
        kern.phase_derivatives(planes[0], planes[1], taps, done, ylim, e0 - 2 * m, flat,
                               mod, dphi[0], dphi[1], out0, tmp)
        if sink is not None:
            h = ylim - done
            full_mod[done:ylim] = mod[:h]  # kept for the validity threshold
            sink(done, ylim, psi[:h], dphi[:, :h], mod[:h])
        done = ylim
        # the block's last 2m rows lead the next one's
        h = e1 - e0
        planes[:, :2 * m] = planes[:, h:h + 2 * m]


@dataclass(frozen=True, eq=False)
class _Band:
    """What :func:`_one_wave_vector_compiled` needs of one wave vector's band, the
    same for every frame of a size (:func:`_compiled_band`; never written to)."""

    rows: np.ndarray  # the band's rows of the spectrum
    dst: np.ndarray  # and where they go, shifted down by the carrier's bin
    cols: np.ndarray
    ygaps: list  # the rows of the y transform that no band row fills
    gx: np.ndarray  # the window's transfer function on the band, the frame's precision
    gy: np.ndarray
    runs: np.ndarray  # (n, 3) the x band's runs: destination, source, length
    gaps: np.ndarray  # (n, 2) the x spectrum's bins outside the band
    ey_re: np.ndarray  # the carrier's residuals along y and x, extended by m
    ey_im: np.ndarray
    ex_re: np.ndarray
    ex_im: np.ndarray


@functools.lru_cache(maxsize=16)
def _compiled_band(ny: int, nx: int, H: int, W: int, k: tuple, sigma: float, m: int,
                   rdtype: str) -> _Band:
    """The band of wave vector ``k`` for a padded ``ny x nx`` spectrum of an ``H x W``
    image, computed once for a stack's frames rather than for each."""
    rdtype = np.dtype(rdtype)
    rows, yruns, _, sy, gy = _axis_band(ny, k[1], sigma)
    cols, xruns, _, sx, gx = _axis_band(nx, k[0], sigma)
    # the carrier's residuals (less than half a bin) along y and x, on the extended
    # rows and columns; applied in the compiled pass
    ey = np.exp(2j * math.pi * (sy / ny - k[1]) * np.arange(-m, H + m))
    ex = np.exp(2j * math.pi * (sx / nx - k[0]) * np.arange(-m, W + m))
    return _Band(
        rows=rows, dst=(rows - sy) % ny, cols=cols, ygaps=_gaps(yruns, ny),
        gx=gx.astype(rdtype), gy=gy.astype(rdtype),
        runs=np.array([(d.start, s.start, d.stop - d.start) for d, s in xruns],
                      dtype=np.int64),
        gaps=np.array([(g.start, g.stop) for g in _gaps(xruns, nx)],
                      dtype=np.int64).reshape(-1, 2),
        ey_re=ey.real.astype(rdtype), ey_im=ey.imag.astype(rdtype),
        ex_re=ex.real.astype(rdtype), ex_im=ex.imag.astype(rdtype))


def _ifft_into(x: np.ndarray, axis: int):
    """Inverse FFT of ``x`` along ``axis``, written into ``x``."""
    out = _ifft(x, axis)
    if not np.shares_memory(out, x):
        x[...] = out


