"""Uncertainty: how precise a map is, and what it does not cover.

- ``_noise``: the sensor's noise model ``Var = K l + L`` from a stack of frames
  (:func:`~gridstrain.noise.estimate_noise`), the Anscombe transform;
- ``_noise_image``: the same model from one image;
- ``_maps``: the per-pixel standard deviation of the phases, the displacement and the
  strain (:func:`predict_uncertainty`), the noise floor of a state (:class:`NoiseFloor`)
  and the metrological figures (:func:`metrology`);
- ``_biases``: the systematic errors (aliasing of harmonics, the window's smoothing);
- :mod:`~gridstrain.uncertainty.floors`: the noise floors a series measurement states.

The noise model's public path is :mod:`gridstrain.noise`.
"""

from __future__ import annotations

from ._biases import aliasing_bias, smoothing_bias
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

__all__ = [
    "NoiseFloor",
    "Uncertainty",
    "aliasing_bias",
    "displacement_strain_std",
    "metrology",
    "noise_floor",
    "noise_variance_map",
    "predict_uncertainty",
    "smoothing_bias",
]
