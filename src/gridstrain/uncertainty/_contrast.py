"""The bias next to a step of the grid's contrast (a stain, a shadow, a hole's edge
appearing between two states): a systematic error the uncertainty maps do not cover
(:func:`contrast_step_bound`), bounded pixel by pixel from the measured moduli.

A step of the image's amplitude is not band-limited: its spectrum, a ``1/f`` tail,
carries the grid's conjugate, its harmonics and the mean level into the carrier's
band, and the window's phase is off next to it. The error follows the modulus's
steepness ``s = sigma |grad ln |Psi||``: about 0.046 ``s`` px for a contrast step,
0.15-0.18 ``s`` px for a stain that darkens mean level and contrast alike and up to
0.24 ``s`` px for a step of the mean level alone (pitch 5 px, sigma 5 px, contrast
drops of 0.3-0.9, mean drops of 0.3-0.5; tests/test_small_defects.py). A feature
carried by the specimen is seen at the same material point in both states with the
same bias, which cancels in ``u``: what counts is the change of the log-modulus's
gradient between the reference at ``x`` and the deformed state at ``x + u``.

A hole's edge moving with the specimen (0.3 to 3.4 px) gives a bound of 0.001 to
0.0015 px beside it, the order of the window's other errors there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy import ndimage

from .._progress import Finding
from .._runtime.threads import THREADED_PIXELS, map_leaves
from .._validation import check_positive, check_workers
from ._maps import _load_kernels

__all__ = ["CONTRAST_STEP_PX", "contrast_step_bound", "contrast_step_findings"]

#: The bound's displacement per unit of the steepness's change, px: above the
#: largest error over steepness measured (0.24 for a step of the mean level alone,
#: 0.18 for a stain, 0.063 for a contrast step), so that the bound holds wherever
#: the leak is what makes the error.
CONTRAST_STEP_PX = 0.3

# Pixels whose material points are computed at once.
_BLOCK = 1 << 20
# The compiled loop (gridstrain.uncertainty._kernels, the "fast" extra) when installed:
# loaded on the first bound, never at import. False forces the numpy and scipy path
# (what runs without numba).
_COMPILED = True
# Rows of the compiled loop's blocks, run on the usable cores (each pixel's value does
# not depend on the blocks).
_KERNEL_ROWS = 64


def _kernel():
    """The compiled loops (:func:`gridstrain.uncertainty._maps._load_kernels`), unless
    switched off."""
    return _load_kernels() if _COMPILED else None


# A contrast step's bound is stated where it exceeds this many times the pixel's
# displacement noise std |(std u_x, std u_y)|: on grids of uniform contrast the bound
# made from the noise of the moduli stays within about one std (0.4 to 0.9 of twice
# it on noisy checkerboards and line grids; tests/test_small_defects.py).
_CONTRAST_FACTOR = 2.0
# ... or, where no noise is known, this many times the bound's median over the valid
# pixels, the level the moduli's noise sets: on 24 noisy uniform grids (checkerboards
# and lines, 0 and 10 degrees, with and without a hole moving with the specimen) the
# largest bound was 1.3 to 2.0 times the median.
_CONTRAST_OVER_MEDIAN = 4.0
# ... and never below this displacement, px: below it no measurement can tell a bias
# from noise (the floor of the aliasing bound's finding too).
_MIN_PX = 1e-3


def _log_gradient(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``grad ln |psi|`` per px, ``(d/dx, d/dy)``; zero where the modulus is zero."""
    mod = np.abs(psi)
    tiny = np.finfo(np.float64).tiny
    lg = np.log(np.maximum(mod, tiny, out=mod) if mod.dtype == np.float64 else
                np.maximum(mod, tiny))
    gy, gx = np.gradient(lg)
    return gx, gy


