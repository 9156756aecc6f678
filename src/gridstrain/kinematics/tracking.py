"""The fringe order followed along a series: each state's whole number of periods taken from
the previous state's displacement, checked against image features where they are
conclusive (:class:`FringeTracker`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage

from .._progress import Finding, as_finding
from .._stats import median
from .._validation import (
    check_mask,
)
from ..phase import Lattice, PhaseMaps
from ..uncertainty import nearest_filled
from ._deformation import (
    Measurement,
    _Handover,
    _kernels,
    deformation,
)
from ._fringe_order import (
    FringeOrder,
    _CoarseReference,
    _from_estimate,
    cut_into_parts,
    sharp,
    strain_if_off,
)
from ._grid_free import decimation

# A state followed from the previous one is confirmed only if its displacement
# changed by at most this many periods (along each wave vector) at every pixel: the
# phase change is taken within half a period of the previous field, and the margin of
# 0.1 period covers noise and a step that is not quite uniform. A larger change may
# be a step of more than half a period, followed one period off.
_MAX_STEP = 0.4
# A step of at most this many periods (along each wave vector, at every pixel) is well
# under half a period: following it is evidence of its own, which image features that
# put the state whole periods away cannot overrule (light that moved, a hot spot or a
# highlight, imitates them; the steps of an ordinary load series are 0.01 to 0.02
# period). The first state of a series is followed from the reference (its
# displacement is the step) when its smallest displacement is within it.
SMALL_STEP = 0.1


def _filled(u: np.ndarray, valid: np.ndarray) -> np.ndarray | None:
    """``u`` with every invalid pixel given its nearest valid pixel's value."""
    if not valid.any():
        return None
    if valid.all():
        return np.array(u)
    return nearest_filled(u, valid)


