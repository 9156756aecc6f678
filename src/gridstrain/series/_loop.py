"""The measurement loop of a series: the door where the options are taken (a
:class:`~gridstrain.series.MeasureOptions` and keywords, each declared once in
``_options.py``) and checked together, then each series read in one pass, each state
measured against the reference and dropped once its maps are kept.

The stages and their algorithms are described in :mod:`gridstrain.series`, the public
path of :func:`measure_series`.
"""

from __future__ import annotations

import dataclasses
import textwrap

import numpy as np
from scipy import ndimage

from .._progress import Progress, null_progress
from .._runtime import paging as _paging
from .._runtime.threads import one_blas_thread
from .._validation import check_sigma
from ..io import StateInputs, close_readers, state_inputs
from ..kinematics import Measurement, check_parts, find_discontinuities, without_discontinuities
from ..kinematics.tracking import _Tracker, check_after_warp
from ..phase import Lattice, Window, coupling_corrected, demodulated_in_place
from ..phase.lattice import reference_carrier
from ..results import SeriesResult
from ..uncertainty import aliasing_bias, metrology, nearest_filled, nearest_index
from ._floors import _check_model_units, _Noise, _ReferenceFloor
from ._inputs import (
    _check_fit,
    _check_memory,
    _glob_warning,
    _inputs,
    _loads_and_times,
)
from ._options import (
    MeasureOptions,
    check_together,
    loads_file,
    options_signature,
    parameters_doc,
    unknown_option,
)
from ._passes import (
    _LATTICE_FRAMES,
    _WFT_COST,
    _carrier,
    _check_given_lattice,
    _connect,
    _contrast_notes,
    _detect,
    _dist,
    _lattice_image,
    _one_series,
    _pair_check,
    _pass_cost,
    _plan,
    _run_pass,
    _Steps,
)
from ._sinks import _InMemory, _streamed, empty_state_message

__all__ = ["measure_series"]

# The previous state's displacement is kept in memory up to this size, bytes (a 0.5
# Mpx field in float64), and read back from the result file above it: reading it
# twice per state costs more than the transform of a frame that small, and keeping
# it adds a constant, small amount to the peak.
_FOLLOW_IN_MEMORY = 8 * 2**20


# --------------------------------------------------------------------------- the door


