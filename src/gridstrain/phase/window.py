"""The analysis window of the windowed Fourier transform, checked once: the Gaussian's
standard deviation ``sigma``, the validity margin and the minimum modulus (:class:`Window`).

A measurement resolves its window at the door (``sigma`` from the lattice's pitch when
not given) and hands it inward; :func:`gridstrain.phase.transform` takes it whole.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from .._validation import check_positive, check_sigma

__all__ = ["DEFAULT_MARGIN", "MIN_MODULUS", "Window"]

# Default width, in window standard deviations, of the band along the image border
# and around masked pixels where results are declared invalid. Near an edge the
# window is cut and the conjugate carrier leaks in. Measured on a noise-free grid at
# sigma = p = 5 (tests/test_wft.py::test_edge_bias_decays_as_a_gaussian): phase
# error 3.5e-3 rad at 2 sigma, 2.5e-4 at 3 sigma, 7e-6 at 4 sigma, 6e-8 at 5 sigma;
# strain error 1e-4 at 3 sigma, 4e-6 at 4 sigma. 4 sigma keeps the edge bias below
# the 1e-5 strain that users resolve.
DEFAULT_MARGIN = 4.0
# Pixels whose modulus is below this fraction of the median modulus hold no grid.
MIN_MODULUS = 0.25


@dataclass(frozen=True)
class Window:
    """The window of the transform, checked.

    Attributes
    ----------
    sigma : float
        Standard deviation of the Gaussian window, px; at least the pitch when made by
        :meth:`for_lattice`.
    margin : float
        Width of the invalid band along the borders and the mask's edges, in sigmas.
    min_modulus : float
        Pixels whose modulus is below this fraction of the median modulus hold no grid,
        in ``[0, 1)``.
    """

    sigma: float
    margin: float = DEFAULT_MARGIN
    min_modulus: float = MIN_MODULUS

    def __post_init__(self):
        object.__setattr__(self, "sigma", check_positive(self.sigma, "sigma"))
        object.__setattr__(self, "margin", check_positive(self.margin, "margin"))
        m = self.min_modulus
        if isinstance(m, bool) or not isinstance(m, numbers.Real) or not 0 <= m < 1:
            raise ValueError(f"min_modulus must be in [0, 1), got {m!r}")
        object.__setattr__(self, "min_modulus", float(m))

    @classmethod
    def for_lattice(cls, lattice, *, sigma: float | None = None,
                    margin: float = DEFAULT_MARGIN,
                    min_modulus: float = MIN_MODULUS) -> Window:
        """The window for ``lattice``: ``sigma`` checked against its pitch (None gives the
        pitch, as in :func:`gridstrain.phase.wft`)."""
        return cls(float(check_sigma(sigma, lattice.pitch)), margin, min_modulus)

    @property
    def band(self) -> float:
        """Width of the invalid band, px: ``margin * sigma``."""
        return self.margin * self.sigma

    def min_side(self) -> int:
        """Smallest frame side, px, with a valid pixel: the band on each side."""
        return min_side(self.sigma, self.margin)

    def options(self) -> dict:
        """The transform's keywords for this window."""
        return {"sigma": self.sigma, "margin": self.margin, "min_modulus": self.min_modulus}


def min_side(sigma: float, margin: float) -> int:
    """Smallest frame side, px, with a valid pixel: a band of ``margin`` sigmas each side."""
    return 2 * math.ceil(margin * sigma) + 1
