"""The pair's measurement from two images (:func:`measure`): lattice, transforms,
kinematics, and the fringe order checked part by part where invalid bands part the
field.
"""

from __future__ import annotations

import dataclasses

from .._validation import as_image, check_mask, check_same_shape, check_type
from ..phase import (
    DEFAULT_MARGIN,
    MIN_MODULUS,
    Lattice,
    coupling_corrected,
    demodulated_at,
    detect_lattice,
    no_grid,
    wft,
)
from ..phase.lattice import reference_carrier, state_carrier
from ._deformation import Measurement, deformation
from ._discontinuities import check_parted
from ._fringe_order import strain_if_off

__all__ = ["measure"]

def measure(reference, deformed, *, lattice: Lattice | None = None,
            sigma: float | None = None, mask=None, lagrangian: bool = True,
            guess="auto", margin: float = DEFAULT_MARGIN) -> Measurement:
    """Displacement and strain maps between a reference and a deformed grid image.

    Parameters
    ----------
    reference, deformed : (H, W) array_like
        Grid images of the specimen before and after loading (grey levels).
    lattice : Lattice, optional
        The grid's wave vectors; detected on the reference image by default.
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen, in the reference configuration. The reference's
        regions without a grid (a hole or background left unmasked: the modulus
        below a quarter of its median, :func:`gridstrain.phase.no_grid`) are masked
        too, so that the band of ``margin`` sigmas around them is invalid, as
        :func:`gridstrain.measure_series` does.
    lagrangian : bool
        Large-displacement correction (default on); see :func:`deformation`.
    guess : "auto", None, (2,) or (2, H, W) array_like
        Initial displacement fixing the fringe order. ``"auto"`` uses the images'
        features (:func:`coarse_displacement`) when they are conclusive and falls
        back to the smallest displacement the phases allow otherwise;
        :attr:`Measurement.fringe_order` says which, and whether it is confirmed. A
        field that bands of invalid pixels part (a gradient too steep for the window)
        is confirmed only part by part, each by its own content
        (:func:`check_parts`), the parts it cannot decide left out.
    margin : float
        Invalid band along borders and mask edges, in units of ``sigma``.

    Returns
    -------
    Measurement

    Examples
    --------
    >>> import numpy as np
    >>> from gridstrain import Lattice, measure
    >>> from gridstrain.models import synthetic
    >>> lat = Lattice.from_pitch(5.0)
    >>> ref = synthetic.grid_image((96, 96), lat)
    >>> cur = synthetic.grid_image((96, 96), lat,
    ...                            displacement=lambda X, Y: (0.3 + 0 * X, -0.2 + 0 * Y))
    >>> res = measure(ref, cur, lattice=lat, guess=None)
    >>> [round(float(np.nanmean(c)), 5) for c in res.u]
    [0.3, -0.2]
    """
    ref = as_image(reference, "reference")
    cur = as_image(deformed, "deformed")
    check_same_shape(cur.shape, ref.shape, "deformed", "reference")
    m = check_mask(mask, ref.shape)
    if check_type(lattice, "lattice", Lattice, allow_none=True) is None:
        lattice = detect_lattice(ref, mask=m)
    pm_ref = wft(ref, lattice, sigma=sigma, mask=m, margin=margin, workers=None)
    nogrid = no_grid(pm_ref.modulus, pm_ref.valid, m, MIN_MODULUS, away=pm_ref.sigma)
    if nogrid.any():
        # a hole or background left unmasked: masked, so that the windows straddling
        # it are invalid as along a mask's edge (as measure_series does)
        m = m & ~nogrid
        if not m.any():
            raise ValueError("reference: no pixel shows a grid at the lattice's wave "
                             f"vectors (pitch {lattice.pitch:.4g} px)")
        pm_ref = wft(ref, lattice, sigma=sigma, mask=m, margin=margin, workers=None)
    # each transform corrected at its own carrier, before any change of carrier: the
    # window's phase-modulus coupling (gridstrain.phase.coupling_corrected)
    pm_ref = coupling_corrected(pm_ref)
    # the deformed specimen has moved: its mask is not the reference's, so the
    # deformed image is transformed whole and validity comes from its own moduli; at
    # its own carrier, a window off it biases the phase where the grid's amplitude
    # varies (gridstrain.phase.demodulated_at)
    carrier = state_carrier(cur, lattice, reference_carrier(ref, lattice))
    pm_cur = coupling_corrected(wft(cur, carrier, sigma=pm_ref.sigma, margin=margin,
                                    workers=None))
    if carrier is not lattice:
        pm_cur = demodulated_at(pm_cur, lattice)
    res = deformation(pm_ref, pm_cur, lagrangian=lagrangian, guess=guess,
                      _images=(ref, cur, m))
    if res.guess_source == "auto":
        # invalid bands part the field: each part by its own content (as measure_series)
        res, _ = check_parted(res, ref, cur, mask=m)
    if res.fringe_order is not None and not res.fringe_order.confirmed:
        # how far its strain may be off too (FringeOrder.strain_if_off)
        res = dataclasses.replace(res, fringe_order=dataclasses.replace(
            res.fringe_order, strain_if_off=strain_if_off(res)))
    return res
