"""Every frame of a series checked against the series before it is averaged.

A series holds ``T`` frames of one static state (:mod:`gridstrain.series`).
Averaging assumes that they are: one frame of another state, a grid that slipped,
a black or clipped frame enters the mean image (method A) or the mean phases
(method B) as silently as a good one, and biases every map by ``1/T`` of its error.
:func:`screen_frames` reads each frame once and measures, per frame:

- the carrier coefficient of each wave vector over the whole frame (the probe of
  :func:`gridstrain.stacks.vibration.frame_shifts`), hence its rigid shift ``(alpha_t,
  beta_t)`` (paper eq. 2) and its grid's modulus;
- the same coefficient on a few tiles of the frame: once the frame's rigid motion
  (translation and small rotation) is taken out, the tiles of a frame of the same
  state keep their phases (up to the noise), those of a frame of another state
  move by its non-rigid displacement (a strain of 1e-3 moves tiles 70 px apart by
  0.07 px, the noise of a tile is about 1e-3 px);
- the fraction of its pixels clipped at the sensor's ceiling: the container's
  maximum or a level ``2^n - 1`` (a 12-bit camera writing right-aligned values
  into 16-bit files clips at 4095), recognised as a pile-up of pixels at the
  frame's maximum.

A frame is *flagged* when

- it is uniform or shows no grid (its carrier stands less than 5 times above the
  white-noise level of the frame, as :func:`gridstrain.stacks.vibration.frame_shifts`
  requires of a first frame);
- its grid's modulus is less than half the series' median (a dark, defocused or
  occluded frame);
- its rigid shift lies farther than a fifth of a pitch (and six robust standard
  deviations of the others' shifts) from the series' robust centre: a slip. The
  shift is known modulo a pitch only: a 3-px slip at pitch 5 reads as -2 px,
  still flagged; a slip of a whole pitch cannot be seen;
- its tiles' non-rigid residual (rms, px) exceeds three times the series' median
  (five times with the four tiles of a small image) and 1e-3 px: a frame of
  another state;
- more than ``max_saturation`` of its pixels are clipped.

Conventions: :mod:`gridstrain.conventions`. The decisions (exclude, refuse or keep
the flagged frames) belong to the caller; :func:`gridstrain.series.measure_series`
takes them with its ``outliers`` option.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..phase import Lattice
from .vibration import (
    MIN_PROMINENCE,
    CarrierProbe,
    _window_sums,
    as_frame,
    carrier_phases,
    numbered_frames,
    shift_matrix,
    shifts_from_coefficients,
)

__all__ = ["FrameScreen", "NoGridError", "Trend", "screen_frames"]

# A rigid shift farther than this fraction of the pitch from the series' centre is a
# slip: the paper's vibrations (std 0.02 to 0.1 px at pitch 5) stay 10 times below,
# and the second-order theory of averaging (Prop. 2.2) fails well before it.
_SLIP_FRACTION = 0.2
# ... and farther than this many robust standard deviations of the other frames'
# shifts, so that a series shaken by 0.3 px at pitch 5 does not lose its tails
# (a Gaussian exceeds 6 std once in 5e8 draws).
_SLIP_SIGMAS = 6.0
# A frame whose grid modulus is below this fraction of the series' median is dark,
# defocused or occluded: it would lower the mean image's contrast by its share.
_LOW_CONTRAST = 0.5
# A frame's non-rigid residual above this many times the series' median is a frame
# of another state. The residual of a frame of the series is the rms of the tiles'
# noise, 2 n - 3 degrees of freedom for n tiles: with 16 tiles (29) three times the
# median is out of its reach; with 4 (5), and the median itself taken over a few
# frames, the largest of 1800 clean frames reached 3.0 times it (see the tests).
_RESIDUAL_FACTOR = 3.0
_RESIDUAL_FACTOR_FEW_TILES = 5.0
_FEW_TILES = 8
# ... and above this absolute floor, px: noise-free frames have residuals of 1e-7 px
# from the window's leakage, which the factor alone would compare. A frame of another
# state with a residual of 1e-3 px biases an average of 10 frames by 1e-4 px.
_RESIDUAL_FLOOR = 1e-3
# Tiles per side for the residual: at most 4, each at least 12 pitches wide (the
# sin^4 apodisation leaves about 4 periods of effective width; below that the
# conjugate carrier leaks into the phase).
_MAX_TILES = 4
_TILE_PITCHES = 12.0
# A pile-up at a level 2^n - 1 is clipping when at least this many pixels sit at the
# frame's maximum and more than twice as many as at the next value below it: the
# upper tail of a noisy, unclipped histogram thins out instead.
_CLIP_MIN_PIXELS = 4
_CLIP_BITS = range(8, 17)
# A series' tiles are compared between frames from this many frames with a grid: the
# residual's median needs three.
_RESIDUAL_FRAMES = 3
# Up to this many frames, each frame's tiles are compared with the median of the
# others; beyond, with the median of all (one frame weighs 1/T in it).
_LEAVE_ONE_OUT = 64
# A series is a sequence (frames of a test in progress, not one static state) when a
# linear trend in frame order explains its rigid shifts or its tiles' non-rigid
# displacements with a false-alarm probability below this, for frames of one state
# shaken by independent vibrations (F test of the slopes against the scatter about
# them) ...
_TREND_FALSE_ALARM = 1e-6
# ... and the trend moves the frames by a material amount over the series: a drift
# of a slip's fraction of a pitch (the frames could no longer be averaged by
# method A), or a non-rigid growth above the residual floor (px, rms over the tiles).
_TREND_DRIFT_FRACTION = _SLIP_FRACTION
_TREND_GROWTH_PX = _RESIDUAL_FLOOR
# Median absolute deviation of a Gaussian over its standard deviation.
MAD_TO_STD = 1.4826


def _p(p: float) -> str:
    """A false-alarm probability for a message (F's tail is exact to about 1e-16)."""
    return "p < 1e-16" if p < 1e-16 else f"p = {p:.1e}"


class NoGridError(ValueError):
    """No frame of a series shows a grid at the lattice's wave vectors."""


@dataclass(frozen=True)
class Check:
    """One check of the screening: the flag it raises on a frame, what to do about the
    frames it flags, and its threshold (None where the series or the caller sets it)."""

    flag: str
    advice: str
    threshold: float | None = None


#: The screening's checks, by flag, in the order a frame's reasons are listed: a frame
#: with a carrier below ``MIN_PROMINENCE`` times white noise shows no grid; a modulus
#: below ``_LOW_CONTRAST`` of the series' median is a low contrast; a rigid shift of
#: ``_SLIP_FRACTION`` of a pitch is a slip; a non-rigid residual ``_RESIDUAL_FACTOR``
#: times the series' median is a frame of another state; the saturated fraction is
#: the caller's ``max_saturation``.
CHECKS = {c.flag: c for c in (
    Check("uniform", "remove the blank frames"),
    Check("no grid", "remove the blank frames", MIN_PROMINENCE),
    Check("low contrast", "remove the dark or blurred frames", _LOW_CONTRAST),
    Check("slip", "measure the frames before and after the slip as two series",
          _SLIP_FRACTION),
    Check("other state", "move the frames of another state to their own series",
          _RESIDUAL_FACTOR),
    Check("saturated", "shorten the exposure, mask the saturated area, or accept more "
          "clipped pixels with max_saturation= (--max-saturation FRACTION: photos of white "
          "paper clip between the lines, and the phase stays measurable there)"),
)}


@dataclass(frozen=True)
class Trend:
    """Whether a series' frames are a sequence: a linear trend in frame order.

    Attributes
    ----------
    frames : int
        Frames tested (the unflagged ones with a grid), ``n``.
    drift_px : (float, float)
        The rigid shift's fitted change from the first to the last frame, px.
    drift_p : float
        Probability of a trend at least as strong in the shifts of ``n`` frames of
        one state shaken by independent Gaussian vibrations (F test of the two
        slopes, 2 and ``2 (n - 2)`` degrees of freedom).
    growth_px : float
        The tiles' non-rigid displacement's fitted change over the series, rms over
        the tiles, px (NaN without tiles).
    growth_p : float
        The same test for the non-rigid displacements of the tiles (NaN without).
    """

    frames: int
    drift_px: tuple[float, float]
    drift_p: float
    growth_px: float
    growth_p: float
    pitch: float

    @property
    def drifting(self) -> bool:
        """A steady rigid drift of at least a slip's fraction of a pitch."""
        return self.drift_p < _TREND_FALSE_ALARM and \
            math.hypot(*self.drift_px) > _TREND_DRIFT_FRACTION * self.pitch

    @property
    def deforming(self) -> bool:
        """A non-rigid displacement growing steadily above the residual floor."""
        return bool(self.growth_p < _TREND_FALSE_ALARM and self.growth_px > _TREND_GROWTH_PX)

    @property
    def sequence(self) -> bool:
        """The frames are a sequence, not one static state."""
        return self.drifting or self.deforming

    def describe(self) -> str:
        """What the test found, for a message."""
        out = []
        if self.deforming:
            out.append(f"a non-rigid displacement growing by {self.growth_px:.2g} px rms "
                       f"from the first frame to the last ({_p(self.growth_p)})")
        if self.drifting:
            out.append(f"a steady rigid drift of {math.hypot(*self.drift_px):.2f} px "
                       f"({_p(self.drift_p)})")
        return " and ".join(out)


@dataclass(frozen=True, eq=False)
class FrameScreen:
    """What :func:`screen_frames` measured on each frame of a series.

    Attributes
    ----------
    coefficients : (T, 2) complex128 ndarray
        Carrier coefficient of each wave vector over the whole frame (apodised,
        grey levels x window weight); their phases give the rigid shifts.
    deviation : (T, 2) float64 ndarray
        Each frame's rigid shift from the series' robust centre, px, ``(x, y)``;
        NaN for a frame without a grid. Known modulo the lattice's periods.
    modulus_ratio : (T, 2) float64 ndarray
        Each frame's carrier modulus over the series' median, per wave vector.
    prominence : (T, 2) float64 ndarray
        Carrier modulus over the frame's white-noise level (a grid gives tens to
        hundreds, noise about 1).
    residual : (T,) float64 ndarray
        The tiles' displacements against the other frames once the frame's rigid
        motion (translation, rotation) is fitted out, rms, px; NaN where
        unavailable (a frame without a grid, an image too small for two tiles per
        side, fewer than three frames).
    saturated : (T,) float64 ndarray
        Fraction of the frame's (masked) pixels at the clipping level.
    clip_level : (T,) float64 ndarray
        The level the frame is clipped at, raw grey levels (NaN: not clipped).
    reasons : tuple of tuple of str
        Per frame, why it is flagged (empty: a good frame).
    lattice : Lattice
        The wave vectors used.
    trend : Trend or None
        The test of the frames unflagged, in order, for a steady drift or a
        growing deformation (None with fewer than four of them).
    flags : tuple of tuple of str
        Per frame, the flags of the checks it fails (:data:`CHECKS`), one per reason.
    """

    coefficients: np.ndarray
    deviation: np.ndarray
    modulus_ratio: np.ndarray
    prominence: np.ndarray
    residual: np.ndarray
    saturated: np.ndarray
    clip_level: np.ndarray
    reasons: tuple[tuple[str, ...], ...]
    lattice: Lattice
    trend: Trend | None = None
    flags: tuple[tuple[str, ...], ...] = ()

    def __post_init__(self):
        for name in ("coefficients", "deviation", "modulus_ratio", "prominence",
                     "residual", "saturated", "clip_level"):
            getattr(self, name).flags.writeable = False

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return int(self.coefficients.shape[0])

    @property
    def flagged(self) -> tuple[int, ...]:
        """Indices of the flagged frames."""
        return tuple(t for t, r in enumerate(self.reasons) if r)

    def listing(self, describe=None, *, most: int = 5) -> str:
        """The flagged frames and why, for a message: ``"NAME: reason, ...; ..."``,
        the first ``most`` of them, then how many more; ``describe(t)`` names frame
        ``t`` (default ``frames[t]``)."""
        bad = self.flagged
        name = describe or (lambda t: f"frames[{t}]")
        text = "; ".join(f"{name(t)}: {', '.join(self.reasons[t])}" for t in bad[:most])
        return text + (f"; and {len(bad) - most} more" if len(bad) > most else "")

    def shifts(self, keep=None) -> np.ndarray:
        """(T_kept, 2) rigid shifts of the frames ``keep`` (default: all), px,
        centred on their mean frame, as :func:`gridstrain.stacks.vibration.frame_shifts`
        gives them for those frames alone."""
        idx = np.arange(self.n_frames) if keep is None else np.asarray(keep, dtype=int)
        return shifts_from_coefficients(self.coefficients[idx], self.lattice)

    def coherence(self, keep=None) -> np.ndarray:
        """(2,) ``|mean_t c_t| / mean_t |c_t|`` over the frames ``keep``: the fraction
        of the frames' grid contrast that survives in their mean image (1 without
        vibrations; ``1 - (2 pi f)^2 Var / 2`` for small ones, Prop. 2.2)."""
        idx = np.arange(self.n_frames) if keep is None else np.asarray(keep, dtype=int)
        c = self.coefficients[idx]
        den = np.abs(c).mean(axis=0)
        return np.where(den > 0, np.abs(c.mean(axis=0)) / np.where(den > 0, den, 1), 0.0)

    def __repr__(self) -> str:
        return f"FrameScreen(T={self.n_frames}, flagged={list(self.flagged)})"


def _tiles(shape: tuple[int, int], lattice: Lattice) -> list[tuple[slice, slice]]:
    """Tiles of the residual test, or none when the image holds fewer than two."""
    p = max(lattice.pitches)
    n = tuple(min(_MAX_TILES, int(s // (_TILE_PITCHES * p))) for s in shape)
    return [] if min(n) < 2 else list(_tile_slices(tuple(shape), n))


@functools.lru_cache(maxsize=8)
def _tile_slices(shape: tuple[int, int], n: tuple[int, int]) -> tuple:
    """The ``n[0] x n[1]`` tiles of a frame of ``shape``, row by row: the same for
    every state of a record."""
    edges = [np.linspace(0, s, k + 1).round().astype(int) for s, k in zip(shape, n, strict=True)]
    return tuple((slice(int(y0), int(y1)), slice(int(x0), int(x1)))
                 for y0, y1 in zip(edges[0][:-1], edges[0][1:], strict=True)
                 for x0, x1 in zip(edges[1][:-1], edges[1][1:], strict=True))


def _clipped(frame: np.ndarray, level: float | None, scale: int, mask, *,
             top: float | None = None) -> tuple[float, float]:
    """``(fraction, level)`` of the frame's pixels clipped at the ceiling, or ``(0, nan)``.

    ``level`` is the container's (or declared sensor's) saturation level, None for
    float data. Beyond it, a pile-up at the frame's maximum when that maximum is
    ``2^n - 1`` (times ``scale``) for ``n`` in 8..16, or 1 (normalised float data).
    ``top`` is the maximum of the (masked) pixels when the caller knows it: an
    unclipped frame then costs no further pass.
    """
    sel = frame if mask is None else frame[mask]
    if sel.size == 0:
        return 0.0, math.nan
    if top is None:
        top = float(sel.max())
    if level is not None and top >= level:
        k = int(np.count_nonzero(sel >= level))
        if k:
            return k / sel.size, float(level)
    if top not in {float((2**n - 1) * s) for n in _CLIP_BITS for s in {1, scale}} | {1.0}:
        return 0.0, math.nan
    at = int(np.count_nonzero(sel == top))
    if at < _CLIP_MIN_PIXELS:
        return 0.0, math.nan
    below = sel[sel < top]
    nxt = int(np.count_nonzero(below == below.max())) if below.size else 0
    if at <= 2 * nxt:
        return 0.0, math.nan
    return at / sel.size, top


def _level_name(level: float, scale: int) -> str:
    """`` = 2^n - 1`` (or ``(2^n - 1) x scale``) for a clipping level, else ``""``."""
    for s, suffix in ((1, ""), (scale, f" x {scale}")):
        n = math.log2(level / s + 1)
        if n == int(n):
            return f" = 2^{int(n)} - 1" if not suffix else f" = (2^{int(n)} - 1){suffix}"
    return ""


def _wrap(phase: np.ndarray) -> np.ndarray:
    return (phase + np.pi) % (2 * np.pi) - np.pi


def _robust_centre(theta: np.ndarray) -> np.ndarray:
    """Circular medoid of the phases ``theta`` (n,): the sample with the least sum of
    circular distances to the others (at most 256 candidates, evenly spread)."""
    cand = theta[np.linspace(0, theta.size - 1, min(theta.size, 256)).round().astype(int)]
    cost = np.abs(_wrap(theta[:, None] - cand[None, :])).sum(axis=0)
    return cand[int(np.argmin(cost))]


def screen_frames(frames, lattice: Lattice, *, saturation_level: float | None = None,
                  scale: int = 1, mask=None, max_saturation: float = 0.01) -> FrameScreen:
    """Measure every frame of a series against the series (see the module docstring).

    Parameters
    ----------
    frames : (T, H, W) array_like or iterable of (H, W) array_like
        The series, raw grey levels; an iterable is consumed once, one frame alive
        at a time. Computed in float64.
    lattice : Lattice
        The grid's wave vectors.
    saturation_level : float, optional
        The sensor's or container's largest value, raw grey levels
        (:attr:`gridstrain.io.FrameSeries.saturation_level`); None for float data.
        Clipping at a level ``2^n - 1`` below it is found either way.
    scale : int
        Raw value of one sensor grey level (16 for 12-bit data stored x16).
    mask : (H, W) bool array_like, optional
        Count clipped pixels only here (the specimen).
    max_saturation : float
        Largest clipped fraction of a frame's pixels before it is flagged, in [0, 1].

    Returns
    -------
    FrameScreen

    Raises
    ------
    ValueError
        No frame, frames of different shapes, or no frame showing a grid at the
        lattice's wave vectors.

    Notes
    -----
    Each frame is read once. Per frame the cost is one matrix product per column of
    tiles, of its columns of the frame with a ``(w, 10)`` matrix (the whole frame's
    sums and the tiles'), the frame's minimum and maximum (uniformity, clipping,
    scale), and the white-noise level from the differences of every 16th row; the
    clipping test reads the frame again only when its maximum is a clipping level.
    About 2 ms per 1040 x 1376 frame on one core. The decisions, at the end, work
    on ``(T, tiles, 2)`` numbers.
    """
    if not isinstance(lattice, Lattice):
        raise TypeError(f"lattice must be a Lattice, got {type(lattice).__name__}")
    if not 0 <= max_saturation <= 1:
        raise ValueError(f"max_saturation must be a fraction in [0, 1], got {max_saturation!r}")
    m = None if mask is None else np.asarray(mask, dtype=bool)
    probe, shape, records = None, None, []
    for t, frame in numbered_frames(frames):
        arr = as_frame(frame, shape, t)
        if probe is None:
            shape = arr.shape
            if m is not None and m.shape != shape:
                raise ValueError(f"mask must have the frames' shape {shape}, got {m.shape}")
            probe = FrameProbe(lattice, shape, saturation_level=saturation_level,
                               scale=scale, mask=m)
        records.append(probe(arr))
    if probe is None:
        raise ValueError("frames must hold at least one frame, got none")
    return decide(records, probe, max_saturation=max_saturation)


@dataclass(frozen=True, eq=False)
class FrameRecord:
    """What :class:`FrameProbe` measures on one frame (a few numbers, whatever its size).

    Attributes
    ----------
    coefficients : (2,) complex128 ndarray
        Carrier coefficient of each wave vector over the whole frame.
    uniform : bool
        Whether the frame has a single grey level.
    prominence : (2,) float64 ndarray
        Carrier modulus over the frame's white-noise level.
    saturated : float
        Fraction of the (masked) pixels at the clipping level.
    clip_level : float
        The clipping level, raw grey levels (NaN: not clipped).
    tiles : (n_tiles, 2) complex128 ndarray
        Carrier coefficients of the residual test's tiles.
    """

    coefficients: np.ndarray
    uniform: bool
    prominence: np.ndarray
    saturated: float
    clip_level: float
    tiles: np.ndarray


class FrameProbe:
    """Per-frame measurements of the screening, one frame at a time.

    Records of frames probed by equal probes (same lattice, shape, levels and
    mask), in any order and on any machine, are decided together by
    :func:`decide`: the probe is what a streamed or distributed pass over a
    series needs (:mod:`gridstrain.stacks.accumulate`).

    Parameters
    ----------
    lattice : Lattice
    shape : (2,) tuple of int
        ``(H, W)`` of the frames.
    saturation_level, scale, mask
        As for :func:`screen_frames`.
    residual : bool
        Measure the tiles' coefficients of the residual test. A series of fewer than
        ``_RESIDUAL_FRAMES`` frames has no such test (:func:`decide` leaves its
        residuals NaN): without them its records' tiles are NaN, and a frame costs
        the whole frame's sums alone.
    """

    def __init__(self, lattice: Lattice, shape: tuple[int, int], *,
                 saturation_level: float | None = None, scale: int = 1, mask=None,
                 residual: bool = True):
        self.lattice = lattice
        self.shape = tuple(shape)
        self.saturation_level = saturation_level
        self.scale = scale
        self.mask = mask
        self.residual = residual
        # a mask that keeps every pixel counts as none: no copy of the frame per frame
        self._count = None if mask is None or np.all(mask) else np.asarray(mask, dtype=bool)
        # the carriers' factors once for the frame, its tiles' probes taking their first
        # rows (a tile's sums are in its own coordinates): 0.61 -> 0.2 ms a 250 x 400
        # frame of 16 tiles, one core, built for each state of a record
        phases = carrier_phases(lattice, self.shape)
        self.carrier = CarrierProbe(lattice, self.shape, phases=phases)
        self.tiles = _tiles(self.shape, lattice)
        # a probe's sums are in its block's own coordinates: the blocks of one size
        # share theirs (the 16 tiles of a frame come in one to four sizes)
        probes = {self.shape: self.carrier}

        def probe(h: int, w: int) -> CarrierProbe:
            if (h, w) not in probes:
                probes[h, w] = CarrierProbe(lattice, (h, w), phases=phases)
            return probes[h, w]

        # One product per column of tiles, of the frame's columns there with a (w, 10)
        # matrix: the whole frame's x sums over those columns (summed over the blocks
        # afterwards) and the tiles'. The frame is read once, and each pixel meets 10
        # columns rather than the 5 + 5 n of one product with every tile column.
        layout = _tile_layout(self.shape, tuple((ys.start, ys.stop, xs.start, xs.stop)
                                                for ys, xs in self.tiles))
        right = self.carrier._right
        self._blocks = [] if layout.cols else [(slice(None), right)]
        for x0, x1 in layout.cols:
            R = np.empty((x1 - x0, 10))
            R[:, :5] = right[x0:x1]
            R[:, 5:] = probe(self.shape[0], x1 - x0)._right
            self._blocks.append((slice(x0, x1), R))
        # per column of tiles, the y sums of every tile of the column at once: each
        # tile's y window (for its weighted mean) and y carrier, zero off its rows. A
        # series of fewer than _RESIDUAL_FRAMES frames has no residual test: its
        # records' tiles are NaN (decide does not read them)
        self._ysums = []
        if not residual:
            return
        for (x0, x1), (idx, wy, wsum, sizes, at) in zip(layout.cols, layout.ysums,
                                                       strict=True):
            tps = [probe(h, x1 - x0) for h in sizes]
            ey = np.zeros((wy.shape[0], len(idx), 2), dtype=np.complex128)
            # each row in one tile of the column: its window times its carrier there
            ey[np.arange(wy.shape[0]), at] = np.concatenate([tp._ey for tp in tps])
            dc = np.array([tp._dc for tp in tps])
            self._ysums.append((idx, wy, ey, dc, wsum))

    def __call__(self, arr: np.ndarray) -> FrameRecord:
        """The record of one frame (H, W), float64 (or float32, or integer grey levels:
        the products are taken in float64)."""
        # the extrema and the clipping on the frame as stored (a 16-bit frame is a
        # quarter of its float64 copy to read; the values are the same)
        lo, hi = float(arr.min()), float(arr.max())
        top = hi if self._count is None else None
        f, lev = _clipped(arr, self.saturation_level, self.scale, self._count, top=top)
        if arr.dtype != np.float64 and arr.dtype != np.float32:
            arr = arr.astype(np.float64)
        # np.dot: BLAS, not numpy's slower matmul loop for this shape;
        # a block of columns is a strided view BLAS reads in place
        P = [np.dot(arr[:, xs], R) for xs, R in self._blocks]
        whole = P[0][:, :5] if len(P) == 1 else np.add.reduce([p[:, :5] for p in P])
        c = self.carrier.from_rows(whole)
        tiles = np.empty((len(self.tiles), 2), dtype=np.complex128)
        if not self.residual:
            tiles[:] = np.nan
        for Pj, (idx, wy, ey, dc, wsum) in zip(P, self._ysums, strict=False):
            # as CarrierProbe.from_rows, for the column's tiles together
            m = (Pj[:, 5] @ wy) / wsum  # (n,) window-weighted means
            rows = Pj[:, 6:8] - 1j * Pj[:, 8:10]  # (H, 2)
            tiles[idx] = np.einsum("hnj,hj->nj", ey, rows) - m[:, None] * dc
        return FrameRecord(coefficients=c, uniform=lo == hi,
                           prominence=self.carrier.prominence(
                               arr, c, scale=max(abs(lo), abs(hi))),
                           saturated=f, clip_level=lev, tiles=tiles)


@dataclass(frozen=True)
class _Layout:
    """A frame's columns of tiles and, per column, its tiles' indices, their y
    windows placed on their rows ``wy`` (H, n), the windows' sums ``wsum`` (n,), the
    tiles' heights (in order down the column), and each row's tile in the column."""

    cols: tuple
    ysums: tuple


@functools.lru_cache(maxsize=8)
def _tile_layout(shape: tuple[int, int], tiles: tuple) -> _Layout:
    """The :class:`_Layout` of the ``tiles`` ``(y0, y1, x0, x1)`` of a frame of
    ``shape``: it depends on neither the frame nor the carrier, the same for every
    state of a record (read-only arrays)."""
    H = shape[0]
    cols = tuple(sorted({(x0, x1) for _, _, x0, x1 in tiles}))
    ysums = []
    for x0, x1 in cols:
        col = [(i, y0, y1) for i, (y0, y1, t0, _) in enumerate(tiles) if t0 == x0]
        wy = np.zeros((H, len(col)))
        wsum = np.empty(len(col))
        at = np.empty(H, dtype=np.intp)
        for n, (_, y0, y1) in enumerate(col):
            w, sy = _window_sums(y1 - y0)
            wy[y0:y1, n] = w
            wsum[n] = _window_sums(x1 - x0)[1] * sy
            at[y0:y1] = n
        for a in (wy, wsum, at):
            a.flags.writeable = False
        ysums.append(([i for i, _, _ in col], wy, wsum,
                      tuple(y1 - y0 for _, y0, y1 in col), at))
    return _Layout(cols, tuple(ysums))


def decide(records, probe: FrameProbe, *, max_saturation: float = 0.01) -> FrameScreen:
    """The screening's verdicts on a series from its frames' records, in frame order.

    Parameters
    ----------
    records : sequence of FrameRecord
        One per frame of the series, in the series' order.
    probe : FrameProbe
        The probe that made them.
    max_saturation : float
        As for :func:`screen_frames`.

    Returns
    -------
    FrameScreen

    Raises
    ------
    ValueError
        No record, or no frame showing a grid at the lattice's wave vectors.
    """
    if not records:
        raise ValueError("frames must hold at least one frame, got none")
    lattice, tiles, scale = probe.lattice, probe.tiles, probe.scale
    saturation_level = probe.saturation_level
    coeffs = np.array([r.coefficients for r in records])
    prom = np.array([r.prominence for r in records])
    uniform = [r.uniform for r in records]
    grid = np.all(prom >= MIN_PROMINENCE, axis=1) & ~np.array(uniform)
    if not grid.any():
        raise NoGridError(f"no frame shows a grid at the lattice's wave vectors: the carrier "
                         f"stands at most {float(prom.min(axis=1).max()):.3g} times above the "
                         "level of white noise (a grid gives tens to hundreds); check the "
                         "lattice")
    T = coeffs.shape[0]
    mod = np.abs(coeffs)
    ratio = mod / np.median(mod[grid], axis=0)
    dev, slip = _deviation(coeffs, grid, lattice)
    centres = np.array([((xs.start + xs.stop - 1) / 2, (ys.start + ys.stop - 1) / 2)
                        for ys, xs in tiles]).reshape(len(tiles), 2)
    tile_c = np.array([r.tiles for r in records]).reshape(T, len(tiles), 2)
    residual = _residual(coeffs, tile_c, centres, grid, lattice)
    sat = np.array([r.saturated for r in records], dtype=np.float64)
    clip = np.array([r.clip_level for r in records], dtype=np.float64)
    reasons, flags = [], []
    res_ok = residual[grid & np.isfinite(residual)]
    res_median = float(np.median(res_ok)) if res_ok.size >= 3 else math.nan
    factor = _RESIDUAL_FACTOR if len(tiles) > _FEW_TILES else _RESIDUAL_FACTOR_FEW_TILES
    res_limit = max(factor * res_median, _RESIDUAL_FLOOR) if res_ok.size >= 3 else math.inf
    for t in range(T):
        r, f = [], []
        if uniform[t]:
            r.append("uniform (no grey-level variation)")
            f.append("uniform")
        elif not grid[t]:
            f.append("no grid")
            r.append(f"shows no grid (its carrier stands {float(prom[t].min()):.3g} times "
                     f"above white noise, a grid's tens to hundreds)")
        elif ratio[t].min() < _LOW_CONTRAST:
            f.append("low contrast")
            r.append(f"low grid contrast ({float(ratio[t].min()):.2f} of the series' median "
                     "modulus: dark, defocused or occluded?)")
        if grid[t] and slip[t]:
            f.append("slip")
            r.append(f"rigid shift ({dev[t, 0]:+.2f}, {dev[t, 1]:+.2f}) px from the other "
                     "frames (modulo a pitch): the grid or camera slipped")
        if grid[t] and residual[t] > res_limit:
            f.append("other state")
            r.append(f"non-rigid displacement {residual[t]:.2g} px rms against the "
                     f"other frames (typical {res_median:.2g} px): a frame of another "
                     "state?")
        if sat[t] > max_saturation:
            below = saturation_level is not None and clip[t] < saturation_level
            f.append("saturated")
            r.append(f"{sat[t]:.2%} of its pixels saturated (clipped at {clip[t]:g}"
                     + (f"{_level_name(clip[t], scale)}, below the files' range: a camera "
                        "of fewer bits?" if below else "")
                     + f"), more than max_saturation={max_saturation:.2%}")
        reasons.append(tuple(r))
        flags.append(tuple(f))
    kept = np.array([grid[t] and not reasons[t] for t in range(T)])
    return FrameScreen(coefficients=coeffs, deviation=dev, modulus_ratio=ratio,
                       prominence=prom, residual=residual, saturated=sat, clip_level=clip,
                       reasons=tuple(reasons), flags=tuple(flags), lattice=lattice,
                       trend=_trend(coeffs[kept], tile_c[kept], centres, lattice))


def _deviation(coeffs: np.ndarray, grid: np.ndarray, lattice: Lattice):
    """``(dev, slip)``: (T, 2) shift of every frame from the robust centre of the
    gridded ones, px (NaN without a grid), and (T,) whether it is a slip."""
    ref = coeffs[grid].mean(axis=0)
    theta = np.angle(coeffs * np.conj(ref))  # (T, 2), 2 pi k_j . a_t, eq. (2)
    medoid = np.array([_robust_centre(theta[grid, j]) for j in range(2)])
    d = _wrap(theta - medoid)
    # the centre: the mean of the frames within a slip's distance of the medoid
    limit = np.full(2, 2 * np.pi * _SLIP_FRACTION)  # rad, per wave vector
    inl = grid & np.all(np.abs(d) <= limit, axis=1)
    d = _wrap(d - d[inl].mean(axis=0))
    if inl.sum() >= 3:  # and their spread, robustly
        spread = MAD_TO_STD * np.median(np.abs(d[inl]), axis=0)
        limit = np.maximum(limit, _SLIP_SIGMAS * spread)
    slip = grid & np.any(np.abs(d) > limit, axis=1)
    dev = d @ shift_matrix(lattice).T
    dev[~grid] = np.nan
    return dev, slip


def _residual(coeffs: np.ndarray, tiles: np.ndarray, centres: np.ndarray,
              grid: np.ndarray, lattice: Lattice) -> np.ndarray:
    """(T,) rms of the tiles' displacements left by the frame's rigid motion
    (translation and rotation), px; NaN where unavailable."""
    T, n = tiles.shape[:2]
    out = np.full(T, np.nan)
    if n < 4 or grid.sum() < _RESIDUAL_FRAMES:
        return out
    g = grid
    ref_t = tiles[g].mean(axis=0)  # (n, 2), the mean frame's tiles (linearity)
    ref_g = coeffs[g].mean(axis=0)  # (2,)
    # tile phase change minus the frame's rigid phase change: small, no wrapping
    rigid = np.angle(coeffs * np.conj(ref_g))  # (T, 2)
    psi = _wrap(np.angle(tiles * np.conj(ref_t)) - rigid[:, None, :])  # (T, n, 2)
    # per-tile robust reference: the median over the other frames (leaving the frame
    # out keeps a short series' median frame from reading a residual of zero)
    idx = np.flatnonzero(g)
    if idx.size <= _LEAVE_ONE_OUT:
        ref_psi = np.empty_like(psi)
        for t in range(T):
            ref_psi[t] = np.median(psi[idx[idx != t]], axis=0)
    else:
        ref_psi = np.median(psi[idx], axis=0)[None]
    psi = _wrap(psi - ref_psi)
    # each tile's displacement (x, y), px (eq. 2 inverted per tile), weighted by the
    # inverse phase-noise variance |C|^2 of its weaker wave vector
    d = (psi @ shift_matrix(lattice).T).reshape(T, 2 * n)
    w = np.min(np.abs(ref_t) ** 2, axis=1)
    w = np.repeat(w / w.sum(), 2)  # per component, (2n,)
    r = _non_rigid(d, centres, w)
    out[g] = np.sqrt((w * r[g] ** 2).sum(axis=1))  # rms |residual| over the tiles
    return out


def _non_rigid(d: np.ndarray, centres: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(T, 2n) tiles' displacements ``d`` (x, y interleaved, px) less each frame's
    rigid motion fitted with the weights ``w`` (2n,)."""
    n = centres.shape[0]
    # the frame's rigid motion, a translation and a small rotation omega about the
    # weighted centre (d_x = t_x - omega y, d_y = t_y + omega x), fitted and taken
    # out: a camera that rocks moves no material point against another
    c = centres - (w[::2] / w[::2].sum()) @ centres  # (n, 2), (x, y)
    A = np.zeros((n, 2, 3))
    A[:, 0, 0] = A[:, 1, 1] = 1.0
    A[:, 0, 2], A[:, 1, 2] = -c[:, 1], c[:, 0]
    A = A.reshape(2 * n, 3)
    sw = np.sqrt(w)
    fit = np.linalg.lstsq(A * sw[:, None], (d * sw).T, rcond=None)[0]  # (3, T)
    return d - (A @ fit).T


def _slopes_test(y: np.ndarray, dof_per_frame: int) -> tuple[np.ndarray, float]:
    """Least-squares slopes of the columns of ``y`` (n, q) against the frame order, and
    the probability of slopes at least as large under no trend: the F test of the
    slopes' sum of squares against the scatter about the lines, with
    ``dof_per_frame`` independent columns (equal variances)."""
    from scipy.special import fdtrc

    n = y.shape[0]
    t = np.arange(n) - (n - 1) / 2
    sxx = float(t @ t)
    b = (t @ (y - y.mean(axis=0))) / sxx  # (q,)
    rss = float(((y - y.mean(axis=0) - np.outer(t, b)) ** 2).sum())
    ess = float((b**2).sum() * sxx)
    d1, d2 = dof_per_frame, dof_per_frame * (n - 2)
    if rss <= 0:
        return b, 0.0 if ess > 0 else 1.0
    # the F law's survival function from scipy.special, as scipy.stats computes it:
    # importing scipy.stats costs a series more than the whole test
    return b, float(fdtrc(d1, d2, (ess / d1) / (rss / d2)))


def _unwrap_if_smooth(theta: np.ndarray) -> np.ndarray:
    """The phases (n, 2) unwrapped along the frames where every step from one frame to
    the next is below pi/2 (a sequence's smooth drift); else as they are, wrapped
    about their mean (a shaken static series, whose steps would be taken for wraps)."""
    steps = np.abs(_wrap(np.diff(theta, axis=0)))
    out = theta.copy()
    for j in range(theta.shape[1]):
        if steps[:, j].max(initial=0.0) < np.pi / 2:
            out[:, j] = np.unwrap(theta[:, j])
    return out


def _trend(coeffs: np.ndarray, tiles: np.ndarray, centres: np.ndarray,
           lattice: Lattice) -> Trend | None:
    """The trend test of the frames ``coeffs`` (n, 2) and their tiles (n, tiles, 2), in
    order (see :class:`Trend`)."""
    n = coeffs.shape[0]
    if n < 4:
        return None
    M = shift_matrix(lattice)
    theta = _unwrap_if_smooth(np.angle(coeffs * np.conj(coeffs.mean(axis=0))))
    shifts = theta @ M.T  # (n, 2) px
    b, p_drift = _slopes_test(shifts, 2)
    drift = tuple(float(v) * (n - 1) for v in b)
    growth, p_growth = math.nan, math.nan
    k = tiles.shape[1]
    if k >= 4:
        ref_t = tiles.mean(axis=0)
        rigid = np.angle(coeffs * np.conj(coeffs.mean(axis=0)))
        # the tiles' phases less the frame's: small for frames of one state, however
        # they vibrate; unwrapped along the frames where a deformation grows past pi
        psi = np.unwrap(_wrap(np.angle(tiles * np.conj(ref_t)) - rigid[:, None, :]), axis=0)
        d = (psi @ M.T).reshape(n, 2 * k)
        w = np.min(np.abs(ref_t) ** 2, axis=1)
        w = np.repeat(w / w.sum(), 2)
        r = _non_rigid(d, centres, w) * np.sqrt(w * 2 * k)  # equal variances (weights)
        bg, p_growth = _slopes_test(r, 2 * k - 3)
        growth = float(np.sqrt(np.mean(bg**2))) * (n - 1)
    return Trend(frames=n, drift_px=drift, drift_p=p_drift, growth_px=growth,
                 growth_p=p_growth, pitch=float(max(lattice.pitches)))

