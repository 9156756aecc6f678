"""The options of :func:`~gridstrain.series.measure_series`, each declared once.

Every option is one :class:`Option`: its name (the keyword of ``measure_series``
and the field of :class:`MeasureOptions`), its default, its check, its text in the
documentation, the command-line flag and configuration-file key it has (the key is
the flag without its dashes), and whether the result records it (and a replay takes
it back) or it only says how to run. ``measure_series``'s keywords, its docstring's
parameters, :class:`MeasureOptions`, :meth:`MeasureOptions.parameters` and
:meth:`MeasureOptions.from_parameters`, and ``gridstrain measure``'s arguments and
configuration keys all come from :data:`OPTIONS`. A new option is one entry there.

The checks are in one place: each option's own (its type and range) in its entry,
run whenever a :class:`MeasureOptions` is made, and those between options in
:func:`check_together`. Both take the name to use in their messages, so that the
command line names its flags and a configuration file its keys.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import math
import numbers
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from .._validation import (
    SIGMA_PITCH_RTOL,
    check_callable,
    check_choice,
    check_float_dtype,
    check_fraction,
    check_int,
    check_positive,
    check_sigma,
    check_type,
)
from ..io import LoadsFile
from ..phase import DEFAULT_MARGIN, Lattice
from ..uncertainty import NoiseModel
from ._floors import _check_noise_model
from ._inputs import _guess_parameter
from ._outliers import OUTLIER_POLICIES
from ._passes import _check_scheduler

__all__ = ["OPTIONS", "MeasureOptions", "Option", "check_together", "unknown_option"]

#: How the states are ordered: "series" follows them in time (each state's fringe
#: order from the previous state's field), "independent" measures each on its own.
ORDERS = ("series", "independent")
METHODS = ("A", "B", "C")
# Largest fraction of saturated pixels accepted in a frame (gridstrain.io's default).
_MAX_SATURATION = 0.01
# Seconds the command waits for a cluster's result of one series: an hour covers
# thousands of method-B transforms on a few workers, and ends a stalled run.
_COMMAND_TIMEOUT = 3600.0


@dataclass(frozen=True, repr=False)
class Option:
    """One option of :func:`~gridstrain.series.measure_series`, declared once.

    Attributes
    ----------
    name : str
        The keyword of ``measure_series`` and the field of :class:`MeasureOptions`.
    default : object
        Its value when not given.
    check : callable
        ``check(value, name) -> value``: the value checked (and normalised, e.g. an
        int to a float); its errors name ``name`` (the keyword, a flag or a key).
    doc : str
        Its entry in ``measure_series``'s Parameters: the type line, then the text
        (empty for an option of a command alone, such as ``gridstrain measure``'s
        ``--pixel-size``).
    flag : str or None
        The command-line flag that gives it as it is (``--sigma``); its key in a
        configuration file is the flag without the dashes. None where the command
        line builds it from flags of its own (``via``) or cannot give it.
    kind : str
        How the command line and a TOML file give the value: ``"float"``,
        ``"int"``, ``"bool"`` (a switch), ``"str"``, ``"path"``, ``"choice"``,
        ``"method"``.
    help : str
        The flag's help.
    metavar : str or None
        The flag's value's name in the help.
    group : str
        The section of ``gridstrain measure --help`` the flag is in.
    recorded : bool
        Stored in the result's ``parameters`` and taken back by a replay
        (``measure --config RESULT``); False for what only says how to run (the
        output, the cluster, the progress) or is stored in the result otherwise
        (the mask).
    record, replay : callable
        The value as the result records it (JSON-friendly) and back.
    via : tuple of str
        The command-line flags the option is built from, where it has no ``flag``.
    choices : tuple of str
        The values allowed, for a ``"choice"`` or ``"method"`` kind (its check
        refuses the others).
    command_default : object
        The command line's default where it is not ``default`` (None: the same).
    """

    name: str
    default: object
    check: Callable
    doc: str
    flag: str | None = None
    kind: str = "str"
    help: str = ""
    metavar: str | None = None
    group: str = "specimen"
    recorded: bool = True
    record: Callable = lambda v: v
    replay: Callable = lambda v: v
    via: tuple = ()
    choices: tuple = ()
    command_default: object = None

    def __repr__(self) -> str:
        return f"Option({self.name!r}, flag={self.flag!r})"

    @property
    def key(self) -> str | None:
        """The key in a configuration file (``sigma-pitches``), or None."""
        return None if self.flag is None else self.flag[2:]


# ----------------------------------------------------------------------- the checks


def _any(value, name):
    return value


def _bool(value, name):
    if not isinstance(value, bool | np.bool_):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _choice(choices):
    def check(value, name):
        return check_choice(value, name, choices)
    return check


def _method(value, name):
    if isinstance(value, str):
        value = value.upper()
    return check_choice(value, name, METHODS)


def _positive_or_none(value, name):
    return check_positive(value, name, allow_none=True)


def _count_or_none(value, name):
    return None if value is None else check_int(value, name, minimum=1)


def _bit_depth(value, name):
    if value is None:
        return None
    bits = check_int(value, name, minimum=1)
    if bits > 32:
        raise ValueError(f"{name} must be between 1 and 32, got {bits}")
    return bits


def _text_or_none(value, name):
    if value is not None and (not isinstance(value, str) or not value):
        raise TypeError(f"{name} must be a non-empty string or None, got {value!r}")
    return value


def _finite(value, name):
    if isinstance(value, bool) or not isinstance(value, numbers.Real) \
            or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def _sigma_pitches(value, name):
    if value is None:
        return None
    value = check_positive(value, name)
    if value < 1 - SIGMA_PITCH_RTOL:
        raise ValueError(f"{name} must be at least 1 (the window must hold one period), "
                         f"got {value!r}")
    return max(value, 1.0)


def _lattice(value, name):
    return check_type(value, name, Lattice, allow_none=True)


def _noise_model(value, name):
    return _check_noise_model(value)


def _scheduler(value, name):
    if isinstance(value, str) and not value.strip():
        raise ValueError(f"{name} must be 'local' or a scheduler address such as "
                         f"'tcp://HOST:PORT', got {value!r}")
    return _check_scheduler(value)


def _output(value, name):
    if value is None:
        return None
    from ..results import ResultFile  # the results import the series' face

    return value if isinstance(value, ResultFile) else ResultFile(value)


def _dtype(value, name):
    return check_float_dtype(value, name)


def _loads(value, name):
    """A loads file (a path or a :class:`LoadsFile`), or one finite load per state."""
    if value is None or isinstance(value, LoadsFile):
        return value
    if isinstance(value, str | os.PathLike):
        if not os.fspath(value):
            raise ValueError(f"{name} must be a loads file's path, got ''")
        return os.fspath(value)
    try:
        load = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a loads file (a path or a LoadsFile) or one "
                        f"number per loaded state, got {value!r}") from None
    if load.ndim != 1 or not np.all(np.isfinite(load)):
        raise ValueError(f"{name} must hold one finite number per loaded state, got "
                         f"shape {load.shape}")
    return tuple(float(v) for v in load)


# --------------------------------------------------------------- records and replays


def _float_or_none(v):
    return None if v is None else float(v)


def _lattice_record(lat):
    return None if lat is None else {"k1": list(lat.k1), "k2": list(lat.k2)}


def _lattice_replay(rec):
    return None if rec is None else Lattice(tuple(rec["k1"]), tuple(rec["k2"]))


def _noise_replay(rec):
    if rec is None:
        return None
    return NoiseModel(K=rec["K"], L=rec["L"], method=rec.get("method", "given"),
                      scale=rec.get("scale", 1.0), bit_depth=rec.get("bit_depth"))


def _guess_replay(rec):
    if isinstance(rec, list) and rec and all(isinstance(v, list | str) or v is None
                                             for v in rec):
        return [_guess_replay(v) for v in rec]
    if isinstance(rec, list):
        return (float(rec[0]), float(rec[1]))
    if rec == "field":  # a (2, H, W) field is not kept in the parameters
        raise ValueError("a guess given as a field is not recorded; pass it again")
    return rec


def _loads_record(v):
    if v is None:
        return None
    if isinstance(v, str):
        return os.path.abspath(os.path.expanduser(v))
    return list(v)


def _loads_replay(rec):
    return tuple(rec) if isinstance(rec, list) else rec


# --------------------------------------------------------------------- the declaration

_SIGMA_DOC = """sigma : float, optional
    Window standard deviation, px (default: the pitch; at least the pitch; a
    value within a relative 1e-3 below the pitch is taken as the pitch)."""

#: Every option of :func:`~gridstrain.series.measure_series`, in the order of its
#: documentation.
OPTIONS: tuple[Option, ...] = (
    Option("lattice", None, _lattice, """lattice : Lattice, optional
    The grid's wave vectors; detected on the mean reference image by default.""",
           group="window", via=("--pitch", "--angle", "--k1", "--k2"),
           record=_lattice_record, replay=_lattice_replay),
    Option("sigma", None, _positive_or_none, _SIGMA_DOC, flag="--sigma", kind="float",
           metavar="PX", group="window", record=_float_or_none,
           help="window standard deviation, px (default and minimum: the pitch)"),
    Option("sigma_pitches", None, _sigma_pitches, """sigma_pitches : float, optional
    The window's standard deviation in pitches (``sigma = sigma_pitches x
    pitch``, at least 1), instead of ``sigma``.""", flag="--sigma-pitches",
           kind="float", metavar="X", group="window", record=_float_or_none,
           help="window standard deviation in pitches (sigma = X pitch, X >= 1), instead "
           "of --sigma"),
    Option("method", "A", _method, """method : {"A", "B", "C"}
    "A" (paper §2.2): one windowed Fourier transform of each averaged series.
    "B" (§2.3): one transform per frame, phases and derivatives averaged.
    "C": each series averaged with its frames' carriers realigned by their
    measured rigid shifts, one transform per wave vector
    (:func:`gridstrain.stacks.method_c`): method B's precision without method
    A's contrast loss, at about twice method A's cost. Warns (in
    ``warnings``) when a series' motion is not a rigid translation.""",
           flag="--method", kind="method", group="window", choices=METHODS,
           help="A: transform of the averaged images (default); B: transform of every "
           "frame, averaged; C: frames averaged with their carriers realigned by their "
           "measured shifts (B's precision, no vibration contrast loss, about twice A's "
           "cost)"),
    Option("margin", DEFAULT_MARGIN, check_positive, """margin : float
    Invalid band along borders and mask edges, in units of ``sigma``.""",
           flag="--margin", kind="float", metavar="N", group="window", record=float,
           help=f"invalid band at borders and mask edges, in sigmas (default "
           f"{DEFAULT_MARGIN:g})"),
    Option("to_edges", False, _bool, """to_edges : bool
    Measure up to the specimen's edges (method A): the grid is continued beyond
    the mask's and the frame's edges by its own demodulated maps before the
    window (:func:`gridstrain.phase.transform_to_edges`), so that ``valid``
    reaches them rather than stopping ``margin`` sigmas short. The pixels within
    that band are then edge pixels (:func:`gridstrain.phase.edge_pixels` of the
    result's ``mask`` and window), exact for a strain uniform or linear in space,
    biased by its second derivative along the edge's normal otherwise (about
    ``-4.1 sigma^2 eps''`` at the edge for ``sigma`` = the pitch). The grid's
    harmonics are not continued: a print far from a sine (a square or ``sin^3``
    profile, a checkerboard) keeps part of the cut window's bias there, up to
    several 1e-3 of strain; the reference's is measured and said (finding
    ``edges.harmonics``, its bound). The mask's outermost pixels that show the grid
    in part (a mask drawn at the specimen's edge) are continued over (finding
    ``edges.partial``).""",
           flag="--to-edges", kind="bool", group="window",
           help="measure up to the specimen's edges (method A): the grid continued beyond "
           "them by its own phase before the window; the band of --margin sigmas is then "
           "edge pixels, exact for a strain uniform or linear in space on a grid close to "
           "a sine, biased by about -4.1 sigma^2 times the strain's second derivative "
           "normal to the edge; a print with strong harmonics (square lines, a "
           "checkerboard) keeps part of the cut window's bias there, up to several 1e-3, "
           "stated (edges.harmonics)"),
    Option("mask", None, _any, """mask : (H, W) bool array_like or path, optional
    True (nonzero, for an image file) on the specimen, in the reference
    configuration. Regions without a grid are masked automatically on top. Not in
    ``parameters``: the result stores the mask applied.""",
           via=("--mask", "--roi", "--roi-polygon"), recorded=False),
    Option("lagrangian", True, _bool, """lagrangian : bool
    Large-displacement correction (:func:`gridstrain.kinematics.deformation`).""",
           via=("--no-lagrangian",)),
    Option("guess", "auto", _any, """\
guess : "auto", None, (2,) or (2, H, W) array_like, or a sequence of them
    Initial displacement fixing the fringe order (the whole number of periods),
    px. "auto": from the previous state in series order, else from image
    features (:func:`gridstrain.kinematics.coarse_displacement`, used only when
    confident), else the smallest displacement the phases allow, with a
    warning. None: the smallest displacement. A pair or field fixes the first
    state in series order (the others follow it) and every state in
    independent order. A sequence gives one entry per state (``"auto"`` for
    the automatic choice). Checked against the states and the frames; a field is
    recorded as ``"field"``.""", via=("--guess",), record=_guess_parameter,
           replay=_guess_replay),
    Option("order", "series", _choice(ORDERS), """order : {"series", "independent"}
    "series" (default): the states are load steps in time, and each state's
    fringe order comes from the previous state's displacement field, so that a
    series whose displacement changes by less than half a period between
    consecutive states is followed whatever its total motion. Every state is
    still measured against the reference (Lagrangian, no accumulation of
    error); only its guess comes from the previous one. "independent": every
    state on its own (unordered states). How each order was fixed is in
    :attr:`SeriesResult.fringe_orders`.""", flag="--order", kind="choice",
           metavar="ORDER", choices=ORDERS,
           help="'series' (default): the states are load steps in time, each state's "
           "fringe order followed from the previous one; 'independent': unordered "
           "states, each on its own"),
    Option("max_saturation", _MAX_SATURATION, check_fraction, """max_saturation : float
    Largest fraction of saturated pixels accepted in any frame of a file
    series (within the mask), in [0, 1].""", flag="--max-saturation", kind="float",
           metavar="FRACTION", record=float,
           help=f"largest fraction of saturated pixels accepted in a frame, in [0, 1] "
           f"(default {_MAX_SATURATION:g}); photos of white paper clip between the lines"),
    Option("bit_depth", None, _bit_depth, """bit_depth : int, optional
    Significant bits of the camera, 1 to 32, passed to
    :func:`gridstrain.io.open_series` for paths (default: detected).""",
           flag="--bit-depth", kind="int", metavar="BITS",
           help="significant bits of the camera (default: detected)"),
    Option("outliers", "exclude", _choice(OUTLIER_POLICIES), """\
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
    ``systematic["pair_match"]``), but with "warn".""", flag="--outliers",
           kind="choice", choices=OUTLIER_POLICIES, metavar="POLICY",
           help="frames that do not belong to their series (no grid, low contrast, a "
           "slip, another state's frame, clipped): 'exclude' them with a warning "
           "(default; a series with half its frames flagged is refused), 'refuse' the "
           "run, or 'warn' and keep them (noise floor then not stated)"),
    Option("each_frame", False, _bool, """each_frame : bool
    Every frame of the states' inputs (a folder, a glob, a list of files, a
    multi-page TIFF, a ``(T, H, W)`` array) is a state of its own, named after
    its file (and page): a sequence such as a high-speed record
    (:mod:`gridstrain.io`). Without it a series whose frames drift or
    deform steadily is refused rather than averaged.""", flag="--each-frame",
           kind="bool", group="sequence",
           help="every frame of the DEF inputs (a folder, a glob, a multi-page TIFF, a "
           "video, a Phantom cine or Photron MRAW record) is a state of its own, named "
           "after its file (and page): a high-speed record or a load-step series. Without "
           "it a DEF whose frames drift or deform steadily is refused, never averaged"),
    Option("reference_frames", None, _count_or_none, """reference_frames : int, optional
    The reference is the first ``reference_frames`` frames of the record given
    as ``states`` (averaged) and every later frame is a state; ``reference``
    must then be None. Implies ``each_frame``.""", flag="--reference-frames",
           kind="int", metavar="N", group="sequence",
           help="the reference is the first N frames of the record (REF, then any DEF, "
           "read as one record), averaged; every later frame is a state (implies "
           "--each-frame)"),
    Option("keep_order", False, _bool, """keep_order : bool
    Keep explicit files in the order given even where it is not natural.""",
           flag="--keep-order", kind="bool", group="sequence",
           help="keep explicit files in the order given (default: files whose names form "
           "one numbered family, as a shell lists frame_1 frame_10 frame_2, are measured "
           "in natural order)"),
    Option("loads", None, _loads, """\
loads : str, os.PathLike, LoadsFile or (n_states,) array_like, optional
    The load of each state: a testing machine's export read by
    :func:`gridstrain.io.read_loads` (``load_column``, ``time_column`` and
    ``loads_offset`` say how, or a :class:`gridstrain.io.LoadsFile`), or the loads
    themselves (no unit). A log with a time column is joined to the states' times
    (``frame_rate`` or the camera's time stamps) by linear interpolation. Stored as
    :attr:`SeriesResult.load`, how it was read as :attr:`SeriesResult.load_source`
    (with the file's SHA-256); recorded as the file's absolute path or the
    numbers.""", flag="--loads", kind="path", metavar="FILE.csv", group="sequence",
           record=_loads_record, replay=_loads_replay,
           help="the load of each state: a testing machine's export as it comes (',', "
           "';', tab or spaces between columns, decimal comma, preamble lines, units in "
           "the header: 'Force (kN)', 'Zeit [ms]'); a log with a time column is joined to "
           "the states' times (--frame-rate or the camera's) by linear interpolation; else "
           "one row per state in order or a 'state' column naming them"),
    Option("load_column", None, _text_or_none, """load_column : str, optional
    The loads file's load column (default: the one named load, force or Kraft).""",
           flag="--load-column", metavar="NAME", group="sequence",
           help="the load column's name (default: the one named load, force or Kraft)"),
    Option("time_column", None, _text_or_none, """time_column : str, optional
    The loads file's time column (default: the one named time or Zeit).""",
           flag="--time-column", metavar="NAME", group="sequence",
           help="the time column's name (default: the one named time or Zeit)"),
    Option("loads_offset", 0.0, _finite, """loads_offset : float
    The time on the loads file's clock at the camera's time zero, s (a log started
    0.2 s before the camera's trigger: 0.2).""", flag="--loads-offset", kind="float",
           metavar="SECONDS", group="sequence", record=float,
           help="the time on the log's clock at the camera's time zero, s (a log started "
           "0.2 s before the camera's trigger: 0.2; default 0)"),
    Option("frame_rate", None, _positive_or_none, """frame_rate : float, optional
    The camera's frame rate, Hz: each state's time is its frame's number in
    the record over the rate, s (:attr:`SeriesResult.time`). Needs
    ``each_frame``. Without it, states read from one video get its time stamps,
    else the loads file's time column (one row per state) gives the times.""",
           flag="--frame-rate", kind="float", metavar="HZ", group="sequence",
           record=_float_or_none,
           help="the camera's frame rate: each state's time is its frame's number in the "
           "record over the rate, s (with --each-frame; default: the times a video or "
           "camera record holds)"),
    Option("noise_model", None, _noise_model, """noise_model : NoiseModel or (K, L), optional
    The camera's noise ``Var = K l + L`` in the stored grey levels of the
    images (a :class:`gridstrain.uncertainty.NoiseModel`, e.g. from ``gridstrain
    noise``, or a pair from a datasheet). Used for every series instead of
    the noise measured in the data. Default: the temporal variance of each
    series of two frames or more, and for single frames the model estimated
    from one image (:func:`gridstrain.uncertainty.estimate_noise_image`).""",
           group="noise", via=("--noise", "--noise-model"),
           record=lambda m: None if m is None else m.as_dict(), replay=_noise_replay),
    Option("dtype", None, _dtype, """dtype : {None, "float32", "float64"}
    Precision of the returned (and written) maps; None: that of the
    measurement (:mod:`gridstrain.conventions`). Everything is computed as
    without it; see :class:`gridstrain.results.ResultFile` for what float32
    keeps. With ``output``, a dtype writes a lossless file in that precision
    (by default the file's maps are rounded to a tenth of their std).""",
           flag="--dtype", kind="choice", choices=("float32", "float64"), group="output",
           record=lambda d: None if d is None else str(d),
           help="store the maps losslessly in this precision (implies --lossless). "
           "float32 keeps u below 1024 px to 3.1e-5 px and strain to 3e-8"),
    Option("output", None, _output, """\
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
    when read; nothing is left behind, whatever ends the process). Run-only.""",
           group="output", via=("--output", "--lossless", "--phase-maps"), recorded=False),
    Option("progress", None, check_callable, """progress : callable, optional
    ``progress(fraction, message)``. Run-only.""", group="output", recorded=False),
    Option("scheduler", None, _scheduler, """scheduler : str or distributed.Client, optional
    Compute each series' statistics pass (mean, variance, saturation) and
    method B's transforms on Dask: ``"local"`` (one worker process per core),
    a scheduler address ``"tcp://HOST:PORT"`` or a ``distributed.Client``
    (see :func:`gridstrain.series.connect`; needs the ``distributed``
    extra, and on a cluster workers that see the input files at the same
    paths). Every series is submitted before the first is awaited. The frame
    shifts, the lattice, method C, the noise floor and the kinematics stay on
    this machine. Results equal those without a scheduler to the rounding of sums
    added in another order. Run-only.""", flag="--scheduler", metavar="ADDRESS",
           group="distributed", recorded=False,
           help="compute the statistics and method B's transforms on Dask: 'local' (a "
           "worker per core) or a scheduler's tcp://HOST:PORT, whose workers must see the "
           "input files at the same paths"),
    Option("timeout", None, _positive_or_none, """timeout : float, optional
    With a scheduler: the longest wait, s, for the cluster's result of one
    series (TimeoutError past it: a stalled cluster). None waits for ever.
    Run-only.""", flag="--timeout", kind="float", metavar="SECONDS",
           group="distributed", recorded=False, command_default=_COMMAND_TIMEOUT,
           help="with --scheduler, give up on a cluster that returns no result for a "
           f"series within SECONDS (default {_COMMAND_TIMEOUT:g})"),
)

