"""The passes of a series measurement: the lattice detected or checked on the reference, one
streamed pass per series (local or on a Dask cluster) and its phase maps (methods A, B, C),
the regions without a grid masked, progress counted in frames' worth of work.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterable

import numpy as np
from scipy import ndimage

from .._progress import Finding, Progress, as_finding, findings_of, null_progress
from .._runtime.threads import THREADED_PIXELS, map_bounded
from .._stats import median
from .._validation import (
    check_workers,
    exact_in_float32,
)
from ..kinematics import PairMatch, pair_match
from ..phase import (
    DEFAULT_MARGIN,
    Lattice,
    PhaseMaps,
    Window,
    detect_lattice,
    finite_derivatives,
    no_grid,
    partly_covered,
    transform,
    transform_to_edges,
)
from ..phase.lattice import state_carrier
from ..phase.window import min_side
from ..stacks import FrameOrder, circular_offset_std, correct_phases, method_b, phase_offsets
from ..stacks.accumulate import PassPlan, SeriesPass
from ..stacks.vibration import VibrationReport
from ..stacks.vibration import shift_report as _vibration_report
from ._inputs import (
    _as_series,
    _check_pitch_fits,
    _specimen_mask,
)
from ._outliers import _screen_pass, _Screened
from ._records import _Measured, _Stats

# A given lattice must show a modulus this many times larger than at the same
# frequencies turned by 45 degrees, where a grid or checkerboard has no harmonic:
# noise alone gives about 1, the mean of a 12-bit grid image hundreds.
_MIN_GRID_CONTRAST = 5.0


class _Steps:
    """Map the pipeline's steps, weighted by their cost, onto one [0, 1] callback."""

    def __init__(self, progress: Progress, total: float):
        self._progress = progress
        self._total = max(float(total), 1e-12)
        self._done = 0.0

    def sub(self, weight: float, prefix: str) -> Progress:
        start = self._done
        self._done += weight

        def report(fraction: float, message: str) -> None:
            f = min(max(float(fraction), 0.0), 1.0)
            text = f"{prefix}: {message}" if prefix and message else (prefix or message)
            self._progress(min((start + f * weight) / self._total, 1.0), text)

        return report

    def step(self, weight: float, message: str) -> None:
        self._done += weight
        self._progress(min(self._done / self._total, 1.0), message)


def _counting(frames: Iterable, n: int, report: Progress, what: str):
    """Yield ``frames`` unchanged, reporting after each one."""
    for k, f in enumerate(frames, start=1):
        yield f
        report(k / n, f"{what} {k}/{n}")


def _diagnose(name: str, shifts: np.ndarray, estimator: str, lattice: Lattice,
              method: str) -> VibrationReport:
    return _vibration_report(shifts, lattice, method=method, name=name, estimator=estimator)


# Reference frames averaged for the lattice's detection (or its check), spread over
# the series: the lattice must be known before the pass that measures the shifts,
# so these frames are the only ones read twice in a clean series.
_LATTICE_FRAMES = 8


# The cost of a transform, in frames read (progress only).
_WFT_COST = 4.0


def _pass_cost(method: str) -> float:
    """Progress weight of one frame of a pass."""
    return 1.0 + (_WFT_COST if method == "B" else 0.0) + (0.5 if method == "C" else 0.0)


def _lattice_image(ref, report: Progress) -> np.ndarray:
    """Mean of at most :data:`_LATTICE_FRAMES` frames spread over the reference."""
    T = ref.n_frames
    idx = np.unique(np.linspace(0, T - 1, min(T, _LATTICE_FRAMES)).round().astype(int))
    sub = ref if idx.size == T else ref.subset([int(i) for i in idx])
    return sub.mean(progress=report)


def reference_lattice(reference, *, mask=None, margin: float = DEFAULT_MARGIN,
                      bit_depth: int | None = None) -> Lattice:
    """The lattice :func:`measure_series` detects on a reference series.

    Parameters
    ----------
    reference : path, glob, sequence of (H, W) arrays, (T, H, W) array or FrameSeries
        The reference series, as for :func:`measure_series`.
    mask : (H, W) bool array_like, path or None
        The specimen's pixels (default: all).
    margin : float
        Invalid band at the borders, in sigmas: refuses a pitch too large for the
        frames, as :func:`measure_series` does.
    bit_depth : int, optional
        Significant bits of the camera (default: detected).

    Returns
    -------
    Lattice
        Detected on the mean of at most 8 frames spread over the series, the image
        :func:`measure_series` detects it on. ``lattice.pixel_size(grid_pitch)``
        then gives the pixel size from the grid's printed pitch.
    """
    ref = _as_series(reference, "reference", bit_depth)
    m = _specimen_mask(mask, ref.shape)
    return _detect(_lattice_image(ref, null_progress), ref, m, margin)


