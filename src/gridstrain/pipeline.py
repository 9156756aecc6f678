"""From a lab's image series to strain maps: the library side of ``gridstrain measure``.

A *series* is a set of frames of one static state of the specimen (a camera
taking ``T`` images of the reference, then ``T`` of each loaded state). The
pipeline measures every loaded state against the reference, diagnoses the
vibrations of every series and states the noise floor of the maps. Conventions
(axes, signs, the Lagrangian description, units) are those of
:mod:`gridstrain.conventions`; frames are streamed, never held whole.

For each series
    1. If no lattice is given, the reference frames are averaged (streamed) and
       the lattice detected on the mean image.
    2. Screening and vibrations, in one read of every frame
       (:func:`gridstrain.screening.screen_frames`): each frame is checked against
       its series (a grid, its contrast, a rigid slip, the non-rigid residual of a
       frame of another state, clipping at the ceiling or at a level ``2^n - 1``)
       and the flagged frames are excluded, refused or kept with a warning
       (``outliers``); every later pass sees the frames kept only. The rigid
       translation ``(alpha_t, beta_t)`` of every frame comes from the phase of one
       global Fourier coefficient per wave vector, as in
       :func:`gridstrain.vibration.frame_shifts`, no windowed Fourier transform per
       frame. Paper eq. (2): frame ``t`` is ``s(x + alpha_t, y + beta_t)``.
    3. Statistics (streamed): the mean image, the per-pixel sensor noise variance
       (see *Noise floor*) and the saturated fraction of every frame.
    4. Phase maps. Method A (paper §2.2): the windowed Fourier transform of the
       mean image. Method B (§2.3): one transform per frame, averaged
       (:func:`gridstrain.stacks.method_b` when available). Regions without a grid
       (modulus below a quarter of the median, e.g. a hole) are masked
       automatically so that the validity margin applies around them.
    5. Kinematics: :func:`gridstrain.kinematics.deformation` with the
       large-displacement (Lagrangian) correction, every state against the
       reference. The fringe order (the whole number of periods the phases cannot
       see) comes, by default, from the previous state's displacement field
       (incremental tracking: a load step that moves the specimen by less than half
       a period anywhere is followed, whatever the total motion), for the first
       state from image features when they are conclusive
       (:func:`gridstrain.kinematics.coarse_displacement`), else it is the smallest
       displacement the phases allow, flagged as not confirmed with a warning.

Fringe order
    :attr:`SeriesResult.fringe_orders` says, per state, where the order came from
    and whether it is *confirmed*: given by the user; fixed by image features that
    clearly beat their aliases one or two periods away and agree with the phases;
    or followed from a confirmed previous state with a displacement change below
    ``_MAX_STEP`` = 0.4 period at every pixel (or with image features agreeing).
    Conclusive image features that put the specimen half a period or more from
    zero override the tracking when the two disagree (the step was more than half
    a period), with a warning; features that say "no motion" do not (content fixed
    to the camera can say that), and the state is not confirmed.
    A state that is not confirmed may be off by whole periods; a warning says what
    to do. A step of more than 0.6 period between states without image features
    would be followed one period off and cannot be detected from the phases alone.

Noise floor
    Two estimates, both one standard deviation of the map's random error at a
    pixel, for ``T_ref`` reference frames and ``T`` frames of the state:

    - **theory**: the windowed-Fourier noise of :func:`gridstrain.theory.wft_noise_std`
      with the image noise variance ``v / T`` (Prop. 2.3) and the measured median
      modulus ``|Psi|`` of each series (which includes the vibrations' contrast
      loss), carried through eqs. (34)-(35). ``v`` is measured in the data: the
      temporal variance of each pixel, averaged over the valid pixels, after
      regressing out the first-order effect of the measured frame shifts,
      ``v_t(x) - mean = grad s(x) . (a_t - mean a) + noise`` (a least-squares
      fit per pixel on the two shift components, ``T - 3`` degrees of freedom).
      Without that regression a vibration of 0.05 px on a grid of pitch 5 would
      pass for sensor noise. It needs ``T >= 4`` (plain temporal variance for
      ``T = 2, 3``; nothing for ``T = 1``, where the state is assumed as noisy as
      the reference).
    - **split**: an empirical check that assumes nothing about the noise: the
      reference frames are split into two halves, each averaged, and the second
      half is measured against the first. The result is pure error (the specimen
      did not move, a rigid vibration offset aside, which is removed as the map's
      mean), and its spatial standard deviation over the valid pixels, scaled by
      ``sqrt((1/T_ref + 1/T) / (1/T_1 + 1/T_2))``, is the floor of a state of
      ``T`` frames whose noise per frame is the reference's. Needs ``T_ref >= 2``.
      Its own sampling error is about ``1 / sqrt(2 N)`` relative, ``N`` being the
      number of independent windows in the valid region (tens on a small image).

    Separately, the vibrations leave a phase offset ``delta`` constant over the
    map (eqs. 26-31): its standard deviation, Prop. 2.4 with ``Var(mean alpha) =
    Var(alpha) / T``, is reported as ``vibration_u`` (px). It shifts the
    displacement map as a whole (a rigid translation) and does not reach the
    strain (eq. 27).

Spatial resolution
    The maps are the true fields convolved with the Gaussian window
    (eqs. 24-25). The spatial resolution ``d`` is the field's: the period of a sine
    displacement the window damps by 10 %, ``pi sigma sqrt(2 / ln(1 / 0.9)) =
    13.69 sigma`` px (:func:`gridstrain.uncertainty.metrology`); the window's full
    width at half maximum, ``2.355 sigma``, and ``sigma`` itself are stored beside
    it under their own names.

Per-pixel uncertainty maps (``ux_std``, ``uy_std``, ``exx_std``, ``eyy_std``,
``exy_std``) come from :func:`gridstrain.uncertainty.predict_uncertainty`: the
measured per-pixel noise variance of each series (vibrations regressed out),
averaged with the weight ``g^2`` the window gives each pixel and divided by ``T``,
over the local modulus ``|Psi|``. They are :attr:`SeriesResult.uncertainty`, saved
next to the maps by :func:`save_result`.

Where the noise variance comes from (``NoiseFloor.model``)
    - a camera model given by the user (``noise_model``: a
      :class:`gridstrain.noise.NoiseModel` from ``gridstrain noise``, or ``(K, L)``
      in stored grey levels): every series' variance is ``K mean + L``;
    - otherwise the temporal variance of each series of two frames or more, and
      for the series of a single frame the model ``Var = K l + L`` estimated from
      one image (:func:`gridstrain.noise.estimate_noise_image`, on the first
      single-frame series: the camera is the same), evaluated at the image.

    So every state gets its maps, its noise floor and its metrological figures,
    whatever ``T``.

Metrological figures (``SeriesResult.metrology``, :func:`gridstrain.uncertainty.metrology`)
    Per state and map: the resolution (median predicted std), the spatial
    resolution ``d`` (10 % attenuation period), the window's FWHM and the 10-90 %
    width of a step, and the metrological
    efficiency indicator ``sigma_u d`` (displacement) or ``sigma_e d^2``
    (strain), px^2, independent of ``sigma``.

Systematic errors (``SeriesResult.systematic``)
    The uncertainty maps cover noise only. Two biases are estimated and warned
    about where they can exceed the noise: the harmonics of sharp lines aliasing
    onto the carrier (:func:`gridstrain.uncertainty.aliasing_bias`, from the
    reference image's spectrum, or a bound where the profile cannot be seen),
    and the window's smoothing of strain gradients, ``sigma^2 / 2 lap(e)``
    (:func:`gridstrain.uncertainty.smoothing_bias`, from the measured field).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import numbers
import os
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage

from . import _memory, _paging, theory
from ._progress import null_progress
from ._stats import median
from ._threads import map_bounded, one_blas_thread
from ._validation import (
    SIGMA_PITCH_RTOL,
    check_callable,
    check_choice,
    check_float_dtype,
    check_fraction,
    check_mask,
    check_positive,
    check_sigma,
    check_type,
    check_workers,
)
from ._wft import _wft
from .accumulate import PassPlan, SeriesPass
from .discontinuities import find_discontinuities, without_discontinuities
from .io import (
    FrameSeries,
    open_series,
    read_mask,
)
from .kinematics import (
    FringeOrder,
    Measurement,
    _CoarseReference,
    _eulerian_gradient,
    _from_estimate,
    _Handover,
    _phase_products,
    _phase_shift,
    _small_strain,
    _solve,
    deformation,
)
from .lattice import Lattice, _reference_carrier, _state_carrier, detect_lattice
from .noise import NoiseModel, estimate_noise_image
from .screening import FrameScreen
from .sequences import StateInputs, state_inputs
from .stacks import _FrameOrder, method_b
from .uncertainty import (
    _D_PER_SIGMA,
    _FWHM,
    NoiseFloor,
    _displacement_strain_std,
    _nearest_filled,
    _phase_variance,
    aliasing_bias,
    metrology,
    smoothing_bias,
)
from .vibration import VibrationReport
from .vibration import _report as _vibration_report
from .wft import DEFAULT_MARGIN, PhaseMaps, demodulated_at, finite_derivatives, wft

__all__ = [
    "FWHM_PER_SIGMA",
    "MAP_FIELDS",
    "ORDERS",
    "SPATIAL_RESOLUTION_PER_SIGMA",
    "NoiseFloor",
    "SeriesResult",
    "VibrationDiagnostics",
    "measure_series",
    "reference_lattice",
    "save_csv",
    "save_result",
    "state_names",
]

Progress = Callable[[float, str], None]

#: Full width at half maximum of a Gaussian over its standard deviation,
#: ``2 sqrt(2 ln 2)``: the window's FWHM is this times sigma.
FWHM_PER_SIGMA = _FWHM
#: Spatial resolution over sigma, ``pi sqrt(2 / ln(1 / 0.9))`` = 13.69: the period
#: of a sine displacement the window damps by 10 %.
SPATIAL_RESOLUTION_PER_SIGMA = _D_PER_SIGMA
#: Names of the maps, in file order, with their units before ``pixel_size``.
MAP_FIELDS = {"ux": "px", "uy": "px", "exx": "1", "eyy": "1", "exy": "1"}

# A pixel holds no grid when its modulus, for either wave vector, is below this
# fraction of the median modulus (the threshold gridstrain.wft uses for validity):
# such regions (holes, specimen edges, stains) are masked and get the margin.
_NO_GRID_MODULUS = 0.25
# A state followed from the previous one is confirmed only if its displacement
# changed by at most this many periods (along each wave vector) at every pixel: the
# phase change is taken within half a period of the previous field, and the margin of
# 0.1 period covers noise and a step that is not quite uniform. A larger change may
# be a step of more than half a period, followed one period off.
_MAX_STEP = 0.4
#: How the states are ordered: "series" follows them in time (each state's fringe
#: order from the previous state's field), "independent" measures each on its own.
ORDERS = ("series", "independent")
# A given lattice must show a modulus this many times larger than at the same
# frequencies turned by 45 degrees, where a grid or checkerboard has no harmonic:
# noise alone gives about 1, the mean of a 12-bit grid image hundreds.
_MIN_GRID_CONTRAST = 5.0
# Aliasing of the lines' harmonics is flagged only above this displacement error, px
# (when the noise is lower still): below it no measurement can tell it from noise.
_ALIAS_MIN_PX = 1e-3
# Largest fraction of saturated pixels accepted in a frame (gridstrain.io's default).
_MAX_SATURATION = 0.01


# --------------------------------------------------------------------------- results


#: The vibrations of one series: :class:`gridstrain.vibration.VibrationReport`, named
#: after the series (kept under this name for existing code).
VibrationDiagnostics = VibrationReport


@dataclass(frozen=True, eq=False)
class SeriesResult:
    """Displacement and strain maps of every loaded state against the reference.

    Attributes
    ----------
    u : (n_states, 2, H, W) float ndarray
        ``(u_x, u_y)`` per state, px, Lagrangian; NaN where not ``valid``. float32
        when every series holds float32 frames, float64 otherwise (precision in
        :mod:`gridstrain.conventions`).
    strain : (n_states, 3, H, W) float ndarray
        ``(e_xx, e_yy, e_xy)`` per state, dimensionless (tensor shear).
    valid : (n_states, H, W) bool ndarray
        With ``measure_series(..., output=...)`` these three, the uncertainty maps
        and the measurements' maps are :class:`gridstrain.results.StoredMaps`:
        read from the result file when indexed (``result.u[i]`` reads state
        ``i``), ``numpy.asarray`` reading the whole.
    lattice : Lattice
    lattice_detected : bool
        Whether the lattice was detected (True) or given.
    sigma : float
        Window standard deviation, px.
    method : {"A", "B", "C"}
    lagrangian : bool
    margin : float
        Invalid band along borders and mask edges, in units of ``sigma``.
    mask : (H, W) bool ndarray
        The specimen mask used for the reference: the given one, less the regions
        found without a grid.
    reference_image : (H, W) float64 ndarray
        Mean reference frame, raw grey levels (for display).
    names : tuple of str
        ``("reference", name of state 0, ...)``: folder or file names
        (:func:`state_names`).
    sources : tuple of tuple of str
        The files of each series (empty for arrays given in memory).
    n_frames : tuple of int
        ``T`` of each series, reference first.
    bit_depth, scale : tuple
        Of each series (:class:`gridstrain.io.FrameSeries`; ``None``/1 for arrays).
    saturation : tuple of float
        Largest saturated fraction of a frame in each series.
    measurements : tuple of Measurement
        One per state, with its phase maps and iterations.
    guesses : tuple of (float, float)
        The initial displacement that fixed each state's fringe order (median of
        the guess field), px.
    guess_sources : tuple of str
        Where each guess came from: ``fringe_orders[i].source``.
    vibration : tuple of VibrationReport
        One per series, reference first.
    noise : NoiseFloor
    parameters : dict
        Every option of the measurement, as given.
    warnings : tuple of str
        Things the user should know that did not stop the measurement.
    excluded : tuple of tuple of int
        Per series, the numbers of the frames the screening excluded (their files
        and reasons are in ``warnings``); ``n_frames`` counts the frames kept.
    screening : tuple of gridstrain.screening.FrameScreen
        Per series, what the screening measured on every frame (excluded ones
        included).
    uncertainty : dict of str to ndarray, optional
        Per-pixel predicted standard deviations ``"ux_std"``, ``"uy_std"`` (px),
        ``"exx_std"``, ``"eyy_std"``, ``"exy_std"``, each ``(n_states, H, W)``, NaN
        where not valid; ``None`` when no noise variance could be had (a single
        frame per series whose noise could not be estimated, and no model given).
    metrology : dict, optional
        Per state and per map: resolution (median predicted std), spatial
        resolution (10 % attenuation period, window FWHM and 10-90 % step width,
        px) and the metrological
        efficiency indicator (:func:`gridstrain.uncertainty.metrology`).
    systematic : dict, optional
        Estimated systematic errors that the uncertainty maps do not cover:
        harmonic aliasing onto the carrier and the window's smoothing of strain
        gradients (:func:`gridstrain.uncertainty.aliasing_bias`,
        :func:`gridstrain.uncertainty.smoothing_bias`).
    fringe_orders : tuple of FringeOrder
        How each state's whole number of periods was fixed and whether anything
        confirms it (see :class:`gridstrain.kinematics.FringeOrder`).
    state_order : {"natural", "reordered", "given"}
        The order the states were measured in: natural order (folders, globs, a
        numbered family of files already in it), explicit files put in natural
        order from the order given, or the order given kept
        (:mod:`gridstrain.sequences`).
    load : (n_states,) float64 ndarray, optional
        The load of each state, in ``load_unit`` (``measure_series(loads=...)``).
    load_unit : str, optional
        The unit of ``load`` (``"N"``, ``"kN"``...); None without loads or when
        they were given without a unit.
    time : (n_states,) float64 ndarray, optional
        The time of each state, s: from the loads file's ``time [s]`` column or
        the frame rate (frame number in the record over the rate).
    discontinuities : tuple of tuple of dict
        Per state, the displacement jumps found (a crack, an edge, a torn grid):
        their bounding boxes (``rows``, ``cols``: first and last, px), the pixels
        left out around them (``pixels``, invalid in ``valid``) and the jump
        (``jump_px``, modulo a pitch); see
        :func:`gridstrain.discontinuities.find_discontinuities`.
    """

    u: np.ndarray
    strain: np.ndarray
    valid: np.ndarray
    lattice: Lattice
    lattice_detected: bool
    sigma: float
    method: str
    lagrangian: bool
    margin: float
    mask: np.ndarray
    reference_image: np.ndarray
    names: tuple[str, ...]
    sources: tuple[tuple[str, ...], ...]
    n_frames: tuple[int, ...]
    bit_depth: tuple[int | None, ...]
    scale: tuple[int, ...]
    saturation: tuple[float, ...]
    measurements: tuple[Measurement, ...] = field(repr=False)
    guesses: tuple[tuple[float, float], ...]
    guess_sources: tuple[str, ...]
    vibration: tuple[VibrationReport, ...]
    noise: NoiseFloor
    parameters: dict
    warnings: tuple[str, ...] = ()
    uncertainty: dict | None = None
    fringe_orders: tuple[FringeOrder, ...] = ()
    excluded: tuple[tuple[int, ...], ...] = ()
    screening: tuple = field(default=(), repr=False)
    metrology: dict | None = None
    systematic: dict | None = None
    state_order: str = "given"
    load: np.ndarray | None = None
    load_unit: str | None = None
    time: np.ndarray | None = None
    discontinuities: tuple = ()

    def __post_init__(self):
        for name in ("u", "strain", "valid", "mask", "reference_image", "load", "time"):
            arr = getattr(self, name)
            if isinstance(arr, np.ndarray):  # maps read from a file are read-only already
                arr.flags.writeable = False

    @property
    def n_states(self) -> int:
        """Number of loaded states."""
        return int(self.u.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the maps."""
        return tuple(self.valid.shape[1:])

    def get_map(self, name: str) -> np.ndarray:
        """The ``(n_states, H, W)`` map of one of :data:`MAP_FIELDS`."""
        check_choice(name, "name", tuple(MAP_FIELDS))
        i = tuple(MAP_FIELDS).index(name)
        return self.u[:, i] if i < 2 else self.strain[:, i - 2]

    @property
    def ux(self) -> np.ndarray:
        """(n_states, H, W) displacement along x, px."""
        return self.u[:, 0]

    @property
    def uy(self) -> np.ndarray:
        """(n_states, H, W) displacement along y, px."""
        return self.u[:, 1]

    @property
    def exx(self) -> np.ndarray:
        """(n_states, H, W) normal strain along x."""
        return self.strain[:, 0]

    @property
    def eyy(self) -> np.ndarray:
        """(n_states, H, W) normal strain along y."""
        return self.strain[:, 1]

    @property
    def exy(self) -> np.ndarray:
        """(n_states, H, W) shear strain (tensor component)."""
        return self.strain[:, 2]

    def save(self, path, **options):
        """Write this result to its HDF5 file (:func:`gridstrain.results.save_result`)."""
        from .results import save_result as _save

        return _save(self, path, **options)

    def to_xarray(self, **options):
        """This result as an ``xarray.Dataset`` (:func:`gridstrain.results.to_xarray`);
        needs ``gridstrain[xarray]``."""
        from .results import to_xarray

        return to_xarray(self, **options)

    def plot(self, name: str = "exx", **options):
        """Maps of ``name`` for every state on common colour limits
        (:func:`gridstrain.plotting.plot_states`); returns a matplotlib Figure."""
        from .plotting import plot_states

        return plot_states(self, name, **options)

    def __repr__(self) -> str:
        H, W = self.shape
        valid = ", ".join(f"{v.mean():.1%}" for v in self.valid)
        return (f"SeriesResult({self.n_states} state(s) of {H}x{W}, method {self.method}, "
                f"sigma={self.sigma:.4g} px, frames {list(self.n_frames)}, valid {valid})")


