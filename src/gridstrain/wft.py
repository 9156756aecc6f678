"""Windowed Fourier transform of grid images: phases and phase derivatives.

The public face of the transform of the paper's eqs. (22)-(25)::

    from gridstrain.wft import wft, wft_complex, PhaseMaps, transfer_function

The implementation lives in :mod:`gridstrain.phase`. This module carries the name of
the function it exports, so the package binds the function, not
this module, as ``gridstrain.wft`` (see the package's ``__init__``).
"""

from __future__ import annotations

from .phase import DEFAULT_MARGIN, PhaseMaps, transfer_function, wft, wft_complex

# a state's maps at the reference's carrier, and the derivatives the kinematics take
from .phase import demodulated_at as demodulated_at
from .phase import finite_derivatives as finite_derivatives

__all__ = ["DEFAULT_MARGIN", "PhaseMaps", "transfer_function", "wft", "wft_complex"]