def _largest_step(res: Measurement, field: np.ndarray, lattice: Lattice,
                  before: np.ndarray) -> float:
    """Largest change of the displacement from ``field``, in periods along k1/k2; inf
    where none of the pixels valid in both is left, or a change is not finite.

    One compiled pass where numba is installed (1.0 -> 0.1 ms at 250 x 400 px);
    otherwise by blocks of rows (about a megapixel each): whole-map differences would
    add three (2, H, W) temporaries to the kinematics' peak (a state followed from
    the previous one peaked 56 MiB higher than the first at 2048^2)."""
    v = res.valid & before
    kern = _kernels()
    if kern is not None and np.shape(field) == res.u.shape:
        largest = kern.largest_step(res.u, field, v, np.ascontiguousarray(lattice.K))
        return math.inf if largest < 0 else largest
    if not v.any():
        return math.inf
    H, W = v.shape
    rows = max(1, 2**20 // W)
    largest = 0.0
    for r0 in range(0, H, rows):
        vb = v[r0:r0 + rows]
        if vb.any():
            # each map gathered on its own (a mask over the trailing axes of a stack
            # gathers several times slower), laid out as that gather lays them out
            d = np.stack([res.u[k, r0:r0 + rows][vb] - field[k, r0:r0 + rows][vb]
                          for k in range(2)], axis=-1).T
            block = float(np.max(np.abs(lattice.K @ d)))
            largest = max(largest, block if block == block else math.inf)
    return largest


def _median_displacement(res: Measurement) -> np.ndarray | None:
    """The median ``(u_x, u_y)`` over the valid pixels, px; None when none is valid."""
    if not res.valid.any():
        return None
    return np.array([median(c[res.valid], overwrite_input=True) for c in res.u])


def _order_offset(res: Measurement, shift, lattice: Lattice) -> float:
    """How far, in periods, the measured median displacement is from ``shift``."""
    med = _median_displacement(res)
    if med is None:
        return math.inf
    return float(np.max(np.abs(lattice.K @ (med - np.asarray(shift)))))


def _median_u(res: Measurement) -> str:
    med = _median_displacement(res)
    return "(n/a)" if med is None else f"({med[0]:.2f}, {med[1]:.2f}) px"


def _what_to_do(lattice: Lattice) -> str:
    p1, p2 = lattice.pitches
    return (f"if the specimen moved by more than half a period (periods {p1:.3g}/{p2:.3g} "
            "px) it is off by whole periods: pass --guess UX UY (guess= in Python), add an "
            "intermediate image to the series, or image a grid with printed features")


def with_strain_doubt(res: Measurement, rec: FringeOrder) -> tuple[FringeOrder, str]:
    """A record not confirmed, with how far the strain may be off too
    (:func:`strain_if_off`), and the words that say it."""
    s = strain_if_off(res)
    rec = dataclasses.replace(rec, strain_if_off=s)
    if not s > 0:
        return rec, ""
    return rec, (f"; its strain may be off too, by up to {s:.1e} (95 % of the pixels: "
                 "the strain a period away, which the large-displacement correction reads "
                 "if the displacement is a period off)")


class Tracker:
    """Measure the states one after the other and fix each one's fringe order (see
    :class:`FringeOrder`): in series order, a state's guess is the previous state's
    field (:meth:`follow`), which is all that is kept of it."""

    def __init__(self, ref_pm: PhaseMaps, mean_ref: np.ndarray, mask: np.ndarray,
                 lattice: Lattice, order: str, lagrangian: bool):
        self.ref_pm, self.mean_ref, self.mask = ref_pm, mean_ref, mask
        self.lattice, self.order, self.lagrangian = lattice, order, lagrangian
        self.prev = None  # (read-back of (u, valid), confirmed, name) of the last state
        # states followed from an unconfirmed one, with their place in the series
        self.inherited: list[tuple[int, str]] = []
        self.measured = 0  # states measured so far
        # the reference's side of the image-feature estimate, made once for all states
        self.coarse = _CoarseReference(np.asarray(mean_ref, dtype=np.float64), lattice,
                                       check_mask(mask, mean_ref.shape))

    def snapshot(self) -> tuple:
        """What :meth:`measure` changes, for :meth:`restore`: a state measured on
        trial is measured again as if the first time."""
        return self.prev, self.measured, list(self.inherited)

    def restore(self, saved: tuple) -> None:
        self.prev, self.measured, inherited = saved
        self.inherited = list(inherited)

    def features(self, pm: PhaseMaps, mean: np.ndarray, g):
        """The image-feature estimate of the next state's displacement
        (:func:`coarse_displacement`) from its mean image, or None when its guess
        is not automatic: the mean image is not needed afterwards."""
        if not isinstance(g, str):
            return None
        return self.coarse.decide(np.asarray(mean, dtype=np.float64), self.ref_pm, pm)

    def _followed(self, pm: PhaseMaps, est, prev, place: int, name: str,
                  warnings: list) -> tuple:
        """``(Measurement, FringeOrder)`` of a state followed from the previous one in
        series order (``prev``, as :meth:`follow` kept it), checked against the image
        features ``est``; what it finds goes to ``warnings``."""
        ref_pm = self.ref_pm
        get, prev_ok, prev_name = prev
        # the previous field, its invalid pixels filled, is handed over to the
        # kinematics (not held here while they run); the step is taken on the
        # previous state's valid pixels, where the field is its u unchanged
        res = deformation(ref_pm, pm, lagrangian=self.lagrangian,
                          guess=_Handover(_filled(*get())))
        u_prev, before = get()
        step = _largest_step(res, u_prev, self.lattice, before)
        del u_prev, before
        gmed = res.guess
        away = est.confident and bool(np.max(np.abs(self.lattice.K @ est.shift)) >= 0.5)
        if est.confident and _order_offset(res, est.shift, self.lattice) < 0.5:
            rec = _from_estimate(est, "previous state", True, gmed,
                                 f"followed from {prev_name} (step {step:.2f} period); "
                                 f"image features agree ({est.reason})", step)
        elif est.confident and (step > _MAX_STEP or (away and step > SMALL_STEP)):
            # conclusive features that moved with the specimen beat the assumption
            # of a step below half a period where the step followed is not small:
            # the step was larger
            followed = _median_u(res)
            res = deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=est.shift)
            rec = _from_estimate(est, "image features", True, res.guess,
                                 f"{est.reason}; followed from {prev_name} it would "
                                 f"have been {followed}", step)
            warnings.append(Finding(
                "fringe_order.features_used",
                f"{name}: image features fix the displacement at {_median_u(res)}, "
                f"whole periods from {followed} followed from {prev_name}: the load "
                "step was more than half a period; the features were used",
                state=name, step=step))
        elif est.confident:
            # two kinds of evidence disagree: a small step followed, and features
            # whole periods away (light that moved: a hot spot, a highlight) or at
            # no motion (content fixed to the camera: dust, hot pixels)
            rec, said = _disagreement(res, est, prev_name, step, name)
            warnings.append(said)
        elif step > _MAX_STEP:
            rec = _from_estimate(est, "previous state", False, gmed,
                                 f"followed from {prev_name}, but the displacement "
                                 f"changed by up to {step:.2f} period", step)
            warnings.append(Finding(
                "fringe_order.unconfirmed",
                f"{name}: the displacement changed by up to {step:.2f} period since "
                f"{prev_name}, more than the {_MAX_STEP} a load step can be followed "
                "with: fringe order not confirmed; " + _what_to_do(self.lattice),
                state=name, step=step))
        else:
            rec = _from_estimate(est, "previous state", prev_ok, gmed,
                                 f"followed from {prev_name} (step {step:.2f} period)"
                                 + ("" if prev_ok else ", itself not confirmed"), step)
            if not prev_ok:
                self.inherited.append((place, name))
        return res, rec

    def measure(self, pm: PhaseMaps, est, g, name: str):
        """``(Measurement, FringeOrder, warnings)`` of the next state, with ``est``
        from :meth:`features`."""
        ref_pm = self.ref_pm
        warnings: list[str] = []
        place, self.measured = self.measured, self.measured + 1
        prev, self.prev = self.prev, None  # the next state's guess comes from this one
        first = None  # the first state's smallest displacement, once measured
        if isinstance(g, str) and self.order == "series" and prev is not None:
            res, rec = self._followed(pm, est, prev, place, name, warnings)
        elif isinstance(g, str) and self.order == "series" and place == 0 and \
                not (est.confident and _beyond_small_step(ref_pm, pm, self.lagrangian)) \
                and (first := _first_step(ref_pm, pm, self.lagrangian))[1] <= SMALL_STEP:
            # (confident features replace a first step that is not small: it is
            # measured only when it may be small or is the one kept)
            # the first state of a series, within a small step of the reference: followed
            # from it, as every later state is from the one before
            res, step = first
            if est.confident and _order_offset(res, est.shift, self.lattice) >= 0.5:
                rec, said = _disagreement(res, est, "the reference", step, name)
                warnings.append(said)
            else:
                agree = f"; image features agree ({est.reason})" if est.confident else ""
                rec = _from_estimate(est, "previous state", True, res.guess,
                                     f"followed from the reference: its displacement, "
                                     f"{step:.2f} period at most, is a step well under half "
                                     f"a period{agree}", step)
        elif isinstance(g, str) and est.confident:
            first = None  # not held while the features' order is measured
            res = deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=est.shift)
            rec = _from_estimate(est, "image features", True, res.guess, est.reason)
        elif isinstance(g, str) or g is None:
            res = first[0] if first is not None else \
                deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=None)
            if g is None:
                rec = FringeOrder("smallest displacement", False, (0.0, 0.0),
                                  "guess=None: the order closest to zero, as asked")
            else:
                rec = _from_estimate(est, "smallest displacement", False, (0.0, 0.0),
                                     f"image features undecided: {est.reason}")
                warnings.append(Finding(
                    "fringe_order.unconfirmed",
                    f"{name}: fringe order not confirmed ({est.reason}); the smallest "
                    f"displacement the phases allow was taken (median {_median_u(res)}); "
                    + _what_to_do(self.lattice), state=name))
        else:
            res = deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=g)
            rec = FringeOrder("user", True, res.guess, "the given guess")
        if rec.confirmed and rec.source == "image features" and est.light_doubt:
            # the features' whole periods are used (the grid's modulus shows them) but
            # nothing that the light cannot imitate confirms them
            rec = dataclasses.replace(rec, confirmed=False,
                                      detail=f"{est.light_doubt}; {rec.detail}")
            warnings.append(Finding("fringe_order.unconfirmed",
                                    f"{name}: fringe order {est.light_doubt}; the "
                                    "displacement the image features give is kept "
                                    f"({_median_u(res)})", state=name))
        if rec.confirmed and rec.source in ("previous state", "image features") and \
                (parts := cut_into_parts(res.valid)):
            rec = dataclasses.replace(rec, confirmed=False, detail=f"{parts}; {rec.detail}")
            warnings.append(Finding(
                "fringe_order.unconfirmed",
                f"{name}: {parts}: fringe order not confirmed; " + _what_to_do(self.lattice),
                state=name))
        if not rec.confirmed:
            rec = _doubt_said(res, rec, warnings)
        # the measurement carries the series' record, not the pair's view of its guess
        res = dataclasses.replace(res, fringe_order=rec)
        return res, rec, warnings

    def follow(self, res: Measurement, name: str, stored=None) -> None:
        """Keep what guesses the next state in series order: the displacement and
        validity of ``res`` (its field is made from them, invalid pixels filled,
        when the next state is measured). ``stored``: a callable giving them back
        bit for bit (from the result file), so that they are not in memory while
        the next state's frames are read."""
        if not res.valid.any():
            self.prev = None  # nothing to follow
            return
        u, valid = res.u, res.valid
        get = stored if stored is not None else (lambda: (u, valid))
        self.prev = (get, res.fringe_order.confirmed, name)

    def finish(self) -> list[str]:
        """The warnings that concern several states."""
        if not self.inherited:
            return []
        return [Finding("fringe_order.inherited",
                        f"{state_runs(self.inherited)}: followed from a state whose fringe order "
                        "is not confirmed; they share its uncertainty (their strain too: "
                        "each state's record says by how much it may be off)",
                        states=len(self.inherited))]


