"""The virtual fields method on a measured result: its maps, std maps, pixel size and
loads."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .._validation import check_type
from ..post import frame_of, own_length, place_mask, refuse_empty, strain_noise_correlation
from ..results import SeriesResult
from ._identify import VirtualFields, virtual_fields

_STRAINS = ("exx", "eyy", "exy")
# A result measured to the edges (measure --to-edges) may stop this many pixels short
# of its mask: a state's edge, found in its image where the grid's modulus halves
# (gridstrain.series), moves with the noise and the displacement by about one pixel.
_EDGE_SLACK = 1


def _specimen(result) -> np.ndarray:
    """The specimen the used region is checked against: the result's mask, less the
    pixels a to-edges measurement may leave along its edges."""
    mask = np.asarray(result.mask, dtype=bool)
    if not (result.parameters or {}).get("to_edges"):
        return mask
    return ndimage.binary_erosion(mask, iterations=_EDGE_SLACK, border_value=1)


def _loads(result, load, load_unit):
    n = result.n_states
    if load is None:
        load, load_unit = result.load, result.load_unit if load_unit is None else load_unit
    if load is None:
        raise ValueError("the result has no loads: give them (gridstrain identify --loads "
                         "FILE.csv, or identify(..., load=...))")
    try:
        arr = np.array(load, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"load must be numbers, one per loaded state, got {load!r}") \
            from None
    if arr.size == n + 1:  # stored with the reference first
        arr = arr[1:]
    if arr.size != n:
        raise ValueError(f"load must hold one value per loaded state ({n}), got "
                         f"{arr.size}")
    return arr, (load_unit or "N")


def _region_mask(frame, region):
    """The pixels of ``region`` (in the frame's unit), by the rule every command names
    places with (:func:`gridstrain.post.place_mask`)."""
    if region is None:
        return np.ones(frame.shape, dtype=bool)
    return place_mask(frame, region=region)[0]


def identify(result: SeriesResult, *, thickness: float, loaded_edge: str,
             load_direction: str, pixel_size: float | None = None,
             unit: str | None = None, load=None,
             load_unit: str | None = None, region=None, px: bool = False,
             elements=None) -> VirtualFields:
    """Young's modulus and Poisson's ratio of a measured result by the virtual fields
    method (:func:`virtual_fields` on its maps).

    Parameters
    ----------
    result : SeriesResult
        With its uncertainty maps (``exx_std``...).
    thickness : float
        The specimen's thickness, ``unit``.
    loaded_edge : {"left", "right", "top", "bottom"}
    load_direction : {"x", "y"}
    pixel_size : float, optional
    unit : str, optional
        The length unit of ``pixel_size``, ``thickness`` and ``region``. Default: the
        result's own (:attr:`SeriesResult.pixel_size`, :attr:`SeriesResult.unit`);
        given, they must be its own (a pixel size typed from a printed one, within
        1e-5, is): another is refused naming both, since it would scale E.
    load : (n_states,) array_like, optional
        The loads, ``load_unit`` (default: the result's own). A leading value for the
        reference is dropped.
    load_unit : str, optional
        Default: the result's, else ``"N"``.
    region : (x0, y0, x1, y1) floats, optional
        Only the pixels whose centre lies in ``x0 <= x < x1``, ``y0 <= y < y1``
        (``unit``, px with ``px``); its edges are then the loaded, gripped and free
        edges.
    px : bool
        ``region`` in px (:mod:`gridstrain.post`'s rule for places); ``thickness`` and
        the moduli keep ``unit``.
    elements : (int, int), optional

    Returns
    -------
    VirtualFields
        Where the result's maps are valid in every state and inside ``region``; the
        noise of neighbouring pixels correlated by the window
        (:func:`gridstrain.post.strain_noise_correlation`).

    Raises
    ------
    NotIdentifiable
        (:func:`virtual_fields`).
    ValueError
        Also when the region used stops short of the specimen's free edges (the
        result's ``mask``): the maps stop ``margin`` window widths from the mask's
        edges, so that the load carried in that strip is missed. A result measured
        up to the edges (``measure_series(..., to_edges=True)``, recorded in its
        ``parameters``) is accepted: its maps reach within two pixels of the mask
        (the edge found where the grid's modulus halves, less one pixel), whose
        load is then left out (a relative bias of about that strip's share of the
        section, 2 / 80 px on a 10-mm beam imaged at 8 px/mm, less where the free
        edge carries no shear). It is also refused when ``region``
        reaches outside the measured field or holds no valid pixel (the message names
        the field's extent in ``unit``).
    """
    check_type(result, "result", SeriesResult)
    ps, unit = own_length(result.pixel_size, result.unit, pixel_size=pixel_size,
                          unit=unit, px_too=False)
    if ps is None:
        raise ValueError("identify needs the pixel size, and this result carries none: "
                         "measure with --pixel-size SIZE --unit mm, or give pixel_size= "
                         "and unit=: moduli need lengths")
    unc = result.uncertainty
    if unc is None or any(f"{k}_std" not in unc for k in _STRAINS):
        raise ValueError("the result has no strain uncertainty maps (exx_std, eyy_std, "
                         "exy_std): the virtual fields' weights and intervals need them")
    load, load_unit = _loads(result, load, load_unit)
    frame = frame_of(result.shape, pixel_size=ps, unit=unit, px=px)
    keep = _region_mask(frame, region)
    n = result.n_states
    valid = np.zeros((n, *result.shape), dtype=bool)
    strain = np.empty((n, 3, *result.shape))
    std = np.empty_like(strain)
    for i in range(n):
        valid[i] = np.asarray(result.valid[i]) & keep
        for c, name in enumerate(_STRAINS):
            strain[i, c] = result.get_map(name)[i]
            std[i, c] = unc[f"{name}_std"][i]
    if region is not None and not valid.any():
        refuse_empty(frame, f"region {' '.join(f'{v:g}' for v in region)} {frame.unit}",
                     lambda i: result.valid[i], n)
    return virtual_fields(strain, std, load, thickness=thickness, loaded_edge=loaded_edge,
                          load_direction=load_direction, pixel_size=ps, unit=unit,
                          load_unit=load_unit, valid=valid, specimen=_specimen(result),
                          correlation=strain_noise_correlation(result),
                          elements=elements,
                          states=tuple(result.names[1:]))
