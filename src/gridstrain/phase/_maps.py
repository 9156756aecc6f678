"""The phase maps of a transform (:class:`PhaseMaps`), a state's maps brought to another
carrier (:func:`demodulated_at`) and the derivatives the kinematics take
(:func:`finite_derivatives`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .._runtime import compiled
from .lattice import Lattice


@dataclass(frozen=True, eq=False)
class PhaseMaps:
    """Windowed Fourier transform of one grid image (or of a stack, averaged).

    Attributes
    ----------
    psi : (2, H, W) complex ndarray
        ``Psi_k1`` and ``Psi_k2`` (eqs. 22-23), demodulated by the absolute carrier,
        grey levels. Defined at every pixel; trust it only where ``valid``.
    dphi : (2, 2, H, W) float ndarray
        Phase derivatives, rad/px: ``dphi[j, 0] = d phi_j / dx`` and
        ``dphi[j, 1] = d phi_j / dy``, computed from the analytic derivative of the
        window, or from a least-squares differentiator of ``Psi`` (``wft``'s
        ``derivatives`` option), without unwrapping.
    valid : (H, W) bool ndarray
        Pixels whose window lies inside the image and the mask (up to ``margin``
        standard deviations) and whose moduli show a grid.
    lattice : Lattice
        The wave vectors used.
    sigma : float
        Window standard deviation, px.
    """

    psi: np.ndarray
    dphi: np.ndarray
    valid: np.ndarray
    lattice: Lattice
    sigma: float

    def __post_init__(self):
        for name in ("psi", "dphi", "valid"):
            getattr(self, name).flags.writeable = False

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(H, W)``."""
        return self.valid.shape

    @property
    def phase(self) -> np.ndarray:
        """(2, H, W) wrapped phases ``arg Psi_k`` in (-pi, pi], rad."""
        return np.angle(self.psi)

    @property
    def modulus(self) -> np.ndarray:
        """(2, H, W) moduli ``|Psi_k|``, grey levels."""
        return np.abs(self.psi)

    def __repr__(self) -> str:
        H, W = self.shape
        return (f"PhaseMaps({H}x{W}, sigma={self.sigma:.4g} px, "
                f"{self.valid.mean():.1%} valid, {self.lattice!r})")


# The phase folder's compiled loops (gridstrain.phase._kernels: numba, the "fast" extra)
# for the transform's derivatives, the coupling correction and the carrier's move, when
# installed: loaded on the first use, never at import. The one switch of them all: False
# forces the numpy paths (what a machine without numba runs), which tests set to compare
# the two.
_COMPILED = True


@functools.cache
def _load_kernels():
    """The module of the phase folder's compiled loops (:mod:`gridstrain.phase._kernels`,
    :func:`gridstrain._runtime.compiled.load`), or None without numba."""
    return compiled.load(__package__, "._kernels")


def compiled_loops():
    """The module of the phase folder's compiled loops (:mod:`gridstrain.phase._kernels`),
    or None where numba is not installed or the loops are switched off
    (:data:`_COMPILED`)."""
    return _load_kernels() if _COMPILED else None


def demodulated_at(pm: PhaseMaps, lattice: Lattice) -> PhaseMaps:
    """``pm``'s maps as demodulated by ``lattice``'s carrier rather than its own.

    ``Psi_k(x) = sum_xi v(xi) g(xi - x) exp(-2 i pi k . xi)`` (conventions): moving
    the carrier from ``k`` to ``k'`` multiplies ``Psi`` by ``exp(2 i pi (k - k') .
    x)`` and adds ``2 pi (k - k')`` to the phase derivatives, exactly where the
    grid's amplitude is uniform under the window. Where it is not (lighting, print,
    a hole's edge), a window centred off the grid's own carrier weighs its sides
    unequally and biases the phase by about ``2 pi dk . sigma^2 grad ln A``: a
    homogeneous strain of 10 % under lighting falling by half over 100 px, 0.01 px
    at sigma = 5 px. Transforming each state at its own carrier
    (:func:`gridstrain.phase.follow_lattice`) and bringing the maps to the
    reference's lattice with this function avoids that bias.
    """
    # new maps (the given ones are read-only), written by the first operation
    return _carrier_moved(pm, np.empty_like(pm.psi), np.empty_like(pm.dphi), lattice)


def _carrier_moved(pm: PhaseMaps, psi: np.ndarray, dphi: np.ndarray,
                   lattice: Lattice) -> PhaseMaps:
    """:func:`demodulated_at` of ``pm`` written into ``psi`` and ``dphi`` (writable
    arrays of ``pm``'s shapes: new ones, or ``pm``'s own maps)."""
    dk = np.array(pm.lattice.K) - np.array(lattice.K)  # (2 wave vectors, (x, y))
    H, W = pm.shape
    ctype = psi.dtype
    x = np.arange(W, dtype=np.float64)
    y = np.arange(H, dtype=np.float64)
    kern = compiled_loops()
    real = np.finfo(ctype).dtype
    for j in range(2):
        ex = np.exp(2j * np.pi * dk[j, 0] * x).astype(ctype)
        ey = np.exp(2j * np.pi * dk[j, 1] * y).astype(ctype)
        src = pm.psi[j]
        if kern is not None and src.dtype == ctype and src.flags.c_contiguous \
                and psi[j].flags.c_contiguous:
            # one pass of both products (the whole move 1.0 -> 0.7 ms at 250 x 400 px)
            kern.carrier_moved(src.view(real), ex.real.copy(), ex.imag.copy(),
                               ey.real.copy(), ey.imag.copy(), psi[j].view(real))
        else:
            np.multiply(src, ex[None, :], out=psi[j])
            psi[j] *= ey[:, None]
        np.add(pm.dphi[j, 0], 2 * np.pi * dk[j, 0], out=dphi[j, 0])
        np.add(pm.dphi[j, 1], 2 * np.pi * dk[j, 1], out=dphi[j, 1])
    return PhaseMaps(psi=psi, dphi=dphi, valid=np.array(pm.valid), lattice=lattice,
                     sigma=pm.sigma)


def demodulated_in_place(pm: PhaseMaps, lattice: Lattice) -> PhaseMaps:
    """:func:`demodulated_at`, written over ``pm``'s own maps where they own their
    memory (copied otherwise), for the caller that made ``pm`` and drops it: a state
    transformed at its own carrier does not hold two sets of maps, and touches no
    fresh memory (90 MB at 1040 x 1376). ``pm`` must not be used afterwards."""
    own = []
    for a in (pm.psi, pm.dphi):
        if a.base is None:
            a.flags.writeable = True
            own.append(a)
        else:
            own.append(np.array(a))
    return _carrier_moved(pm, *own, lattice)


def finite_derivatives(pm: PhaseMaps) -> PhaseMaps:
    """``pm`` with its undefined derivatives (where ``psi = 0``) set to 0 and invalid.

    Far inside a large masked region the transform is exactly 0 and its phase
    derivatives are 0/0; a spline's prefilter (the kinematics interpolate the
    deformed maps) would spread a single NaN over whole rows and columns.
    """
    ok = np.isfinite(pm.dphi)
    if ok.all():
        return pm
    return PhaseMaps(psi=pm.psi, dphi=np.where(ok, pm.dphi, 0).astype(pm.dphi.dtype),
                     valid=pm.valid & ok.all(axis=(0, 1)), lattice=pm.lattice,
                     sigma=pm.sigma)
