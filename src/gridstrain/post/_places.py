"""Where a place is named on a result's maps: one rule for every gauge, point, polygon,
history and command.

Coordinates follow :mod:`gridstrain.conventions` (x the column, y the row, from 0):
pixel ``(col, row)`` has its centre at ``(col * s, row * s)`` with ``s`` the pixel size,
in the result file's length unit when it has one and in px otherwise (or when px are
asked for). The measured field spans ``0 <= x < W s``, ``0 <= y < H s``; a place
reaching outside it, or holding no valid pixel in any state, is refused in one line
that names the field's extent (and that of its valid pixels) in the unit the place
was given in: a wrong place never becomes an empty figure or a NaN reading.

The command line names places in the file's unit, px with ``--px``. The API follows
the same rule with the unit said (:func:`result_frame`): a result carries its file's
pixel size, and a place on it says ``unit=`` or ``px=True``; without either it is
refused, since such a call read px before results carried their pixel size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validation import check_pixel_size
from ..io import roi_mask

# A coordinate on the field's edge typed with a rounded pixel size (0.04 mm x 250 px
# = 10 mm) is on the edge, not outside: relative slack on the extent.
_SLACK = 1e-9
# Relative difference below which a pixel size given with a call is the result's own: a
# value printed to 6 digits and typed back.
_TYPED = 1e-5


@dataclass(frozen=True)
class Frame:
    """The measured field's frame: its size and the unit places are named in.

    Attributes
    ----------
    shape : (int, int)
        ``(H, W)`` of the maps, px.
    scale : float
        Length of a pixel in ``unit`` (1 for px).
    unit : str
        ``"px"`` or the file's length unit (``"mm"``...).
    """

    shape: tuple[int, int]
    scale: float
    unit: str

    @property
    def extent(self) -> str:
        """The field's extent in words, in :attr:`unit`."""
        H, W = self.shape
        return (f"the measured field spans x 0 to {W * self.scale:g}, y 0 to "
                f"{H * self.scale:g} {self.unit} ({W} x {H} px)")

    def inside(self, x: float, y: float) -> bool:
        """Whether ``(x, y)`` (in :attr:`unit`) lies in the field."""
        H, W = self.shape
        return all(-_SLACK * v <= c <= (1 + _SLACK) * v
                   for c, v in ((x, W * self.scale), (y, H * self.scale)))


def frame_of(shape, *, pixel_size: float | None = None, unit: str | None = None,
             px: bool = False) -> Frame:
    """The :class:`Frame` places are named in: ``unit`` with ``pixel_size``, px without
    it or with ``px=True``."""
    ps, unit = check_pixel_size(pixel_size, unit)
    if ps is None or px:
        return Frame(tuple(shape), 1.0, "px")
    return Frame(tuple(shape), ps, unit)


def result_frame(result, *, pixel_size: float | None = None, unit: str | None = None,
                 px: bool = False, places=()) -> Frame:
    """The :class:`Frame` a call's places on ``result`` are named in: the API's rule.

    ``px=True``: pixels. ``unit`` (the result's length unit, ``"mm"``...): that unit,
    with the result's own pixel size (:attr:`gridstrain.results.SeriesResult.pixel_size`).
    ``pixel_size`` and ``unit``: those (for a result that carries none; one that
    carries another is refused). None of them: px for a result without a pixel size;
    for one with a pixel size, a place given without its unit is refused, naming the
    two ways to write it, since a call once read in px would now mean the file's unit
    (the command line's default): the numbers of a script are never silently
    reinterpreted. ``places`` are ``(name, value)`` of the call's coordinates.
    """
    px = bool(px)
    own_ps, own_unit = getattr(result, "pixel_size", None), getattr(result, "unit", None)
    shape = tuple(result.shape)
    if px:
        if pixel_size is not None or unit is not None:
            raise ValueError(f"px=True names places in pixels: give it without pixel_size "
                             f"and unit, got pixel_size={pixel_size!r}, unit={unit!r}")
        return Frame(shape, 1.0, "px")
    if pixel_size is None and unit is None:
        if own_ps is None:
            return Frame(shape, 1.0, "px")
        for name, value in places:
            if value is not None:
                raise ValueError(
                    f"{name} {_text(value)} does not say its unit, and this result has a "
                    f"pixel size ({own_ps:g} {own_unit}): write unit={own_unit!r} to name "
                    f"it in {own_unit}, as the command line reads it, or px=True for "
                    "pixels")
        return Frame(shape, own_ps, own_unit)
    ps, u = own_length(own_ps, own_unit, pixel_size=pixel_size, unit=unit)
    return Frame(shape, ps, u)