def _doubt_said(res: Measurement, rec: FringeOrder, warnings: list) -> FringeOrder:
    """``rec`` with how far the strain may be off (:func:`with_strain_doubt`), said in
    the last of ``warnings``, the one that says why it is not confirmed."""
    rec, said = with_strain_doubt(res, rec)
    if warnings and said:
        last = as_finding(warnings[-1], "fringe_order.unconfirmed")
        warnings[-1] = Finding(last.code, last + said, state=last.state, **last.figures,
                               strain_if_off=rec.strain_if_off)
    return rec


def _beyond_small_step(ref_pm: PhaseMaps, pm: PhaseMaps, lagrangian: bool) -> bool:
    """Whether the smallest displacement the phases allow certainly moves some pixel by
    more than :data:`SMALL_STEP` along a wave vector (True only when proved; False
    when it cannot tell): :func:`_first_step`'s step is then above it, and its
    measurement, which confident image features replace, need not be made.

    The start of :func:`deformation` without a guess is computed as it computes it (eq.
    34 at ``X``, unwrapped, the order closest to zero), ``u_E``. Without the
    correction it is the measurement: any valid pixel with ``|K u_E| >`` SMALL_STEP
    proves it. With the correction, a witness ``X`` is a pixel far enough inside both
    states' valid pixels where ``M = (2 pi K)^-1 D_def`` is small: the fixed point
    ``u*`` solves ``(I + M_bar) u* = u_E`` with ``M_bar`` the mean of ``M`` between ``X``
    and ``X + u*``, so ``|u* - u_E| <= b = q / (1 - q) |u_E|`` with ``q`` the largest
    norm of ``M`` around ``X``; the iterations start within ``e0`` of ``u*`` (the
    pointwise start, or the median derivatives' one), which keeps the wrapped residual
    under half a period, and after one or more iterations the error is at most ``q
    e0``; ``X + u`` lies inside the deformed state's valid pixels with a margin of two
    pixels, so ``X`` is valid in the measurement. Then ``|K u| >= |K u_E| - ||K|| (b + q
    e0)``, which must exceed SMALL_STEP with a margin. Costs the start alone (a fifth
    of the measurement on a 1040 x 1376 pair).
    """
    from ._deformation import _median_start, _unwrapped_displacement

    lattice = ref_pm.lattice
    K = lattice.K
    valid = ref_pm.valid & pm.valid & np.all(np.isfinite(ref_pm.dphi), axis=(0, 1))
    if not valid.any():
        return False
    zero = np.broadcast_to(np.zeros((2, 1, 1)), (2, *valid.shape))
    u = _unwrapped_displacement(ref_pm, pm, valid, K, zero)
    if not lagrangian:  # u_E is the measurement, valid its pixels
        periods = np.max(np.abs(np.tensordot(K, u, axes=1)), axis=0)  # |K u_E|
        return bool((valid & (periods > SMALL_STEP)).any())
    margin = 0.02  # periods: the spline's phase derivatives are not exactly dphi's
    two_pi_K = 2 * np.pi * K
    kn = float(np.linalg.norm(K, 2))
    m_of_d = np.linalg.inv(two_pi_K)
    H, W = valid.shape
    # candidates a few pixels apart, within a period of no motion, whose neighbours
    # two candidates away are valid in the deformed state too, the largest first
    s = 8
    periods = np.max(np.abs(np.tensordot(K, u[:, ::s, ::s], axes=1)), axis=0)
    sub = valid[::s, ::s] & (periods > SMALL_STEP) & (periods <= 1.0)
    inner = np.zeros_like(sub)
    inner[2:-2, 2:-2] = True
    dv = pm.valid[::s, ::s]
    for di in range(-2, 3):
        for dj in range(-2, 3):
            inner[2:-2, 2:-2] &= dv[2 + di:dv.shape[0] - 2 + di, 2 + dj:dv.shape[1] - 2 + dj]
    sub &= inner
    rows, cols = np.nonzero(sub)
    if rows.size == 0:
        return False
    a_med = None
    order = np.argsort(-periods[rows, cols], kind="stable")[:32]
    for r, c in zip(rows[order], cols[order], strict=True):
        i, j, ue = r * s, c * s, u[:, r * s, c * s]
        a = float(np.hypot(ue[0], ue[1]))
        # q around X first with a generous box, checked below against what it allows
        R = math.ceil(2 * a) + 4
        if i < R or j < R or i + R >= H or j + R >= W:
            continue
        box = (slice(i - R, i + R + 1), slice(j - R, j + R + 1))
        if not pm.valid[box].all():
            continue
        D = pm.dphi[(slice(None), slice(None), *box)].astype(np.float64)
        M = np.tensordot(m_of_d, D, axes=1)
        q = float(np.sqrt(np.max(np.sum(M * M, axis=(0, 1))))) + margin
        if not q < 0.25:
            continue
        b = q / (1 - q) * a
        if a_med is None:
            a_med = _median_start(pm, two_pi_K)
        e0 = max(b, float(np.linalg.norm(a_med - np.eye(2), 2)) * a) + b
        # every point the iterations visit, from the start (within e0 of u*) on, lies
        # within a + b + e0 of X: inside the box where q bounds M
        if kn * (1 + q) * e0 >= 0.5 - margin or a + b + e0 + 2 > R:
            continue
        if periods[r, c] - kn * (b + q * e0) > SMALL_STEP + margin:
            return True
    return False