def measure_series(reference, states, options: MeasureOptions | None = None,
                   **overrides) -> SeriesResult:
    """Displacement and strain maps of loaded states from series of grid images.

    Parameters
    ----------
    reference : FrameSeries, path, glob, list of files, or array
        The reference series: a :class:`gridstrain.io.FrameSeries`, anything
        :func:`gridstrain.io.open_series` opens, one ``(H, W)`` frame or a
        ``(T, H, W)`` stack of grey levels.
    states : series, sequence of series, or StateInputs
        The loaded states, each like ``reference``, in the order they were loaded
        (a list of file names is read as a list of states; wrap it, ``[files]``, to
        make one series of it). States given as paths are named after their folder
        or file stem. Explicit files whose names form one numbered family are
        measured in natural order (``frame_2`` before ``frame_10``) unless
        ``keep_order``; :attr:`SeriesResult.state_order` says which order was
        used. A :class:`gridstrain.io.StateInputs` (from
        :func:`gridstrain.io.state_inputs`) is used as it is.
    options : MeasureOptions, optional
        The options below as one object (e.g. ``MeasureOptions.from_parameters``
        of an earlier result's ``parameters``); keywords given beside it override
        its fields. An unknown keyword is a TypeError naming the close ones.
@OPTIONS_DOC@

    Returns
    -------
    SeriesResult

    Raises
    ------
    ValueError, TypeError, OSError
        Bad arguments or input files (the message names the series, the frame
        and the file); an unreachable scheduler (OSError); a series whose frames
        form a sequence rather than a static state (measure it with
        ``each_frame=True``).

    Notes
    -----
    Frames are read one at a time, never held whole, in one pass per series
    (:class:`gridstrain.stacks.accumulate.SeriesPass`: screening, shifts, mean, variance,
    the noise floor's halves, method B's transforms or method C's sums). Read twice:
    at most 8 reference frames (their mean detects or checks the lattice, which the
    pass needs), the frames the screening excludes (taken out of the sums), and,
    with method B, a series whose mean image shows regions without a grid (they
    change the windows' support: the kept frames are transformed again).

    Examples
    --------
    >>> import numpy as np
    >>> from gridstrain import Lattice
    >>> from gridstrain.models import synthetic
    >>> lat = Lattice.from_pitch(5.0)
    >>> ref = synthetic.grid_image((96, 96), lat)
    >>> cur = synthetic.grid_image((96, 96), lat,
    ...                            displacement=lambda X, Y: (1e-3 * X, 0 * Y))
    >>> res = measure_series(ref, cur, lattice=lat, guess=None)
    >>> round(float(np.nanmean(res.strain[0, 0])), 6)
    0.001
    """
    if options is not None and not isinstance(options, MeasureOptions):
        raise TypeError(f"options must be a MeasureOptions, got {type(options).__name__}")
    unknown_option(overrides)
    o = MeasureOptions(**overrides) if options is None else dataclasses.replace(
        options, **overrides)
    o = check_together(o)
    each_frame, reference_frames, keep_order = o.each_frame, o.reference_frames, o.keep_order
    loads, frame_rate, guess, mask = loads_file(o), o.frame_rate, o.guess, o.mask
    progress = null_progress if o.progress is None else o.progress
    given = states if isinstance(states, StateInputs) else state_inputs(
        states, each_frame=each_frame, reference_frames=reference_frames,
        keep_order=keep_order, bit_depth=o.bit_depth)
    if given.reference is not None:
        if reference is not None:
            raise ValueError("reference must be None with reference_frames (the reference "
                             "is the record's first frames), got "
                             f"{type(reference).__name__}")
        reference = given.reference
    series, guesses, m = _inputs(reference, given, guess, mask, bit_depth=o.bit_depth,
                                 order=o.order, sigma=o.sigma, margin=o.margin,
                                 lattice=o.lattice)
    _check_memory(series, method=o.method, held=o.output is None)
    steps = _Steps(progress, _total_cost(series, o))
    # how the frames were read (colour converted, lossy JPEG), series by series
    warnings: list[str] = [n for s in series for n in getattr(s, "notes", ())]
    warnings += list(given.warnings)
    if not (each_frame or given.reference is not None or reference_frames):
        warnings += _glob_warning(series)
    o = dataclasses.replace(o, state_order=given.order)
    extra, notes = _loads_and_times(loads, frame_rate, series, each_frame=o.each_frame,
                                    first_frame=o.reference_frames or 0)
    warnings += notes
    # BLAS on the calling thread throughout: its products here are small or memory
    # bound, and OpenBLAS's own threads would spin between them (gridstrain._runtime.threads)
    try:
        with one_blas_thread():
            o = _window(series[0], m, o, steps)
            return _measure(series, guesses, m, o, steps, warnings, progress, extra)
    finally:
        close_readers()  # the files kept open between states: none held after the run


# the options' entries are their declaration's (gridstrain.series._options), written once;
# the signature shown (help(), inspect, editors) names every keyword the overrides take
measure_series.__doc__ = measure_series.__doc__.replace(
    "@OPTIONS_DOC@\n", textwrap.indent(parameters_doc(), " " * 4) + "\n")
measure_series.__signature__ = options_signature(measure_series)