# --------------------------------------------------------------------------- inputs


class _ArraySeries:
    """Frames held in memory, behaving like a :class:`gridstrain.io.FrameSeries`."""

    bit_depth = None
    scale = 1
    saturation_level = None
    paths: tuple = ()

    def __init__(self, data, name: str):
        arr = np.asarray(data)
        if arr.dtype == bool or arr.dtype.kind not in "uif":
            raise TypeError(f"{name} must hold real grey levels, got dtype {arr.dtype}")
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[0] < 1:
            raise ValueError(f"{name} must be one (H, W) frame or a (T, H, W) stack, got "
                             f"shape {np.shape(data)}")
        if min(arr.shape[1:]) < 8:
            raise ValueError(f"{name} frames must be at least 8 x 8 pixels, got "
                             f"{arr.shape[1:]}")
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} has NaN or infinite pixels; frames must hold finite "
                             "grey levels")
        self.name = name
        self.dtype = arr.dtype
        self.shape = (int(arr.shape[1]), int(arr.shape[2]))
        self._data = arr
        self._numbers = np.arange(arr.shape[0])  # frames kept, numbered in ``data``
        if arr.dtype.kind in "ui":  # the container's ceiling, for the screening
            self.saturation_level = int(np.iinfo(arr.dtype).max)

    @property
    def n_frames(self) -> int:
        return int(self._numbers.size)

    def __len__(self) -> int:
        return self.n_frames

    def _number(self, j: int) -> int:
        return int(self._numbers[j])

    def describe_frame(self, i: int) -> str:
        return f"frame {self._number(i)}"

    def subset(self, indices) -> _ArraySeries:
        out = object.__new__(_ArraySeries)
        out.__dict__.update(self.__dict__)
        out._numbers = self._numbers[np.asarray(indices, dtype=int)]
        return out

    def frames(self, *, dtype=np.float64, start: int = 0, stop: int | None = None):
        return (np.array(self._data[t], dtype=dtype) for t in self._numbers[start:stop])

    def mean(self, *, start: int = 0, stop: int | None = None, progress=None):
        sub = self._numbers[start:stop]
        acc = np.zeros(self.shape)
        for t in sub:
            acc += self._data[t]
        return acc / len(sub)


def _as_series(source, name: str, bit_depth):
    if isinstance(source, FrameSeries):
        return source
    if isinstance(source, np.ndarray):
        return _ArraySeries(source, name)
    if isinstance(source, str | os.PathLike | list | tuple):
        return open_series(source, name=name, bit_depth=bit_depth)
    raise TypeError(f"{name} must be a FrameSeries, a path, a glob pattern, a list of "
                    f"files or an array of frames, got {type(source).__name__}")


def _check_one_guess(guess, what: str):
    """One state's guess: "auto", None, a finite (u_x, u_y) pair or a (2, H, W) field."""
    if isinstance(guess, str):
        check_choice(guess, what, ("auto",))
        return guess
    if guess is None:
        return None
    try:
        g = np.asarray(guess, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be 'auto', None, a (u_x, u_y) pair or a (2, H, W) "
                         f"field in px, got {guess!r}") from None
    if not (g.shape == (2,) or (g.ndim == 3 and g.shape[0] == 2)) \
            or not np.all(np.isfinite(g)):
        raise ValueError(f"{what} must be 'auto', None, a finite (u_x, u_y) pair or a "
                         f"finite (2, H, W) field in px, got shape {g.shape}")
    return (float(g[0]), float(g[1])) if g.shape == (2,) else g