def _first_step(ref_pm: PhaseMaps, pm: PhaseMaps, lagrangian: bool):
    """``(Measurement, step)``: the smallest displacement the phases allow and its
    largest size along a wave vector over the valid pixels, in periods (the step from
    the reference, whose displacement is zero)."""
    res = deformation(ref_pm, pm, lagrangian=lagrangian, guess=None)
    zero = np.broadcast_to(np.zeros((2, 1, 1)), res.u.shape)
    return res, _largest_step(res, zero, ref_pm.lattice, res.valid)


def _disagreement(res: Measurement, est, prev_name: str, step: float, name: str):
    """``(record, warning)`` of a state followed by a small step from ``prev_name``
    whose image features (``est``, confident) put it whole periods away: two kinds of
    evidence disagree, the followed displacement is kept and not confirmed."""
    sx, sy = est.shift
    rec = _from_estimate(est, "previous state", False, res.guess,
                         f"followed from {prev_name} (step {step:.2f} period), but image "
                         f"features put it at {sx:.2f}, {sy:.2f} px, whole periods away "
                         f"({est.reason})", step)
    said = Finding(
        "fringe_order.unconfirmed",
        f"{name}: the displacement followed from {prev_name} (median {_median_u(res)}, "
        f"a step of {step:.2f} period at most) and the image features ({sx:.2f}, "
        f"{sy:.2f}) px disagree by whole periods: features fixed to the camera (dust, "
        "hot pixels) or light that moved (a hot spot, a highlight) imitate the "
        "specimen's, and a load step of whole periods imitates a small one; the "
        "followed displacement is kept: fringe order not confirmed; check the order of "
        "the states or pass --guess UX UY", state=name, step=step,
        features_shift=[float(sx), float(sy)])
    return rec, said


