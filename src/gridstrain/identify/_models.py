"""Stiffness models of the virtual fields method: the unknowns and how they enter the
internal virtual work.

A model is linear in its parameters ``p``: the stress is ``sigma = C(p) eps`` in Voigt
notation with the engineering shear (``eps6 = 2 e_xy``, ``sigma6 = sigma_xy``),
``C(p) = sum_k p_k M_k`` with symmetric ``M_k`` (``basis``), so that the internal
virtual work density ``sigma . eps*`` is ``sum_k p_k (eps . M_k eps*)``. A model gives
its basis, a starting guess (the optimal fields depend on the ratios of the parameters
only), the stiffnesses it admits and its engineering constants. An orthotropic model
(``Q11, Q22, Q12, Q66`` in the material axes: ``M_k`` the unit matrices of the entries
``(1, 1)``, ``(2, 2)``, ``(1, 2) + (2, 1)`` and ``(6, 6)``) is one more class of this
shape.
"""

from __future__ import annotations

import math

import numpy as np


class Isotropic:
    """Linear-elastic isotropic material in plane stress: ``p = (Q11, Q12)``.

    ``Q11 = E / (1 - nu^2)``, ``Q12 = nu E / (1 - nu^2)``, ``Q66 = (Q11 - Q12) / 2 = G``.
    """

    name = "isotropic"
    parameters = ("Q11", "Q12")
    #: Poisson's ratio of an isotropic solid lies in (-1, 0.5)
    nu_range = (-1.0, 0.5)

    @staticmethod
    def guess() -> np.ndarray:
        """A starting point: only the ratio matters, nu = 0.3."""
        return np.array([1.0, 0.3])

    #: ``C(p) = sum_k p_k basis[k]``: symmetric ``(3, 3)``, Voigt, engineering shear
    basis = (np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.5]]),
             np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -0.5]]))

    @classmethod
    def stiffness(cls, p) -> np.ndarray:
        """``(3, 3)`` ``C(p)``: Voigt, engineering shear."""
        return sum(float(v) * b for v, b in zip(p, cls.basis, strict=True))

    @classmethod
    def plausible(cls, p) -> bool:
        """Whether ``p`` is an isotropic solid's stiffness: Q11 > 0, -1 < nu < 0.5."""
        return bool(np.all(np.isfinite(p)) and p[0] > 0
                    and cls.nu_range[0] < p[1] / p[0] < cls.nu_range[1])

    @staticmethod
    def constants(p, cov):
        """``(E, nu)`` and their ``(2, 2)`` covariance (first order) from ``p`` and its own.
        """
        q11, q12 = float(p[0]), float(p[1])
        nu = q12 / q11
        E = q11 - q12 * q12 / q11
        jac = np.array([[1.0 + nu * nu, -2.0 * nu],
                        [-q12 / (q11 * q11), 1.0 / q11]])
        return (E, nu), jac @ np.asarray(cov) @ jac.T

    @staticmethod
    def describe(coefficients) -> str:
        """The combination ``a Q11 + b Q12`` that a degenerate test still gives, in words."""
        a, b = (float(c) for c in coefficients)
        if abs(a + b) < 0.05 * math.hypot(a, b):  # Q11 - Q12 = 2 G
            return "only the shear modulus G = E / (2 (1 + nu)) (a shear-dominated field)"
        if abs(a - b) < 0.05 * math.hypot(a, b):  # Q11 + Q12 = E / (1 - nu)
            return ("only the biaxial modulus E / (1 - nu) (an equibiaxial field)")
        return f"only the combination {a:.3g} Q11 + {b:.3g} Q12"
