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
from dataclasses import dataclass

import numpy as np

from .._progress import Progress, as_finding, findings_of, null_progress
from .._runtime import paging as _paging
from .._runtime.threads import one_blas_thread
from .._validation import check_sigma
from ..io import StateInputs, close_readers, state_inputs
from ..kinematics.tracking import SMALL_STEP, Tracker
from ..phase import Lattice, Window, coupling_corrected, demodulated_in_place
from ..phase.lattice import reference_carrier
from ..results import SeriesResult
from ..uncertainty import aliasing_bias, metrology
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
    _pass_cost,
    _plan,
    _run_pass,
    _Steps,
)
from ._sinks import _InMemory, _streamed
from ._stages import _Policy, _State, measure_state, stages_cost

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
    # how the frames were read (colour converted, lossy JPEG), series by series: each
    # note said of the series (a record's state) it was read for
    warnings = [as_finding(n, "input").restated(n, state=s.name)
                for s in series for n in getattr(s, "notes", ())]
    warnings += findings_of(given.warnings, "input")
    if not (each_frame or given.reference is not None or reference_frames):
        warnings += findings_of(_glob_warning(series), "input")
    o = dataclasses.replace(o, state_order=given.order)
    extra, notes = _loads_and_times(loads, frame_rate, series, each_frame=o.each_frame,
                                    first_frame=o.reference_frames or 0)
    warnings += findings_of(notes, "input")
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


def _total_cost(series: list, o: MeasureOptions) -> float:
    """The measurement's cost for its progress: reading a frame costs 1, a transform
    about 4 frames' worth."""
    total = min(series[0].n_frames, _LATTICE_FRAMES) + 1.0
    for s in series:
        total += s.n_frames * _pass_cost(o.method) + 2 * _WFT_COST
    total += (len(series) - 1) * stages_cost()
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


@dataclass(eq=False)
class _Run:
    """What the stages of every state share (:mod:`gridstrain.series._stages`): the
    options, the reference's tracker, noise and floor, the sink, the summaries of the
    series measured so far and the findings."""

    o: MeasureOptions
    n_states: int
    steps: _Steps
    warnings: list
    sink: object
    pager: object
    noise: _Noise
    floor: _ReferenceFloor | None = None
    tracker: Tracker | None = None
    policy: _Policy | None = None
    alias: dict | None = None
    done: list = dataclasses.field(default_factory=list)
    follow_in_memory: int = _FOLLOW_IN_MEMORY

    @property
    def lattice(self) -> Lattice:
        return self.o.lattice


def _measure(series: list, guesses: list, m: np.ndarray, o: MeasureOptions, steps: _Steps,
             warnings: list, progress: Progress, extra: dict) -> SeriesResult:
    """One pass over every series (screening, shifts, statistics, the halves of the
    noise floor, method B's or C's sums), the flagged frames then taken out; the
    states measured one after the other by :data:`STAGES`, each dropped once stored."""
    lattice, window, method, n_states = o.lattice, o.window, o.method, len(series) - 1
    carriers, doubts = _carriers(series, lattice, warnings)
    plans = [_plan(s, carriers[k] or lattice, method, window, m, k == 0)
             for k, s in enumerate(series)]
    _check_model_units(o.noise_model, series)
    sink = _InMemory(n_states, o.dtype) if o.output is None else _streamed(o.output,
                                                                           n_states)
    with sink, _connect(o.scheduler, o.timeout) as client:
        run = _Run(o, n_states, steps, warnings, sink, _paging.Unpaged(), None,
                   follow_in_memory=_FOLLOW_IN_MEMORY)
        one = _Series(series, plans, o, m, steps, client, run)
        r, ref_pass = one(0)
        if not r.maps.valid.any():
            raise ValueError(f"{r.name}: no valid pixel: the mask, the band of margin = "
                             f"{o.margin:g} sigmas (sigma {window.sigma:.4g} px) and the "
                             "grid's modulus leave no pixel to measure")
        run.noise = _Noise(o.noise_model, lattice, r.mask, warnings)
        r = _paged_reference(run, run.noise.complete(r))
        run.done.append(r.summary())
        run.pager.page_out()  # the noise floor transforms the reference's halves
        run.floor = _ReferenceFloor(r, run.done[0], ref_pass, lattice, window, method,
                                    steps.sub(3 * _WFT_COST, "noise floor"), warnings,
                                    to_edges=o.to_edges)
        del ref_pass
        r = run.floor.r  # without its variance map: the floor keeps the smoothed one
        run.tracker = Tracker(r.maps, r.stats.mean, r.mask, lattice, o.order, o.lagrangian)
        run.alias = aliasing_bias(r.stats.mean, lattice, sigma=window.sigma, mask=r.mask)
        run.policy = _Policy(n_states, o.order, all(s.n_frames == 1 for s in series[1:]))
        cracks, matches = [], []
        for i in range(n_states):
            # the state's maps held by its _State alone, which drops each after its use
            st = measure_state(run, _State(i, one(i + 1)[0], guesses[i],
                                           carrier_doubt=doubts[i]))
            cracks.append(st.found)
            matches.append(st.match)
            run.done.append(st.summary)
            del st
        warnings += [*run.tracker.finish(), *run.policy.finding()]
        done = run.done
        if method == "A":
            warnings += findings_of(_contrast_notes([d.vib for d in done]), "contrast.vibration")
        for d in done:
            warnings += findings_of(d.saturation_warnings, "saturation", d.name)
        progress(1.0, "done")
        return sink.result(
            lattice=lattice, lattice_detected=o.detected, sigma=window.sigma, method=method,
            lagrangian=o.lagrangian, margin=float(o.margin), mask=r.mask.copy(),
            reference_image=np.array(r.stats.mean), names=tuple(d.name for d in done),
            sources=tuple(d.sources for d in done), n_frames=tuple(d.T for d in done),
            bit_depth=tuple(d.bit_depth for d in done), scale=tuple(d.scale for d in done),
            saturation=tuple(d.saturation for d in done),
            excluded=tuple(d.excluded for d in done),
            screening=tuple(d.screening for d in done), vibration=tuple(d.vib for d in done),
            noise=run.floor.noise_floor(done, run.noise.info(done)),
            parameters=o.parameters(), warnings=tuple(warnings),
            metrology=metrology(sink.floors, window.sigma),
            systematic={"aliasing": run.alias, "smoothing": sink.smoothing,
                        "vibration_offset": [d.offset for d in done], "pair_match": matches},
            state_order=o.state_order, discontinuities=tuple(cracks), **extra)