def state_runs(states: list[tuple[int, str]]) -> str:
    """``(place, name)`` of states in series order, named one by one, a run of three or
    more states in a row as its first and last (``rec[2] to rec[100] (99 states)``)."""
    parts, k = [], 0
    while k < len(states):
        j = k
        while j + 1 < len(states) and states[j + 1][0] == states[j][0] + 1:
            j += 1
        if j - k >= 2:
            parts.append(f"{states[k][1]} to {states[j][1]} ({j - k + 1} states)")
        else:
            parts += [name for _, name in states[k:j + 1]]
        k = j + 1
    return ", ".join(parts)


def check_after_warp(res: Measurement, rec: FringeOrder, coarse: _CoarseReference,
                     mean_cur: np.ndarray, lattice: Lattice, name: str):
    """``(res, rec, warnings)`` with the fringe order checked on the images' content
    once the deformed image is warped back by the measured field.

    Image features compared as a rigid shift (:func:`coarse_displacement`) fix the
    order only when the specimen moved as a whole: under a homogeneous strain of 10
    % a hole 40 px from the centre moves by 4 px while the field's median does not.
    Warped back by the measured ``u``, the deformed image's content lies where the
    reference's does if the order is right, and whole periods away if not. A state
    followed from the previous one keeps that order (its record says why). The
    field is extended to the invalid pixels by their nearest valid neighbour's, so
    that a hole's edge, the strongest feature, is warped with the specimen around
    it. The content below the grid's frequency is compared first, at whole-period
    offsets of the measured field (:meth:`_CoarseReference.content`, on samples a
    pitch apart: no full-size warp); the correlation at the pitch of the warped
    image only when it cannot decide. A state whose order that comparison fixed
    before it was measured is not compared again. ``coarse``: the reference's side
    of :func:`coarse_displacement` (its mean image and mask), the one the states'
    image features use."""
    v = res.valid
    if rec.source == "previous state" or not v.any() or res.reference is None:
        return res, rec, []
    if rec.confirmed and rec.tiles_agreeing:
        return res, rec, []  # fixed by the content at whole-period offsets of the field
    q = decimation(lattice)
    uq, vq = res.u[:, ::q, ::q].astype(np.float64), v[::q, ::q]
    c = coarse.content(mean_cur, uq, vq)

    def shown(off, image=None):
        # a correction by whole periods only where the grid's own modulus shows it too:
        # the image's light alone (a hot spot, a highlight) may have moved by them; the
        # smooth content below the grid's frequency confirmed only by the ratio of the
        # grid's harmonics, which no light changes (the doubt where it cannot tell)
        return coarse.evidence(res.reference, res.deformed, uq, vq, off, material=True,
                               image=image)

    if c.confident:
        t = lattice.periods @ np.array(c.offset, dtype=float)
        seen, said, doubt = shown(c.offset, mean_cur)
        if any(c.offset) and not seen:
            return _unshown(res, rec, t, name, c.reason, said)
        if not any(c.offset) and not rec.confirmed and (doubt or not seen):
            # the content that matches may be a light that moved with the field's
            # whole periods: no confirmation without the grid's harmonics
            return res, rec, []
        return _recheck(res, rec, t, name, c.reason, _content_record(c), doubt=doubt)
    u = np.stack([nearest_filled(res.u[k], v) for k in range(2)])
    H, W = v.shape
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    yy += u[1]
    xx += u[0]
    warped = ndimage.map_coordinates(np.asarray(mean_cur, dtype=np.float64), [yy, xx],
                                     order=1, mode="nearest")
    del yy, xx
    est = coarse.estimate(warped, np.zeros(2))
    if not est.confident:
        return res, rec, []
    # the whole periods the content is off, and the correction they call for
    off = np.rint(lattice.K @ np.array(est.shift))
    t = np.linalg.solve(lattice.K, off)
    light = None if sharp(est) else mean_cur  # features finer than light: no ratio needed
    seen, said, doubt = shown(off, light) if np.any(off) or light is not None \
        else (True, "", "")
    if np.any(off) and not seen:
        return _unshown(res, rec, t, name, est.reason, said)
    if not np.any(off) and not rec.confirmed and (doubt or not seen):
        return res, rec, []  # as above: the content may be light that moved
    figures = {"correlation": est.correlation, "peak_to_alias": est.peak_to_alias,
               "disagreement": est.disagreement, "features_shift": est.shift}
    return _recheck(res, rec, t, name, est.reason, figures, doubt=doubt)


