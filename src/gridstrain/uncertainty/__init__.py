"""Uncertainty: how precise a map is, and what it does not cover.

- ``_noise``: the sensor's noise model ``Var = K l + L`` from a stack of frames
  (:func:`~gridstrain.uncertainty.estimate_noise`), the Anscombe transform;
- ``_noise_image``: the same model from one image;
- ``_maps``: the per-pixel standard deviation of the phases, the displacement and the
  strain (:func:`predict_uncertainty`), the noise floor of a state (:class:`NoiseFloor`)
  and the metrological figures (:func:`metrology`);
- ``_aliasing``: the systematic error of the grid's harmonics aliasing onto the
  carriers, its bound and advice;
- ``_smoothing``: the systematic error of the window's smoothing of strain gradients;
- ``_contrast``: the bias next to a change of the grid's contrast (a stain, a shadow),
  bounded per pixel (:func:`contrast_step_bound`), its compiled loop in ``_kernels``
  (numba, loaded on first use);
- ``_nearest``: each pixel's nearest valid pixel, and fields filled from it;
- :mod:`~gridstrain.uncertainty.floors`: the noise floors a series measurement states.

The noise model's public path is :mod:`gridstrain.uncertainty`.
"""

from __future__ import annotations

# shared with gridstrain's other folders, not part of the public API
from ._aliasing import aliasing_advice as aliasing_advice
from ._aliasing import aliasing_bias
from ._contrast import CONTRAST_STEP_PX, contrast_step_bound, contrast_step_findings
from ._contrast import contrast_step_bytes as contrast_step_bytes
from ._maps import FWHM_PER_SIGMA as FWHM_PER_SIGMA
from ._maps import SPATIAL_RESOLUTION_PER_SIGMA as SPATIAL_RESOLUTION_PER_SIGMA
from ._maps import (
    NoiseFloor,
    Uncertainty,
    displacement_strain_std,
    metrology,
    noise_floor,
    noise_variance_map,
    predict_uncertainty,
)
from ._maps import noise_weighted as noise_weighted
from ._maps import phase_variance as phase_variance
from ._maps import std_from_phase_variance as std_from_phase_variance
from ._nearest import nearest_filled as nearest_filled
from ._nearest import nearest_index as nearest_index
from ._noise import (
    NOISE_RESULT_KIND,
    NoiseModel,
    anscombe,
    estimate_noise,
    inverse_anscombe,
)
from ._noise_image import estimate_noise_image
from ._smoothing import smoothing_bias

__all__ = [
    "CONTRAST_STEP_PX",
    "NOISE_RESULT_KIND",
    "NoiseFloor",
    "NoiseModel",
    "Uncertainty",
    "aliasing_bias",
    "anscombe",
    "contrast_step_bound",
    "contrast_step_findings",
    "displacement_strain_std",
    "estimate_noise",
    "estimate_noise_image",
    "inverse_anscombe",
    "metrology",
    "noise_floor",
    "noise_variance_map",
    "predict_uncertainty",
    "smoothing_bias",
]
