"""The phase of a grid image: its lattice, the analysis window and the windowed Fourier
transform (paper eqs. 22-25).

- :mod:`~gridstrain.phase.lattice`: the grid's wave vectors, detected or followed;
- :mod:`~gridstrain.phase.window`: the Gaussian window (``sigma``, the validity margin
  and the minimum modulus), checked once;
- ``_transform``: the transform itself, its fast and compiled derivatives, and
  ``_kernels`` (numba loops, loaded on the first transform that uses them);
- ``_edges``: the transform up to the specimen's edges, the grid continued beyond them
  by its own maps (:func:`transform_to_edges`);
- ``_coupling``: the window's phase-modulus coupling, corrected to first order.
"""

from __future__ import annotations

from ._coupling import coupling_corrected
from ._edges import (
    EDGE_DEPTH,
    EDGE_HARMONIC_SPREAD,
    EDGE_PASSES,
    edge_harmonic_bias,
    edge_noise_gain,
    edge_pixels,
    partly_covered,
    transform_to_edges,
)
from ._maps import PhaseMaps, demodulated_at, finite_derivatives
from ._maps import compiled_loops as compiled_loops
from ._maps import demodulated_in_place as demodulated_in_place

# shared with gridstrain's other folders, not part of the public API
from ._spectrum import spectrum_block as spectrum_block
from ._spectrum import transfer_function
from ._transform import DEFAULT_MARGIN, transform, wft, wft_complex
from ._transform import Workspace as Workspace
from ._validity import filled_box as filled_box
from ._validity import no_grid
from .lattice import Lattice, detect_lattice, follow_lattice
from .window import MIN_MODULUS, Window

__all__ = [
    "DEFAULT_MARGIN",
    "EDGE_DEPTH",
    "EDGE_HARMONIC_SPREAD",
    "EDGE_PASSES",
    "MIN_MODULUS",
    "Lattice",
    "PhaseMaps",
    "Window",
    "coupling_corrected",
    "demodulated_at",
    "detect_lattice",
    "edge_harmonic_bias",
    "edge_noise_gain",
    "edge_pixels",
    "finite_derivatives",
    "follow_lattice",
    "no_grid",
    "partly_covered",
    "transfer_function",
    "transform",
    "transform_to_edges",
    "wft",
    "wft_complex",
]