_BY_NAME = {o.name: o for o in OPTIONS}
# Completed by the measurement once the reference is seen, never given.
_COMPLETED = ("detected", "window", "state_order")


def _post_init(self) -> None:
    for o in OPTIONS:
        object.__setattr__(self, o.name, o.check(getattr(self, o.name), o.name))
    if self.detected is None:
        object.__setattr__(self, "detected", self.lattice is None)


def _parameters(self) -> dict:
    """The recorded options, JSON-friendly, as the result stores them
    (:attr:`SeriesResult.parameters`)."""
    out = {o.name: o.record(getattr(self, o.name)) for o in OPTIONS if o.recorded}
    if self.detected:  # the lattice found on the reference is the result's, not an option
        out["lattice"] = None
    return out


def _from_parameters(cls, parameters: Mapping, **overrides) -> MeasureOptions:
    """The options a result's ``parameters`` record, with ``overrides`` (the run-only
    ones: ``output``, ``progress``, ``scheduler``...) on top: the same measurement
    again. A window ``sigma`` recorded beside ``sigma_pitches`` is the one it gave,
    and is left for the measurement to derive again."""
    values = {}
    for o in OPTIONS:
        if o.recorded and o.name in parameters:
            values[o.name] = o.replay(parameters[o.name])
    if values.get("sigma_pitches") is not None:
        values.pop("sigma", None)
    unknown_option(overrides)
    values.update(overrides)
    return cls(**values)