def _detect(image: np.ndarray, ref, mask: np.ndarray, margin: float) -> Lattice:
    """The lattice detected on ``image``, or an error naming what to do."""
    try:
        lattice = detect_lattice(image, mask=mask)
    except ValueError as exc:
        # frames smaller than a common 5-px pitch needs: say so first
        need = min_side(2.0, margin)
        if min(ref.shape) < min_side(5.0, margin):
            raise ValueError(f"reference: no grid detected on frames of {ref.shape[0]} "
                             f"x {ref.shape[1]} px, too small for the grid method: a "
                             f"window of sigma >= the pitch with its band of margin = "
                             f"{margin:g} sigmas needs {need} px for a 2-px pitch, "
                             f"{min_side(5.0, margin)} px for a 5-px pitch") from None
        raise ValueError(f"reference: {exc}") from None
    _check_pitch_fits(ref.shape, lattice.pitch, margin)
    return lattice


def _plan(s, lattice: Lattice, method: str, window: Window, mask: np.ndarray,
          is_ref: bool) -> PassPlan:
    """What the pass over series ``s`` gathers. Method B's transforms use the
    reference's mask (the states': the whole frame), as its phase maps do; regions
    without a grid, known only from the mean image, may change that afterwards.
    ``lattice``: the series' own wave vectors (:func:`_carrier`)."""
    return PassPlan(lattice=lattice, n_frames=s.n_frames, method=method, window=window,
                    transform_mask=(mask if is_ref else np.ones(s.shape, dtype=bool))
                    if method == "B" else None,
                    saturation_level=s.saturation_level, scale=int(s.scale),
                    count_mask=mask)


# A state whose grid is the reference's stretched by more than this (a principal
# stretch of its carrier's deformation gradient off 1) is suspect: strains of 10 %
# and more are measured, but two grids of pitches 13.6 and 15.8 px (16 %) from two
# experiments are more often a mismatched pair than one homogeneous strain.
_PLAUSIBLE_STRETCH = 0.15


def _carrier(s, lattice: Lattice, reference) -> tuple[Lattice | None, list[str]]:
    """The wave vectors of state series ``s`` (on its first frame) near the
    reference's, and a warning when they differ by more than a plausible strain.

    A state rotated or strained homogeneously has moved its carrier by ``|dk| =
    |k| (strain + rotation)``. The screening and the vibrations' shifts probe each
    frame's carrier over the whole frame: at the reference's they lose it once ``|dk|
    W`` reaches a bin (2 degrees on a 200-px frame) and the series would be refused
    as showing no grid; and a window centred off the carrier biases the phase where
    the grid's amplitude varies (:func:`gridstrain.phase.demodulated_at`). So each
    state's pass and transforms use its own carrier, and its maps are brought to
    the reference's lattice afterwards. None (the reference's) where no peak stands
    out near it (the screening then says what it sees) or the carrier has not moved
    (:func:`gridstrain.phase.lattice.state_carrier`)."""
    # the frame as stored (follow_lattice converts it): a float64 copy read for it
    # alone cost as much as the rest of the search, 0.4 ms of 250 x 400 px
    own = state_carrier(next(iter(s.frames(dtype=None, start=0, stop=1))), lattice,
                        reference)
    if own is lattice:
        return None, []
    # k_s^T = k_r^T F^-1 for a homogeneous deformation gradient F
    F = np.linalg.inv(np.linalg.solve(lattice.K, own.K))
    U, stretch, Vt = np.linalg.svd(F)
    R = U @ Vt  # the polar decomposition's rotation
    turn = math.degrees(math.atan2(R[1, 0], R[0, 0]))
    if np.max(np.abs(stretch - 1)) <= _PLAUSIBLE_STRETCH:
        return own, []
    files = _files(s.paths)
    return own, [f"{s.name}: its grid (pitches {own.pitches[0]:.4g}/{own.pitches[1]:.4g} "
                 f"px, angles {own.angles[0]:.3g}/{own.angles[1]:.3g} deg) is the "
                 f"reference's stretched by {stretch.min() - 1:+.1%}/{stretch.max() - 1:+.1%}"
                 f" and turned by {turn:.3g} deg: more than a plausible strain "
                 f"({_PLAUSIBLE_STRETCH:.0%}); check that {files} and the reference "
                 "images are of the same specimen and grid"]


