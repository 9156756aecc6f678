"""Windowed Fourier transform of grid images: phases and phase derivatives.

The public face of the transform of the paper's eqs. (22)-(25)::

    from gridstrain.wft import wft, wft_complex, PhaseMaps, transfer_function

The implementation lives in the private module ``gridstrain._wft``. This module
carries the name of the function it exports, so the package binds the function, not
this module, as ``gridstrain.wft`` (see the package's ``__init__``).
"""

from __future__ import annotations

# demodulated_at (a state's maps at the reference's carrier), finite_derivatives, _wft
# (the transform with a sink, for method B) and _Workspace
# (its scratch arrays) serve the stacks, the series workflow and the Dask module
from ._wft import (  # noqa: F401
    DEFAULT_MARGIN,
    PhaseMaps,
    _wft,
    _Workspace,
    demodulated_at,
    finite_derivatives,
    transfer_function,
    wft,
    wft_complex,
)

__all__ = ["DEFAULT_MARGIN", "PhaseMaps", "transfer_function", "wft", "wft_complex"]
