"""Conventions used everywhere in gridstrain.

This module holds no code: it is the one place where the conventions are written.
Every other module cites it instead of restating them.

Arrays and coordinates
    Images and maps are 2-D arrays indexed ``[row, col] = [y, x]``. The coordinate
    ``x`` is the column index and ``y`` the row index, both counted from 0 at the
    centre of the first pixel; pixel ``[i, j]`` covers ``[j - 1/2, j + 1/2] x
    [i - 1/2, i + 1/2]``. Vectors (wave vectors, displacements, gradients) are
    written in ``(x, y)`` component order. A stack of maps of vector components has
    the component first: ``u[0] = u_x``, ``u[1] = u_y``, each ``(H, W)``.

Lattice
    A grid is described by two wave vectors ``k1 = (k1x, k1y)`` and
    ``k2 = (k2x, k2y)`` in cycles per pixel; the matrix ``K`` has rows ``k1`` and
    ``k2``. The paper's axis-aligned grid of pitch ``p`` is ``k1 = (1/p, 0)``,
    ``k2 = (0, 1/p)``. A checkerboard is described by its fundamental wave vectors,
    which run along the diagonals of its squares.

Windowed Fourier transform (paper eqs. 22-23)
    ``Psi_k(x) = sum_xi v(xi) g_sigma(xi - x) exp(-2 i pi k . xi)`` with the carrier
    evaluated at *absolute* pixel coordinates ``xi`` (not relative to the window
    centre), and ``g_sigma`` a Gaussian of standard deviation ``sigma`` pixels,
    centred on the pixel and normalised to unit sum, never truncated (it is applied
    through its analytic transfer function). The phase ``phi_k = arg Psi_k`` is
    therefore the phase *modulation* of eq. (1), without the carrier, up to the
    constant ``arg d_1``. Before the transform the mean grey level of the valid
    pixels is subtracted and the image is extended by zero beyond its border and
    inside masked pixels: a constant carries no phase, and removing it suppresses
    the step that zero extension would otherwise create at the border.

Displacement (paper eq. 34, generalised to any two wave vectors)
    Lagrangian (reference) description: ``u(X)`` is the displacement of the material
    point that sits at pixel ``X`` in the reference image. The sign follows the
    paper, ``u = -(1/2pi) K^-1 (phi_def(X + u(X)) - phi_ref(X))``; for the
    axis-aligned grid ``u_x = -p/(2 pi) (phi1_def - phi1_ref)``. Without the
    large-displacement correction ``phi_def`` is taken at ``X`` (eq. 34 as
    printed), which is exact only to first order in ``u . grad``.

Strain (paper eq. 35)
    The small-strain tensor of the Lagrangian displacement gradient
    ``G[i, m] = du_i/dX_m``: ``eps_xx = G[0, 0]``, ``eps_yy = G[1, 1]``,
    ``eps_xy = (G[0, 1] + G[1, 0]) / 2`` (tensor shear, half the engineering
    shear) and the rotation ``omega = (G[1, 0] - G[0, 1]) / 2``. Strain is
    dimensionless.

Units
    The numerical core works in pixels and radians. A pixel size and its unit are
    applied only when exporting and plotting.

Masks
    A mask is a boolean ``(H, W)`` array, ``True`` on the specimen (pixels to use).
    Every result carries a ``valid`` map; quantities are NaN where it is ``False``.

Precision
    One policy, held by every public function (``tests/test_dtypes.py``):

    - The *precision* of a computation is float32 when every input image (or frame)
      is float32, and float64 otherwise: integer images (8, 12, 16 bits...),
      float64, float16, or float32 mixed with any of them.
    - *Maps* -- an image transformed pixel by pixel (Anscombe), the windowed
      Fourier coefficients ``psi`` (complex64 / complex128) and phase derivatives
      ``dphi``, the displacement ``u``, strain and rotation -- are returned in that
      precision, whichever path made them (``wft``, methods A and B, on Dask or
      not, ``measure``, ``deformation``, ``measure_series``).
    - Sums over frames or pixels are accumulated in float64 whatever the
      precision (mean images, method B's running sums, temporal variances), and
      the maps of float32 input are computed from them in float64 where the
      precision matters (the mean image before method A's float32 transform, the
      kinematics, whose fixed point and interpolation run in float64 and are
      rounded once at the end).
    - Everything else is float64: mean images, per-frame shifts and the
      screening's figures, noise models and variance maps, uncertainty maps and
      noise floors, and every scalar.
    - One exception inside a computation, never in what it returns: method B
      transforms each integer frame of at most 16 bits in float32 (its grey levels
      are exact there), at half the cost of float64, and adds it to its float64
      sums; its maps are float64 as above. A series of one such frame (a record
      measured frame by frame, a pair) is transformed and its phase-modulus
      coupling corrected in float32 in the same way, the correction writing its
      maps in float64 (a third of float64's cost; u and strain within 5e-7 px
      and 5e-7 of float64's on 12-bit records, masked or not,
      ``tests/test_sequences.py``). The rounding this leaves, against
      float64 transforms, was 1.7e-7 rad in phase and 4e-8 rad/px in derivative on
      30 frames of 1040 x 1376, and at most 6e-7 rad and 6e-7 rad/px (a strain of
      5e-7 at a 5 px pitch) on 2048 x 2048 frames of 0.5 % contrast at 60,000 grey
      levels: three to four orders of magnitude below the phase noise of one frame
      (1e-3 rad or more).
"""