def _options_class():
    fields = [(o.name, object, dataclasses.field(default=o.default)) for o in OPTIONS]
    fields += [("detected", object, dataclasses.field(default=None, repr=False)),
               ("window", object, dataclasses.field(default=None, repr=False)),
               ("state_order", str, dataclasses.field(default="given", repr=False))]
    doc = ("The options of :func:`~gridstrain.series.measure_series` (each field an\n"
           "entry of :data:`~gridstrain.series.OPTIONS`, documented there), every one\n"
           "checked when made. ``measure_series(ref, states, options, **overrides)``\n"
           "takes one; :meth:`parameters` is what the result records,\n"
           ":meth:`from_parameters` the options back from it. The measurement completes\n"
           "``lattice``, ``sigma``, ``detected`` (the lattice was detected), ``window``\n"
           "(the transform's :class:`~gridstrain.phase.Window`) and ``state_order`` once\n"
           "the reference is seen.\n")
    return dataclasses.make_dataclass(
        "MeasureOptions", fields, frozen=True, eq=False,
        namespace={"__doc__": doc, "__module__": __name__, "__post_init__": _post_init,
                   "parameters": _parameters,
                   "from_parameters": classmethod(_from_parameters)})


MeasureOptions = _options_class()


def unknown_option(given: Mapping) -> None:
    """Refuse, in one TypeError, a keyword that is not an option, naming the close
    ones."""
    bad = [k for k in given if k not in _BY_NAME]
    if not bad:
        return
    k = bad[0]
    close = difflib.get_close_matches(k, list(_BY_NAME), n=3, cutoff=0.6)
    hint = (f"; did you mean {' or '.join(close)}?" if close else "")
    raise TypeError(f"measure_series got an unknown option {k!r}{hint} (the options: "
                    f"{', '.join(_BY_NAME)})")


