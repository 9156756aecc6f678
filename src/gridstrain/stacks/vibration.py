"""Rigid vibrations of a static grid stack: per-frame translations and their effects.

A frame of a static stack affected by vibrations is (paper eq. 2)
``v(x, y, t) = s(x + alpha_t, y + beta_t) + n(x, y, t)``: the reference image seen
through a small rigid translation ``(alpha_t, beta_t)`` in px. Coordinates and the
wave vectors follow :mod:`gridstrain.conventions`.

The translation moves the phase of every grid component: for ``s(x + a)`` the
windowed Fourier coefficient at ``k`` is multiplied by ``exp(+2 i pi k . a)``, i.e.
its phase gains ``+2 pi k . a`` (the same sign as the phase change that
:func:`gridstrain.phase.wft` measures between ``s`` and ``s(x + a)``, checked in
``tests/test_vibration.py::test_phase_sign_matches_wft``; in the Lagrangian language
of the conventions the image ``s(x + a)`` is the specimen displaced by ``u = -a``).
:func:`frame_shifts` inverts this with one global coefficient per wave vector and
frame, which costs two matrix-vector products per frame instead of a windowed
Fourier transform.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from .. import theory
from .._validation import as_image, check_same_shape, check_type
from ..phase import Lattice

__all__ = ["VibrationReport", "frame_shifts", "vibration_report"]

# A carrier coefficient must stand this many times above the white-noise level of
# its frame (see CarrierProbe.check): noise gives about 1 (a Rayleigh variable,
# above 4 once in 3000), the paper's grid 0.24 per pixel of side, i.e. 5 at 21 px.
MIN_PROMINENCE = 5.0


def _apodisation(n: int) -> np.ndarray:
    """Squared Hann window (``sin^4``) over ``n`` samples, zero-free at the ends.

    Its spectrum falls as ``1/f^5``: the conjugate peak, the other family of lines,
    the harmonics and the mean sit 40 or more bins away from ``k`` on a 256-px side
    and leak below ``1e-8`` of the carrier's modulus, so the phase is that of the
    carrier alone (the plain Hann window, ``1/f^3``, leaks about ``1e-6``).
    """
    return np.sin(np.pi * (np.arange(n) + 0.5) / n) ** 4


@functools.lru_cache(maxsize=32)
def _window_sums(n: int) -> tuple[np.ndarray, float]:
    """:func:`_apodisation` of ``n`` samples (read-only) and its sum: the same for
    every frame (and every tile) of that side."""
    w = _apodisation(n)
    w.flags.writeable = False
    return w, float(w.sum())


def carrier_phases(lattice: Lattice, shape: tuple[int, int]):
    """The carriers' factors along the columns and rows of an ``(H, W)`` frame, from
    pixel 0: ``(cos ax, sin ax, exp(-i ax))`` with ``ax = 2 pi x k_j,x`` (W, 2), and
    ``exp(-i ay)`` with ``ay = 2 pi y k_j,y`` (H, 2). A block's probe of ``h x w`` px,
    whose sums are in its own coordinates, takes their first ``w`` and ``h`` rows
    (:class:`CarrierProbe`, ``phases=``): a frame's tiles share one evaluation."""
    H, W = shape
    K = lattice.K
    ax = 2 * np.pi * np.outer(np.arange(W, dtype=np.float64), K[:, 0])  # (W, 2)
    ay = 2 * np.pi * np.outer(np.arange(H, dtype=np.float64), K[:, 1])  # (H, 2)
    return np.cos(ax), np.sin(ax), np.exp(-1j * ax), np.exp(-1j * ay)