def _unshown(res: Measurement, rec: FringeOrder, t, name: str, reason: str, seen: str):
    """``(res, rec, warnings)`` when the warped-back image's light lies whole periods
    (``t``, px) from the reference's but the grid's own modulus does not show them: two
    kinds of evidence disagree; the displacement is kept as measured, not confirmed."""
    said = (f"the deformed image warped back by the measured field {_median_u(res)} showed "
            f"the reference's light {t[0]:.2f}, {t[1]:.2f} px away ({reason}), but {seen}: "
            "light that moved (a hot spot, a highlight) imitates the specimen")
    was = rec.confirmed
    rec = dataclasses.replace(rec, confirmed=False, detail=f"{said}; {rec.detail}")
    if was:
        rec, doubt = with_strain_doubt(res, rec)
    else:
        doubt = ""
    return res, rec, [Finding("fringe_order.unconfirmed",
                              f"{name}: {said}; the displacement is kept as measured: "
                              f"fringe order not confirmed{doubt}", state=name,
                              offset_px=[float(t[0]), float(t[1])])]


def _content_record(c) -> dict:
    """The figures of a :class:`ContentOrder` as fields of a :class:`FringeOrder`."""
    return {"residual_ratio": c.residual_ratio, "tiles_agreeing": c.tiles_agreeing,
            "tiles_informative": c.tiles_informative}


