"""The sensor's noise: the Poisson-Gaussian model ``Var = K l + L``, estimated from a stack
of frames or from one image, and the Anscombe transform.

Public path of the noise model, implemented in :mod:`gridstrain.uncertainty`.
"""

from __future__ import annotations

from .uncertainty._noise import (
    NOISE_RESULT_KIND,
    NoiseModel,
    anscombe,
    estimate_noise,
    inverse_anscombe,
)
from .uncertainty._noise_image import estimate_noise_image

__all__ = ["NOISE_RESULT_KIND", "NoiseModel", "anscombe", "estimate_noise", "estimate_noise_image",
           "inverse_anscombe"]
