"""The result of a series measurement: :class:`SeriesResult`, its maps and everything that
qualifies them (the fringe orders, the noise floor, the screening, the warnings).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

import numpy as np

from .._progress import FINDINGS, Finding, as_finding
from .._validation import check_choice, check_pixel_size
from ..kinematics import (
    DERIVED_STRAINS,
    FiniteStrains,
    FringeOrder,
    Measurement,
    PrincipalStrains,
    finite_strains,
    principal_strains,
)
from ..phase import Lattice
from ..stacks.vibration import VibrationReport
from ..uncertainty import NoiseFloor

#: Names of the maps, in file order, with their units before ``pixel_size``.
MAP_FIELDS = {"ux": "px", "uy": "px", "exx": "1", "eyy": "1", "exy": "1"}
#: The finite strains' maps (:meth:`SeriesResult.finite_strains`): the Green–Lagrange
#: ``gl_*`` and logarithmic ``log_*`` tensors' components, by the
#: :class:`~gridstrain.kinematics.FiniteStrains` field each is.
FINITE_FIELDS = {"gl_xx": "Exx", "gl_yy": "Eyy", "gl_xy": "Exy",
                 "log_xx": "Lxx", "log_yy": "Lyy", "log_xy": "Lxy"}
#: The maps derived from the measured ones, with their units: the strains derived from
#: the tensor (:meth:`SeriesResult.principal_strains`) and the finite strains; each
#: has a ``*_std`` when the result has uncertainty maps.
DERIVED_FIELDS = dict(DERIVED_STRAINS) | dict.fromkeys(FINITE_FIELDS, "1")


def map_unit(name: str) -> str:
    """The unit of any map a result offers (``ux``, ``rotation``, ``e1_std``...)."""
    base = name.removesuffix("_std")
    return MAP_FIELDS.get(base) or DERIVED_FIELDS.get(base) or \
        {"rotation": "rad"}[base]


# What a result does with itself, implemented by the file and the figures, which know the
# result type: found when called, so that the type depends on neither of them.
_ELSEWHERE = {"save": ("gridstrain.results", "save_result"),
              "to_xarray": ("gridstrain.results", "to_xarray"),
              "plot": ("gridstrain.post", "plot_states")}


def _elsewhere(action: str):
    module, name = _ELSEWHERE[action]
    return getattr(importlib.import_module(module), name)


# States listed one by one in a result's repr; beyond, the first and the last
_REPR_STATES = 6


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
        Every recorded option of the measurement (:data:`gridstrain.series.OPTIONS`;
        the run-only ones left out), JSON-friendly;
        ``gridstrain.series.MeasureOptions.from_parameters`` gives them back.
    warnings : tuple of Finding
        Things the user should know that did not stop the measurement: each a
        sentence (a ``str``) carrying its code, state and figures
        (:class:`gridstrain.Finding`; select them by ``code``). A file written
        before codes were stored gives them the code ``"other"``.
    findings : tuple of dict
        ``warnings``' codes, states and figures as plain records
        (:meth:`gridstrain.Finding.record`), one per warning: what a file stores
        beside the sentences.
    excluded : tuple of tuple of int
        Per series, the numbers of the frames the screening excluded (their files
        and reasons are in ``warnings``); ``n_frames`` counts the frames kept.
    screening : tuple of gridstrain.stacks.screening.FrameScreen
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
        :func:`gridstrain.uncertainty.smoothing_bias`); ``"vibration_offset"``, per
        series, the phase offset about the frames' mean position removed from
        methods A and B (``removed_rad``) and its predicted spread
        (``predicted_std_rad``, :func:`gridstrain.stacks.circular_offset_std`), None
        for method C; ``"pair_match"``, per state, whether its image shows the
        reference's specimen (:func:`gridstrain.kinematics.pair_match`).
    fringe_orders : tuple of FringeOrder
        How each state's whole number of periods was fixed and whether anything
        confirms it (see :class:`gridstrain.kinematics.FringeOrder`).
    state_order : {"natural", "reordered", "given"}
        The order the states were measured in: natural order (folders, globs, a
        numbered family of files already in it), explicit files put in natural
        order from the order given, or the order given kept
        (:mod:`gridstrain.io`).
    load : (n_states,) float64 ndarray, optional
        The load of each state, in ``load_unit`` (``measure_series(loads=...)``).
    load_unit : str, optional
        The unit of ``load`` (``"N"``, ``"kN"``...); None without loads or when
        they were given without a unit.
    time : (n_states,) float64 ndarray, optional
        The time of each state, s: from the frame rate (frame number in the
        record over the rate), the camera's time stamps, or the loads file's time
        column.
    load_source : dict, optional
        How ``load`` was read from a file (:attr:`gridstrain.io.LoadTable.source`):
        the file, its SHA-256, the columns and their units, the offset and the
        method joining it to the states; None when the loads were given as numbers.
    discontinuities : tuple of tuple of dict
        Per state, the displacement jumps found (a crack, an edge, a torn grid):
        their bounding boxes (``rows``, ``cols``: first and last, px), the pixels
        left out around them (``pixels``, invalid in ``valid``), the jump
        (``jump_px``, its ``opening_px`` and ``sliding_px``, known modulo the
        period ``pitch_px`` along it); see
        :func:`gridstrain.kinematics.find_discontinuities`.
    pixel_size : float, optional
        The length of a pixel on the specimen, in ``unit`` (``measure --pixel-size`` or
        ``--grid-pitch``; the result file's root attribute): places on the maps are
        named in ``unit`` by the command line, and in the API with ``unit=``
        (:mod:`gridstrain.post._places`). None when the file has none (px only).
    unit : str, optional
        The length unit of ``pixel_size`` (``"mm"``...); None with it.
    maps_precision : str, optional
        None for maps as measured; for maps read from a file that rounded them
        (:func:`gridstrain.results.save_result` without ``lossless``), that file's
        ``maps_precision``: a file or export written from them says so, never
        "lossless".
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
    load_source: dict | None = None
    #: ``warnings``' codes, states and figures (:meth:`Finding.record`), as a file
    #: stores them beside the sentences; filled from ``warnings`` when not given.
    findings: tuple = field(default=(), repr=False)
    pixel_size: float | None = None
    unit: str | None = None
    maps_precision: str | None = None

    def __post_init__(self):
        _with_findings(self)
        ps, unit = check_pixel_size(self.pixel_size, self.unit)
        object.__setattr__(self, "pixel_size", ps)
        object.__setattr__(self, "unit", unit)
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

    def _states(self, state):
        if state is None:
            return slice(None)
        if isinstance(state, bool) or not isinstance(state, int | np.integer) or \
                not -self.n_states <= state < self.n_states:
            raise ValueError(f"state must be an index of the {self.n_states} state(s) or "
                             f"None, got {state!r}")
        return int(state)

    def principal_strains(self, state: int | None = None) -> PrincipalStrains:
        """Principal strains ``e1``, ``e2``, their angle, the equivalent strain and the
        maximum shear, with their std when the result has uncertainty maps.

        Parameters
        ----------
        state : int, optional
            One state (maps ``(H, W)``); default every state (``(n_states, H, W)``).

        Returns
        -------
        gridstrain.kinematics.PrincipalStrains
            See :func:`gridstrain.kinematics.principal_strains`: the std to first order,
            the noises of ``exx``, ``eyy`` and ``exy`` taken as uncorrelated. NaN where
            not ``valid``.
        """
        i = self._states(state)
        unc = self.uncertainty or {}
        stds = {f"{c}_std": np.asarray(unc[f"{c}_std"][i]) for c in ("exx", "eyy", "exy")
                if f"{c}_std" in unc}
        if len(stds) < 3:
            stds = {}
        return principal_strains(np.asarray(self.exx[i]), np.asarray(self.eyy[i]),
                                 np.asarray(self.exy[i]), **stds)

    def finite_strains(self, state: int | None = None) -> FiniteStrains:
        """Green-Lagrange and logarithmic strains, rebuilt from the displacement
        gradient (the strain tensor and the rotation), with their first-order std when
        the result has uncertainty maps: see :func:`gridstrain.kinematics.finite_strains`.
        ``state`` as for :meth:`principal_strains`.

        The gradient's std are those of the noise model of the uncertainty maps
        (:func:`gridstrain.uncertainty.predict_uncertainty`): the derivatives of ``u_x``
        along x and along y have one variance, that of ``exx``, and those of ``u_y``
        that of ``eyy`` (so that ``exy_std`` is ``sqrt(exx_std^2 + eyy_std^2) / 2``, and
        so is the rotation's std), the four taken as uncorrelated.

        Raises
        ------
        ValueError
            A result measured with ``lagrangian=False``: its gradient is Eulerian, and
            the finite strains of :mod:`gridstrain.kinematics` need the Lagrangian one.
        """
        if not self.lagrangian:
            raise ValueError("the finite strains need the Lagrangian displacement "
                             "gradient, and this result was measured with "
                             "lagrangian=False (measure --no-lagrangian): measure again "
                             "without it")
        i = self._states(state)
        rot = self.measurements[i].rotation if state is not None else \
            np.stack([np.asarray(m.rotation) for m in self.measurements])
        stds = self._gradient_std(i)
        return finite_strains(np.asarray(self.exx[i]), np.asarray(self.eyy[i]),
                              np.asarray(self.exy[i]), np.asarray(rot), gradient_std=stds)

    def _gradient_std(self, i):
        """The std maps of ``(du_x/dx, du_x/dy, du_y/dx, du_y/dy)`` of state(s) ``i``
        (see :meth:`finite_strains`), or None without uncertainty maps."""
        unc = self.uncertainty or {}
        if "exx_std" not in unc or "eyy_std" not in unc:
            return None
        sx, sy = np.asarray(unc["exx_std"][i]), np.asarray(unc["eyy_std"][i])
        return sx, sx, sy, sy

    @property
    def has_finite_strains(self) -> bool:
        """Whether :meth:`finite_strains` has a meaning here (``lagrangian=True``,
        rotation maps kept)."""
        return bool(self.lagrangian) and all(getattr(m, "rotation", None) is not None
                                             for m in self.measurements)

    def derived_maps(self, state: int | None = None, *, finite: bool | None = None
                     ) -> dict[str, np.ndarray]:
        """The maps of :data:`DERIVED_FIELDS` (and their ``*_std``, with uncertainty
        maps, and ``rotation_std``), by name: those the exports write.

        The finite strains (``gl_*``, ``log_*``): with ``finite=None`` (the default)
        where :attr:`has_finite_strains`, with ``True`` always (refused on an Eulerian
        result, see :meth:`finite_strains`), with ``False`` never."""
        p = self.principal_strains(state)
        out = {name: getattr(p, name) for name in DERIVED_STRAINS}
        if finite is None:
            finite = self.has_finite_strains
        f = self.finite_strains(state) if finite else None
        if f is not None:
            out.update({name: getattr(f, attr) for name, attr in FINITE_FIELDS.items()})
        for name in DERIVED_STRAINS:
            if getattr(p, f"{name}_std") is not None:
                out[f"{name}_std"] = getattr(p, f"{name}_std")
        if f is not None and f.Exx_std is not None:
            out.update({f"{name}_std": getattr(f, f"{attr}_std")
                        for name, attr in FINITE_FIELDS.items()})
        stds = self._gradient_std(self._states(state))
        if stds is not None:
            # the rotation's std under the uncertainty maps' noise model: that of exy
            out["rotation_std"] = np.sqrt(stds[0] ** 2 + stds[2] ** 2) / 2
        return out

    def save(self, path, **options):
        """Write this result to its HDF5 file (:func:`gridstrain.results.save_result`)."""
        return _elsewhere("save")(self, path, **options)

    def to_xarray(self, **options):
        """This result as an ``xarray.Dataset`` (:func:`gridstrain.results.to_xarray`);
        needs ``gridstrain[xarray]``."""
        return _elsewhere("to_xarray")(self, **options)

    def plot(self, name: str = "exx", **options):
        """Maps of ``name`` for every state on common colour limits
        (:func:`gridstrain.post.plot_states`); returns a matplotlib Figure."""
        return _elsewhere("plot")(self, name, **options)

    def __repr__(self) -> str:
        H, W = self.shape
        n = self.n_states
        if n <= _REPR_STATES:
            valid = ", ".join(f"{np.mean(self.valid[i]):.1%}" for i in range(n))
            frames = str(list(self.n_frames))
        else:  # a record: its first and last states (each read alone from a file)
            valid = (f"{np.mean(self.valid[0]):.1%} (first) to "
                     f"{np.mean(self.valid[n - 1]):.1%} (last)")
            lo, hi = min(self.n_frames[1:]), max(self.n_frames[1:])
            frames = (f"reference {self.n_frames[0]}, states "
                      + (f"{lo}" if lo == hi else f"{lo} to {hi}") + " each")
        return (f"SeriesResult({n} state(s) of {H}x{W}, method {self.method}, "
                f"sigma={self.sigma:.4g} px, frames {frames}, valid {valid})")


def _with_findings(result) -> None:
    """``result.warnings`` as findings and ``result.findings`` as their records: the
    one made from the other (a result measured now carries findings; one read from a
    file, their sentences and records apart; an older file, sentences alone)."""
    texts, records = result.warnings, result.findings
    if len(records) == len(texts) and texts:
        out = tuple(Finding(r["code"], t, state=r.get("state"), **(r.get("figures") or {}))
                    if not isinstance(t, Finding) and isinstance(r, dict)
                    and r.get("code") in FINDINGS else as_finding(t, "other")
                    for t, r in zip(texts, records, strict=True))
    else:
        out = tuple(as_finding(t, "other") for t in texts)
    object.__setattr__(result, "warnings", out)
    object.__setattr__(result, "findings", tuple(f.record() for f in out))