def check_together(o: MeasureOptions, *, label: Callable[[str], str] = str
                   ) -> MeasureOptions:
    """``o`` with the checks between options done: what one option's value
    forbids or needs of another. ``label(name)`` is how a message names an option
    (its flag on the command line)."""
    if o.sigma is not None and o.sigma_pitches is not None:
        raise ValueError(f"give {label('sigma')} or {label('sigma_pitches')}, not both "
                         f"(got {o.sigma!r} and {o.sigma_pitches!r})")
    # what the measurement completes, from these options (a replace() carries the
    # values of the options it was made from)
    changes: dict = {"detected": o.lattice is None, "window": None}
    if o.sigma is not None and o.lattice is not None:
        changes["sigma"] = check_sigma(o.sigma, o.lattice.pitch, label("sigma"))
    if o.to_edges and o.method != "A":
        raise ValueError(f"{label('to_edges')} needs method 'A' (the averaged image is "
                         f"continued beyond the edges), got {label('method')} {o.method!r}")
    each_frame = o.each_frame or o.reference_frames is not None
    if o.frame_rate is not None and not each_frame:
        raise ValueError(f"{label('frame_rate')} needs one frame per state "
                         f"({label('each_frame')}), got {o.frame_rate!r}")
    changes["each_frame"] = each_frame
    loads = o.loads
    joined = {"load_column": o.load_column, "time_column": o.time_column,
              "loads_offset": o.loads_offset or None}
    given = [n for n, v in joined.items() if v is not None]
    if isinstance(loads, LoadsFile):
        if given:
            raise ValueError(f"give {label(given[0])} in the LoadsFile given as "
                             f"{label('loads')}, not beside it")
        changes.update(loads=os.fspath(loads.path), load_column=loads.load_column,
                       time_column=loads.time_column,
                       loads_offset=float(loads.offset))
    elif given and not isinstance(loads, str):
        raise ValueError(f"{label(given[0])} needs {label('loads')} (a loads file)")
    if o.output is not None:
        out, dtype = o.output, o.dtype
        if dtype is not None and out.dtype is not None and out.dtype != dtype:
            raise ValueError(f"{label('dtype')}={dtype} and {label('output')}'s "
                             f"dtype={out.dtype} disagree")
        dtype = out.dtype if dtype is None else dtype
        # a precision asked for is kept as it is: a lossless file
        changes.update(dtype=dtype, output=dataclasses.replace(
            out, dtype=dtype, lossless=out.lossless or dtype is not None))
    return dataclasses.replace(o, **changes)


def loads_file(o: MeasureOptions):
    """The loads as :func:`measure_series` reads them: a :class:`LoadsFile` with
    its columns, the numbers, or None."""
    if isinstance(o.loads, str):
        return LoadsFile(os.path.expanduser(o.loads), load_column=o.load_column,
                         time_column=o.time_column, offset=o.loads_offset)
    return o.loads


def options_signature(func) -> inspect.Signature:
    """``func(reference, states, options=None, **overrides)``'s signature with the
    overrides spelt out: every option, keyword-only, with its default."""
    sig = inspect.signature(func)
    fixed = [p for p in sig.parameters.values() if p.kind is not p.VAR_KEYWORD]
    keywords = [inspect.Parameter(o.name, inspect.Parameter.KEYWORD_ONLY, default=o.default)
                for o in OPTIONS]
    return sig.replace(parameters=[*fixed, *keywords])


def parameters_doc() -> str:
    """The Parameters entries of the options, for ``measure_series``'s docstring."""
    return "\n".join(o.doc for o in OPTIONS)