def _carriers(series: list, lattice: Lattice, warnings: list) -> tuple[list, list]:
    """Each series' own carrier (None: the reference's), its warning kept, and for
    each state whether its carrier is in doubt: beyond a plausible strain, or moved
    from the previous state's by more than a small step across the frame (the
    phase across the frame changes by ``|dK| W`` periods)."""
    if len(series) < 2:
        return [None], []
    base = reference_carrier(next(iter(series[0].frames(start=0, stop=1))), lattice)
    out, doubts, before = [None], [], lattice.K
    for s in series[1:]:
        own, notes = _carrier(s, lattice, base)
        out.append(own)
        K = lattice.K if own is None else own.K
        doubts.append(bool(notes) or
                      float(np.max(np.abs(K - before))) * max(s.shape) > SMALL_STEP)
        before = K
        warnings += findings_of(notes, "carrier.implausible", s.name)
    return out, doubts


def _paged_reference(run: _Run, r):
    """The reference with its maps paged out to a temporary file beside the result
    while the states' frames are transformed (methods B and C with a file)."""
    o = run.o
    if o.output is None or not run.n_states or o.method not in ("B", "C"):
        return r
    # nothing reads the reference's maps while a state's frames are transformed, the
    # pass that needs the most memory: they wait in a temporary file beside the
    # result, paged in again by the system when the kinematics read them
    paged = _paging.page({"psi": r.maps.psi, "dphi": r.maps.dphi},
                         folder=run.sink.path.parent)
    if paged is None:
        return r
    run.pager = paged
    return dataclasses.replace(r, maps=dataclasses.replace(r.maps, **paged.arrays))


class _Series:
    """``one(k)``: series ``k`` read in its pass (here, or awaited from the cluster
    that worked while this machine read the others), screened, averaged and
    transformed: ``(_Measured, its pass)``."""

    def __init__(self, series, plans, o: MeasureOptions, m, steps: _Steps, client,
                 run: _Run):
        self.series, self.plans, self.o, self.m, self.steps = series, plans, o, m, steps
        self.client, self.run = client, run
        self.f32 = all(np.dtype(s.dtype) == np.float32 for s in series)
        self.pending = None if client is None else [
            _dist()._submit_pass(client, s, plan, timeout=o.timeout)
            for s, plan in zip(series, plans, strict=True)]

    def __call__(self, k: int):
        s, o, steps = self.series[k], self.o, self.steps
        n = s.n_frames
        self.run.pager.page_out()
        if self.client is None:
            acc = _run_pass(s, self.plans[k], steps.sub(n * _pass_cost(o.method), s.name))
        else:
            acc = self.pending[k].result(o.timeout)
            self.pending[k] = None
            steps.step(n * _pass_cost(o.method), f"{s.name}: one pass")
        out = _one_series(s, acc, self.m if k == 0 else None, o.window, o.max_saturation,
                          o.outliers, o.method, self.f32, steps, to_edges=o.to_edges)
        # at the carrier it was transformed at (gridstrain.phase.coupling_corrected); a
        # frame transformed in float32 (_one_series) gets its float64 maps there
        out = dataclasses.replace(out, maps=coupling_corrected(
            out.maps, dtype=np.float32 if self.f32 else np.float64))
        if self.plans[k].lattice != o.lattice:  # a state at its own carrier (_carrier)
            out = dataclasses.replace(out, maps=demodulated_in_place(out.maps, o.lattice))
        # the phase maps' weight of two transforms: 1.5 for the transform (_one_series),
        # 0.5 here, so that the correction's time is reported by its own name
        steps.step(0.5 * _WFT_COST, f"{s.name}: coupling correction")
        self.run.warnings.extend(findings_of(out.warnings, "screening.flagged", s.name))
        return out, acc