def _files(paths) -> str:
    paths = [str(p) for p in paths]
    return ", ".join(paths[:2]) + (", ..." if len(paths) > 2 else "")


def _pair_check(res, ref_mean: np.ndarray, ref_mask: np.ndarray, ref, cur, lattice: Lattice,
                outliers: str) -> tuple[dict, list[str]]:
    """The record of :func:`~gridstrain.kinematics.pair_match` for a state measured
    against the reference, and its warning; a refusal when nothing of the reference's
    content is found in the state's, unless ``outliers="warn"``. ``ref``: the
    reference's summary (``_Summary``); ``cur``: the state (``_Measured``) with its
    mean image and noise variance."""
    files = {str(p) for p in cur.series.paths}
    if files and files <= set(ref.sources):
        # the state's frames are frames of the very file the reference's come from
        # (--reference-frames on a record): one camera's record of one specimen
        nan = math.nan
        same = PairMatch(nan, nan, nan, nan, (nan, nan), False, "same record", False)
        return {"state": cur.name, **same.as_dict()}, []
    v = res.valid
    var = cur.stats.variance
    var_cur = float(np.mean(var[v])) if var is not None and v.any() else math.nan
    m = pair_match(ref_mean, cur.stats.mean, res.u, v, pitch=max(lattice.pitches),
                   noise=(ref.variance / ref.T, var_cur / cur.series.n_frames), mask=ref_mask)
    record = {"state": cur.name, **m.as_dict()}
    if m.verdict not in ("mismatch", "nothing matches"):
        return record, []
    both = (f"the reference ({_files(ref.sources)}) and {cur.name} "
            f"({_files(cur.series.paths)})")
    what = (f"{cur.name}: once warped back by the measured displacement, its image's "
            f"content (printing defects, texture, below the grid's frequency) keeps "
            f"{max(m.match, 0.0):.0%} of the correlation with the reference's that a "
            f"pair of one specimen shows (correlation {m.rho:.2f} for {m.rho_match:.2f}, "
            f"spread {m.rho_sd:.2f}): ")
    if m.verdict == "nothing matches" and outliers != "warn":
        raise ValueError(what + f"nothing matches; {both} do not show the same specimen "
                         "and grid: check the folders, or pass --outliers warn "
                         "(outliers='warn') to measure the pair anyway")
    return record, [what + f"check that {both} show the same specimen and grid (an "
                    "image of another specimen or experiment gives a displacement that "
                    "is no measurement)"]


def _run_pass(s, plan: PassPlan, report: Progress) -> SeriesPass:
    """One pass over the frames of ``s`` on this machine. Method B's transforms run
    on threads (the usable cores), adding their sums in frame order (the result
    does not depend on the number of threads); the rest follows the reading."""
    n = s.n_frames
    workers = check_workers(None) if plan.method == "B" else 1
    order = FrameOrder() if workers > 1 else None
    box: list = []

    def read():
        # the frames as stored: integer frames are summed as read, and method B
        # transforms them in float32 (gridstrain.stacks.accumulate, gridstrain.stacks)
        for t, frame in enumerate(s.frames(dtype=None)):
            if not box:
                box.append(SeriesPass(plan, frame))
            box[0].add(t, frame, transform=False)
            yield t, frame

    def transform(item):
        t, frame = item
        if plan.method == "B":
            try:
                box[0].add_transform(t, frame, order=order)
            except BaseException:
                if order is not None:
                    order.fail(t)  # the frames after this one must not wait for it
                raise
        return t

    # BLAS is on the calling thread already (measure_series): its idle threads would
    # spin on the transforms' cores
    for t in map_bounded(transform, read(), workers):
        report((t + 1) / n, f"frame {t + 1}/{n}")
    if not box:
        raise ValueError(f"{s.name}: no frame")
    return box[0]