def _is_per_state(guess) -> bool:
    """A sequence of per-state guesses, rather than one pair (numbers) or one field."""
    if isinstance(guess, str) or guess is None or isinstance(guess, np.ndarray):
        return False
    if isinstance(guess, Sequence):
        return not all(isinstance(v, numbers.Real) and not isinstance(v, bool)
                       for v in guess)
    return False


def _check_guess(guess, n_states: int, order: str) -> list:
    """One guess per state ("auto", None, a pair or a field).

    A single guess fixes the first state in series order (the others follow it) and
    every state in independent order.
    """
    if _is_per_state(guess):
        if len(guess) != n_states:
            raise ValueError(f"guess must hold one entry per loaded state ({n_states}), "
                             f"got {len(guess)}")
        return [_check_one_guess(g, f"guess[{i}]") for i, g in enumerate(guess)]
    g = _check_one_guess(guess, "guess")
    if order == "series":
        return [g] + ["auto"] * (n_states - 1)
    return [g] * n_states


def _guess_parameter(guess):
    """The guess as given, JSON-friendly (a field is recorded as "field")."""
    if _is_per_state(guess):
        return [_guess_parameter(g) for g in guess]
    if isinstance(guess, str) or guess is None:
        return guess
    g = np.asarray(guess, dtype=float)
    return [float(g[0]), float(g[1])] if g.shape == (2,) else "field"


def _source_name(source, i: int) -> str:
    """A state's name from its folder or file (``"state i"`` for arrays)."""
    if isinstance(source, FrameSeries):
        return source.name
    if isinstance(source, list | tuple) and source \
            and all(isinstance(p, str | os.PathLike) for p in source):
        paths = [Path(os.fspath(p)) for p in source]
        parents = {p.parent for p in paths}
        if len(paths) > 1 and len(parents) == 1 and paths[0].parent.name:
            return paths[0].parent.name
        return paths[0].stem or f"state {i}"
    if isinstance(source, str | os.PathLike):
        p = Path(os.path.expanduser(os.fspath(source)))
        if p.is_dir():
            return p.resolve().name or f"state {i}"
        if any(ch in p.name for ch in "*?[") and p.parent.name \
                and not any(ch in str(p.parent) for ch in "*?["):
            return p.parent.name  # "run3/*.tif": the folder names the state
        return p.stem or f"state {i}"
    return f"state {i}"


def state_names(states) -> list[str]:
    """Names of the loaded states, after their folder or file stem, made unique.

    Arrays are named ``"state i"``; a name that repeats (or ``"reference"``) gets
    ``" (2)"``, ``" (3)"``... appended.
    """
    seen = {"reference": 1}
    out = []
    for i, src in enumerate(states):
        base = _source_name(src, i)
        name = base
        while name in seen:
            seen[base] = seen.get(base, 1) + 1
            name = f"{base} ({seen[base]})"
        seen[name] = 1
        out.append(name)
    return out


def _glob_warning(series) -> list[str]:
    """Warn when a shell glob seems to have made every frame a state of its own: the
    reference and every state are single frames of one folder, numbered alike."""
    if len(series) < 3 or not all(isinstance(s, FrameSeries) for s in series):
        return []
    if any(s.n_frames != 1 or len(s.paths) != 1 for s in series):
        return []
    if len({Path(s.paths[0]).resolve().parent for s in series}) != 1:
        return []
    # numbered frames of one acquisition (img_001, img_002...), not ref/load1/load2
    if len({re.sub(r"\d+", "#", Path(s.paths[0]).stem) for s in series}) != 1:
        return []
    folder = Path(series[0].paths[0]).parent
    return [f"the reference and all {len(series) - 1} states are single frames of one "
            f"folder ({folder}): if they are frames of one series, the shell expanded an "
            f"unquoted glob; quote it (\"{folder}/*.tif\") or pass the folder, and give "
            "each state its own folder or quoted glob"]


def _min_side(sigma: float, margin: float) -> int:
    """Smallest frame side, px, with a valid pixel: a band of ``margin`` sigmas each side."""
    return 2 * math.ceil(margin * sigma) + 1


def _check_fit(shape, sigma, margin: float, guesses=()) -> None:
    """Refuse, before any frame is read, a window or a guess that cannot fit the frames."""
    H, W = shape
    if sigma is not None and min(H, W) < _min_side(sigma, margin):
        top = (min(H, W) - 1) / (2 * margin)
        raise ValueError(f"sigma must be at most {top:.4g} px for frames of {H} x {W} px "
                         f"(the window and its invalid band of margin = {margin:g} sigmas "
                         f"on each side must leave a pixel), got {sigma:.4g}")
    for guess in guesses:
        if isinstance(guess, tuple) and (abs(guess[0]) >= W or abs(guess[1]) >= H):
            raise ValueError(f"guess must lie within the frame, |u_x| < {W} px and |u_y| < "
                             f"{H} px (a larger displacement leaves no pixel of the specimen "
                             f"to compare), got ({guess[0]:g}, {guess[1]:g})")


def _check_pitch_fits(shape, pitch: float, margin: float) -> None:
    """Refuse frames too small for a window of one pitch and its invalid band."""
    H, W = shape
    need = _min_side(pitch, margin)
    if min(H, W) < need:
        raise ValueError(f"the frames ({H} x {W} px) are too small for the grid's pitch "
                         f"({pitch:.3g} px): a window of sigma >= the pitch with its band "
                         f"of margin = {margin:g} sigmas needs frames of at least {need} x "
                         f"{need} px")


# --------------------------------------------------------------------------- progress


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


# --------------------------------------------------------------------------- vibrations


def _diagnose(name: str, shifts: np.ndarray, estimator: str, lattice: Lattice,
              method: str) -> VibrationReport:
    return _vibration_report(shifts, lattice, method=method, name=name, estimator=estimator)


# --------------------------------------------------------------------------- screening

#: What ``outliers`` may say to do with the frames the screening flags.
OUTLIER_POLICIES = ("exclude", "refuse", "warn")
# A screened series keeps the mean image's contrast above this fraction
# (|mean c_t| / mean |c_t|): 0.8 is a vibration of 0.25 pitch / 2 pi ~ 0.2 px std at
# pitch 5, past the second-order theory of the noise floor (Prop. 2.2).
_MIN_COHERENCE = 0.8


@dataclass(frozen=True, eq=False)
class _Screened:
    screen: FrameScreen
    series: object  # the frames kept
    shifts: np.ndarray  # (T_kept, 2) px, centred
    excluded: tuple[int, ...]  # frame numbers
    kept_flagged: bool  # frames flagged but kept (outliers="warn")
    saturation: float  # largest clipped fraction of a kept frame
    clip_level: float  # the level of that frame, NaN when none is clipped
    warnings: tuple[str, ...]


def outlier_verdict(s, sc: FrameScreen, outliers: str) -> tuple[list[int], list[str]]:
    """The frames of series ``s`` to keep after its screening ``sc``, and the warnings
    naming the flagged ones, as ``outliers`` says ("exclude", "refuse" or "warn"; see
    :func:`measure_series`). A strict minority is excluded; when half the frames or
    more are flagged the series is refused whatever the policy but "warn": the good
    frames cannot be told from the bad."""
    n, bad = s.n_frames, sc.flagged
    if not bad:
        return list(range(n)), []
    listed = sc.listing(s.describe_frame)
    if outliers != "warn" and (outliers == "refuse" or 2 * len(bad) >= n):
        why = "" if outliers == "refuse" or len(bad) == n else " (half or more: the " \
            "good frames cannot be told from the bad)"
        raise ValueError(f"{s.name}: {listed} -- {len(bad)} of {n} frame(s) flagged{why}; "
                         f"{_advice(sc, bad)}, or pass outliers='warn' (--outliers warn) "
                         "to measure anyway")
    if outliers == "exclude":
        return ([t for t in range(n) if t not in set(bad)],
                [f"{s.name}: excluded {len(bad)} of {n} frames: {listed}"])
    return list(range(n)), [f"{s.name}: kept {len(bad)} flagged frame(s) of {n} (outliers="
                            f"'warn'): {listed}; the noise floor and uncertainty maps of the "
                            "states measured with them are not stated (NaN)"]


def _screen_pass(s, acc: SeriesPass, max_saturation: float, outliers: str):
    """The screening of the frames of ``s`` from its pass (:meth:`SeriesPass.screen`),
    and the pass once the flagged frames are excluded, refused or kept as ``outliers``
    says: ``(_Screened, pass)``. A strict minority is excluded (read a second time
    to take them out of the sums); when half the frames or more are flagged the
    series is refused whatever the policy but "warn": the good frames cannot be told
    from the bad."""
    n = s.n_frames
    try:
        sc = acc.screen(max_saturation=max_saturation)
    except ValueError as exc:
        hint = ("; a state whose grid turned by more than 17 degrees or stretched by more "
                "than 30 % from the reference's is not followed (gridstrain.lattice."
                "follow_lattice): measure it against an intermediate state"
                if "shows a grid" in str(exc) else "")
        raise ValueError(f"{s.name}: {exc}{hint}") from None
    sequence = []
    if sc.trend is not None and sc.trend.sequence:
        what = (f"{s.name}: its {n} frames are a sequence, not one static state "
                f"({sc.trend.describe()})")
        if outliers != "warn":
            raise ValueError(f"{what}: averaging them would mix states; measure each frame "
                             "as a state of its own with --each-frame (each_frame=True)")
        sequence.append(f"{what}; averaged all the same (outliers='warn'): the maps mix "
                        "the states (--each-frame measures each frame)")
    bad = sc.flagged
    keep, warnings = outlier_verdict(s, sc, outliers)
    warnings = sequence + warnings
    if outliers == "exclude":
        for t in bad:  # the second read of a frame: only for the excluded ones
            # as stored, as the pass read it: taken out exactly as it was added
            acc.remove(t, next(iter(s.frames(dtype=None, start=t, stop=t + 1))))
    kept = s if len(keep) == n else s.subset(keep)
    coh = sc.coherence(keep)
    if len(keep) > 1 and coh.min() < _MIN_COHERENCE:
        warnings.append(f"{s.name}: the frames' rigid shifts leave only {coh.min():.0%} of "
                        "the grid's contrast in their mean (vibrations of a large fraction "
                        "of a pitch): the noise floor's theory does not hold")
    sat = sc.saturated[keep]
    worst = int(np.argmax(sat))
    level = float(sc.clip_level[keep][worst]) if sat[worst] > 0 else math.nan
    return _Screened(screen=sc, series=kept, shifts=sc.shifts(keep),
                     excluded=tuple(s._number(t) for t in bad if outliers == "exclude"),
                     kept_flagged=bool(bad) and outliers == "warn",
                     saturation=float(sat[worst]), clip_level=level,
                     warnings=tuple(warnings)), acc


# What the user can do about a flagged frame, by what its reason says.
_ADVICE = (("uniform", "remove the blank frames"), ("shows no grid", "remove the blank frames"),
           ("low grid contrast", "remove the dark or blurred frames"),
           ("rigid shift", "measure the frames before and after the slip as two series"),
           ("non-rigid", "move the frames of another state to their own series"),
           ("pixels saturated", "shorten the exposure, mask the saturated area, or accept "
            "more clipped pixels with max_saturation= (--max-saturation FRACTION: photos of "
            "white paper clip between the lines, and the phase stays measurable there)"))


def _advice(sc, bad) -> str:
    out = []
    for t in bad:
        for reason in sc.reasons[t]:
            for key, what in _ADVICE:
                if key in reason and what not in out:
                    out.append(what)
    return "; ".join(out) or "remove or re-take them"