def contrast_step_bytes(shape) -> int:
    """Bytes :func:`contrast_step_bound` allocates on maps of ``shape`` ``(H, W)``
    beyond its inputs, at its peak: for the memory budget of a measurement, whose
    sampled checks make the bound while the state's transforms are held.

    The larger of a carrier's log-modulus gradients being made (66 bytes a pixel:
    the bound's map, the reference's gradients and the deformed state's with their
    temporaries; 64 measured) and a block of rows' material points beside both
    gradients (42 bytes a pixel and 40 a pixel of the block, at most ``_BLOCK``
    pixels; 40 and 40 measured), and 128 KiB of small arrays: 1.03 to 1.15 times the
    peaks ``tracemalloc`` measures, 64 to 80 bytes a pixel from 12 kpx to 2.2 Mpx
    (tests/test_memory.py). The compiled loop (numba installed) makes no block
    temporaries (64 to 68 bytes a pixel measured): the figure, the numpy path's, is
    1.03 to 1.28 times its peaks, and is made without importing numba.
    """
    H, W = (int(v) for v in shape)
    block = min(H, max(1, _BLOCK // max(W, 1))) * W
    return max(66 * H * W, 42 * H * W + 40 * block) + 2**17


def _steepest_change(s: np.ndarray, r: np.ndarray, d: np.ndarray, u: np.ndarray,
                     v: np.ndarray) -> None:
    """``s = max(s, |grad ln|d|(x + u) - grad ln|r|(x)|)`` for one carrier, in place;
    its gradients and a block's temporaries are freed on return (the budget's
    :func:`contrast_step_bytes`)."""
    H, W = v.shape
    gr = _log_gradient(r)
    gd = _log_gradient(d)
    kern = _kernel()
    if kern is not None:  # weights once per point, and no temporaries
        # C-ordered arrays only: one compiled signature, whatever views are given
        uu = np.ascontiguousarray(u, dtype=np.float64)
        v = np.ascontiguousarray(v)
        gr, gd = ([np.ascontiguousarray(g) for g in pair] for pair in (gr, gd))
        blocks = [(i, min(i + _KERNEL_ROWS, H)) for i in range(0, H, _KERNEL_ROWS)]
        # on the calling thread alone below THREADED_PIXELS, as the other loops
        workers = check_workers(None) if v.size >= THREADED_PIXELS else 1
        map_leaves(lambda b: kern.steepest_change(s, *gr, *gd, uu, v, *b), blocks,
                   max(min(workers, len(blocks)), 1))
        return
    # the material points' coordinates by blocks of rows: two float64 maps of the
    # image's size would be the largest arrays of the bound
    step = max(1, _BLOCK // W)
    for r0 in range(0, H, step):
        _block_change(s, gr, gd, u, v, slice(r0, min(H, r0 + step)))


def _block_change(s, gr, gd, u, v, b: slice) -> None:
    """:func:`_steepest_change` on the rows ``b``."""
    W = v.shape[1]
    vb = v[b]
    rows = np.arange(b.start, b.stop, dtype=np.float64)[:, None]
    cols = np.arange(W, dtype=np.float64)[None, :]
    # one (2, h, W) array for both maps (a list is made into one at each call)
    at = np.empty((2, *vb.shape))
    np.add(rows, np.where(vb, u[1, b], 0.0), out=at[0])
    np.add(cols, np.where(vb, u[0, b], 0.0), out=at[1])
    dx, dy = (ndimage.map_coordinates(g, at, order=1, mode="nearest") - q[b]
              for g, q in zip(gd, gr, strict=True))
    np.maximum(s[b], np.hypot(dx, dy), out=s[b])


def contrast_step_bound(reference_psi, deformed_psi, u, valid, *, sigma: float) -> np.ndarray:
    """A per-pixel bound on the displacement's bias next to a change of the grid's
    contrast, px (NaN where not ``valid``).

    Parameters
    ----------
    reference_psi, deformed_psi : (2, H, W) complex array_like
        The two states' windowed transforms at their carriers.
    u : (2, H, W) array_like
        Measured displacement ``(u_x, u_y)``, px, Lagrangian.
    valid : (H, W) bool array_like
    sigma : float
        Window standard deviation, px.

    Returns
    -------
    (H, W) float ndarray
        ``CONTRAST_STEP_PX`` times the largest over the carriers of
        ``sigma |grad ln|Psi_def|(x + u) - grad ln|Psi_ref|(x)|``, its largest
        value within a sigma.
    """
    sigma = check_positive(sigma, "sigma")
    ref = np.asarray(reference_psi)
    dfm = np.asarray(deformed_psi)
    v = np.asarray(valid, dtype=bool)
    if ref.shape != dfm.shape or ref.ndim != 3 or ref.shape[1:] != v.shape:
        raise ValueError(f"reference_psi and deformed_psi must be (n, H, W) with (H, W) "
                         f"valid's shape {v.shape}, got {ref.shape} and {dfm.shape}")
    H, W = v.shape
    u = np.asarray(u)
    s = np.zeros((H, W))
    for r, d in zip(ref, dfm, strict=True):
        _steepest_change(s, r, d, u, v)
    # the steepness ripples within a period where the leak does not (the grid's
    # harmonics in the modulus): its largest value within a sigma bounds the leak,
    # over the valid pixels only (an invalid one is not followed by u, and a hole's
    # collapsing modulus would spread into the valid band around it)
    s[~v] = 0.0
    size = 2 * int(np.ceil(sigma)) + 1
    s = ndimage.maximum_filter(s, size=size, mode="nearest")
    return np.where(v, CONTRAST_STEP_PX * sigma * s, np.nan)


def _noise_std(noise, shape):
    """``|(std u_x, std u_y)|`` px of ``noise`` in any of the forms
    :func:`contrast_step_findings` takes: an (H, W) map, a float, or None where the
    noise is not known (None, NaN floors)."""
    if noise is None:
        return None
    if hasattr(noise, "u_std"):  # an Uncertainty (gridstrain.predict_uncertainty)
        noise = noise.u_std
    if isinstance(noise, Mapping):  # a result's std maps, or Uncertainty.median()
        keys = next((k for k in (("ux_std", "uy_std"), ("ux", "uy"))
                     if all(c in noise for c in k)), None)
        if keys is None:
            raise ValueError("noise as a mapping must hold 'ux_std' and 'uy_std' (or "
                             "Uncertainty.median()'s 'ux' and 'uy'), got the keys "
                             f"{sorted(map(str, noise))}")
        pair = noise[keys[0]], noise[keys[1]]
    else:
        pair = noise
    try:
        ux, uy = (np.asarray(x, dtype=np.float64) for x in pair)
        std = np.hypot(ux, uy)
    except (TypeError, ValueError):
        std = None
    if std is None or std.shape not in ((), tuple(shape)):
        raise ValueError(
            "noise must be an Uncertainty, its (2, H, W) u_std, a mapping with "
            "'ux_std' and 'uy_std' (maps or floats), or the floors (std u_x, std u_y) "
            f"px, on the valid map's shape {tuple(shape)}; got {type(noise).__name__}"
            + (f" of shape {std.shape}" if std is not None else ""))
    if std.ndim == 0:
        return float(std) if math.isfinite(float(std)) else None
    return std


def contrast_step_findings(bound, valid, *, noise=None, name: str = "state"
                           ) -> list[Finding]:
    """The finding of a change of the grid's contrast whose bias bound exceeds the
    noise: the pixels beyond it counted, or none.

    Parameters
    ----------
    bound : (H, W) float array_like
        :func:`contrast_step_bound`, px.
    valid : (H, W) bool array_like
    noise : Uncertainty, (2, H, W) array, mapping or (float, float), optional
        The displacement noise, px: an :class:`Uncertainty` (its ``u_std``) or its
        ``(2, H, W)`` ``u_std``, a mapping ``{"ux_std": ..., "uy_std": ...}`` of maps
        (a result's uncertainty maps) or ``Uncertainty.median()``'s floats (keys
        ``"ux"``, ``"uy"``), or the state's floors ``(std u_x, std u_y)``. Default
        (or NaN floors): not known. Any other form is refused, naming these.
    name : str
        The state, in the sentence and the finding's ``state``.

    Returns
    -------
    list of Finding
        None, or one ``"contrast.step"`` finding with its figures ``pixels``,
        ``fraction`` (of the valid pixels) and ``max_px``.

    Notes
    -----
    A pixel counts where its bound exceeds twice the noise std
    ``|(std u_x, std u_y)|`` (on grids of uniform contrast the bound stays within
    about one std) and 1e-3 px; without a noise, four times the bound's median over
    the valid pixels (the level the moduli's noise sets: at most twice it on uniform
    grids).
    """
    v = np.asarray(valid, dtype=bool)
    if not v.any():
        return []
    b = np.asarray(bound, dtype=np.float64)[v]
    std = _noise_std(noise, v.shape)
    if std is not None:
        level = _CONTRAST_FACTOR * std[v] if np.ndim(std) else _CONTRAST_FACTOR * std
        against = f"{_CONTRAST_FACTOR:g} times the noise std"
    else:
        level = _CONTRAST_OVER_MEDIAN * float(np.median(b))
        against = (f"{_CONTRAST_OVER_MEDIAN:g} times the bound's median (the noise "
                   "not known)")
    beyond = (b > level) & (b > _MIN_PX)
    n = int(np.count_nonzero(beyond))
    if not n:
        return []
    worst = float(np.max(b))
    text = (f"{name}: the grid's contrast changes between the states (a stain, a shadow, a "
            f"hole's edge): next to it the displacement may be biased by up to {worst:.2g} px, "
            f"more than {against} on {n} valid pixels "
            f"({n / b.size:.1%}); gridstrain.uncertainty.contrast_step_bound maps the bound; "
            "mask the region or keep the contrast steady")
    return [Finding("contrast.step", text, state=name, pixels=n, fraction=n / b.size,
                    max_px=worst)]