def _check_given_lattice(image: np.ndarray, lattice: Lattice, window: Window,
                         mask: np.ndarray) -> None:
    """Refuse a given lattice that the reference image does not show.

    The lattice is detected anyway and each given wave vector must lie within the
    window's bandwidth of a detected one, ``2 pi sigma |dk| <= 1`` (the window's
    transfer, hence the modulus, would otherwise drop below exp(-1/2)); a
    neighbouring pattern's side lobe would otherwise pass for the grid. When the
    detection itself fails (a pattern it does not handle), the modulus at the
    given wave vectors must stand above that 45 degrees away.
    """
    try:
        found = detect_lattice(image, mask=mask)
    except ValueError:
        pm, used = _phase_maps_a(image, lattice, window, mask)
        _check_grid(pm, image, used, window)
        return
    for j, k in enumerate((lattice.k1, lattice.k2)):
        kv = np.array(k)
        dk = min(float(np.hypot(*(kv - s * np.array(f)))) for f in (found.k1, found.k2)
                 for s in (1, -1))
        if 2 * math.pi * window.sigma * dk > 1:
            p1, p2 = found.pitches
            a1, a2 = found.angles
            raise ValueError(f"reference: the given lattice is not the grid's: k{j + 1} = "
                             f"({k[0]:.4g}, {k[1]:.4g}) cycles/px is not among the wave "
                             f"vectors detected in the image (pitches {p1:.4g}/{p2:.4g} "
                             f"px, angles {a1:.3g}/{a2:.3g} deg); check --pitch/--angle or "
                             "--k1/--k2, or let the lattice be detected")


def _check_grid(pm: PhaseMaps, image: np.ndarray, mask: np.ndarray, window: Window) -> None:
    """Refuse a lattice at which the image shows no more than noise."""
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    turned = Lattice(*((k[0] * c - k[1] * s, k[0] * s + k[1] * c)
                       for k in (pm.lattice.k1, pm.lattice.k2)))
    control = transform(image, turned, window, mask=mask)
    sel = pm.valid if pm.valid.any() else mask
    for j in range(2):
        grid = median(pm.modulus[j][sel], overwrite_input=True)
        other = median(control.modulus[j][sel], overwrite_input=True)
        ratio = grid / other if other > 0 else math.inf
        if ratio < _MIN_GRID_CONTRAST:
            raise ValueError(f"reference: no grid at the given lattice: the modulus at k{j + 1} "
                             f"is only {ratio:.3g} times that 45 degrees away (a grid gives "
                             "tens to hundreds); check --pitch/--angle or --k1/--k2, or let "
                             "the lattice be detected")


# With to_edges, a specimen found in the image (no mask, or regions without a grid
# inside it) ends where the grid's modulus falls to this fraction of its median: half,
# where a straight edge cuts the window in two (MIN_MODULUS, a quarter, reaches ~0.7
# sigma into the background beside the specimen). The step of the mean grey level at
# the edge leaks into the modulus and moves that line by up to 3 px (sigma = pitch, a
# background at a third of the grid's mean; measured), and at a corner, where a
# quarter of the window is on the specimen, the line cuts it 4 px deep: the grid is
# continued from _EDGE_INSIDE px inside that line, and the maps reach _EDGE_BEYOND px
# beyond it (the continuation's: the best estimate of the grid there), so that a
# reference's mask at the specimen's edge is covered by the states' maps. The
# reference's mask bounds the result's valid pixels (the kinematics).
_EDGE_MODULUS = 0.5
_EDGE_INSIDE = 2
_EDGE_BEYOND = 6


# Images of fewer pixels are transformed on the calling thread alone, rather than one
# wave vector on each of two threads
_THREADED_PIXELS = THREADED_PIXELS