def _saturation_warning(s, sc: _Screened, saturation: float) -> list[str]:
    if saturation <= 0:
        return []
    lvl = sc.clip_level
    at = "" if not math.isfinite(lvl) else f" (clipped at {lvl:g}" + (
        ")" if s.saturation_level is None or lvl >= s.saturation_level else
        ", a level 2^n - 1 below the files' range: a camera of fewer bits? pass its "
        "bit depth)")
    return [f"{s.name}: up to {saturation:.2%} of a frame's pixels are saturated{at}"]


# --------------------------------------------------------------------------- statistics


@dataclass(frozen=True)
class _Stats:
    mean: np.ndarray
    variance: np.ndarray | None  # per-pixel noise variance of one frame, grey levels^2
    variance_method: str
    saturation: float


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


def _specimen_mask(mask, shape) -> np.ndarray:
    """The mask given as an image file or an array, checked against the frames."""
    if isinstance(mask, str | os.PathLike):
        return read_mask(mask, shape)
    return check_mask(mask, shape)


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
        need = _min_side(2.0, margin)
        if min(ref.shape) < _min_side(5.0, margin):
            raise ValueError(f"reference: no grid detected on frames of {ref.shape[0]} "
                             f"x {ref.shape[1]} px, too small for the grid method: a "
                             f"window of sigma >= the pitch with its band of margin = "
                             f"{margin:g} sigmas needs {need} px for a 2-px pitch, "
                             f"{_min_side(5.0, margin)} px for a 5-px pitch") from None
        raise ValueError(f"reference: {exc}") from None
    _check_pitch_fits(ref.shape, lattice.pitch, margin)
    return lattice


def _plan(s, lattice: Lattice, method: str, sigma: float, margin: float,
          mask: np.ndarray, is_ref: bool) -> PassPlan:
    """What the pass over series ``s`` gathers. Method B's transforms use the
    reference's mask (the states': the whole frame), as its phase maps do; regions
    without a grid, known only from the mean image, may change that afterwards.
    ``lattice``: the series' own wave vectors (:func:`_carrier`)."""
    return PassPlan(lattice=lattice, n_frames=s.n_frames, method=method, sigma=sigma,
                    margin=margin,
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
    the grid's amplitude varies (:func:`gridstrain.wft.demodulated_at`). So each
    state's pass and transforms use its own carrier, and its maps are brought to
    the reference's lattice afterwards. None (the reference's) where no peak stands
    out near it (the screening then says what it sees) or the carrier has not moved
    (:func:`gridstrain.lattice._state_carrier`)."""
    own = _state_carrier(next(iter(s.frames(start=0, stop=1))), lattice, reference)
    if own is lattice:
        return None, []
    # k_s^T = k_r^T F^-1 for a homogeneous deformation gradient F
    F = np.linalg.inv(np.linalg.solve(lattice.K, own.K))
    U, stretch, Vt = np.linalg.svd(F)
    R = U @ Vt  # the polar decomposition's rotation
    turn = math.degrees(math.atan2(R[1, 0], R[0, 0]))
    if np.max(np.abs(stretch - 1)) <= _PLAUSIBLE_STRETCH:
        return own, []
    files = ", ".join(str(p) for p in list(s.paths)[:2]) + (", ..." if len(s.paths) > 2
                                                          else "")
    return own, [f"{s.name}: its grid (pitches {own.pitches[0]:.4g}/{own.pitches[1]:.4g} "
                 f"px, angles {own.angles[0]:.3g}/{own.angles[1]:.3g} deg) is the "
                 f"reference's stretched by {stretch.min() - 1:+.1%}/{stretch.max() - 1:+.1%}"
                 f" and turned by {turn:.3g} deg: more than a plausible strain "
                 f"({_PLAUSIBLE_STRETCH:.0%}); check that {files} and the reference "
                 "images are of the same specimen and grid"]


def _run_pass(s, plan: PassPlan, report: Progress) -> SeriesPass:
    """One pass over the frames of ``s`` on this machine. Method B's transforms run
    on threads (the usable cores), adding their sums in frame order (the result
    does not depend on the number of threads); the rest follows the reading."""
    n = s.n_frames
    workers = check_workers(None) if plan.method == "B" else 1
    order = _FrameOrder() if workers > 1 else None
    box: list = []

    def read():
        # the frames as stored: integer frames are summed as read, and method B
        # transforms them in float32 (gridstrain.accumulate, gridstrain.stacks)
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


# --------------------------------------------------------------------------- phase maps


def _no_grid(mod: np.ndarray, valid: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Pixels of ``mask`` whose modulus ``mod`` (2, H, W) shows no grid (``valid``:
    the transform's valid pixels, where the median is taken)."""
    ref = valid if valid.any() else mask
    out = np.zeros(mask.shape, dtype=bool)
    for j in range(2):
        out |= mod[j] < _NO_GRID_MODULUS * median(mod[j][ref], overwrite_input=True)
    return out & mask


def _check_given_lattice(image: np.ndarray, lattice: Lattice, sigma: float,
                         mask: np.ndarray, margin: float) -> None:
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
        pm, used = _phase_maps_a(image, lattice, sigma, mask, margin)
        _check_grid(pm, image, used, margin)
        return
    for j, k in enumerate((lattice.k1, lattice.k2)):
        kv = np.array(k)
        dk = min(float(np.hypot(*(kv - s * np.array(f)))) for f in (found.k1, found.k2)
                 for s in (1, -1))
        if 2 * math.pi * sigma * dk > 1:
            p1, p2 = found.pitches
            a1, a2 = found.angles
            raise ValueError(f"reference: the given lattice is not the grid's: k{j + 1} = "
                             f"({k[0]:.4g}, {k[1]:.4g}) cycles/px is not among the wave "
                             f"vectors detected in the image (pitches {p1:.4g}/{p2:.4g} "
                             f"px, angles {a1:.3g}/{a2:.3g} deg); check --pitch/--angle or "
                             "--k1/--k2, or let the lattice be detected")


def _check_grid(pm: PhaseMaps, image: np.ndarray, mask: np.ndarray, margin: float) -> None:
    """Refuse a lattice at which the image shows no more than noise."""
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    turned = Lattice(*((k[0] * c - k[1] * s, k[0] * s + k[1] * c)
                       for k in (pm.lattice.k1, pm.lattice.k2)))
    control = wft(image, turned, sigma=pm.sigma, mask=mask, margin=margin)
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


def _phase_maps_a(image, lattice, sigma, mask, margin):
    """WFT of an averaged image, masking regions without a grid (method A)."""
    m = np.ones(image.shape, dtype=bool) if mask is None else mask
    pm = wft(image, lattice, sigma=sigma, mask=m, margin=margin, workers=None)
    nogrid = _no_grid(pm.modulus, pm.valid, m)
    if nogrid.any():
        m = _less(m, nogrid)
        pm = wft(image, lattice, sigma=sigma, mask=m, margin=margin, workers=None)
    return finite_derivatives(pm), m


def _less(m: np.ndarray, nogrid: np.ndarray) -> np.ndarray:
    m = m & ~nogrid
    if not m.any():
        raise ValueError("no pixel shows a grid at the lattice's wave vectors")
    return m


def _grid_support(image, lattice, sigma, mask, margin) -> np.ndarray:
    """The mask :func:`_phase_maps_a` ends with (``mask`` less the regions without a
    grid), for methods B and C, whose maps come from their own sums: one transform
    of the averaged image, of which only the moduli are kept (float32, for the
    threshold), not its maps."""
    m = np.ones(image.shape, dtype=bool) if mask is None else mask
    mod = np.empty((2, *image.shape), dtype=np.float32)

    def keep(j, r0, r1, psi, dphi, modulus):
        mod[j, r0:r1] = modulus

    valid = _wft(image, lattice, sigma=sigma, mask=m, margin=margin, sink=keep,
                 workers=check_workers(None))
    nogrid = _no_grid(mod, valid, m)
    return _less(m, nogrid) if nogrid.any() else m