def own_length(own_ps: float | None, own_unit: str | None, *,
               pixel_size: float | None = None, unit: str | None = None,
               what: str = "this result", px_too: bool = True
               ) -> tuple[float | None, str | None]:
    """``(pixel_size, unit)`` of a call on something that carries its own (a result, a
    gauge's reading; ``own_ps`` None when it carries none).

    None given: its own. ``unit`` alone: it must be its own unit, with its own pixel
    size. Both: for one that carries none, those; else they must be its own (a size
    typed from a printed one, within ``1e-5``, is, and its own is used): one that
    contradicts it is refused
    naming both, since a length scale taken from the call would silently change every
    length and modulus that follows. ``px_too``: the messages offer ``px=True`` (a call
    that can name px).
    """
    alt = ", or px=True for pixels" if px_too else ""
    if pixel_size is None and unit is None:
        return own_ps, own_unit
    if pixel_size is None:
        if own_ps is None:
            raise ValueError(f"unit={unit!r} needs a pixel size, and {what} carries "
                             "none (measured without --pixel-size or --grid-pitch): give "
                             f"pixel_size= with it{alt}")
        if not isinstance(unit, str) or unit.strip() != own_unit:
            raise ValueError(f"unit must be {what}'s length unit {own_unit!r} (pixel "
                             f"size {own_ps:g} {own_unit}){alt}, got {unit!r}")
        return own_ps, own_unit
    ps, u = check_pixel_size(pixel_size, own_unit if unit is None and own_ps is not None
                             else unit)
    # a pixel size typed from a printed one (0.04 for 0.0400003) is the result's own
    if own_ps is not None and (u != own_unit or not math.isclose(ps, own_ps,
                                                                 rel_tol=_TYPED)):
        raise ValueError(f"pixel_size={ps:g} {u} disagrees with {what}'s own "
                         f"({own_ps:g} {own_unit}): give unit={own_unit!r} alone{alt}, "
                         "or change the result's with dataclasses.replace(result, "
                         "pixel_size=..., unit=...)")
    # an equal one is the own one, to the last digit
    return (own_ps, own_unit) if own_ps is not None else (ps, u)


def drawn_in(result, *, pixel_size: float | None = None, unit: str | None = None,
             px: bool = False) -> tuple[float | None, str | None]:
    """``(pixel_size, unit)`` a figure of ``result`` draws its axes and displacements
    in: those given, else the result's own (:func:`result_frame`'s rule, no place
    named); ``(None, None)`` for px."""
    frame = result_frame(result, pixel_size=pixel_size, unit=unit, px=px)
    return (None, None) if frame.unit == "px" else (frame.scale, frame.unit)


def _text(value) -> str:
    try:
        return "(" + ", ".join(f"{float(v):g}" for v in np.ravel(value)) + ")"
    except (TypeError, ValueError):
        return repr(value)


def _numbers(values, name: str, n: int | None) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or not np.all(np.isfinite(arr)) or arr.ndim != 1 or \
            (n is not None and arr.size != n) or (n is None and (arr.size < 6 or
                                                                 arr.size % 2)):
        what = f"{n} finite numbers" if n else "at least 3 (x, y) vertices"
        raise ValueError(f"{name} must be {what}, got {values!r}")
    return arr


def check_inside(frame: Frame, points, name: str) -> None:
    """Refuse ``points`` (``(x, y)`` pairs in the frame's unit) outside the field."""
    for x, y in np.reshape(points, (-1, 2)):
        if not frame.inside(x, y):
            raise ValueError(f"{name} ({x:g}, {y:g}) {frame.unit} lies outside: "
                             f"{frame.extent}")


def points_px(frame: Frame, values, name: str, n: int) -> np.ndarray:
    """``n`` numbers (``n / 2`` points ``x, y``) in the frame's unit, checked inside the
    field, as px."""
    arr = _numbers(values, name, n)
    check_inside(frame, arr, name)
    return arr / frame.scale


