"""The measurement of a series of grid images: the loop that orchestrates the others.

- ``_loop``: :func:`measure_series`, its options checked once at the door and the loop
  over the series and the states;
- ``_options``: every option of :func:`measure_series` declared once
  (:data:`OPTIONS`), :class:`MeasureOptions` and the checks between options;
- ``_inputs``: the frames, guesses, names, mask, loads and times, checked together;
- ``_passes``: the lattice, one streamed pass per series and its phase maps;
- ``_outliers``: the frames the screening flags, and what is done with them;
- ``_records``: what is kept of each series measured;
- ``_stages``: a state's measurement, stage by stage (:data:`STAGES`), and the
  long-record policy that samples its expensive checks;
- ``_floors``: the noise floors of the maps;
- ``_sinks``: the states' maps kept in memory or written as measured;
- ``_distributed``: the same pass on a Dask cluster (``--scheduler``).

A *series* is a set of frames of one static state of the specimen (a camera
taking ``T`` images of the reference, then ``T`` of each loaded state). The
pipeline measures every loaded state against the reference, diagnoses the
vibrations of every series and states the noise floor of the maps. Conventions
(axes, signs, the Lagrangian description, units) are those of
:mod:`gridstrain.conventions`; frames are streamed, never held whole.

For each series
    1. If no lattice is given, the reference frames are averaged (streamed) and
       the lattice detected on the mean image.
    2. Screening and vibrations, in one read of every frame
       (:func:`gridstrain.stacks.screening.screen_frames`): each frame is checked against
       its series (a grid, its contrast, a rigid slip, the non-rigid residual of a
       frame of another state, clipping at the ceiling or at a level ``2^n - 1``)
       and the flagged frames are excluded, refused or kept with a warning
       (``outliers``); every later pass sees the frames kept only. The rigid
       translation ``(alpha_t, beta_t)`` of every frame comes from the phase of one
       global Fourier coefficient per wave vector, as in
       :func:`gridstrain.stacks.vibration.frame_shifts`, no windowed Fourier transform per
       frame. Paper eq. (2): frame ``t`` is ``s(x + alpha_t, y + beta_t)``.
    3. Statistics (streamed): the mean image, the per-pixel sensor noise variance
       (see *Noise floor*) and the saturated fraction of every frame.
    4. Phase maps. Method A (paper §2.2): the windowed Fourier transform of the
       mean image. Method B (§2.3): one transform per frame, averaged
       (:func:`gridstrain.stacks.method_b` when available). Regions without a grid
       (modulus below a quarter of the median, e.g. a hole) are masked
       automatically so that the validity margin applies around them.
    5. Kinematics: :func:`gridstrain.kinematics.deformation` with the
       large-displacement (Lagrangian) correction, every state against the
       reference. The fringe order (the whole number of periods the phases cannot
       see) comes, by default, from the previous state's displacement field
       (incremental tracking: a load step that moves the specimen by less than half
       a period anywhere is followed, whatever the total motion), for the first
       state from image features when they are conclusive
       (:func:`gridstrain.kinematics.coarse_displacement`), else it is the smallest
       displacement the phases allow, flagged as not confirmed with a warning.

Fringe order
    :attr:`SeriesResult.fringe_orders` says, per state, where the order came from
    and whether it is *confirmed*: given by the user; fixed by image features that
    clearly beat their aliases one or two periods away and agree with the phases;
    or followed from a confirmed previous state with a displacement change below
    ``_MAX_STEP`` = 0.4 period at every pixel (or with image features agreeing).
    Conclusive image features that put the specimen half a period or more from
    zero override the tracking when the two disagree (the step was more than half
    a period), with a warning; features that say "no motion" do not (content fixed
    to the camera can say that), and the state is not confirmed.
    A state that is not confirmed may be off by whole periods; a warning says what
    to do. A step of more than 0.6 period between states without image features
    would be followed one period off and cannot be detected from the phases alone.

Noise floor
    Two estimates, both one standard deviation of the map's random error at a
    pixel, for ``T_ref`` reference frames and ``T`` frames of the state:

    - **theory**: the windowed-Fourier noise of :func:`gridstrain.theory.wft_noise_std`
      with the image noise variance ``v / T`` (Prop. 2.3) and the measured median
      modulus ``|Psi|`` of each series (which includes the vibrations' contrast
      loss), carried through eqs. (34)-(35). ``v`` is measured in the data: the
      temporal variance of each pixel, averaged over the valid pixels, after
      regressing out the measured frame shifts: a least-squares fit per pixel on
      the two shift components (``T - 3`` degrees of freedom) and, where the
      vibrations need them, the cosine and sine of the carriers' harmonics of the
      shifts (:mod:`gridstrain.stacks.accumulate`). Without that regression a
      vibration of 0.05 px on a grid of pitch 5 would pass for sensor noise, and
      without the harmonics one of 0.3 px would, by its second-order term. It
      needs ``T >= 4`` (plain temporal variance for ``T = 2, 3``; nothing for
      ``T = 1``, where the state is assumed as noisy as the reference).
    - **split**: an empirical check that assumes nothing about the noise: the
      reference frames are split into two halves, each averaged, and the second
      half is measured against the first. The result is pure error (the specimen
      did not move, a rigid vibration offset aside, which is removed as the map's
      mean), and its spatial standard deviation over the valid pixels, scaled by
      ``sqrt((1/T_ref + 1/T) / (1/T_1 + 1/T_2))``, is the floor of a state of
      ``T`` frames whose noise per frame is the reference's. Needs ``T_ref >= 2``.
      Its own sampling error is about ``1 / sqrt(2 N)`` relative, ``N`` being the
      number of independent windows in the valid region (tens on a small image).

    Separately, the vibrations leave a phase offset ``delta`` constant over the
    map (eqs. 26-31): its standard deviation, Prop. 2.4 with ``Var(mean alpha) =
    Var(alpha) / T``, is reported as ``vibration_u`` (px). It shifts the
    displacement map as a whole (a rigid translation) and does not reach the
    strain (eq. 27).

Spatial resolution
    The maps are the true fields convolved with the Gaussian window
    (eqs. 24-25). The spatial resolution ``d`` is the field's: the period of a sine
    displacement the window damps by 10 %, ``pi sigma sqrt(2 / ln(1 / 0.9)) =
    13.69 sigma`` px (:func:`gridstrain.uncertainty.metrology`); the window's full
    width at half maximum, ``2.355 sigma``, and ``sigma`` itself are stored beside
    it under their own names.

Per-pixel uncertainty maps (``ux_std``, ``uy_std``, ``exx_std``, ``eyy_std``,
``exy_std``) come from :func:`gridstrain.uncertainty.predict_uncertainty`: the
measured per-pixel noise variance of each series (vibrations regressed out),
averaged with the weight ``g^2`` the window gives each pixel and divided by ``T``,
over the local modulus ``|Psi|``. They are :attr:`SeriesResult.uncertainty`, saved
next to the maps by :func:`save_result`.

Where the noise variance comes from (``NoiseFloor.model``)
    - a camera model given by the user (``noise_model``: a
      :class:`gridstrain.uncertainty.NoiseModel` from ``gridstrain noise``, or ``(K, L)``
      in stored grey levels): every series' variance is ``K mean + L``;
    - otherwise the temporal variance of each series of two frames or more, and
      for the series of a single frame the model ``Var = K l + L`` estimated from
      one image (:func:`gridstrain.uncertainty.estimate_noise_image`, on the first
      single-frame series: the camera is the same), evaluated at the image.

    So every state gets its maps, its noise floor and its metrological figures,
    whatever ``T``.

Metrological figures (``SeriesResult.metrology``, :func:`gridstrain.uncertainty.metrology`)
    Per state and map: the resolution (median predicted std), the spatial
    resolution ``d`` (10 % attenuation period), the window's FWHM and the 10-90 %
    width of a step, and the metrological
    efficiency indicator ``sigma_u d`` (displacement) or ``sigma_e d^2``
    (strain), px^2, independent of ``sigma``.

Systematic errors (``SeriesResult.systematic``)
    The uncertainty maps cover noise only. Two biases are estimated and warned
    about where they can exceed the noise: the grid's harmonics aliasing onto the
    carriers (:func:`gridstrain.uncertainty.aliasing_bias`, every harmonic's
    amplitude fitted on the reference image, a sharp print's where one lands on a
    carrier and cannot be seen; a bound per component, warned of above twice the
    displacement noise),
    and the window's smoothing of strain gradients, ``sigma^2 / 2 lap(e)``
    (:func:`gridstrain.uncertainty.smoothing_bias`, from the measured field).
"""

from __future__ import annotations

from ..results import SeriesResult
from ._distributed import (
    MissingDistributedError,
    as_dask_stack,
    connect,
    mean_image_dask,
    method_a_dask,
    method_b_dask,
)
from ._inputs import state_names
from ._loop import measure_series
from ._options import OPTIONS, ORDERS, MeasureOptions, Option

# shared with gridstrain's other folders, not part of the public API
from ._options import check_together as check_together
from ._outliers import OUTLIER_POLICIES
from ._outliers import outlier_verdict as outlier_verdict
from ._passes import reference_lattice
from ._sinks import empty_state_message

__all__ = [
    "OPTIONS",
    "ORDERS",
    "OUTLIER_POLICIES",
    "MeasureOptions",
    "MissingDistributedError",
    "Option",
    "SeriesResult",
    "as_dask_stack",
    "connect",
    "empty_state_message",
    "mean_image_dask",
    "measure_series",
    "method_a_dask",
    "method_b_dask",
    "reference_lattice",
    "state_names",
]