def _method_b_maps(s, sc: _Screened, acc: SeriesPass, used: np.ndarray,
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
    return finite_derivatives(method_b(frames, plan.lattice, sigma=plan.sigma, mask=used,
                                       margin=plan.margin, screen=False).maps)


# Method A's averaged grid keeps this fraction of its contrast or less (eq. 14): its
# phase-derivative noise is then 2 % or more above method C's, about the precision of
# the noise floor itself, and worth method C's 2 to 3 times A's cost.
_SUGGEST_C_CONTRAST = 0.98


def _contrast_notes(vib) -> list[str]:
    """Series whose vibrations cost method A more than method C's extra time."""
    out = []
    for v in vib:
        c = min(v.contrast_factor)
        if math.isfinite(c) and c < _SUGGEST_C_CONTRAST:
            out.append(f"{v.name}: vibrations of ({v.std[0]:.3g}, {v.std[1]:.3g}) px std "
                       f"lower the averaged grid's contrast to {c:.3f} (Prop. 2.2, eq. 14): "
                       f"method A's strain noise is {1 / c - 1:.1%} above that of method C, "
                       "which realigns the frames before averaging (--method C)")
    return out


# --------------------------------------------------------------------------- Dask


def _dist():
    """gridstrain.distributed, imported only when a scheduler is given."""
    from . import distributed

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


# --------------------------------------------------------------------------- kinematics


def _filled(u: np.ndarray, valid: np.ndarray) -> np.ndarray | None:
    """``u`` with every invalid pixel given its nearest valid pixel's value."""
    if not valid.any():
        return None
    if valid.all():
        return np.array(u)
    idx = ndimage.distance_transform_edt(~valid, return_distances=False,
                                         return_indices=True)
    return u[:, idx[0], idx[1]]


def _largest_step(res: Measurement, field: np.ndarray, lattice: Lattice,
                  before: np.ndarray) -> float:
    """Largest change of the displacement from ``field``, in periods along k1/k2.

    Taken by blocks of rows (about a megapixel each): whole-map differences would
    add three (2, H, W) temporaries to the kinematics' peak (a state followed from
    the previous one peaked 56 MiB higher than the first at 2048^2)."""
    v = res.valid & before
    if not v.any():
        return math.inf
    H, W = v.shape
    rows = max(1, 2**20 // W)
    largest = 0.0
    for r0 in range(0, H, rows):
        vb = v[r0:r0 + rows]
        if vb.any():
            d = res.u[:, r0:r0 + rows][:, vb] - field[:, r0:r0 + rows][:, vb]
            largest = max(largest, float(np.max(np.abs(lattice.K @ d))))
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


class _Tracker:
    """Measure the states one after the other and fix each one's fringe order (see
    :class:`FringeOrder`): in series order, a state's guess is the previous state's
    field (:meth:`follow`), which is all that is kept of it."""

    def __init__(self, ref_pm: PhaseMaps, mean_ref: np.ndarray, mask: np.ndarray,
                 lattice: Lattice, order: str, lagrangian: bool):
        self.ref_pm, self.mean_ref, self.mask = ref_pm, mean_ref, mask
        self.lattice, self.order, self.lagrangian = lattice, order, lagrangian
        self.prev = None  # (read-back of (u, valid), confirmed, name) of the last state
        self.inherited: list[str] = []  # states followed from an unconfirmed one
        # the reference's side of the image-feature estimate, made once for all states
        self.coarse = _CoarseReference(np.asarray(mean_ref, dtype=np.float64), lattice,
                                       check_mask(mask, mean_ref.shape))

    def features(self, pm: PhaseMaps, mean: np.ndarray, g):
        """The image-feature estimate of the next state's displacement
        (:func:`coarse_displacement`) from its mean image, or None when its guess
        is not automatic: the mean image is not needed afterwards."""
        if not isinstance(g, str):
            return None
        return self.coarse.estimate(np.asarray(mean, dtype=np.float64),
                                    _phase_shift(self.ref_pm, pm))

    def measure(self, pm: PhaseMaps, est, g, name: str):
        """``(Measurement, FringeOrder, warnings)`` of the next state, with ``est``
        from :meth:`features`."""
        ref_pm = self.ref_pm
        warnings: list[str] = []
        prev, self.prev = self.prev, None  # the next state's guess comes from this one
        if isinstance(g, str) and self.order == "series" and prev is not None:
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
            if est.confident and _order_offset(res, est.shift, self.lattice) < 0.5:
                rec = _from_estimate(est, "previous state", True, gmed,
                                     f"followed from {prev_name} (step {step:.2f} period); "
                                     f"image features agree ({est.reason})", step)
            elif est.confident and (step > _MAX_STEP
                                    or np.max(np.abs(self.lattice.K @ est.shift)) >= 0.5):
                # conclusive features that moved with the specimen beat the assumption
                # of a step below half a period: the step was larger
                followed = _median_u(res)
                res = deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=est.shift)
                rec = _from_estimate(est, "image features", True, res.guess,
                                     f"{est.reason}; followed from {prev_name} it would "
                                     f"have been {followed}", step)
                warnings.append(f"{name}: image features fix the displacement at "
                                f"{_median_u(res)}, whole periods from {followed} followed "
                                f"from {prev_name}: the load step was more than half a "
                                "period; the features were used")
            elif est.confident:
                # the features say "no motion" while the specimen was followed away from
                # zero: content fixed to the camera (dust, hot pixels) can do that
                rec = _from_estimate(est, "previous state", False, gmed,
                                     f"followed from {prev_name}, but image features "
                                     f"suggest {est.shift[0]:.2f}, {est.shift[1]:.2f} px",
                                     step)
                warnings.append(f"{name}: the displacement followed from {prev_name} "
                                f"(median {_median_u(res)}) and the image features "
                                f"({est.shift[0]:.2f}, {est.shift[1]:.2f}) px, which may be "
                                "dust or hot pixels fixed to the camera, disagree by whole "
                                "periods: fringe order not confirmed; check the order of "
                                "the states or pass --guess UX UY")
            elif step > _MAX_STEP:
                rec = _from_estimate(est, "previous state", False, gmed,
                                     f"followed from {prev_name}, but the displacement "
                                     f"changed by up to {step:.2f} period", step)
                warnings.append(f"{name}: the displacement changed by up to {step:.2f} "
                                f"period since {prev_name}, more than the {_MAX_STEP} a load "
                                "step can be followed with: fringe order not confirmed; "
                                + _what_to_do(self.lattice))
            else:
                rec = _from_estimate(est, "previous state", prev_ok, gmed,
                                     f"followed from {prev_name} (step {step:.2f} period)"
                                     + ("" if prev_ok else ", itself not confirmed"), step)
                if not prev_ok:
                    self.inherited.append(name)
        elif isinstance(g, str) and est.confident:
            res = deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=est.shift)
            rec = _from_estimate(est, "image features", True, res.guess, est.reason)
        elif isinstance(g, str) or g is None:
            res = deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=None)
            if g is None:
                rec = FringeOrder("smallest displacement", False, (0.0, 0.0),
                                  "guess=None: the order closest to zero, as asked")
            else:
                rec = _from_estimate(est, "smallest displacement", False, (0.0, 0.0),
                                     f"image features undecided: {est.reason}")
                warnings.append(f"{name}: fringe order not confirmed ({est.reason}); the "
                                f"smallest displacement the phases allow was taken (median "
                                f"{_median_u(res)}); " + _what_to_do(self.lattice))
        else:
            res = deformation(ref_pm, pm, lagrangian=self.lagrangian, guess=g)
            rec = FringeOrder("user", True, res.guess, "the given guess")
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
        return [f"{', '.join(self.inherited)}: followed from a state whose fringe order "
                "is not confirmed; they share its uncertainty"]


# --------------------------------------------------------------------------- noise


def _median_modulus(pm: PhaseMaps, valid: np.ndarray) -> np.ndarray:
    mod = pm.modulus
    sel = valid if valid.any() else pm.valid
    if not sel.any():
        return np.full(2, np.nan)
    return np.array([median(mod[j][sel], overwrite_input=True) for j in range(2)])


def _theory_floor(var_ref, T_ref, mod_ref, var_s, T_s, mod_s, sigma, lattice):
    """(2,) px and (3,) strain from the WFT noise theory; NaN when unavailable."""
    if not (math.isfinite(var_ref) or math.isfinite(var_s)):
        return np.full(2, np.nan), np.full(3, np.nan)
    # a single-frame series is taken as noisy per frame as the other one
    var_ref = var_ref if math.isfinite(var_ref) else var_s
    var_s = var_s if math.isfinite(var_s) else var_ref
    if not (np.all(np.isfinite(mod_ref)) and np.all(np.isfinite(mod_s))):
        return np.full(2, np.nan), np.full(3, np.nan)
    ph_r, d_r, ph_s, d_s = [], [], [], []
    for j in range(2):
        p, d = theory.wft_noise_std(var_ref / T_ref, float(mod_ref[j]), sigma)  # Prop. 2.3
        ph_r.append(p)
        d_r.append(d)
        p, d = theory.wft_noise_std(var_s / T_s, float(mod_s[j]), sigma)
        ph_s.append(p)
        d_s.append(d)
    su = theory.displacement_noise_std(ph_r, ph_s, lattice)  # eq. (34)
    se = theory.strain_noise_std(d_r, d_s, lattice)  # eq. (35)
    return su, se


def _split_floor(acc: SeriesPass, lattice, sigma, mask, margin, method: str, report,
                 mean_maps: PhaseMaps | None = None):
    """Spatial std of a half-against-half measurement of the reference, from the
    halves' sums of its pass (method A, or method C when it was the method).

    With ``mean_maps``, the maps of the mean of all the kept frames (method A's
    reference maps, same mask), only the first half is transformed: the mean is
    ``m = h1 + (n2 / T) (h2 - h1)`` and the transform is linear, so that to first
    order in the noise every map of eqs. (34)-(35) moves from ``h1`` to ``m`` by
    ``n2 / T`` of its move to ``h2``: ``std(h2 - h1) = (T / n2) std(m - h1)``. The
    phase difference is ``Im log(1 + r)`` with ``r`` the ratio of the halves'
    difference to the transform (phase noise, 1e-4 to 1e-2 rad), so the second-order
    term changes the std by about ``|r| n1 / 2T`` of itself, below 0.5 % and below
    the std's own sampling error (1 % for the 4,500 independent windows of a
    megapixel map at sigma = 5 px). The large-displacement correction is left out
    (eqs. 34-35 as printed, :func:`_difference_std`): it would evaluate the second
    maps at ``x + u`` instead of ``x``, a change of ``-(1/2pi) K^-1 grad(phi) u`` in
    ``u``, where the carrier's ``2 pi K u`` is already eq. (34)'s own term and what
    is left is the grid's own phase modulation: its gradient, at most 5e-3 rad/px in
    the paper's example against ``2 pi / p = 1.26`` rad/px at a 5-px pitch, makes it
    0.4 % of ``u``. Between two halves of a static series ``u`` is noise (1e-3 px)
    and their mean vibration shifts (0.02 px at most): 1e-4 px, added in quadrature
    to a noise floor ten times larger.
    """
    n1, n2 = acc.half_counts()
    if mean_maps is not None and method == "A":
        img = acc.half_means()[0]
        h1 = finite_derivatives(wft(img, lattice, sigma=sigma, mask=mask, margin=margin,
                                    workers=None))
        report(2 / 3, "half 1 of the reference")
        su, se = _difference_std(h1, mean_maps)
        report(1.0, "half against the whole")
        scale = (n1 + n2) / n2
        return su * scale, se * scale
    halves = []
    for h in (0, 1):
        if method == "C":
            halves.append(acc.method_c(sigma=sigma, mask=mask, margin=margin,
                                       halves=(h,)).maps)
        else:
            img = acc.half_means()[h]
            halves.append(wft(img, lattice, sigma=sigma, mask=mask, margin=margin,
                              workers=None))
        report((h + 1) / 3, f"half {h + 1} of the reference")
    su, se = _difference_std(finite_derivatives(halves[0]), finite_derivatives(halves[1]))
    report(1.0, "half against half")
    return su, se


def _difference_std(a: PhaseMaps, b: PhaseMaps) -> tuple[np.ndarray, np.ndarray]:
    """Spatial std (ddof 1) of the displacement (2,) and small strain (3,) between
    two phase-map sets of a static specimen, over the pixels valid in both: eqs.
    (34)-(35) without the large-displacement correction, as
    :func:`gridstrain.kinematics.deformation` gives them with ``lagrangian=False``,
    on the valid pixels only (the maps differ by noise: no phase wraps, and whole
    periods would not change a standard deviation).

    Computed by bands of rows that stay in cache, their means and sums of squared
    deviations merged exactly (Chan et al.'s pairwise update): no map-sized
    temporary."""
    valid = a.valid & b.valid & np.all(np.isfinite(a.dphi), axis=(0, 1))
    K = a.lattice.K
    n, mean, m2 = 0, np.zeros(5), np.zeros(5)
    for rows, v, z in _phase_products(a, b, valid):
        k = z.shape[1]
        dD = b.dphi[:, :, rows][:, :, v].astype(np.float64)
        dD -= a.dphi[:, :, rows][:, :, v]
        q = np.concatenate([-_solve(K, np.angle(z)) / (2 * np.pi),  # eq. (34)
                            _small_strain(_eulerian_gradient(K, dD))])  # eq. (35)
        qm = q.mean(axis=1)
        qm2 = ((q - qm[:, None]) ** 2).sum(axis=1)
        delta = qm - mean
        tot = n + k
        mean = mean + delta * (k / tot)
        m2 = m2 + qm2 + delta**2 * (n * k / tot)
        n = tot
    if n < 2:
        return np.full(2, np.nan), np.full(3, np.nan)
    std = np.sqrt(m2 / (n - 1))
    return std[:2], std[2:]