def _phase_maps_a(image, lattice: Lattice, window: Window, mask, *, to_edges: bool = False):
    """WFT of an averaged image, masking regions without a grid (method A); with
    ``to_edges``, valid up to the specimen's edges
    (:func:`gridstrain.phase.transform_to_edges`), the regions without a grid cut at
    the half-modulus line less one pixel, so that no background is taken for grid."""
    m = np.ones(image.shape, dtype=bool) if mask is None else mask
    workers = None if image.size >= _THREADED_PIXELS else 1
    pm = transform(image, lattice, window, mask=m, workers=workers)
    nogrid = no_grid(pm.modulus, pm.valid, m, window.min_modulus)
    if to_edges:
        if not nogrid.any():  # the mask's edges are the specimen's
            return finite_derivatives(transform_to_edges(image, lattice, window, mask=m)), m
        half = no_grid(pm.modulus, pm.valid, m, _EDGE_MODULUS, away=window.sigma)
        inner = _less(m, ndimage.binary_dilation(half | nogrid, iterations=_EDGE_INSIDE))
        pm = transform_to_edges(image, lattice, window, mask=inner,
                                extend=_EDGE_INSIDE + _EDGE_BEYOND)
        pm = dataclasses.replace(pm, valid=pm.valid & m)
        return finite_derivatives(pm), _less(m, half | nogrid)
    if nogrid.any():
        m = _less(m, nogrid)
        pm = transform(image, lattice, window, mask=m, workers=workers)
    return finite_derivatives(pm), m


def _edge_findings(name: str, image, pm: PhaseMaps, used) -> list:
    """The mask's outermost pixels of a measurement up to the edges that show the grid
    in part (continued over, :func:`~gridstrain.phase.partly_covered`)."""
    part = partly_covered(image, pm, used)
    if not part.any():
        return []
    n = int(part.sum())
    return [Finding(
        "edges.partial", f"{name}: {n} of the mask's outermost pixels show the grid "
        "only in part (the specimen's edge crosses them: a mask drawn at or beyond it): "
        "taken as outside and the grid continued over them; their maps are the "
        "continuation's", state=name, pixels=n)]


def _less(m: np.ndarray, nogrid: np.ndarray) -> np.ndarray:
    m = m & ~nogrid
    if not m.any():
        raise ValueError("no pixel shows a grid at the lattice's wave vectors")
    return m


def _grid_support(image, lattice: Lattice, window: Window, mask) -> np.ndarray:
    """The mask :func:`_phase_maps_a` ends with (``mask`` less the regions without a
    grid), for methods B and C, whose maps come from their own sums: one transform
    of the averaged image, of which only the moduli are kept (float32, for the
    threshold), not its maps."""
    m = np.ones(image.shape, dtype=bool) if mask is None else mask
    mod = np.empty((2, *image.shape), dtype=np.float32)

    def keep(j, r0, r1, psi, dphi, modulus):
        mod[j, r0:r1] = modulus

    valid = transform(image, lattice, window, mask=m, sink=keep, workers=None)
    nogrid = no_grid(mod, valid, m, window.min_modulus)
    return _less(m, nogrid) if nogrid.any() else m


def _method_b_maps(s, sc: _Screened, acc: SeriesPass, used: np.ndarray, window: Window,
                   report: Progress) -> PhaseMaps:
    """Method B's maps of series ``s`` from its pass (whose transform sums they
    replace in memory); the kept frames are transformed again (a second read) only
    when the mean image showed regions without a grid, which change the windows'
    support near them."""
    plan = acc.plan
    if np.array_equal(used, plan.transform_mask):
        return finite_derivatives(acc.method_b(release=True).maps)
    # the pass's transform sums are of no use: freed (the halves' sums stay if kept)
    acc.release(keep_halves=acc.lin is not None, keep_method=False)
    kept = sc.series
    n = kept.n_frames
    frames = _counting(kept.frames(dtype=None), n, report,
                       "method B, without the regions showing no grid")
    # the kept frames were screened in the pass: not again
    return finite_derivatives(method_b(frames, plan.lattice, sigma=window.sigma, mask=used,
                                       margin=window.margin, screen=False).maps)


# Method A's averaged grid keeps this fraction of its contrast or less (eq. 14): its
# phase-derivative noise is then 2 % or more above method C's, about the precision of
# the noise floor itself, and worth method C's 2 to 3 times A's cost.
_SUGGEST_C_CONTRAST = 0.98


def _contrast_notes(vib) -> list[Finding]:
    """Series whose vibrations cost method A more than method C's extra time, each
    said of its series."""
    out = []
    for v in vib:
        c = min(v.contrast_factor)
        if math.isfinite(c) and c < _SUGGEST_C_CONTRAST:
            out.append(Finding(
                "contrast.vibration",
                f"{v.name}: vibrations of ({v.std[0]:.3g}, {v.std[1]:.3g}) px std "
                f"lower the averaged grid's contrast to {c:.3f} (Prop. 2.2, eq. 14): "
                f"method A's strain noise is {1 / c - 1:.1%} above that of method C, "
                "which realigns the frames before averaging (--method C)",
                state=v.name, contrast=float(c)))
    return out