def _kinematics(tracker: _Tracker, c, guess, lattice: Lattice, ref_summary, outliers: str):
    """``(measurement, fringe order, warnings, cracks, pair check)`` of state ``c``: its
    kinematics with the tracker's guess, the fringe order checked once the image is
    warped back, the cracks left out (each part they cut off checked on its own
    content), and the pair check against the reference (``ref_summary``)."""
    auto = isinstance(guess, str)
    prev = tracker.prev  # the previous state's field, read back by a crack's parts
    est = tracker.features(c.maps, c.stats.mean, guess)
    res, rec, notes = tracker.measure(c.maps, est, guess, c.name)
    if auto:
        res, checked, said = check_after_warp(res, rec, tracker.coarse, c.stats.mean,
                                              lattice, c.name)
        if checked is not rec:  # confirmed now: the doubt said before is void
            notes = [n for n in notes if "fringe order not confirmed" not in n]
        rec = checked
        notes = [*notes, *said]
    images = (tracker.mean_ref, c.stats.mean, tracker.mask) if auto else None
    confirmed = rec.confirmed
    follow = prev[0] if prev is not None and rec.source == "previous state" else None
    res, rec, found, said = _discontinuities(res, rec, c.name, images, follow)
    del prev, follow
    if rec.confirmed and not confirmed:  # each part by its own features now
        notes = [n for n in notes if "fringe order not confirmed" not in n]
    match, told = _pair_check(res, tracker.mean_ref, tracker.mask, ref_summary, c, lattice,
                              outliers)
    return res, rec, [*notes, *said, *told], found, match


def _total_cost(series: list, o: MeasureOptions) -> float:
    """The measurement's cost for its progress: reading a frame costs 1, a transform
    about 4 frames' worth."""
    total = min(series[0].n_frames, _LATTICE_FRAMES) + 1.0
    for s in series:
        total += s.n_frames * _pass_cost(o.method) + 2 * _WFT_COST
    total += (len(series) - 1) * (3 * _WFT_COST if o.lagrangian else _WFT_COST)
    return total + 3 * _WFT_COST


def _window(ref, m: np.ndarray, o: MeasureOptions, steps: _Steps) -> MeasureOptions:
    """The options completed with the lattice, detected on (or checked against) the
    mean of a few reference frames, and the window's ``sigma``."""
    mean_ref = _lattice_image(ref, steps.sub(min(ref.n_frames, _LATTICE_FRAMES), ""))
    lattice = _detect(mean_ref, ref, m, o.margin) if o.detected else o.lattice
    sigma = o.sigma if o.sigma_pitches is None else o.sigma_pitches * lattice.pitch
    sigma = check_sigma(sigma, lattice.pitch)
    _check_fit(ref.shape, sigma, o.margin)
    window = Window(float(sigma), o.margin)
    if not o.detected:
        _check_given_lattice(mean_ref, lattice, window, m)
    steps.step(1.0, "lattice")
    return dataclasses.replace(o, lattice=lattice, sigma=window.sigma, window=window)