# --------------------------------------------------------------------------- pipeline


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
                   loads=None, frame_rate: float | None = None) -> SeriesResult:
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
        used. A :class:`gridstrain.sequences.StateInputs` (from
        :func:`gridstrain.sequences.state_inputs`) is used as it is.
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
        against its series by :func:`gridstrain.screening.screen_frames`: no grid
        or a uniform frame, low contrast, a rigid slip, a frame of another state,
        more than ``max_saturation`` clipped pixels, at the container's ceiling or
        at a level ``2^n - 1``). "exclude" (default): leave them out of every
        average (mean, variance, method B, the noise floor's halves, ``T``) and
        name them in the warnings; a series with half its frames flagged or more
        is refused, the good ones being then unknown. "refuse": raise on any
        flagged frame. "warn": keep them, name them in the warnings, and give the
        noise floor and uncertainty maps of the states they enter as NaN. A series
        whose frames form a sequence (a steady drift or a growing deformation,
        :class:`gridstrain.screening.Trend`) is refused, but with "warn", which
        averages it with a warning.
    progress : callable, optional
        ``progress(fraction, message)``.
    scheduler : str or distributed.Client, optional
        Compute each series' statistics pass (mean, variance, saturation) and
        method B's transforms on Dask: ``"local"`` (one worker process per core),
        a scheduler address ``"tcp://HOST:PORT"`` or a ``distributed.Client``
        (see :func:`gridstrain.distributed.connect`; needs the ``distributed``
        extra, and on a cluster workers that see the input files at the same
        paths). Every series is submitted before the first is awaited. The frame
        shifts, the lattice, method C, the noise floor and the kinematics stay on
        this machine. Results equal those without a scheduler to the rounding of sums
        added in another order.
    noise_model : NoiseModel or (K, L), optional
        The camera's noise ``Var = K l + L`` in the stored grey levels of the
        images (a :class:`gridstrain.noise.NoiseModel`, e.g. from ``gridstrain
        noise``, or a pair from a datasheet). Used for every series instead of
        the noise measured in the data. Default: the temporal variance of each
        series of two frames or more, and for single frames the model estimated
        from one image (:func:`gridstrain.noise.estimate_noise_image`).
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
        keeps.

    each_frame : bool
        Every frame of the states' inputs (a folder, a glob, a list of files, a
        multi-page TIFF, a ``(T, H, W)`` array) is a state of its own, named after
        its file (and page): a sequence such as a high-speed record
        (:mod:`gridstrain.sequences`). Without it a series whose frames drift or
        deform steadily is refused rather than averaged.
    reference_frames : int, optional
        The reference is the first ``reference_frames`` frames of the record given
        as ``states`` (averaged) and every later frame is a state; ``reference``
        must then be None. Implies ``each_frame``.
    keep_order : bool
        Keep explicit files in the order given even where it is not natural.
    loads : str, os.PathLike or (n_states,) array_like, optional
        The load of each state: a CSV file read by :func:`gridstrain.io.read_loads`
        (its ``load [UNIT]`` and optional ``time [s]`` columns), or the loads
        themselves (no unit). Stored as :attr:`SeriesResult.load`.
    frame_rate : float, optional
        The camera's frame rate, Hz: each state's time is its frame's number in
        the record over the rate, s (:attr:`SeriesResult.time`). Without it (and
        without a time column), states read from one video get its time stamps.

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
    (:class:`gridstrain.accumulate.SeriesPass`: screening, shifts, mean, variance,
    the noise floor's halves, method B's transforms or method C's sums). Read twice:
    at most 8 reference frames (their mean detects or checks the lattice, which the
    pass needs), the frames the screening excludes (taken out of the sums), and,
    with method B, a series whose mean image shows regions without a grid (they
    change the windows' support: the kept frames are transformed again).

    Examples
    --------
    >>> import numpy as np
    >>> from gridstrain import Lattice, synthetic
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
    series, guesses, m = _inputs(reference, given, guess, mask, o)
    _check_memory(series, o)
    steps = _Steps(progress, _total_cost(series, o))
    # how the frames were read (colour converted, lossy JPEG), series by series
    warnings: list[str] = [n for s in series for n in getattr(s, "notes", ())]
    warnings += list(given.warnings)
    if not (each_frame or given.reference is not None or reference_frames):
        warnings += _glob_warning(series)
    o = dataclasses.replace(o, state_order=given.order)
    extra = _loads_and_times(loads, frame_rate, series, o)
    # BLAS on the calling thread throughout: its products here are small or memory
    # bound, and OpenBLAS's own threads would spin between them (gridstrain._threads)
    with one_blas_thread():
        o = _window(series[0], m, o, steps)
        return _measure(series, guesses, m, o, steps, warnings, progress, extra)


def _loads_and_times(loads, frame_rate, series: list, o: _Setup) -> dict:
    """``load``, ``load_unit`` and ``time`` of the result, checked against the
    states before any frame is read."""
    names = [s.name for s in series[1:]]
    load = unit = time = None
    if loads is not None:
        if isinstance(loads, str | os.PathLike):
            from .io import read_loads

            table = read_loads(loads, states=names)
            load, unit, time = table.load, table.unit, table.time
        else:
            load = np.array(loads, dtype=np.float64)
            if load.shape != (len(names),) or not np.all(np.isfinite(load)):
                raise ValueError(f"loads must hold one finite number per loaded state "
                                 f"({len(names)}), got shape {load.shape}")
    if frame_rate is not None:
        rate = check_positive(frame_rate, "frame_rate")
        if not o.each_frame:
            raise ValueError("frame_rate needs one frame per state (each_frame=True, "
                             f"--each-frame), got frame_rate={frame_rate!r}")
        if time is not None:
            raise ValueError(f"give the times by frame_rate or by the loads file's time "
                             f"column, not both (frame_rate={frame_rate!r})")
        time = (np.arange(len(names), dtype=np.float64) + (o.reference_frames or 0)) / rate
    elif time is None and o.each_frame:
        # the camera's own time stamps, where the file holds them (videos)
        stamps = [getattr(s, "times", None) for s in series[1:]]
        if all(t is not None and t.size == 1 for t in stamps):
            time = np.concatenate(stamps)
    return {"load": load, "load_unit": unit, "time": time}


@dataclass(frozen=True, eq=False)
class _Setup:
    """A measurement's options, checked once at the door and passed inward; the
    lattice and ``sigma`` are completed by :func:`_window` once the reference is
    seen."""

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
            "keep_order": bool(self.keep_order)}


def _setup(*, method, outliers, margin, sigma, order, sigma_pitches, max_saturation,
           lattice, scheduler, timeout, noise_model, dtype, output, lagrangian, bit_depth,
           guess) -> _Setup:
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
        from .results import ResultFile  # h5py only when a file is written

        output = output if isinstance(output, ResultFile) else ResultFile(output)
        if dtype is not None and output.dtype is not None and output.dtype != dtype:
            raise ValueError(f"dtype={dtype} and output's dtype={output.dtype} disagree")
        dtype = output.dtype if dtype is None else dtype
        output = dataclasses.replace(output, dtype=dtype)
    return _Setup(method=method, outliers=outliers, margin=margin, sigma=sigma, order=order,
                  sigma_pitches=sigma_pitches, max_saturation=max_saturation,
                  lattice=lattice, detected=lattice is None,
                  scheduler=_check_scheduler(scheduler),
                  timeout=check_positive(timeout, "timeout", allow_none=True),
                  noise_model=_check_noise_model(noise_model), dtype=dtype, output=output,
                  lagrangian=bool(lagrangian), bit_depth=bit_depth, guess=guess)


def _check_memory(series: list, o: _Setup) -> None:
    """Refuse, before the first frame is transformed, a measurement whose estimated
    peak exceeds the memory available (:mod:`gridstrain._memory`)."""
    n_states = len(series) - 1
    held = o.output is None  # every state's maps kept to the end
    peak = _memory.measurement_bytes(series[0].shape, method=o.method, n_states=n_states,
                                     held_states=held)
    H, W = series[0].shape
    advice = ("measure a smaller region (crop the frames), fewer states at once"
              + (", each state written as measured (an output file, without "
                 "--phase-maps)" if held else "")
              + ", or --memory-budget (memory_budget) if more memory is in fact free")
    # the interpreter and libraries, part of the estimate, are loaded already: what
    # the process holds counts against that fixed part (never against the pixels')
    fixed = _memory.measurement_bytes((0, 0))
    _memory.check_fits(peak - min(_memory.resident_memory(), fixed),
                       what=f"measuring {n_states} state(s) of {H} x {W} px with method "
                       f"{o.method} (estimated peak {_memory.format_size(peak)})",
                       advice=advice)


def _inputs(reference, given: StateInputs, guess, mask, o: _Setup
            ) -> tuple[list, list, np.ndarray]:
    """The series (reference first), one guess per state and the mask, checked
    against each other."""
    if reference is None:
        raise TypeError("reference must be a series, a path or an array of frames, got "
                        "None (None only with reference_frames)")
    ref = _as_series(reference, "reference", o.bit_depth)
    raw_states = list(given.states)
    if given.permutation is not None and _is_per_state(guess):
        if len(guess) != len(raw_states):
            raise ValueError(f"guess must hold one entry per loaded state "
                             f"({len(raw_states)}), got {len(guess)}")
        guess = [guess[i] for i in given.permutation]  # in the order measured
    guesses = _check_guess(guess, len(raw_states), o.order)
    series = [ref] + [_as_series(s, name, o.bit_depth)
                      for s, name in zip(raw_states, state_names(raw_states), strict=True)]
    for s in series[1:]:
        if s.shape != ref.shape:
            raise ValueError(f"{s.name}: frames are {s.shape} (H, W) but the reference "
                             f"frames are {ref.shape}")
    _check_fit(ref.shape, o.sigma, o.margin, guesses)
    if o.lattice is not None:
        _check_pitch_fits(ref.shape, o.lattice.pitch, o.margin)
    m = _specimen_mask(mask, ref.shape)
    for i, g in enumerate(guesses):
        if isinstance(g, np.ndarray) and g.shape != (2, *ref.shape):
            raise ValueError(f"guess for {series[i + 1].name} must be a (u_x, u_y) pair or "
                             f"a field of shape {(2, *ref.shape)}, got shape {g.shape}")
    return series, guesses, m


def _total_cost(series: list, o: _Setup) -> float:
    """The measurement's cost for its progress: reading a frame costs 1, a transform
    about 4 frames' worth."""
    total = min(series[0].n_frames, _LATTICE_FRAMES) + 1.0
    for s in series:
        total += s.n_frames * _pass_cost(o.method) + 2 * _WFT_COST
    total += (len(series) - 1) * (3 * _WFT_COST if o.lagrangian else _WFT_COST)
    return total + 3 * _WFT_COST


def _window(ref, m: np.ndarray, o: _Setup, steps: _Steps) -> _Setup:
    """The options completed with the lattice, detected on (or checked against) the
    mean of a few reference frames, and the window's ``sigma``."""
    mean_ref = _lattice_image(ref, steps.sub(min(ref.n_frames, _LATTICE_FRAMES), ""))
    lattice = _detect(mean_ref, ref, m, o.margin) if o.detected else o.lattice
    sigma = o.sigma if o.sigma_pitches is None else o.sigma_pitches * lattice.pitch
    sigma = check_sigma(sigma, lattice.pitch)
    _check_fit(ref.shape, sigma, o.margin)
    if not o.detected:
        _check_given_lattice(mean_ref, lattice, sigma, m, o.margin)
    steps.step(1.0, "lattice")
    return dataclasses.replace(o, lattice=lattice, sigma=float(sigma))


def _measure(series: list, guesses: list, m: np.ndarray, o: _Setup, steps: _Steps,
             warnings: list, progress: Progress, extra: dict) -> SeriesResult:
    """One pass over every series (screening, shifts, statistics, the halves of the
    noise floor, method B's or C's sums), the flagged frames then taken out; the
    states measured one after the other, each dropped once measured."""
    lattice, sigma, method = o.lattice, o.sigma, o.method
    n_states = len(series) - 1
    base = _reference_carrier(next(iter(series[0].frames(start=0, stop=1))), lattice) \
        if n_states else None
    carriers = [(None, [])] + [_carrier(s, lattice, base) for s in series[1:]]
    for _, notes in carriers:
        warnings.extend(notes)
    plans = [_plan(s, carriers[k][0] or lattice, method, sigma, o.margin, m, k == 0)
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
            out = _one_series(s, acc, m if k == 0 else None, o.max_saturation, o.outliers,
                              method, f32, steps)
            if plans[k].lattice != lattice:  # a state at its own carrier (_carrier)
                out = dataclasses.replace(out, maps=demodulated_at(out.maps, lattice))
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
        floor = _ReferenceFloor(r, done[0], ref_pass, lattice, sigma, o.margin, method,
                                steps.sub(3 * _WFT_COST, "noise floor"), warnings)
        del ref_pass
        r = floor.r  # without its variance map: the floor keeps the smoothed one
        tracker = _Tracker(r.maps, r.stats.mean, r.mask, lattice, o.order, o.lagrangian)
        cracks: list[tuple] = []
        alias = aliasing_bias(r.stats.mean, lattice, sigma=sigma, mask=r.mask)
        for i in range(n_states):
            c, acc = one(i + 1)
            del acc
            c = noise.complete(c)
            est = tracker.features(c.maps, c.stats.mean, guesses[i])
            res, rec, notes = tracker.measure(c.maps, est, guesses[i], c.name)
            if isinstance(guesses[i], str):
                res, checked, said = _after_warp(res, rec, tracker.coarse, c.stats.mean,
                                                 lattice, c.name)
                if checked is not rec:  # confirmed now: the doubt said before is void
                    notes = [n for n in notes if "fringe order not confirmed" not in n]
                rec = checked
                notes = [*notes, *said]
            c = c.dropping("mean")  # the image features were its only use
            res, found, said = _discontinuities(res, c.name)
            cracks.append(found)
            notes = [*notes, *said]
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
                tracker.follow(res, done[-1].name, sink.reader(i))
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
            systematic={"aliasing": alias, "smoothing": sink.smoothing},
            state_order=o.state_order, discontinuities=tuple(cracks), **extra)


# --------------------------------------------------------------------------- one series


@dataclass(frozen=True, eq=False)
class _Summary:
    """What the result keeps of a series once its maps are dropped."""

    name: str
    sources: tuple
    T: int
    bit_depth: int | None
    scale: int
    saturation: float
    excluded: tuple
    screening: FrameScreen
    vib: VibrationReport
    variance: float  # mean per-frame noise variance over the valid pixels
    variance_method: str
    modulus: np.ndarray  # (2,) median |Psi|
    kept_flagged: bool
    saturation_warnings: tuple


@dataclass(frozen=True, eq=False)
class _Measured:
    """One series measured: its kept frames, screening, statistics and phase maps."""

    series: object
    screen: _Screened
    vib: VibrationReport
    stats: _Stats
    maps: PhaseMaps
    mask: np.ndarray  # the pixels the maps were computed on
    warnings: tuple

    @property
    def name(self) -> str:
        return self.series.name

    def dropping(self, *names: str) -> _Measured:
        """This series without the statistics maps ``names`` ("mean", "variance"),
        once nothing needs them (each is a float64 image)."""
        return dataclasses.replace(self, stats=dataclasses.replace(
            self.stats, **dict.fromkeys(names)))

    def without_derivatives(self) -> _Measured:
        """This series with its maps' phase derivatives dropped (an unstored NaN view
        in their place), once its kinematics are done: the rest needs only Psi."""
        pm = self.maps
        nan = np.broadcast_to(np.array(np.nan, dtype=pm.dphi.dtype), pm.dphi.shape)
        return dataclasses.replace(self, maps=dataclasses.replace(pm, dphi=nan))

    def summary(self) -> _Summary:
        s, sc, st, pm = self.series, self.screen, self.stats, self.maps
        var = float(np.mean(st.variance[pm.valid])) if st.variance is not None \
            and pm.valid.any() else math.nan
        sat = max(st.saturation, sc.saturation)
        return _Summary(name=s.name, sources=tuple(str(p) for p in s.paths), T=s.n_frames,
                        bit_depth=s.bit_depth, scale=int(s.scale), saturation=sat,
                        excluded=sc.excluded, screening=sc.screen, vib=self.vib,
                        variance=var, variance_method=st.variance_method,
                        modulus=_median_modulus(pm, pm.valid),
                        kept_flagged=sc.kept_flagged,
                        saturation_warnings=tuple(_saturation_warning(s, sc, sat)))


def _one_series(s, acc: SeriesPass, base, max_saturation: float, outliers: str,
                method: str, f32: bool, steps: _Steps) -> _Measured:
    """Screening, statistics and phase maps of series ``s`` from its pass; ``base``
    is the mask of the reference (None for a state: its configuration is deformed)."""
    plan = acc.plan
    sc, acc = _screen_pass(s, acc, max_saturation, outliers)
    notes = list(sc.warnings)
    vib = _diagnose(s.name, sc.shifts, "gridstrain.vibration.frame_shifts", plan.lattice,
                    method)
    st = acc.statistics()
    stats = _Stats(st.mean, st.variance, st.method, sc.saturation)
    del st
    acc.release(keep_halves=base is not None)  # the reference's halves: its noise floor
    if method == "A":
        pm, used = _phase_maps_a(stats.mean, plan.lattice, plan.sigma, base, plan.margin)
    else:  # the mean image gives the mask only
        used = _grid_support(stats.mean, plan.lattice, plan.sigma, base, plan.margin)
    steps.step(2 * _WFT_COST, f"{s.name}: phase maps")
    if method == "C":
        res = acc.method_c(sigma=plan.sigma, mask=used, margin=plan.margin)
        pm = finite_derivatives(res.maps)
        notes.extend(f"{s.name}: {w}" for w in res.warnings)
        del res
    elif method == "B":
        pm = _method_b_maps(s, sc, acc, used, steps.sub(0.0, s.name))
    if f32:  # float32 maps from float32 frames (gridstrain.conventions)
        pm = dataclasses.replace(pm, psi=pm.psi.astype(np.complex64),
                                 dphi=pm.dphi.astype(np.float32))
    return _Measured(series=sc.series, screen=sc, vib=vib, stats=stats, maps=pm,
                     mask=used, warnings=tuple(notes))


def _check_noise_model(noise_model):
    """A NoiseModel from ``noise_model`` (a NoiseModel or a (K, L) pair), or None."""
    if noise_model is None or isinstance(noise_model, NoiseModel):
        if noise_model is not None and not noise_model.K > 0:
            raise ValueError(f"noise_model: K must be positive, got {noise_model.K!r}")
        return noise_model
    if isinstance(noise_model, str | bytes) or not isinstance(noise_model, Sequence) \
            or len(noise_model) != 2:
        raise TypeError(f"noise_model must be a NoiseModel or a (K, L) pair in stored grey "
                        f"levels, got {noise_model!r}")
    K = check_positive(noise_model[0], "noise_model K")
    L = noise_model[1]
    if isinstance(L, bool) or not isinstance(L, numbers.Real) or not math.isfinite(L):
        raise ValueError(f"noise_model L must be a finite number of grey levels^2, got {L!r}")
    return NoiseModel(K=K, L=float(L), method="given")


def _check_model_units(given, series) -> None:
    """Refuse a given noise model in other units than the series' grey levels."""
    if given is None:
        return
    for s in series:
        if s.bit_depth is not None and given.bit_depth is not None \
                and given.bit_depth != s.bit_depth:
            raise ValueError(f"noise model: estimated on {given.bit_depth}-bit images but "
                             f"{s.name} is {s.bit_depth}-bit; estimate it on this camera's "
                             "images or give --noise-model K L in their stored units")
        if given.method != "given" and given.scale != s.scale:
            raise ValueError(f"noise model: estimated on images stored x{given.scale:g} but "
                             f"{s.name} is stored x{s.scale:g}; its K and L are in other "
                             "units")


def _describe_model(model, what: str) -> str:
    return (f"{what}: Var = K l + L, K = {model.K:.4g}, L = {model.L:.4g} (stored grey "
            "levels)")


class _Noise:
    """The per-frame noise variance map of each series, series by series.

    A given camera model sets every series' variance to ``K mean + L``; otherwise
    the series of two frames or more keep their temporal variance, and those of one
    frame get the model estimated from one image (:func:`estimate_noise_image`),
    on the first such series met (the camera is the same).
    """

    def __init__(self, given, lattice: Lattice, ref_mask: np.ndarray, warnings: list):
        self.given, self.lattice, self.ref_mask = given, lattice, ref_mask
        self.warnings = warnings
        self.model = self.how = self.estimated_on = None
        self.failed = False
        self.singles = 0
        self._first = True

    @staticmethod
    def _from_model(r: _Measured, model, how: str) -> _Measured:
        st = r.stats
        var = np.maximum(model.K * st.mean + model.L, 0.0)
        return dataclasses.replace(r, stats=_Stats(st.mean, var, how, st.saturation))

    def complete(self, r: _Measured) -> _Measured:
        """``r`` with its noise variance map."""
        is_ref, self._first = self._first, False
        if self.given is not None:
            return self._from_model(r, self.given, _describe_model(
                self.given, f"camera model ({self.given.method})"))
        if r.stats.variance is not None:
            return r
        self.singles += 1
        if self.model is None and not self.failed:
            s0 = r.series
            try:
                model = estimate_noise_image(r.stats.mean, self.lattice,
                                             mask=self.ref_mask if is_ref else None,
                                             saturation=s0.saturation_level, scale=s0.scale)
            except ValueError as exc:
                self.warnings.append(
                    f"{s0.name}: the noise could not be estimated from its single image "
                    f"({exc}); the single-frame series get no uncertainty of their own "
                    "(give --noise or --noise-model)")
                self.failed = True
                return r
            self.model = dataclasses.replace(model, bit_depth=s0.bit_depth)
            self.estimated_on = s0.name
            self.how = _describe_model(self.model, f"single image ({s0.name})")
        return r if self.failed else self._from_model(r, self.model, self.how)

    def info(self, done: list) -> dict:
        """Where the variances came from (``NoiseFloor.model``)."""
        if self.given is not None:
            return {"source": f"given ({self.given.method})", **self.given.as_dict()}
        if self.singles == 0:
            return {"source": "stack"}
        if self.failed:
            return {"source": "unavailable"}
        source = "single image" if self.singles == len(done) else "stack and single image"
        return {"source": source, "estimated_on": self.estimated_on, **self.model.as_dict()}


class _ReferenceFloor:
    """The noise floor and uncertainty of every state against the reference.

    Holds the reference's maps and the half-against-half measurement of its frames;
    :meth:`state` gives one state's floors, uncertainty maps and systematic-error
    figures (with their warnings), :meth:`noise_floor` the table of them all.
    """

    def __init__(self, r: _Measured, summary: _Summary, ref_pass: SeriesPass,
                 lattice: Lattice, sigma: float, margin: float, method: str,
                 report: Progress, warnings: list):
        self.r, self.lattice, self.sigma = r, lattice, float(sigma)
        T1, T2 = ref_pass.half_counts()
        if min(T1, T2) >= 1:
            self.su, self.se = _split_floor(ref_pass, lattice, sigma, r.mask, margin, method,
                                            report, mean_maps=r.maps)
        else:
            self.su, self.se, (T1, T2) = np.full(2, np.nan), np.full(3, np.nan), (1, 1)
            warnings.append("a single reference frame: no split-halves noise estimate "
                            "(measure a second image of the unloaded specimen as a state: "
                            "its maps are the noise floor)")
        self.T1, self.T2 = T1, T2
        self.sr = summary
        self.local_ref = self._local(r)
        self.var_ref_phase = None  # the reference's phase variance (_uncertainty)
        self.r = r.dropping("variance")  # only its smoothed copy is used from here on
        self.rows: dict[str, list] = {k: [] for k in ("theory_u", "theory_strain", "split_u",
                                                      "split_strain", "vibration_u")}

    def _local(self, r: _Measured):
        if r.stats.variance is None:
            return None
        # the weight of a pixel's noise in Psi is g^2, a Gaussian of std sigma / sqrt 2
        return ndimage.gaussian_filter(r.stats.variance, self.sigma / math.sqrt(2),
                                       mode="nearest", truncate=5.0)

    def state(self, c: _Measured, sc: _Summary, res: Measurement, rec: FringeOrder,
              alias: dict, warnings: list) -> tuple:
        """``(measurement, fringe order, uncertainty maps or None, floors, smoothing)``
        of state ``c`` (summarised in ``sc``)."""
        ref = self.sr
        th_u, th_e = _theory_floor(ref.variance, ref.T, ref.modulus, sc.variance, sc.T,
                                   sc.modulus, self.sigma, self.lattice)
        scale = math.sqrt((1 / ref.T + 1 / sc.T) / (1 / self.T1 + 1 / self.T2))
        vib_u = np.full(2, np.nan)
        offs = [np.array(v.phase_offset_std) for v in (ref.vib, sc.vib)]
        if all(np.all(np.isfinite(o)) for o in offs):
            # the offsets are phases: eq. (34) turns them into a rigid translation
            vib_u = theory.displacement_noise_std(offs[0], offs[1], self.lattice)
        row = {"theory_u": th_u, "theory_strain": th_e, "split_u": self.su * scale,
               "split_strain": self.se * scale, "vibration_u": vib_u}
        unc = self._uncertainty(c, res)
        if ref.kept_flagged or sc.kept_flagged:
            # frames flagged but kept: the precision of this state is not known
            row = {k: np.full_like(np.asarray(v, dtype=float), np.nan) for k, v in row.items()}
            if unc is not None:
                unc = {k: np.full_like(v, np.nan) for k, v in unc.items()}
        for k, v in row.items():
            self.rows[k].append(np.asarray(v, dtype=float))
        if unc is not None and res.valid.any():
            floors = {k.removesuffix("_std"): median(a[res.valid], overwrite_input=True)
                      for k, a in unc.items()}
        else:
            floors = {"ux": float(row["theory_u"][0]), "uy": float(row["theory_u"][1]),
                      "exx": float(row["theory_strain"][0]),
                      "eyy": float(row["theory_strain"][1]),
                      "exy": float(row["theory_strain"][2])}
        smooth = smoothing_bias(res.strain, res.valid, sigma=self.sigma)
        warnings.extend(_systematic_warnings(c.name, res, floors, alias, smooth,
                                             self.lattice))
        return res, rec, unc, floors, smooth

    def _uncertainty(self, c: _Measured, res: Measurement):
        local = self._local(c)
        # a single-frame series is taken as noisy per frame as the other one
        v_ref = self.local_ref if self.local_ref is not None else local
        v_def = local if local is not None else self.local_ref
        if v_ref is None:
            return None
        if self.local_ref is None:
            var_ref = _phase_variance(self.r.maps, v_ref / self.sr.T)
        else:  # the reference's side, the same for every state: made once
            if self.var_ref_phase is None:
                self.var_ref_phase = _phase_variance(self.r.maps, v_ref / self.sr.T)
            var_ref = self.var_ref_phase
        u_std, strain_std = _displacement_strain_std(
            var_ref, c.maps, variance_def=v_def / c.series.n_frames, valid=res.valid)
        names = ("ux_std", "uy_std", "exx_std", "eyy_std", "exy_std")
        return dict(zip(names, (*u_std, *strain_std), strict=True))

    def noise_floor(self, done: list, model_info: dict) -> NoiseFloor:
        n = len(done) - 1
        rows = {k: np.array(v, dtype=float).reshape(n, 2 if k.endswith("_u") else 3)
                for k, v in self.rows.items()}
        return NoiseFloor(sigma=self.sigma, sensor_variance=tuple(d.variance for d in done),
                          variance_method=tuple(d.variance_method for d in done),
                          modulus=np.array([d.modulus for d in done]), model=model_info,
                          frames=tuple(int(d.T) for d in done), **rows)


def _after_warp(res: Measurement, rec: FringeOrder, coarse: _CoarseReference,
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
    it. ``coarse``: the reference's side of :func:`coarse_displacement` (its mean
    image and mask), the one the states' image features use."""
    v = res.valid
    if rec.source == "previous state" or not v.any() or res.reference is None:
        return res, rec, []
    u = np.stack([_nearest_filled(res.u[k], v) for k in range(2)])
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
    off = np.rint(lattice.K @ np.array(est.shift))
    if not off.any():
        if rec.confirmed:
            return res, rec, []
        return res, dataclasses.replace(
            rec, confirmed=True, source="image features",
            detail=f"the deformed image warped back by the measured field matches the "
                   f"reference's content ({est.reason}); {rec.detail}"), []
    before = _median_u(res)
    shift = np.linalg.solve(lattice.K, off)  # the whole periods the content is off
    g = np.array(res.guess, dtype=float) + shift
    again = deformation(res.reference, res.deformed, lagrangian=res.lagrangian, guess=g)
    rec = FringeOrder("image features", True, again.guess,
                      f"the deformed image warped back by the field {before} showed the "
                      f"reference's content {shift[0]:.2f}, {shift[1]:.2f} px away "
                      f"({est.reason}); {rec.source} had given it", est.correlation,
                      est.peak_to_alias, est.disagreement, est.shift)
    return again, rec, [f"{name}: the displacement was whole periods off ({before}): "
                        f"warped back by it, the deformed image's content lay "
                        f"{shift[0]:.2f}, {shift[1]:.2f} px from the reference's; it is "
                        f"now {_median_u(again)}"]


def _discontinuities(res: Measurement, name: str) -> tuple[Measurement, tuple, list[str]]:
    """``res`` measured again without the pixels whose window straddles a jump of
    its displacement (:mod:`gridstrain.discontinuities`), the jumps' regions, and
    the warnings naming them."""
    disc = find_discontinuities(res)
    if not disc:
        return res, (), []
    before = ndimage.label(res.valid)[1]
    res = without_discontinuities(res, disc)
    said = [f"{name}: the displacement jumps (a crack, an edge or a torn grid?) at "
            f"{disc.describe()}: the {int(disc.band.sum())} pixels whose window straddles "
            "it are left out"]
    after = ndimage.label(res.valid)[1]
    if after > before:
        said.append(f"{name}: the jump cuts the field into {after} regions whose whole "
                    "numbers of periods were fixed each on its own (closest to the "
                    "guess): across an opening of more than half a pitch one of them may "
                    "be whole periods off; pass a guess or an intermediate state")
    return res, tuple(disc.regions), said


def _systematic_warnings(name: str, m: Measurement, fl: dict, alias: dict, smooth: dict,
                         lattice: Lattice) -> list[str]:
    """Warnings for the systematic errors of one state that can exceed its noise."""
    out = []
    known = [fl[k] for k in ("ux", "uy") if math.isfinite(fl[k])]
    u_noise = max(known) if known else 0.0
    noise_txt = f"{u_noise:.2g} px" if known else "unknown"
    if alias["u_px"] > max(u_noise, _ALIAS_MIN_PX):
        how = ("estimated from the harmonics seen in the reference image"
               if alias["observable"] else "bound for sharp lines; the line profile "
               "cannot be seen at this pitch")
        e_max = float(np.max(np.abs(m.strain[:, m.valid]))) if m.valid.any() else 0.0
        out.append(f"{name}: harmonics of the grid's lines can alias onto the carrier "
                   f"at pitch {lattice.pitch:.3g} px: displacement error up to "
                   f"{alias['u_px']:.2g} px and strain error up to "
                   f"{alias['strain_per_strain'] * e_max:.2g} ({how}), above the noise "
                   f"({noise_txt}); use a larger sigma, a pitch away from 4 px "
                   "or a smoother (defocused) grid")
    for j, comp in enumerate(("exx", "eyy", "exy")):
        b, bound = smooth["estimate_max"][j], smooth["max"][j]
        e_noise = fl[comp]
        # noise alone takes the largest sigma^2/2 lap(e) to about 1.1 noise std on a
        # 200 x 200 field, 1.5 on 2000 x 2000: 2.5 times it is signal
        if b is None or not math.isfinite(e_noise) or b <= 2.5 * e_noise or b <= 1e-6:
            continue
        text = (f"{name}: the window smooths the {comp} gradients: its bias may reach "
                f"{bound:.2g} ({smooth['factor']:g} x the largest sigma^2/2 lap(e)) against "
                f"a noise std of {e_noise:.2g}")
        if smooth["below_resolution"][j]:
            text += (f"; the sharpest feature is at or below the spatial resolution "
                     f"({SPATIAL_RESOLUTION_PER_SIGMA * m.sigma:.3g} px): its peak may be "
                     f"lowered by up to {smooth['attenuation'][j]:.0%}")
        out.append(text + "; a smaller sigma resolves them better at the cost of noise")
    return out


def empty_state_message(name: str, margin: float, sigma: float, guess, source: str) -> str:
    """Why a state without a single valid pixel is refused (never a written result)."""
    return (f"{name}: no valid pixel, nothing written: the mask, the band of margin = "
            f"{margin:g} sigmas (sigma {sigma:.4g} px), the grid's modulus and the "
            f"displacement (guess {guess[0]:.4g}, {guess[1]:.4g} px, {source}) leave no "
            "pixel to measure")


def _streamed(output, n_states: int):
    from .results import _Streamed  # h5py only when a file is written

    return _Streamed(output, n_states)


def _as_dtype(res: Measurement, unc, dtype):
    """The maps of a state in ``dtype`` (None: as they are)."""
    if dtype is None or res.u.dtype == dtype:
        return res, unc
    res = dataclasses.replace(res, u=res.u.astype(dtype), strain=res.strain.astype(dtype),
                              rotation=res.rotation.astype(dtype))
    return res, None if unc is None else {k: v.astype(dtype) for k, v in unc.items()}


class _InMemory:
    """Collects the states' maps for a :class:`SeriesResult` held in memory."""

    def __init__(self, n_states: int, dtype=None):
        self.n, self.dtype = n_states, dtype
        self.measurements, self.orders, self.unc = [], [], []
        self.floors, self.smoothing = [], []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add(self, i: int, res: Measurement, rec: FringeOrder, unc, floors: dict,
            smooth: dict) -> None:
        res, unc = _as_dtype(res, unc, self.dtype)
        self.measurements.append(res)
        self.orders.append(rec)
        self.unc.append(unc)
        self.floors.append(floors)
        self.smoothing.append(smooth)

    def reader(self, i: int):
        """None: the maps of state ``i`` are held here already."""
        return None

    def result(self, **fields) -> SeriesResult:
        ms = self.measurements
        uncertainty = None
        have = [a for a in self.unc if a is not None]
        if have:
            uncertainty = {k: np.stack([a[k] if a is not None else
                                        np.full_like(have[0][k], np.nan) for a in self.unc])
                           for k in have[0]}
        return SeriesResult(
            u=np.stack([r.u for r in ms]), strain=np.stack([r.strain for r in ms]),
            valid=np.stack([r.valid for r in ms]), measurements=tuple(ms),
            guesses=tuple(tuple(float(v) for v in r.guess) for r in self.orders),
            guess_sources=tuple(r.source for r in self.orders),
            fringe_orders=tuple(self.orders), uncertainty=uncertainty, **fields)


# --------------------------------------------------------------------------- saving


def _check_pixel_size(pixel_size, unit):
    if pixel_size is None:
        if unit is not None:
            raise ValueError(f"unit needs a pixel_size, got unit={unit!r} without one")
        return None, None
    ps = check_positive(pixel_size, "pixel_size")
    if not isinstance(unit, str) or not unit.strip() or len(unit) > 32 \
            or not unit.isprintable():
        raise ValueError(f"unit must be a short name such as 'mm' when pixel_size is "
                         f"given, got {unit!r}")
    return ps, unit.strip()


def save_result(result: SeriesResult, path, **options) -> Path:
    """Write a result to its HDF5 file: :func:`gridstrain.results.save_result`."""
    from .results import save_result as _save

    return _save(result, path, **options)


def save_csv(result: SeriesResult, path, **options) -> Path:
    """One CSV row per valid pixel: :func:`gridstrain.results.save_csv`."""
    from .results import save_csv as _save

    return _save(result, path, **options)