def _dist():
    """gridstrain.series, imported only when a scheduler is given."""
    from . import _distributed as distributed

    return distributed


def _check_scheduler(scheduler):
    if scheduler is None:
        return None
    return _dist()._check_scheduler(scheduler)


def _connect(scheduler, timeout: float | None):
    """A distributed.Client for ``scheduler``, or None without one; connecting waits
    at most ``timeout`` seconds (None: Dask's connection timeout)."""
    if scheduler is None:
        return contextlib.nullcontext()
    return _dist().connect(scheduler, timeout=timeout)


def _one_series(s, acc: SeriesPass, base, window: Window, max_saturation: float,
                outliers: str, method: str, f32: bool, steps: _Steps, *,
                to_edges: bool = False) -> _Measured:
    """Screening, statistics and phase maps of series ``s`` from its pass; ``base``
    is the mask of the reference (None for a state: its configuration is deformed)."""
    plan = acc.plan
    sc, acc = _screen_pass(s, acc, max_saturation, outliers)
    notes = findings_of(sc.warnings, "screening.flagged", s.name)
    vib = _diagnose(s.name, sc.shifts, "gridstrain.stacks.vibration.frame_shifts", plan.lattice,
                    method)
    st = acc.statistics()
    stats = _Stats(st.mean, st.variance, st.method, sc.saturation)
    del st
    acc.release(keep_halves=base is not None)  # the reference's halves: its noise floor
    if method == "A":
        pm, used = _phase_maps_a(_transformed_image(s, stats.mean), plan.lattice, window,
                                 base, to_edges=to_edges)
        if to_edges and base is not None:  # the reference's mask: once a run
            notes.extend(_edge_findings(s.name, stats.mean, pm, used))
    else:  # the mean image gives the mask only
        used = _grid_support(stats.mean, plan.lattice, window, base)
    steps.step(1.5 * _WFT_COST, f"{s.name}: phase maps")
    if method == "C":
        res = acc.method_c(mask=used)
        pm = finite_derivatives(res.maps)
        # each said of this series, with its code and figures
        notes.extend(as_finding(w, "vibration").restated(f"{s.name}: {w}", state=s.name)
                     for w in res.warnings)
        del res
    elif method == "B":
        pm = _method_b_maps(s, sc, acc, used, window, steps.sub(0.0, s.name))
    offset = None
    if method in ("A", "B"):
        pm, offset = _centred(pm, sc.shifts, s.name, method)
    if f32:  # float32 maps from float32 frames (gridstrain.conventions)
        pm = dataclasses.replace(pm, psi=pm.psi.astype(np.complex64),
                                 dphi=pm.dphi.astype(np.float32))
    return _Measured(series=sc.series, screen=sc, vib=vib, stats=stats, maps=pm,
                     mask=used, warnings=tuple(notes), offset=offset)


def _transformed_image(s, mean: np.ndarray) -> np.ndarray:
    """The image method A transforms: the mean of the frames of ``s``, in float32 when
    it is one integer frame of at most 16 bits (exact in float32), as method B
    transforms each of its frames: its transform and the correction of its
    phase-modulus coupling take a third of float64's time, and the correction writes
    its maps in float64 (:mod:`gridstrain.conventions`, precision)."""
    if s.n_frames == 1 and exact_in_float32(s.dtype):
        return mean.astype(np.float32)
    return mean


def _centred(pm: PhaseMaps, shifts: np.ndarray, name: str, method: str):
    """Method A's or B's maps with their vibration offset about the frames' mean
    position removed (:func:`~gridstrain.stacks.correct_phases`, ``about="mean"``),
    from the kept frames' measured shifts, and its record for the result's
    systematic errors: the offset removed and its predicted spread, rad."""
    if len(shifts) < 2:
        return pm, None
    removed = phase_offsets(shifts, pm.lattice, exact=True, about_mean=True)
    record = {"series": name, "method": method,
              "removed_rad": [float(v) for v in removed],
              "predicted_std_rad": [float(v) for v in
                                    circular_offset_std(shifts, pm.lattice)]}
    return correct_phases(pm, shifts, about="mean"), record