def _recheck(res: Measurement, rec: FringeOrder, t, name: str, reason: str, figures: dict,
             *, doubt: str = ""):
    """``(res, rec, warnings)`` once the warped-back content says that the measured
    displacement needs ``t`` (px, a lattice vector) added: confirmed if ``t`` is 0,
    measured again from the guess moved by ``t`` if not. ``doubt``: why only evidence
    the light can imitate shows ``t`` (the image's content and the grid's modulus, with
    nothing else against them): the displacement they support is taken, not
    confirmed."""
    # the content compared over the whole field is the larger part's: a field parted in
    # two by invalid bands keeps the other part's whole periods in doubt
    parts = cut_into_parts(res.valid)
    if not np.any(np.rint(res.lattice.K @ t)):
        if rec.confirmed or parts:
            return res, rec, []
        return res, dataclasses.replace(
            rec, confirmed=True, source="image features", strain_if_off=math.nan,
            detail=f"the deformed image warped back by the measured field matches the "
                   f"reference's content ({reason}); {rec.detail}", **figures), []
    if parts and not doubt:
        doubt = f"not confirmed: {parts}"
    before = _median_u(res)
    g = np.array(res.guess, dtype=float) + t
    again = deformation(res.reference, res.deformed, lagrangian=res.lagrangian, guess=g)
    seen = (f"the deformed image warped back by the field {before} showed the "
            f"reference's content {t[0]:.2f}, {t[1]:.2f} px away ({reason})")
    if doubt:
        # two kinds of evidence on the specimen's side against none: the better
        # supported displacement, said as a choice, not as a fact
        rec, strain = with_strain_doubt(again, FringeOrder(
            "image features", False, again.guess,
            f"{seen}; {doubt}; {rec.source} had given {before}", **figures))
        return again, rec, [Finding(
            "fringe_order.unconfirmed",
            f"{name}: fringe order {doubt}; warped back by {before}, the deformed image's "
            f"content lay {t[0]:.2f}, {t[1]:.2f} px from the reference's, and the grid's "
            f"modulus agrees: {_median_u(again)} is taken, not confirmed{strain}",
            state=name, offset_px=[float(t[0]), float(t[1])],
            strain_if_off=rec.strain_if_off)]
    rec = FringeOrder("image features", True, again.guess,
                      f"{seen}; {rec.source} had given it", **figures)
    return again, rec, [Finding("fringe_order.corrected",
                                f"{name}: the displacement was whole periods off "
                                f"({before}): warped back by it, the deformed image's "
                                f"content lay {t[0]:.2f}, {t[1]:.2f} px from the "
                                f"reference's; it is now {_median_u(again)}", state=name,
                                offset_px=[float(t[0]), float(t[1])])]