class CarrierProbe:
    """Global windowed Fourier coefficients of a frame at ``k1`` and ``k2``.

    ``c_j = sum_xi w(xi) (v(xi) - m) exp(-2 i pi k_j . xi)`` with the separable
    window ``w = wy (x) wx`` and ``m`` the window-weighted mean of the frame, the
    carrier at absolute pixel coordinates (:mod:`gridstrain.conventions`).
    """

    def __init__(self, lattice: Lattice, shape: tuple[int, int], *, phases=None):
        H, W = shape
        self.shape = (H, W)
        (wx, sx), (wy, sy) = _window_sums(W), _window_sums(H)
        # the carriers' factors from pixel 0 (carrier_phases), or the first rows of a
        # larger frame's: the same values
        cos, sin, ex, ey = carrier_phases(lattice, shape) if phases is None else phases
        # Columns: the window (for the weighted mean), then cos and sin of the x part
        # of each carrier, all weighted by wx: one real BLAS product per frame.
        self._right = np.empty((W, 5))
        self._right[:, 0] = wx
        np.multiply(wx[:, None], cos[:W], out=self._right[:, 1:3])
        np.multiply(wx[:, None], sin[:W], out=self._right[:, 3:5])  # (W, 5)
        self._ey = wy[:, None] * ey[:H]  # (H, 2), y part with its window
        self._wy = wy
        # sum of w exp(-2 i pi k.xi): what subtracting the mean m removes from c_j
        self._dc = (wx[:, None] * ex[:W]).sum(axis=0) * self._ey.sum(axis=0)  # (2,)
        self._wsum = sx * sy

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        # np.dot: BLAS; numpy's matmul takes a slower loop of its own for a product
        # this narrow (benchmarks/README.md)
        return self.from_rows(np.dot(frame, self._right))

    def from_rows(self, P: np.ndarray) -> np.ndarray:
        """The coefficients from ``P = frame @ right`` (H, 5), the x sums of each row."""
        m = float(self._wy @ P[:, 0]) / self._wsum
        rows = P[:, 1:3] - 1j * P[:, 3:5]  # sum_x wx v exp(-2 i pi kx x), (H, 2)
        return np.einsum("hj,hj->j", self._ey, rows) - m * self._dc

    def prominence(self, frame: np.ndarray, c: np.ndarray, *,
                   scale: float | None = None) -> np.ndarray:
        """(2,) moduli of the coefficients ``c = self(frame)`` over the white-noise
        level of the frame; zero for a uniform frame. ``scale`` is ``max |frame|``
        when the caller knows it already (it spares a pass over the frame).

        The level is that of the frame's differences along x, ``sqrt(sum w^2 (v(x +
        1) - v(x))^2 / 2)``: for white noise of variance s^2 it is ``s sqrt(sum
        w^2)``, the standard deviation of a coefficient, while what varies slowly
        (lighting, a dark hole, the background of the specimen) leaves it alone:
        a hole of a fifth of the frame would otherwise pass for noise many times
        the grid's.
        """
        wx, wy = self._right[:, 0], self._wy
        wx2 = (wx[:-1] * wx[1:])  # the window between two neighbouring columns
        # every step-th row (at least 64 rows): the level of a megapixel frame from
        # about 90,000 differences is within 0.5 % (1 / sqrt(n / 2)), and the
        # verdict compares a grid's tens to hundreds with a threshold of 5
        step = max(1, min(16, frame.shape[0] // 64))
        d = np.diff(frame[::step], axis=1)
        var = 0.5 * step * float((wy[::step] ** 2) @ np.einsum("ij,ij,j->i", d, d, wx2))
        if scale is None:
            scale = float(np.max(np.abs(frame))) if frame.size else 0.0
        # a uniform frame has no differences at all (to the rounding of its level)
        level = math.sqrt(var) if var > 1e-24 * scale * scale * frame.size else 0.0
        return np.abs(c) / level if level > 0 else np.zeros(2)

    def check(self, frame: np.ndarray, name: str) -> None:
        """Raise if ``frame`` shows no carrier at ``k1`` or ``k2``.

        The modulus of each coefficient is compared with what white noise of the
        frame's own level would give (:meth:`prominence`): about 1 for noise or a
        scene without the grid, tens to hundreds for a grid.
        """
        prom = self.prominence(frame, self(frame))
        if np.any(prom < MIN_PROMINENCE):
            raise ValueError(
                f"{name} shows no grid at the lattice's wave vectors: the carrier stands "
                f"only {float(prom.min()):.3g} times above the level of white noise "
                f"(a grid gives tens to hundreds); check the lattice")


def as_frame(frame, shape, t: int) -> np.ndarray:
    arr = as_image(frame, f"frames[{t}]", allow_uniform=True)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"frames must all have the same shape; frames[0] has shape {shape}, "
                         f"frames[{t}] has shape {arr.shape}")
    return arr.astype(np.float64, copy=False)


def numbered_frames(frames):
    """Yield ``(t, frame)`` from a (T, H, W) array or an iterable of (H, W) arrays."""
    if isinstance(frames, np.ndarray) and frames.ndim != 3:
        raise ValueError(f"frames must be a (T, H, W) array or an iterable of (H, W) "
                         f"frames, got an array of shape {frames.shape}")
    if not isinstance(frames, Iterable):
        raise TypeError(f"frames must be a (T, H, W) array or an iterable of (H, W) frames, "
                        f"got {type(frames).__name__}")
    yield from enumerate(frames)


def shift_matrix(lattice: Lattice) -> np.ndarray:
    """Matrix mapping the phase changes ``(dphi1, dphi2)`` (rad) to ``(a, b)`` (px)."""
    # dphi_j = 2 pi k_j . (a, b)  =>  (a, b) = K^-1 dphi / (2 pi)
    return np.linalg.inv(lattice.K) / (2 * np.pi)


def frame_shifts(frames, lattice: Lattice, *, reference=None) -> np.ndarray:
    """Per-frame rigid translation ``(alpha_t, beta_t)`` of a static grid stack.

    Parameters
    ----------
    frames : (T, H, W) array_like or iterable of (H, W) array_like
        The stack, grey levels; an iterable is consumed once, frame by frame, so a
        stack larger than memory can be streamed. Computed in float64.
    lattice : Lattice
        The grid's wave vectors.
    reference : (H, W) array_like, optional
        Image the shifts are measured from. Default (``None``): the mean frame, and
        the shifts are returned with their mean removed, like the paper's
        zero-mean ``(alpha_t, beta_t)`` of eq. (2).

    Returns
    -------
    (T, 2) float64 ndarray
        ``shifts[t] = (alpha_t, beta_t)`` in px such that frame ``t`` is
        ``s(x + alpha_t, y + beta_t)`` (eq. 2), ``x`` along columns.

    Raises
    ------
    ValueError
        If the frames differ in shape, are not finite, or hold no grid at the
        lattice's wave vectors.

    Notes
    -----
    For each frame, one global coefficient per wave vector,
    ``c_j(t) = sum_xi w(xi) (v_t(xi) - m_t) exp(-2 i pi k_j . xi)``, with ``w`` a
    separable ``sin^4`` apodisation over the whole frame and ``m_t`` its
    window-weighted mean. A translation by ``a`` multiplies the carrier's
    contribution by ``exp(2 i pi k_j . a)``, so
    ``dphi_j(t) = arg(c_j(t) conj(c_j(ref))) = 2 pi k_j . a_t`` and
    ``a_t = K^-1 dphi(t) / (2 pi)``. The window stays fixed while the pattern moves
    under it; this changes the carrier's modulus, never its phase, for a grid of
    constant pitch. When the grid carries a phase modulation ``phi`` (a deformed
    specimen) the phase advances by ``(2 pi k + <grad phi>) . a``, a relative error
    of the order of the mean strain (1e-3) on the shifts.

    The default reference is the mean frame, whose coefficients are the mean of
    the frames' by linearity (so it costs nothing, even when streaming). Because
    the shifts are then centred, the reference's own phase and noise cancel
    exactly; it only sets the branch of ``arg``, and the mean frame is the one
    every frame is closest to, so the result is unambiguous as long as no frame
    moves by more than half a period from the average position. The first frame
    would be a noisier and possibly off-centre branch point.

    Accuracy: better than ``1e-5`` px on noise-free synthetic frames (256 x 256,
    pitch 5). With sensor noise of standard deviation ``s_n`` the per-frame error
    is about ``p s_n sqrt(sum w^2) / (2 sqrt(2) pi |c|)`` px; for 12-bit frames of
    the paper's Poisson-Gaussian noise (``A = 2000``, ``gamma = 0.9``, pitch 5) it is
    about ``5e-4`` px on a 256 x 256 frame and scales as the inverse of the side
    (see ``tests/test_vibration.py``).

    Examples
    --------
    >>> from gridstrain import Lattice
    >>> from gridstrain.models import synthetic
    >>> lat = Lattice.from_pitch(5.0)
    >>> shifted = [synthetic.grid_image((64, 64), lat,
    ...                                 displacement=lambda X, Y, a=a: (-a + 0 * X, 0 * Y))
    ...            for a in (0.0, 0.1, 0.2)]
    >>> frame_shifts(shifted, lat).round(4)[:, 0]
    array([-0.1,  0. ,  0.1])
    """
    check_type(lattice, "lattice", Lattice)
    coeffs, probe = _frame_coefficients(frames, lattice)
    ref = None
    if reference is not None:
        ref_img = as_image(reference, "reference").astype(np.float64, copy=False)
        check_same_shape(ref_img.shape, probe.shape, "reference", "the frames")
        probe.check(ref_img, "reference")
        ref = probe(ref_img)
    return shifts_from_coefficients(coeffs, lattice, ref)


def shifts_from_coefficients(coeffs: np.ndarray, lattice: Lattice,
                              ref: np.ndarray | None = None) -> np.ndarray:
    """(T, 2) shifts from the (T, 2) carrier coefficients of the frames, against the
    coefficients ``ref`` of a reference image, or centred on the mean frame (None)."""
    centred = ref is None
    ref = coeffs.mean(axis=0) if centred else ref
    dphi = np.angle(coeffs * np.conj(ref))  # (T, 2), eq. (2): +2 pi k.a
    shifts = dphi @ shift_matrix(lattice).T
    if centred:
        shifts -= shifts.mean(axis=0)
    return shifts


def _frame_coefficients(frames, lattice: Lattice):
    coeffs = []
    probe = None
    shape = None
    for t, frame in numbered_frames(frames):
        arr = as_frame(frame, shape, t)
        if probe is None:
            shape = arr.shape
            probe = CarrierProbe(lattice, shape)
            probe.check(arr, "frames[0]")
        coeffs.append(probe(arr))
    if probe is None:
        raise ValueError("frames must hold at least one frame, got none")
    return np.array(coeffs), probe


@dataclass(frozen=True, eq=False)
class VibrationReport:
    """Statistics of the rigid vibrations of a static stack and their predicted effects.

    Attributes
    ----------
    shifts : (T, 2) float64 ndarray
        Zero-mean per-frame translations ``(alpha_t, beta_t)``, px (eq. 2).
    std : (2,) float64 ndarray
        ``(Std(alpha), Std(beta))``, px (unbiased, ``T - 1`` in the variance).
    covariance : (2, 2) float64 ndarray
        Variance-covariance matrix ``Var(alpha, beta)`` of eq. (6), px^2.
    contrast_factor : (2,) float64 ndarray
        :func:`gridstrain.theory.contrast_factor` along each wave vector,
        ``1 - (1/2) (2 pi)^2 k_j^T Var(alpha, beta) k_j``: the factor by which
        averaging the stack scales the grid's fundamental along ``k_j`` (Prop. 2.2,
        eq. 14 for large ``T``, with the variance of the shifts along ``k_j``). The
        phase noise of method A grows by its inverse.
    phase_offset_std : (2,) float64 ndarray
        :func:`gridstrain.theory.phase_offset_std` along each wave vector, rad:
        the predicted standard deviation of the spatially constant phase offset
        ``delta_j`` of method A (Prop. 2.4, eq. 31), with
        ``Var(mean alpha) = Var(alpha) / T`` (the paper's worked example after
        eq. 31 uses ``2 Var(alpha)^2 / (T - 1)``, the variance of the sample
        *variance*, not of the sample mean).
    n_frames : int
        ``T``.
    lattice : Lattice
        The wave vectors used.
    name : str
        The series (in :class:`gridstrain.results.SeriesResult`: ``"reference"``,
        then each state); empty for a stack measured on its own.
    estimator : str
        Which code estimated the shifts.
    method : {"A", "B", "C"}
        The averaging the phase offset is predicted for (method C's phase is that
        of the grid at the stack's mean position: its offset is method B's).

    With a single frame nothing is known of the vibrations: every statistic is NaN.
    """

    shifts: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    contrast_factor: np.ndarray
    phase_offset_std: np.ndarray
    n_frames: int
    lattice: Lattice
    name: str = ""
    estimator: str = "gridstrain.stacks.vibration.frame_shifts"
    method: str = "A"

    def __post_init__(self):
        for name in ("shifts", "std", "covariance", "contrast_factor", "phase_offset_std"):
            getattr(self, name).flags.writeable = False

    def __repr__(self) -> str:
        sa, sb = self.std
        c1, c2 = self.contrast_factor
        d1, d2 = self.phase_offset_std
        named = f"{self.name}, " if self.name else ""
        return (f"VibrationReport({named}T={self.n_frames}, std=({sa:.4g}, {sb:.4g}) px, "
                f"contrast factor=({c1:.5g}, {c2:.5g}), "
                f"method-{self.method} phase offset std=({d1:.3g}, {d2:.3g}) rad)")


def vibration_report(frames, lattice: Lattice) -> VibrationReport:
    """Measure the vibrations of a static stack and predict their effect on averaging.

    Parameters
    ----------
    frames : (T, H, W) array_like or iterable of (H, W) array_like
        The static stack (see :func:`frame_shifts`), ``T >= 2``.
    lattice : Lattice
        The grid's wave vectors.

    Returns
    -------
    VibrationReport

    Notes
    -----
    The covariance is the unbiased sample covariance of the measured shifts. It
    includes the variance of the shift estimate itself (about ``(5e-4 px)^2`` for a
    noisy 256 x 256 frame, see :func:`frame_shifts`), negligible against vibrations
    of ``0.01`` px or more. The predictions use the paper's second-order model
    (eq. 3); they hold while ``2 pi |k| Std`` stays well below 1 (0.13 for the
    paper's case 2 at pitch 5).
    """
    shifts = frame_shifts(frames, lattice)
    T = shifts.shape[0]
    if T < 2:
        raise ValueError(f"frames must hold at least 2 frames to measure vibrations, got {T}")
    return shift_report(shifts, lattice)


def shift_report(shifts: np.ndarray, lattice: Lattice, *, method: str = "A", name: str = "",
            estimator: str = "gridstrain.stacks.vibration.frame_shifts") -> VibrationReport:
    """The :class:`VibrationReport` of the measured ``shifts`` (T, 2), px."""
    T = shifts.shape[0]
    if T < 2:  # one frame says nothing about the vibrations
        nan = np.full(2, np.nan)
        return VibrationReport(shifts=shifts, std=nan, covariance=np.full((2, 2), np.nan),
                               contrast_factor=nan.copy(), phase_offset_std=nan.copy(),
                               n_frames=T, lattice=lattice, name=name, estimator=estimator,
                               method=method)
    cov = np.cov(shifts, rowvar=False, ddof=1).reshape(2, 2)
    freq = np.hypot(lattice.K[:, 0], lattice.K[:, 1])  # |k_j|, cycles/px
    # variance of the shifts along each wave vector, k_j^T C k_j / |k_j|^2, px^2
    var_k = np.einsum("ji,ik,jk->j", lattice.K, cov, lattice.K) / freq**2
    contrast = np.array([theory.contrast_factor(f, v) for f, v in zip(freq, var_k, strict=True)])
    offset = []
    for f, v in zip(freq, var_k, strict=True):
        try:  # Prop. 2.4, Var(mean) = Var / T; method C's offset is method B's
            offset.append(theory.phase_offset_std(f, v, T, method="B" if method == "C"
                                                  else method))
        except ValueError:  # eq. (31) breaks down beyond ~1 px of vibration
            offset.append(math.nan)
    return VibrationReport(shifts=shifts, std=np.sqrt(np.maximum(np.diag(cov), 0.0)),
                           covariance=cov, contrast_factor=contrast,
                           phase_offset_std=np.array(offset), n_frames=T, lattice=lattice,
                           name=name, estimator=estimator, method=method)


# Quadrants narrower than this (px) hold too few periods for a reliable carrier
# coefficient (at pitch 5 a 32-px side gives a prominence of about 7.7 against the
# threshold of 5): smaller frames are probed whole, without the rigidity check.
_MIN_QUADRANT = 32


class RigidProbe:
    """Streamed per-frame shifts from the carrier phases, and their departure from rigid.

    The frame is cut into 2 x 2 quadrants and each quadrant's shift is measured
    from its own carrier coefficients (:class:`CarrierProbe`), relative to the
    first frame. The frame's rigid shift is their mean; their spread about it, once
    the static differences between quadrants (the grid's own phase modulation) are
    removed, measures a motion that is not a translation (a rotation turns the
    quadrants' shifts by ``omega x r``, a non-rigid vibration moves them apart).
    Frames with quadrants under :data:`_MIN_QUADRANT` px, or whose first frame
    shows no grid in some quadrant (a masked region), are probed whole.
    """

    def __init__(self, lattice: Lattice, shape: tuple[int, int]):
        H, W = shape
        self._lattice = lattice
        self._M = shift_matrix(lattice)
        h, w = H // 2, W // 2
        if min(h, w) >= _MIN_QUADRANT:
            self.blocks = [np.s_[:h, :w], np.s_[:h, w:2 * w], np.s_[h:2 * h, :w],
                           np.s_[h:2 * h, w:2 * w]]
            self._probe = CarrierProbe(lattice, (h, w))
            # the x sums of the left and the right quadrants in one product
            right = np.zeros((W, 10))
            right[:w, :5] = self._probe._right
            right[w:2 * w, 5:] = self._probe._right
            self._right2 = right
            self._h = h
        else:
            self.blocks = None
            self._probe = CarrierProbe(lattice, (H, W))
        self._shape = (H, W)
        self._ref = None

    def __call__(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """``(shift, parts)``: the frame's shift relative to the first frame, px (2,),
        and the quadrants' shifts (4, 2), or None when probed whole."""
        if self._ref is None and self.blocks is not None:
            try:
                for b in self.blocks:
                    self._probe.check(frame[b], "frames[0]")
            except ValueError:
                self.blocks = None
                self._probe = CarrierProbe(self._lattice, self._shape)
        if self.blocks is None:
            if self._ref is None:
                self._probe.check(frame, "frames[0]")
            c = self._probe(frame)[None]  # (1, 2)
        else:
            P = np.dot(frame, self._right2)  # (H, 10)
            h = self._h
            c = np.array([self._probe.from_rows(P[r, q]) for r in (np.s_[:h], np.s_[h:2 * h])
                          for q in (np.s_[:5], np.s_[5:])])  # quadrants in block order
        if self._ref is None:
            self._ref = c
        parts = np.angle(c * np.conj(self._ref)) @ self._M.T  # eq. (2): +2 pi k.a
        return parts.mean(axis=0), (None if self.blocks is None else parts)


# Kept for the noise estimator, which needs per-frame shifts while streaming (one
# pass): shifts relative to the first frame, valid under the same half-period rule.
def streaming_shift(probe: CarrierProbe, lattice: Lattice):
    state: dict[str, np.ndarray] = {}
    M = shift_matrix(lattice)

    def shift(frame: np.ndarray) -> np.ndarray:
        if "ref" not in state:
            probe.check(frame, "frames[0]")
        c = probe(frame)
        if "ref" not in state:
            state["ref"] = c
        return M @ np.angle(c * np.conj(state["ref"]))

    return shift

