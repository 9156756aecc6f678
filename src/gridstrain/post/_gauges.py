"""Virtual strain gauges and extensometers on the maps of every state."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validation import check_type, freeze_arrays
from ..kinematics import (
    DERIVED_STRAINS,
    FiniteStrains,
    PrincipalStrains,
    finite_strains,
    principal_strains,
)
from ..results import FINITE_FIELDS, SeriesResult, state_loads
from . import _correlation
from ._places import place_mask, points_px, refuse_empty, result_frame
from ._units import strain_scale

_STRAINS = ("exx", "eyy", "exy")


@dataclass(frozen=True)
class GaugeReading:
    """What a virtual gauge (and extensometer) read on each loaded state.

    Attributes
    ----------
    states : tuple of str
        The loaded states' names, in order.
    where : str
        The gauge, in words (its region and unit).
    n_pixels : (n_states,) int ndarray
        Valid pixels averaged in each state.
    exx, eyy, exy : (n_states,) float64 ndarray
        Mean strain over the gauge's valid pixels, dimensionless (tensor shear).
    exx_std, eyy_std, exy_std : (n_states,) float64 ndarray
        Standard deviation of each mean from the sensor noise: the per-pixel std
        maps propagated through the correlation the window gives neighbouring
        pixels (:mod:`gridstrain.post._correlation`). NaN when the result has no
        uncertainty maps.
    ux, uy, ux_std, uy_std : (n_states,) float64 ndarray
        Mean displacement over the gauge and its std, px.
    load : (n_states,) float64 ndarray or None
        The load of each state, in ``load_unit``.
    load_unit : str or None
    time : (n_states,) float64 ndarray or None
        Time of each state, s.
    extensometer : (n_states,) float64 ndarray or None
        Engineering strain ``(l - L) / L`` between the extensometer's two points.
    extensometer_std : (n_states,) float64 ndarray or None
    extensometer_where : str or None
    reference_share : (n_states,) float64 ndarray or None
        The part of each state's noise variance that comes from the reference
        image (:func:`reference_share`): common to every state, it moves all the
        readings together, so it cancels in differences between states, slopes
        and rates. None where the result does not tell.
    rotation, rotation_std : (n_states,) float64 ndarray or None
        Mean rotation ``(du_y/dx - du_x/dy) / 2`` over the gauge and its std, rad; read
        with ``gauge(..., finite=True)`` from a result measured with the Lagrangian
        correction, else None.
    gradient_std : (n_states, 4) float64 ndarray or None
        Std of the mean ``du_x/dx``, ``du_x/dy``, ``du_y/dx``, ``du_y/dy``: what
        :meth:`finite_strains` propagates.
    lagrangian : bool
        Whether the result's strains are Lagrangian.
    pixel_size, unit : float, str or None
        The pixel size of the gauge's result and its length unit (None for a result
        without one), whatever unit the place was named in: :func:`history` gives the
        velocity in it.
    """

    states: tuple[str, ...]
    where: str
    n_pixels: np.ndarray
    exx: np.ndarray
    exx_std: np.ndarray
    eyy: np.ndarray
    eyy_std: np.ndarray
    exy: np.ndarray
    exy_std: np.ndarray
    ux: np.ndarray
    ux_std: np.ndarray
    uy: np.ndarray
    uy_std: np.ndarray
    load: np.ndarray | None = None
    load_unit: str | None = None
    time: np.ndarray | None = None
    extensometer: np.ndarray | None = None
    extensometer_std: np.ndarray | None = None
    extensometer_where: str | None = None
    reference_share: np.ndarray | None = None
    rotation: np.ndarray | None = None
    rotation_std: np.ndarray | None = None
    gradient_std: np.ndarray | None = None
    lagrangian: bool = True
    pixel_size: float | None = None
    unit: str | None = None

    def __post_init__(self):
        freeze_arrays(self)

    def finite_strains(self) -> FiniteStrains:
        """The Green–Lagrange and logarithmic strains of the gauge's mean displacement
        gradient in each state, with their first-order std
        (:func:`gridstrain.kinematics.finite_strains`): of the mean gradient, as
        :meth:`principal_strains` is of the mean tensor; NaN std without uncertainty
        maps.

        Raises
        ------
        ValueError
            The gauge's result was measured with ``lagrangian=False``.
        """
        if self.rotation is None and not self.lagrangian:
            raise ValueError("the finite strains need the Lagrangian displacement "
                             "gradient, and this gauge's result was measured with "
                             "lagrangian=False (measure --no-lagrangian)")
        if self.rotation is None:
            raise ValueError("the finite strains need the gauge's mean rotation: read "
                             "the gauge with gauge(..., finite=True) (gauge --finite)")
        g = self.gradient_std
        return finite_strains(self.exx, self.eyy, self.exy, self.rotation,
                              gradient_std=None if g is None else tuple(g.T))

    def principal_strains(self) -> PrincipalStrains:
        """The principal strains ``e1``, ``e2``, their angle, the equivalent strain and
        the maximum shear of the gauge's mean tensor in each state, with their std.

        Those a strain rosette gives: of the mean of ``exx``, ``eyy``, ``exy`` (not the
        mean of each pixel's principal strain), the std propagated to first order from
        ``exx_std``, ``eyy_std``, ``exy_std``, the three taken as uncorrelated
        (:func:`gridstrain.kinematics.principal_strains`, whose Notes say when that
        holds); NaN std without uncertainty maps.
        """
        return principal_strains(self.exx, self.eyy, self.exy, exx_std=self.exx_std,
                                 eyy_std=self.eyy_std, exy_std=self.exy_std)

    def columns(self, *, derived: bool = False, finite: bool = False
                ) -> dict[str, np.ndarray]:
        """The table, column by column, each name followed by its unit in brackets.

        With ``derived``, the columns of :meth:`principal_strains` after ``exy``:
        ``e1 [-]``, ``e1_std [-]``... ``principal_angle [rad]``...; with ``finite``,
        those of :meth:`finite_strains`: ``gl_xx [-]``, ``gl_xx_std [-]``...
        ``log_xy_std [-]``.
        """
        cols: dict[str, np.ndarray] = {"state": np.array(self.states, dtype=str)}
        if self.load is not None:
            cols[f"load [{self.load_unit or '-'}]"] = self.load
        if self.time is not None:
            cols["time [s]"] = self.time
        for name in _STRAINS:
            cols[f"{name} [-]"] = getattr(self, name)
            cols[f"{name}_std [-]"] = getattr(self, f"{name}_std")
        if derived:
            p = self.principal_strains()
            for name, unit in DERIVED_STRAINS.items():
                unit = "-" if unit == "1" else unit
                cols[f"{name} [{unit}]"] = getattr(p, name)
                cols[f"{name}_std [{unit}]"] = getattr(p, f"{name}_std")
        if finite:
            f = self.finite_strains()
            for name, attr in FINITE_FIELDS.items():
                cols[f"{name} [-]"] = getattr(f, attr)
                cols[f"{name}_std [-]"] = getattr(f, f"{attr}_std")
        if self.extensometer is not None:
            cols["extensometer [-]"] = self.extensometer
            cols["extensometer_std [-]"] = self.extensometer_std
        return cols

    def to_csv(self, path, *, derived: bool = False, finite: bool = False,
               overwrite: bool = False):
        """Write :meth:`columns` to a CSV file, atomically; returns its path.

        Floats with 10 significant digits: a strain to 1e-10, far below any noise.
        Strains dimensionless whatever a table shows.
        """
        from ..io import write_csv

        return write_csv(path, self.columns(derived=derived, finite=finite),
                         overwrite=overwrite, digits=10)

    def table(self, *, strain_units: str = "microstrain", derived: bool = False,
              finite: bool = False) -> str:
        """The readings as a fixed-width text table.

        Parameters
        ----------
        strain_units : {"microstrain", "%", "1"}
            Strains in µε (default, 0.1 µε shown), percent (1e-5 %) or dimensionless
            (1e-7); :data:`gridstrain.post.STRAIN_UNITS`.
        derived : bool
            Also the principal strains, their angle (degrees), the equivalent strain
            and the maximum shear (:meth:`principal_strains`).
        finite : bool
            Also the Green–Lagrange and logarithmic strains (:meth:`finite_strains`).
        """
        factor, label = strain_scale(strain_units)
        # a tenth of a microstrain in every unit: below any noise floor
        decimals = {1e6: 1, 100.0: 5, 1.0: 7}[factor]
        cols = self.columns(derived=derived, finite=finite)
        head, rows = [], []
        for key, arr in cols.items():
            if key.startswith("state"):
                text = [str(v) for v in arr]
            elif key.endswith("[-]"):
                key = key.replace("[-]", f"[{label}]")
                text = [f"{v * factor:.{decimals}f}" for v in arr]
            elif key.endswith("[rad]"):
                key = key.replace("[rad]", "[deg]")
                text = [f"{np.degrees(v):.2f}" for v in arr]
            else:
                text = [f"{v:.6g}" for v in arr]
            head.append(key)
            rows.append(text)
        widths = [max(len(h), *(len(t) for t in col)) for h, col in zip(head, rows,
                                                                          strict=True)]
        lines = [self.where + (f"; extensometer {self.extensometer_where}"
                               if self.extensometer_where else ""),
                 "  ".join(h.rjust(w) for h, w in zip(head, widths, strict=True))]
        for r in range(len(self.states)):
            lines.append("  ".join(col[r].rjust(w) for col, w in zip(rows, widths,
                                                                        strict=True)))
        return "\n".join(lines)

    def to_xarray(self):
        """The readings as an ``xarray.Dataset`` along ``state`` (needs xarray).

        Each variable carries its ``units`` and ``long_name``; the load and the time,
        when known, are coordinates of ``state``.
        """
        import xarray as xr

        coords = {"state": list(self.states)}
        if self.load is not None:
            coords["load"] = ("state", self.load, {"units": self.load_unit or ""})
        if self.time is not None:
            coords["time"] = ("state", self.time, {"units": "s"})
        data = {}
        for name in (*_STRAINS, "extensometer"):
            if getattr(self, name) is None:
                continue
            data[name] = ("state", getattr(self, name), {"units": "1", "long_name":
                                                          f"mean {name} over the gauge"})
            data[f"{name}_std"] = ("state", getattr(self, f"{name}_std"),
                                   {"units": "1", "long_name": f"std of the mean {name}"})
        p = self.principal_strains()
        for name, unit in DERIVED_STRAINS.items():
            data[name] = ("state", getattr(p, name), {"units": unit, "long_name":
                                                      f"{name} of the mean strain tensor"})
            data[f"{name}_std"] = ("state", getattr(p, f"{name}_std"),
                                   {"units": unit, "long_name": f"first-order std of {name}"})
        if self.rotation is not None:
            f = self.finite_strains()
            for name, attr in FINITE_FIELDS.items():
                data[name] = ("state", getattr(f, attr), {"units": "1", "long_name":
                              f"{name} of the mean displacement gradient"})
                data[f"{name}_std"] = ("state", getattr(f, f"{attr}_std"),
                                       {"units": "1", "long_name": f"first-order std of "
                                                                   f"{name}"})
        for name in ("ux", "uy"):
            data[name] = ("state", getattr(self, name), {"units": "px"})
            data[f"{name}_std"] = ("state", getattr(self, f"{name}_std"), {"units": "px"})
        return xr.Dataset(data, coords=coords, attrs={"gauge": self.where})

    def to_pandas(self, *, derived: bool = False, finite: bool = False):
        """The table as a ``pandas.DataFrame`` indexed by state (needs pandas);
        ``derived`` and ``finite`` as for :meth:`columns`."""
        import pandas as pd

        cols = self.columns(derived=derived, finite=finite)
        return pd.DataFrame({k: v for k, v in cols.items() if k != "state"},
                            index=pd.Index(cols["state"], name="state"))


def reference_share(result) -> np.ndarray | None:
    """Per state, the fraction of its maps' noise variance that the reference gives.

    A map's variance adds the reference's and the state's, each the series'
    per-frame noise variance over its frame count and squared carrier modulus
    (:func:`gridstrain.uncertainty.predict_uncertainty`); with the whole-image
    values of :class:`gridstrain.uncertainty.NoiseFloor`, the share is
    ``w_ref / (w_ref + w_state)``, ``w = variance / (T |Psi|^2)``. None when a
    value is missing.
    """
    noise = getattr(result, "noise", None)
    try:
        var = np.asarray(noise.sensor_variance, dtype=np.float64)
        frames = np.asarray(noise.frames if noise.frames else result.n_frames,
                            dtype=np.float64)
        mod2 = np.mean(np.asarray(noise.modulus, dtype=np.float64) ** 2, axis=1)
    except (AttributeError, TypeError, ValueError):
        return None
    w = var / (frames * mod2)
    if w.shape != (result.n_states + 1,) or not np.all(np.isfinite(w) & (w > 0)):
        return None
    return w[0] / (w[0] + w[1:])


def _bilinear(field, valid, x, y):
    """``field`` at the point (x, y) px, bilinear; NaN unless its 4 pixels are valid."""
    H, W = field.shape
    c0, r0 = math.floor(x), math.floor(y)
    if not (c0 >= 0 and r0 >= 0 and c0 + 1 < W and r0 + 1 < H):
        return math.nan
    blk = field[r0:r0 + 2, c0:c0 + 2].astype(np.float64)
    if not valid[r0:r0 + 2, c0:c0 + 2].all():
        return math.nan
    fx, fy = x - c0, y - r0
    return float(blk[0, 0] * (1 - fx) * (1 - fy) + blk[0, 1] * fx * (1 - fy)
                 + blk[1, 0] * (1 - fx) * fy + blk[1, 1] * fx * fy)


def _extensometer(result, i, p0, p1, unc):
    """Engineering strain between two points (px) of state ``i`` and its std."""
    valid = np.asarray(result.valid[i])
    ux, uy = np.asarray(result.ux[i]), np.asarray(result.uy[i])
    d = p1 - p0
    length = float(np.hypot(*d))
    a = [np.array([_bilinear(ux, valid, *p), _bilinear(uy, valid, *p)]) for p in (p0, p1)]
    stretched = d + a[1] - a[0]
    value = (float(np.hypot(*stretched)) - length) / length
    if unc is None:
        return value, math.nan
    e = d / length
    # each end's displacement noise projected on the gauge's direction (u_x and u_y
    # taken as uncorrelated); the two ends correlated through the window
    var = [float(e[0] ** 2 * _bilinear(np.asarray(unc["ux_std"][i]), valid, *p) ** 2
                 + e[1] ** 2 * _bilinear(np.asarray(unc["uy_std"][i]), valid, *p) ** 2)
           for p in (p0, p1)]
    rho = float(_correlation.displacement_correlation(result.sigma, length ** 2))
    total = var[0] + var[1] - 2 * rho * math.sqrt(var[0] * var[1])
    return value, math.sqrt(max(total, 0.0)) / length


def gauge(result: SeriesResult, *, region=None, point=None, polygon=None,
          extensometer=None, unit: str | None = None, px: bool = False,
          pixel_size: float | None = None, load=None, load_unit: str | None = None,
          time=None, finite: bool = False) -> GaugeReading:
    """Mean strain over a region of every state, with its standard deviation.

    Parameters
    ----------
    result : SeriesResult
    region : (x0, y0, x1, y1) floats, optional
        The pixels whose centre lies in ``x0 <= x < x1``, ``y0 <= y < y1``
        (:mod:`gridstrain.conventions`: x is the column). Default (no region,
        point or polygon): the whole image.
    point : (x, y) floats, optional
        The pixel nearest to the point.
    polygon : (N, 2) floats, optional
        The pixels whose centre lies inside the polygon of vertices ``(x, y)``.
    extensometer : (x0, y0, x1, y1) floats, optional
        Two points whose distance is followed: engineering strain ``(l - L) / L``
        from the displacements interpolated (bilinear) at the points.
    unit : str, optional
        The coordinates above are in ``unit``, the result's length unit (``"mm"``:
        :attr:`SeriesResult.unit`, pixel ``x`` at ``x * result.pixel_size``), as the
        command line reads them.
    px : bool
        The coordinates above are in px.
    pixel_size : float, optional
        With ``unit``, for a result that carries no pixel size (one that carries
        another is refused).

        A place on a result that has a pixel size must say its unit (``unit=`` or
        ``px=True``): a call without either is refused, naming both, rather than read
        in a unit its author may not have meant (px before results carried their
        pixel size). On a result without one, places are px. The rule is written
        once, in :mod:`gridstrain.post._places`.
    load, time : (n_states,) array_like, optional
        The load (in ``load_unit``) and the time (s) of each loaded state.
        Default: the result's own ``load``, ``load_unit`` and ``time``, if any.
    finite : bool
        Also read the mean rotation and the std of the mean displacement gradient,
        for :meth:`GaugeReading.finite_strains` (three more double sums per state:
        a gauge takes half as long again). Refused for a result measured with
        ``lagrangian=False``.

    Returns
    -------
    GaugeReading

    Raises
    ------
    ValueError
        A region, point, polygon vertex or extensometer end outside the measured
        field (``0 <= x <= W * pixel_size``, likewise y), or a gauge with no valid
        pixel in any state: the message names the field's extent, and that of its
        valid pixels, in the unit the place was given in.

    Notes
    -----
    Only valid pixels are averaged. The standard deviation of the mean is
    ``sqrt(sum_ij s_i s_j rho_ij) / N``, with ``s`` the per-pixel predicted std
    maps (:func:`gridstrain.uncertainty.predict_uncertainty`) and ``rho`` the
    correlation the Gaussian window gives the noise of two pixels
    (:mod:`gridstrain.post._correlation`). The reference image's noise is common
    to every state: it shifts all the states' readings alike (its share of each
    variance is ``reference_share``).
    """
    check_type(result, "result", SeriesResult)
    frame = result_frame(result, pixel_size=pixel_size, unit=unit, px=px, places=(
        ("region", region), ("point", point), ("polygon", polygon),
        ("extensometer", extensometer)))
    mask, where = place_mask(frame, region=region, point=point, polygon=polygon)
    where = f"gauge over {where}" if point is None else f"gauge at {where}"
    load, load_unit, time = state_loads(result, load=load, load_unit=load_unit, time=time)
    n = result.n_states
    unc = result.uncertainty
    kernels = {name: _correlation.strain_kernel(result.lattice, result.sigma, name)
               for name in _STRAINS}
    kernels["ux"] = kernels["uy"] = _correlation.displacement_kernel(result.sigma)
    # the rotation and the gradient's off-diagonal terms, for the finite strains: their
    # std maps those of the uncertainty maps' noise model (SeriesResult.finite_strains)
    finite = check_type(finite, "finite", bool)
    if finite and not result.has_finite_strains:
        result.finite_strains(0)  # refused, saying why (an Eulerian result)
    extra = {"rotation": "exy_std", "uxy": "exx_std", "uyx": "eyy_std"} if finite else {}
    for name in extra:
        kernels[name] = _correlation.strain_kernel(result.lattice, result.sigma, name)
    out = {name: np.full(n, np.nan) for name in (*_STRAINS, "ux", "uy", *extra)}
    std = {name: np.full(n, np.nan) for name in out}
    count = np.zeros(n, dtype=np.int64)
    ext = ext_std = ext_where = None
    if extensometer is not None:
        pts = points_px(frame, extensometer, "extensometer", 4)
        p0, p1 = pts[:2], pts[2:]
        if np.hypot(*(p1 - p0)) < 1.0:
            raise ValueError(f"extensometer points must be at least 1 px apart, got "
                             f"{extensometer!r}")
        ext, ext_std = np.full(n, np.nan), np.full(n, np.nan)
        e = np.asarray(extensometer, dtype=float)
        length_px = float(np.hypot(*(p1 - p0)))
        # the length in the unit the points were named in, and in px (the window's unit)
        length = (f"L = {length_px:.1f} px" if frame.unit == "px" else
                  f"L = {length_px * frame.scale:.4g} {frame.unit} ({length_px:.1f} px)")
        ext_where = (f"({e[0]:g}, {e[1]:g}) to ({e[2]:g}, {e[3]:g}) {frame.unit}, "
                     f"{length}")
    for i in range(n):
        inside = mask & np.asarray(result.valid[i])
        count[i] = int(inside.sum())
        for name in out:
            if name in ("uxy", "uyx"):
                continue  # their means follow from exy's and the rotation's
            values = np.asarray(result.measurements[i].rotation if name == "rotation"
                                else result.get_map(name)[i])
            ok = inside & np.isfinite(values)
            if ok.any():
                out[name][i] = float(np.mean(values[ok], dtype=np.float64))
                stds = [n for n in ((name,) if name != "rotation" else
                                    ("rotation", "uxy", "uyx")) if n in kernels]
                for k in stds:
                    key = extra.get(k, f"{k}_std")
                    if unc is not None and key in unc:
                        s = np.asarray(unc[key][i])
                        std[k][i] = _correlation.std_of_mean(s, ok & np.isfinite(s),
                                                             kernels[k])
        if ext is not None:
            ext[i], ext_std[i] = _extensometer(result, i, p0, p1, unc)
    if not count.any():
        refuse_empty(frame, where, lambda i: result.valid[i], n)
    return GaugeReading(
        states=tuple(result.names[1:]), where=where, n_pixels=count,
        exx=out["exx"], exx_std=std["exx"], eyy=out["eyy"], eyy_std=std["eyy"],
        exy=out["exy"], exy_std=std["exy"], ux=out["ux"], ux_std=std["ux"],
        uy=out["uy"], uy_std=std["uy"], load=load, load_unit=load_unit, time=time,
        extensometer=ext, extensometer_std=ext_std, extensometer_where=ext_where,
        reference_share=reference_share(result),
        rotation=out["rotation"] if finite else None,
        rotation_std=std["rotation"] if finite else None,
        gradient_std=np.stack([std["exx"], std["uxy"], std["uyx"], std["eyy"]], axis=1)
        if finite else None, lagrangian=bool(result.lagrangian),
        pixel_size=result.pixel_size, unit=result.unit)