def _measure(series: list, guesses: list, m: np.ndarray, o: MeasureOptions, steps: _Steps,
             warnings: list, progress: Progress, extra: dict) -> SeriesResult:
    """One pass over every series (screening, shifts, statistics, the halves of the
    noise floor, method B's or C's sums), the flagged frames then taken out; the
    states measured one after the other, each dropped once measured."""
    lattice, window, method = o.lattice, o.window, o.method
    sigma = window.sigma
    n_states = len(series) - 1
    base = reference_carrier(next(iter(series[0].frames(start=0, stop=1))), lattice) \
        if n_states else None
    carriers = [(None, [])] + [_carrier(s, lattice, base) for s in series[1:]]
    for _, notes in carriers:
        warnings.extend(notes)
    plans = [_plan(s, carriers[k][0] or lattice, method, window, m, k == 0)
             for k, s in enumerate(series)]
    _check_model_units(o.noise_model, series)
    f32 = all(np.dtype(s.dtype) == np.float32 for s in series)
    kin = 3 * _WFT_COST if o.lagrangian else _WFT_COST
    sink = _InMemory(n_states, o.dtype) if o.output is None else _streamed(o.output,
                                                                           n_states)
    pager = _paging.Unpaged()  # the reference's maps, paged out during states' passes
    with sink, _connect(o.scheduler, o.timeout) as client:
        pending = None if client is None else [
            _dist()._submit_pass(client, s, plan, timeout=o.timeout)
            for s, plan in zip(series, plans, strict=True)]

        def one(k):
            s = series[k]
            n = s.n_frames
            pager.page_out()
            if client is None:
                acc = _run_pass(s, plans[k], steps.sub(n * _pass_cost(method), s.name))
            else:  # the cluster worked while this machine read the other series
                acc = pending[k].result(o.timeout)
                pending[k] = None
                steps.step(n * _pass_cost(method), f"{s.name}: one pass")
            out = _one_series(s, acc, m if k == 0 else None, window, o.max_saturation,
                              o.outliers, method, f32, steps, to_edges=o.to_edges)
            # at the carrier it was transformed at (gridstrain.phase.coupling_corrected)
            out = dataclasses.replace(out, maps=coupling_corrected(out.maps))
            if plans[k].lattice != lattice:  # a state at its own carrier (_carrier)
                out = dataclasses.replace(out, maps=demodulated_in_place(out.maps, lattice))
            warnings.extend(out.warnings)
            return out, acc

        r, ref_pass = one(0)
        if not r.maps.valid.any():
            raise ValueError(f"{r.name}: no valid pixel: the mask, the band of margin = "
                             f"{o.margin:g} sigmas (sigma {sigma:.4g} px) and the grid's "
                             "modulus leave no pixel to measure")
        noise = _Noise(o.noise_model, lattice, r.mask, warnings)
        r = noise.complete(r)
        if o.output is not None and n_states and method in ("B", "C"):
            # nothing reads the reference's maps while a state's frames are transformed,
            # the pass that needs the most memory: they wait in a temporary file beside
            # the result, paged in again by the system when the kinematics read them
            paged = _paging.page({"psi": r.maps.psi, "dphi": r.maps.dphi},
                                 folder=sink.path.parent)
            if paged is not None:
                pager = paged
                r = dataclasses.replace(r, maps=dataclasses.replace(r.maps, **paged.arrays))
        done = [r.summary()]
        pager.page_out()  # the noise floor transforms the reference's halves
        floor = _ReferenceFloor(r, done[0], ref_pass, lattice, window, method,
                                steps.sub(3 * _WFT_COST, "noise floor"), warnings,
                                to_edges=o.to_edges)
        del ref_pass
        r = floor.r  # without its variance map: the floor keeps the smoothed one
        tracker = _Tracker(r.maps, r.stats.mean, r.mask, lattice, o.order, o.lagrangian)
        cracks: list[tuple] = []
        matches: list[dict] = []
        alias = aliasing_bias(r.stats.mean, lattice, sigma=sigma, mask=r.mask)
        for i in range(n_states):
            c, acc = one(i + 1)
            del acc
            c = noise.complete(c)
            res, rec, notes, found, match = _kinematics(tracker, c, guesses[i], lattice,
                                                        done[0], o.outliers)
            cracks.append(found)
            matches.append(match)
            c = c.dropping("mean")  # the image features and the pair check were its uses
            pager.page_out()  # the uncertainty maps read back the moduli only
            if o.output is not None:
                # the file keeps no phase maps, and the state's derivatives serve its
                # kinematics only: freed before its uncertainty maps are made
                res = dataclasses.replace(res, reference=None, deformed=None)
                c = c.without_derivatives()
            warnings.extend(notes)
            steps.step(kin, f"{c.name}: kinematics")
            if o.output is not None and not res.valid.any():  # never a file
                raise ValueError(empty_state_message(c.name, o.margin, sigma, rec.guess,
                                                     rec.source))
            done.append(c.summary())
            sink.add(i, *floor.state(c, done[-1], res, rec, alias, warnings))
            del c
            if o.order == "series" and i + 1 < n_states:
                # a small field is kept as measured (the bits the file holds); a large
                # one is read back from the file when the next state needs it
                small = res.u.nbytes <= _FOLLOW_IN_MEMORY
                tracker.follow(res, done[-1].name, None if small else sink.reader(i))
            del res
        warnings.extend(tracker.finish())
        if method == "A":
            warnings.extend(_contrast_notes([d.vib for d in done]))
        for d in done:
            warnings.extend(d.saturation_warnings)
        progress(1.0, "done")
        return sink.result(
            lattice=lattice, lattice_detected=o.detected, sigma=sigma, method=method,
            lagrangian=o.lagrangian, margin=float(o.margin), mask=r.mask.copy(),
            reference_image=np.array(r.stats.mean), names=tuple(d.name for d in done),
            sources=tuple(d.sources for d in done), n_frames=tuple(d.T for d in done),
            bit_depth=tuple(d.bit_depth for d in done), scale=tuple(d.scale for d in done),
            saturation=tuple(d.saturation for d in done),
            excluded=tuple(d.excluded for d in done),
            screening=tuple(d.screening for d in done), vibration=tuple(d.vib for d in done),
            noise=floor.noise_floor(done, noise.info(done)), parameters=o.parameters(),
            warnings=tuple(warnings), metrology=metrology(sink.floors, sigma),
            systematic={"aliasing": alias, "smoothing": sink.smoothing,
                        "vibration_offset": [d.offset for d in done], "pair_match": matches},
            state_order=o.state_order, discontinuities=tuple(cracks), **extra)