def place_mask(frame: Frame, *, region=None, point=None, polygon=None
               ) -> tuple[np.ndarray, str]:
    """The pixels of a place and the place in words.

    Parameters
    ----------
    frame : Frame
        The field and the unit the place is named in (:func:`frame_of`).
    region : (x0, y0, x1, y1) floats, optional
        The pixels whose centre lies in ``x0 <= x < x1``, ``y0 <= y < y1``.
    point : (x, y) floats, optional
        The pixel nearest to the point.
    polygon : (N, 2) floats, optional
        The pixels whose centre lies inside the polygon.
        Default (none of the three): the whole field.

    Returns
    -------
    mask : (H, W) bool ndarray
    where : str
        The place in the unit given, with its columns and rows.

    Raises
    ------
    ValueError
        More than one place; a place reaching outside the field or holding no pixel:
        the message names the field's extent in the frame's unit.
    """
    given = [n for n, v in (("region", region), ("point", point), ("polygon", polygon))
             if v is not None]
    if len(given) > 1:
        raise ValueError(f"give one of region, point or polygon, got {' and '.join(given)}")
    H, W = frame.shape
    s, u = frame.scale, frame.unit
    if point is not None:
        x, y = _numbers(point, "point", 2)
        check_inside(frame, (x, y), "point")
        # the nearest pixel; a point in the last half pixel before the far edge is the
        # last pixel's
        c, r = min(round(x / s), W - 1), min(round(y / s), H - 1)
        m = np.zeros(frame.shape, dtype=bool)
        m[r, c] = True
        return m, f"the pixel x = {c}, y = {r} px (point {x:g}, {y:g} {u})"
    if polygon is not None:
        v = _numbers(np.ravel(polygon), "polygon", None).reshape(-1, 2)
        check_inside(frame, v, "polygon vertex")
        m = roi_mask(frame.shape, polygon=v / s)
        text = " ".join(f"{a:g},{b:g}" for a, b in v)
        if not m.any():
            raise ValueError(f"polygon {text} {u} holds no pixel centre: {frame.extent}")
        return m, f"the polygon {text} {u}"
    whole = region is None
    if whole:
        region = (0.0, 0.0, W * s, H * s)
    x0, y0, x1, y1 = _numbers(region, "region", 4)
    if not (x0 < x1 and y0 < y1):
        raise ValueError(f"region {x0:g} {y0:g} {x1:g} {y1:g} {u} must have x0 < x1 and "
                         f"y0 < y1")
    check_inside(frame, (x0, y0, x1, y1), "region corner")
    # the pixels whose centre x * s lies in [x0, x1) (and likewise in y)
    c0, c1 = max(0, math.ceil(x0 / s - 1e-9)), min(W, math.ceil(x1 / s - 1e-9))
    r0, r1 = max(0, math.ceil(y0 / s - 1e-9)), min(H, math.ceil(y1 / s - 1e-9))
    if not (c0 < c1 and r0 < r1):
        raise ValueError(f"region {x0:g} {y0:g} {x1:g} {y1:g} {u} holds no pixel centre "
                         f"(pixel centres every {s:g} {u}): {frame.extent}")
    m = np.zeros(frame.shape, dtype=bool)
    m[r0:r1, c0:c1] = True
    return m, (f"x in [{x0:g}, {x1:g}), y in [{y0:g}, {y1:g}) {u} "
               f"(columns {c0}-{c1 - 1}, rows {r0}-{r1 - 1})")


def valid_extent(frame: Frame, valid_of, n: int) -> str:
    """The bounding box of the pixels valid in any of the ``n`` states (``valid_of(i)``
    state ``i``'s validity map), in words and in the frame's unit."""
    any_valid = np.zeros(frame.shape, dtype=bool)
    for i in range(n):
        any_valid |= np.asarray(valid_of(i), dtype=bool)
    if not any_valid.any():
        return "no pixel is valid in any state"
    rows, cols = np.nonzero(any_valid.any(axis=1))[0], np.nonzero(any_valid.any(axis=0))[0]
    s = frame.scale
    return (f"its valid pixels lie in x {cols[0] * s:g} to {cols[-1] * s:g}, y "
            f"{rows[0] * s:g} to {rows[-1] * s:g} {frame.unit}")


def refuse_empty(frame: Frame, where: str, valid_of, n: int) -> None:
    """Refuse a place (``where``, from :func:`place_mask`) with no valid pixel in any of
    the ``n`` states, naming the field's extent and that of its valid pixels."""
    raise ValueError(f"{where} holds no valid pixel in any of the {n} state(s): "
                     f"{frame.extent}; {valid_extent(frame, valid_of, n)}")
