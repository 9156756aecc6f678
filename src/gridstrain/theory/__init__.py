"""The paper's closed forms: what averaging vibrated grid images does, in numbers.

Coordinates, signs and the window follow :mod:`gridstrain.conventions`. Every
function here is a formula (or a small numerical evaluation of one); none of them
touches an image stack. They give the levels that the measured errors of
:mod:`gridstrain.phase` and of stack averaging converge to, and the corrections that
remove the vibration-induced phase offset.

Model (paper eq. 2)
    Frame ``t`` of a stack is ``v_t(x, y) = s(x + alpha_t, y + beta_t) + n``: the
    reference image ``s`` seen through a rigid translation ``a_t = (alpha_t,
    beta_t)`` px (i.i.d., zero mean) plus sensor noise of variance ``K s + L``.
    In the Lagrangian terms of :mod:`gridstrain.conventions` the specimen is
    displaced by ``u = -a_t``; with :func:`gridstrain.models.synthetic.grid_image` the
    frame is ``grid_image(..., displacement=lambda X, Y: (-alpha_t + 0 * X,
    -beta_t + 0 * Y))``.

Proposition 2.1 (eqs. 4-6), :func:`mean_image_bias`, :func:`grid_mean_image_bias`
    To second order in the shifts, ``E(v_bar) = s + 1/2 div(C grad s)`` with ``C``
    the 2x2 covariance of ``(alpha, beta)``: the averaged image is a biased
    estimate of ``s``, and its RMSE against ``s`` levels off at
    :func:`mean_image_bias_rms` however many frames are averaged.

Proposition 2.2 (eqs. 13-17), :func:`averaged_profile_coefficients`
    The averaged grid is a grid whose line profile has the Fourier coefficients
    ``(1 + i 2 pi f k mean(alpha) - 1/2 (2 pi f)^2 k^2 mean(alpha^2)) d_k``. For
    many frames the fundamental loses the factor :func:`contrast_factor`
    ``1 - 1/2 (2 pi f)^2 Var(alpha)`` of its modulus and turns by the offset
    ``delta`` of eqs. (28)-(30), :func:`phase_offset`.

Proposition 2.3 (eqs. 18-21), :func:`effective_noise_variance`
    The noise of the averaged image has variance ``(K s + L) / T``. (Eq. 20 as
    printed ends in ``L / T^2``; summing ``T`` terms ``L`` and dividing by ``T^2``
    gives ``L / T``, which is what is used here.)

Proposition 2.4 (eq. 31), :func:`phase_offset_std`
    ``delta`` is zero-mean with, by the delta method, ``Std(delta) = 2 pi f /
    (1 - 1/2 (2 pi f)^2 Var(alpha)) * Std(mean(alpha))``.

    **Correction.** ``Std(mean(alpha))`` is ``Std(alpha) / sqrt(T)``. The paper's
    worked example uses ``2 Var(alpha)^2 / (T - 1)`` instead, which is the variance
    of the *sample variance*, not of the sample mean, and quotes the factor 1.34
    where ``2 pi f / (1 - 1/2 (2 pi f)^2 Var(alpha))`` is 1.259 at ``f = 1/5``,
    ``Var(alpha) = 0.0025``. With both fixed the example gives
    ``Std(delta) = 1.259 * 0.05 / sqrt(T) = 0.063 / sqrt(T)`` rad, not
    ``0.1 / sqrt(T)``; a Monte Carlo of 100 000 stacks confirms the corrected
    value to 0.2 % (see :func:`phase_offset_std`).

Method C (not in the paper), :func:`compensated_noise_std`
    Frames weighted by ``exp(-2 i pi k . a_t)`` before averaging
    (:func:`gridstrain.stacks.method_c`). Prop. 2.2's factor becomes
    ``1 - 1/2 (2 pi)^2 k^T Var(e) k`` with ``e`` the shift estimates' errors, the
    offset ``delta`` about the stack's mean position is third order in ``e``, and
    what remains relative to ``s`` is the mean position ``2 pi k . a_bar`` itself
    (exactly linear; with measured, centred shifts; Prop. 2.4's analogue).

Windowed Fourier noise (paper §2.2, after its refs. [23, 24]), :func:`wft_noise_std`
    White noise of variance ``v`` gives phase and phase-derivative noise of
    standard deviations ``sqrt(v sum g^2 / 2) / |Psi|`` and
    ``sqrt(v sum g'^2 / 2) / |Psi|``; :func:`displacement_noise_std` and
    :func:`strain_noise_std` carry them through eqs. (34)-(35).

References
----------
F. Sur and M. Grédiac, "On noise reduction in strain maps obtained with the grid
method by averaging images affected by vibrations", Optics and Lasers in
Engineering 66 (2015) 210-222. doi:10.1016/j.optlaseng.2014.09.013
"""

from __future__ import annotations

from ._averaging import (
    averaged_profile_coefficients,
    contrast_factor,
    exact_contrast_factor,
    grid_mean_image_bias,
    mean_image_bias,
    mean_image_bias_rms,
    phase_offset,
    phase_offset_std,
    phase_offsets,
    profile_coefficients,
)
from ._noise import (
    compensated_noise_std,
    displacement_noise_std,
    effective_noise_variance,
    grid_modulus,
    strain_noise_std,
    wft_noise_std,
    window_energy,
)

__all__ = [
    "averaged_profile_coefficients",
    "compensated_noise_std",
    "contrast_factor",
    "displacement_noise_std",
    "effective_noise_variance",
    "exact_contrast_factor",
    "grid_mean_image_bias",
    "grid_modulus",
    "mean_image_bias",
    "mean_image_bias_rms",
    "phase_offset",
    "phase_offset_std",
    "phase_offsets",
    "profile_coefficients",
    "strain_noise_std",
    "wft_noise_std",
    "window_energy",
]