def _discontinuities(res: Measurement, rec, name: str, images, follow) -> tuple:
    """``(res, rec, regions, warnings)``: ``res`` measured again without the pixels
    whose window straddles a jump of its displacement
    (:mod:`gridstrain.kinematics`), each part the jump cuts the field into
    followed from the previous state's field pixel by pixel when ``follow`` (a
    callable giving back its ``(u, valid)``) is given and checked on its own
    content when ``images`` (reference, deformed, mask) are, the fringe order's
    record, the jumps' regions, and the warnings naming them."""
    disc = find_discontinuities(res)
    if not disc:
        return res, rec, (), []
    before = res.valid
    guess = None
    if follow is not None:
        u, valid = follow()
        nearest = nearest_index(valid)
        guess = np.stack([nearest_filled(np.asarray(c, dtype=np.float64), valid, nearest)
                          for c in u])
        del u, valid, nearest
    res = without_discontinuities(dataclasses.replace(res, fringe_order=rec), disc,
                                  guess=guess)
    del guess
    said = [f"{name}: the displacement jumps (a crack, an edge or a torn grid?) at "
            f"{disc.describe()}: the {int(disc.band.sum())} pixels whose window straddles "
            "it are left out"]
    if images is not None:
        res, parts = check_parts(res, before, images[0], images[1], mask=images[2])
        said.extend(_parts_notes(parts, name, res.lattice))
        return res, res.fringe_order, tuple(disc.regions), said
    after = ndimage.label(res.valid)[1]
    if after > ndimage.label(before)[1]:
        said.append(f"{name}: the jump cuts the field into {after} parts whose whole "
                    "numbers of periods were fixed each on its own (closest to the "
                    "guess): across an opening of more than half a pitch one of them may "
                    "be whole periods off; pass a guess or an intermediate state")
    return res, rec, tuple(disc.regions), said


def _parts_notes(parts: tuple, name: str, lattice) -> list[str]:
    """The warnings that say how each part a crack cut off was fixed."""
    if not parts:
        return []
    out = []
    for p in parts:
        if p.left_out:
            out.append(f"{name}: the part of the field at {p.describe()}, cut off by the "
                       f"jump, has no image features of its own to fix its whole periods "
                       f"({p.detail}): left out")
        elif p.confirmed and any(p.shift_px):
            out.append(f"{name}: the part of the field at {p.describe()}, cut off by the "
                       f"jump, was whole periods off: {p.detail}")
    if not any(p.confirmed for p in parts):
        p1, p2 = lattice.pitches
        out.append(f"{name}: the jump cuts the field into {len(parts)} parts and none has "
                   "image features of its own: their whole periods assume an opening below "
                   f"half a pitch (periods {p1:.3g}/{p2:.3g} px) across it: fringe order not "
                   "confirmed; pass --guess UX UY per part (guess= a field in Python), an "
                   "intermediate state, or image a grid with printed features")
    return out
