"""The measurement loop of a series: the door where every option is checked once
(:class:`~gridstrain.series.MeasureOptions`), then each series read in one pass, each state
measured against the reference and dropped once its maps are kept.

The stages and their algorithms are described in :mod:`gridstrain.series`, the public
path of :func:`measure_series`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._progress import Progress, as_finding, findings_of, null_progress
from .._runtime import paging as _paging
from .._runtime.threads import one_blas_thread
from .._validation import (
    SIGMA_PITCH_RTOL,
    check_callable,
    check_choice,
    check_float_dtype,
    check_fraction,
    check_positive,
    check_sigma,
    check_type,
)
from ..io import StateInputs, close_readers, state_inputs
from ..kinematics.tracking import SMALL_STEP, _Tracker
from ..phase import DEFAULT_MARGIN, Lattice, Window, coupling_corrected, demodulated_in_place
from ..phase.lattice import reference_carrier
from ..results import SeriesResult
from ..uncertainty import NoiseModel, aliasing_bias, metrology
from ._floors import _check_model_units, _check_noise_model, _Noise, _ReferenceFloor
from ._inputs import (
    _check_fit,
    _check_memory,
    _glob_warning,
    _guess_parameter,
    _inputs,
    _loads_and_times,
)
from ._outliers import OUTLIER_POLICIES
from ._passes import (
    _LATTICE_FRAMES,
    _WFT_COST,
    _carrier,
    _check_given_lattice,
    _check_scheduler,
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

__all__ = ["ORDERS", "MeasureOptions", "measure_series"]

#: How the states are ordered: "series" follows them in time (each state's fringe
#: order from the previous state's field), "independent" measures each on its own.
ORDERS = ("series", "independent")
# Largest fraction of saturated pixels accepted in a frame (gridstrain.io's default).
_MAX_SATURATION = 0.01
# The previous state's displacement is kept in memory up to this size, bytes (a 0.5
# Mpx field in float64), and read back from the result file above it: reading it
# twice per state costs more than the transform of a frame that small, and keeping
# it adds a constant, small amount to the peak.
_FOLLOW_IN_MEMORY = 8 * 2**20


# --------------------------------------------------------------------------- the door


def measure_series(reference, states, *, lattice: Lattice | None = None,
                   sigma: float | None = None, method: str = "A", mask=None,
                   lagrangian: bool = True, guess="auto", order: str = "series",
                   margin: float = DEFAULT_MARGIN, bit_depth: int | None = None,
                   max_saturation: float = _MAX_SATURATION, outliers: str = "exclude",
                   progress: Progress | None = None, scheduler=None, noise_model=None,
                   sigma_pitches: float | None = None,
                   timeout: float | None = None, output=None,
                   dtype=None, each_frame: bool = False,
                   reference_frames: int | None = None, keep_order: bool = False,
                   loads=None, frame_rate: float | None = None,
                   to_edges: bool = False) -> SeriesResult:
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
    lattice : Lattice, optional
        The grid's wave vectors; detected on the mean reference image by default.
    sigma : float, optional
        Window standard deviation, px (default: the pitch; at least the pitch; a
        value within a relative 1e-3 below the pitch is taken as the pitch).
    method : {"A", "B", "C"}
        "A" (paper §2.2): one windowed Fourier transform of each averaged series.
        "B" (§2.3): one transform per frame, phases and derivatives averaged.
        "C": each series averaged with its frames' carriers realigned by their
        measured rigid shifts, one transform per wave vector
        (:func:`gridstrain.stacks.method_c`): method B's precision without method
        A's contrast loss, at about twice method A's cost. Warns (in
        ``warnings``) when a series' motion is not a rigid translation.
    mask : (H, W) bool array_like or path, optional
        True (nonzero, for an image file) on the specimen, in the reference
        configuration. Regions without a grid are masked automatically on top.
    lagrangian : bool
        Large-displacement correction (:func:`gridstrain.kinematics.deformation`).
    guess : "auto", None, (2,) or (2, H, W) array_like, or a sequence of them
        Initial displacement fixing the fringe order (the whole number of periods),
        px. "auto": from the previous state in series order, else from image
        features (:func:`gridstrain.kinematics.coarse_displacement`, used only when
        confident), else the smallest displacement the phases allow, with a
        warning. None: the smallest displacement. A pair or field fixes the first
        state in series order (the others follow it) and every state in
        independent order. A sequence gives one entry per state (``"auto"`` for
        the automatic choice).
    order : {"series", "independent"}
        "series" (default): the states are load steps in time, and each state's
        fringe order comes from the previous state's displacement field, so that a
        series whose displacement changes by less than half a period between
        consecutive states is followed whatever its total motion. Every state is
        still measured against the reference (Lagrangian, no accumulation of
        error); only its guess comes from the previous one. "independent": every
        state on its own (unordered states). How each order was fixed is in
        :attr:`SeriesResult.fringe_orders`.
    margin : float
        Invalid band along borders and mask edges, in units of ``sigma``.
    bit_depth : int, optional
        Passed to :func:`gridstrain.io.open_series` for paths.
    max_saturation : float
        Largest fraction of saturated pixels accepted in any frame of a file
        series (within the mask), in [0, 1].
    outliers : {"exclude", "refuse", "warn"}
        What to do with the frames that the screening flags (every frame is checked
        against its series by :func:`gridstrain.stacks.screening.screen_frames`: no grid
        or a uniform frame, low contrast, a rigid slip, a frame of another state,
        more than ``max_saturation`` clipped pixels, at the container's ceiling or
        at a level ``2^n - 1``). "exclude" (default): leave them out of every
        average (mean, variance, method B, the noise floor's halves, ``T``) and
        name them in the warnings; a series with half its frames flagged or more
        is refused, the good ones being then unknown. "refuse": raise on any
        flagged frame. "warn": keep them, name them in the warnings, and give the
        noise floor and uncertainty maps of the states they enter as NaN. A series
        whose frames form a sequence (a steady drift or a growing deformation,
        :class:`gridstrain.stacks.screening.Trend`) is refused, but with "warn", which
        averages it with a warning. So is a state whose image, warped back by its
        measured displacement, shows nothing of the reference's content (another
        specimen: :func:`gridstrain.kinematics.pair_match`, recorded in
        ``systematic["pair_match"]``), but with "warn".
    progress : callable, optional
        ``progress(fraction, message)``.
    scheduler : str or distributed.Client, optional
        Compute each series' statistics pass (mean, variance, saturation) and
        method B's transforms on Dask: ``"local"`` (one worker process per core),
        a scheduler address ``"tcp://HOST:PORT"`` or a ``distributed.Client``
        (see :func:`gridstrain.series.connect`; needs the ``distributed``
        extra, and on a cluster workers that see the input files at the same
        paths). Every series is submitted before the first is awaited. The frame
        shifts, the lattice, method C, the noise floor and the kinematics stay on
        this machine. Results equal those without a scheduler to the rounding of sums
        added in another order.
    noise_model : NoiseModel or (K, L), optional
        The camera's noise ``Var = K l + L`` in the stored grey levels of the
        images (a :class:`gridstrain.uncertainty.NoiseModel`, e.g. from ``gridstrain
        noise``, or a pair from a datasheet). Used for every series instead of
        the noise measured in the data. Default: the temporal variance of each
        series of two frames or more, and for single frames the model estimated
        from one image (:func:`gridstrain.uncertainty.estimate_noise_image`).
    sigma_pitches : float, optional
        The window's standard deviation in pitches (``sigma = sigma_pitches x
        pitch``, at least 1), instead of ``sigma``.
    timeout : float, optional
        With a scheduler: the longest wait, s, for the cluster's result of one
        series (TimeoutError past it: a stalled cluster). None waits for ever.
    output : str, os.PathLike or gridstrain.results.ResultFile, optional
        Write the result file (:func:`gridstrain.results.save_result`'s layout)
        while measuring: each state's maps go to the file as soon as they are
        measured and leave memory, so that memory holds one state and the
        reference whatever the number of states. The returned result reads its maps
        from the file (see ``u``). The file is put at its path when the measurement
        ends, atomically; nothing is there if it fails. The measurements' phase maps
        are not kept. With methods B and C, the reference's phase maps wait in an
        unlinked temporary file in the result's folder while each state's frames
        are transformed (64 bytes a pixel in float64, paged back in by the system
        when read; nothing is left behind, whatever ends the process).
    dtype : {None, "float32", "float64"}
        Precision of the returned (and written) maps; None: that of the
        measurement (:mod:`gridstrain.conventions`). Everything is computed as
        without it; see :class:`gridstrain.results.ResultFile` for what float32
        keeps. With ``output``, a dtype writes a lossless file in that precision
        (by default the file's maps are rounded to a tenth of their std).

    each_frame : bool
        Every frame of the states' inputs (a folder, a glob, a list of files, a
        multi-page TIFF, a ``(T, H, W)`` array) is a state of its own, named after
        its file (and page): a sequence such as a high-speed record
        (:mod:`gridstrain.io`). Without it a series whose frames drift or
        deform steadily is refused rather than averaged.
    reference_frames : int, optional
        The reference is the first ``reference_frames`` frames of the record given
        as ``states`` (averaged) and every later frame is a state; ``reference``
        must then be None. Implies ``each_frame``.
    keep_order : bool
        Keep explicit files in the order given even where it is not natural.
    loads : str, os.PathLike, LoadsFile or (n_states,) array_like, optional
        The load of each state: a testing machine's export read by
        :func:`gridstrain.io.read_loads` (a :class:`gridstrain.io.LoadsFile` names
        its columns and the log's time offset), or the loads themselves (no unit).
        A log with a time column is joined to the states' times (``frame_rate`` or
        the camera's time stamps) by linear interpolation. Stored as
        :attr:`SeriesResult.load`, how it was read as
        :attr:`SeriesResult.load_source`.
    to_edges : bool
        Measure up to the specimen's edges (method A): the grid is continued beyond
        the mask's and the frame's edges by its own demodulated maps before the
        window (:func:`gridstrain.phase.transform_to_edges`), so that ``valid``
        reaches them rather than stopping ``margin`` sigmas short. The pixels within
        that band are then edge pixels (:func:`gridstrain.phase.edge_pixels` of the
        result's ``mask`` and window), exact for a uniform strain, biased by the
        strain's gradient along the edge's normal otherwise (about
        ``2.2 sigma d eps/dn`` at the edge for ``sigma`` = the pitch); recorded as
        ``parameters["to_edges"]``.
    frame_rate : float, optional
        The camera's frame rate, Hz: each state's time is its frame's number in
        the record over the rate, s (:attr:`SeriesResult.time`). Without it, states
        read from one video get its time stamps, else the loads file's time
        column (one row per state) gives the times.

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
    o = _setup(method=method, outliers=outliers, margin=margin, sigma=sigma, order=order,
               sigma_pitches=sigma_pitches, max_saturation=max_saturation, lattice=lattice,
               scheduler=scheduler, timeout=timeout, noise_model=noise_model, dtype=dtype,
               output=output, lagrangian=lagrangian, bit_depth=bit_depth, guess=guess)
    if not isinstance(to_edges, bool | np.bool_):
        raise TypeError(f"to_edges must be a bool, got {type(to_edges).__name__}")
    if to_edges and o.method != "A":
        raise ValueError(f"to_edges needs method 'A' (the averaged image is continued "
                         f"beyond the edges), got method={o.method!r}")
    o = dataclasses.replace(o, to_edges=bool(to_edges))
    o = dataclasses.replace(o, each_frame=bool(each_frame or reference_frames is not None),
                            reference_frames=reference_frames, keep_order=bool(keep_order))
    progress = null_progress if check_callable(progress, "progress") is None else progress
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
    warnings = [as_finding(n, "input", s.name) for s in series for n in getattr(s, "notes", ())]
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



@dataclass(frozen=True, eq=False)
class MeasureOptions:
    """The options of :func:`measure_series`, checked once at the door (:func:`_setup`) and
    passed inward. The lattice, ``sigma`` and the transform's :class:`Window` are
    completed by :func:`_window` once the reference is seen; every transform of the
    measurement then takes ``window``.

    A new option is a keyword of :func:`measure_series`, a field here (checked in
    :func:`_setup`, recorded by :meth:`parameters`) and, when it shapes the transform, a
    field of :class:`~gridstrain.phase.Window`.
    """

    method: str
    outliers: str
    margin: float
    sigma: float | None
    order: str
    sigma_pitches: float | None
    max_saturation: float
    lattice: Lattice | None
    detected: bool
    scheduler: object
    timeout: float | None
    noise_model: NoiseModel | None
    dtype: np.dtype | None
    output: object
    lagrangian: bool
    bit_depth: int | None
    guess: object
    each_frame: bool = False
    reference_frames: int | None = None
    keep_order: bool = False
    state_order: str = "given"
    window: Window | None = None
    to_edges: bool = False

    def parameters(self) -> dict:
        """The options as the result records them."""
        lat = self.lattice
        return {
            "sigma": float(self.sigma), "method": self.method,
            "lagrangian": bool(self.lagrangian), "guess": _guess_parameter(self.guess),
            "order": self.order, "margin": float(self.margin),
            "max_saturation": float(self.max_saturation), "bit_depth": self.bit_depth,
            "outliers": self.outliers,
            "lattice": None if self.detected else {"k1": list(lat.k1), "k2": list(lat.k2)},
            "noise_model": None if self.noise_model is None else self.noise_model.as_dict(),
            "sigma_pitches": self.sigma_pitches,
            "dtype": None if self.dtype is None else str(self.dtype),
            "each_frame": bool(self.each_frame), "reference_frames": self.reference_frames,
            "keep_order": bool(self.keep_order), "to_edges": bool(self.to_edges)}


def _setup(*, method, outliers, margin, sigma, order, sigma_pitches, max_saturation,
           lattice, scheduler, timeout, noise_model, dtype, output, lagrangian, bit_depth,
           guess) -> MeasureOptions:
    """The options of :func:`measure_series`, checked."""
    check_choice(method, "method", ("A", "B", "C"))
    check_choice(outliers, "outliers", OUTLIER_POLICIES)
    check_choice(order, "order", ORDERS)
    margin = check_positive(margin, "margin")
    sigma = check_positive(sigma, "sigma", allow_none=True)
    if sigma_pitches is not None:
        if sigma is not None:
            raise ValueError(f"give sigma or sigma_pitches, not both (got sigma={sigma!r}, "
                             f"sigma_pitches={sigma_pitches!r})")
        sigma_pitches = check_positive(sigma_pitches, "sigma_pitches")
        if sigma_pitches < 1 - SIGMA_PITCH_RTOL:
            raise ValueError(f"sigma_pitches must be at least 1 (the window must hold one "
                             f"period), got {sigma_pitches!r}")
        sigma_pitches = max(sigma_pitches, 1.0)
    max_saturation = check_fraction(max_saturation, "max_saturation")
    check_type(lattice, "lattice", Lattice, allow_none=True)
    if sigma is not None and lattice is not None:
        sigma = check_sigma(sigma, lattice.pitch)
    dtype = check_float_dtype(dtype, "dtype")
    if output is not None:
        from ..results import ResultFile

        output = output if isinstance(output, ResultFile) else ResultFile(output)
        if dtype is not None and output.dtype is not None and output.dtype != dtype:
            raise ValueError(f"dtype={dtype} and output's dtype={output.dtype} disagree")
        dtype = output.dtype if dtype is None else dtype
        # a precision asked for is kept as it is: a lossless file
        output = dataclasses.replace(output, dtype=dtype,
                                     lossless=output.lossless or dtype is not None)
    return MeasureOptions(method=method, outliers=outliers, margin=margin, sigma=sigma, order=order,
                  sigma_pitches=sigma_pitches, max_saturation=max_saturation,
                  lattice=lattice, detected=lattice is None,
                  scheduler=_check_scheduler(scheduler),
                  timeout=check_positive(timeout, "timeout", allow_none=True),
                  noise_model=_check_noise_model(noise_model), dtype=dtype, output=output,
                  lagrangian=bool(lagrangian), bit_depth=bit_depth, guess=guess)



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
    tracker: _Tracker | None = None
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
        run.tracker = _Tracker(r.maps, r.stats.mean, r.mask, lattice, o.order, o.lagrangian)
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
        # at the carrier it was transformed at (gridstrain.phase.coupling_corrected)
        out = dataclasses.replace(out, maps=coupling_corrected(out.maps))
        if self.plans[k].lattice != o.lattice:  # a state at its own carrier (_carrier)
            out = dataclasses.replace(out, maps=demodulated_in_place(out.maps, o.lattice))
        self.run.warnings.extend(findings_of(out.warnings, "screening.flagged", s.name))
        return out, acc
