"""Displacement and strain from phase maps (paper eqs. 34-35, any two wave vectors).

Signs, axes and the Lagrangian description are those of
:mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from skimage.restoration import unwrap_phase

from .._runtime import compiled
from .._runtime.threads import THREADED_PIXELS, map_leaves
from .._stats import median
from .._validation import (
    check_int,
    check_mask,
    check_positive,
    check_same_shape,
    check_type,
    check_workers,
)
from ..phase import (
    Lattice,
    PhaseMaps,
    filled_box,
)
from ..uncertainty import contrast_step_bound, contrast_step_findings
from ._fringe_order import (
    FringeOrder,
    _CoarseReference,
    _from_estimate,
    coarse_displacement,  # noqa: F401  (named by the docstrings)
    cut_into_parts,
    solve_k,
)

__all__ = ["Measurement", "deformation"]

# Spline order used to evaluate the deformed maps at x + u. The demodulated maps are
# band-limited by the window (their spectrum falls as exp(-2 pi^2 sigma^2 nu^2)), so
# cubic splines suffice: against the direct sum at off-grid points the phase error is
# 3e-7 rad at sigma = pitch = 5 px (tests/test_lagrangian_interpolation.py), and on a noisy
# 1040 x 1376 pair they change u by less than 1e-7 px from quintic splines, with 16
# coefficients per point instead of 36.
_SPLINE_ORDER = 3
# Rows and columns of edge values added around a map before its spline prefilter, as
# scipy's map_coordinates(mode="nearest") does: the prefilter's boundary then matches
# the clamped evaluation outside the image.
_SPLINE_PAD = 12

@dataclass(frozen=True, eq=False)
class Measurement:
    """Displacement and strain maps between a reference and a deformed state.

    Attributes
    ----------
    u : (2, H, W) float ndarray
        Displacement ``(u_x, u_y)`` in px, Lagrangian (at reference pixels), NaN
        where not ``valid``. Computed in float64; float32 (as are ``strain`` and
        ``rotation``) when both sets of phase maps are (:mod:`gridstrain.conventions`).
    strain : (3, H, W) float ndarray
        ``(eps_xx, eps_yy, eps_xy)``, dimensionless small-strain tensor (tensor
        shear), NaN where not ``valid``.
    rotation : (H, W) float ndarray
        Infinitesimal rotation ``omega = (du_y/dx - du_x/dy)/2``, rad.
    valid : (H, W) bool ndarray
        Pixels where both states were measured.
    lattice : Lattice
    sigma : float
        Window standard deviation, px.
    lagrangian : bool
        Whether the large-displacement (Lagrangian) correction was applied.
    iterations : int
        Fixed-point iterations of the correction (0 without it).
    step_rms : float
        RMS change of ``u`` over the valid pixels at the last iteration, px.
    guess : (2,) tuple of float
        Median of the initial guess that fixed the fringe order, px.
    guess_source : str
        ``"auto"`` (image features, :func:`coarse_displacement`), ``"zero"``, or
        ``"user"``.
    reference, deformed : PhaseMaps
        The phase maps the measurement was made from.
    fringe_order : FringeOrder
        How the whole number of periods was fixed, and whether it is confirmed.
    """

    u: np.ndarray
    strain: np.ndarray
    rotation: np.ndarray
    valid: np.ndarray
    lattice: Lattice
    sigma: float
    lagrangian: bool
    iterations: int
    step_rms: float
    guess: tuple[float, float]
    guess_source: str
    reference: PhaseMaps = field(repr=False)
    deformed: PhaseMaps = field(repr=False)
    fringe_order: FringeOrder | None = field(default=None, repr=False)

    def __post_init__(self):
        for name in ("u", "strain", "rotation", "valid"):
            arr = getattr(self, name)
            if isinstance(arr, np.ndarray):  # maps read from a file are read-only already
                arr.flags.writeable = False

    @property
    def ux(self) -> np.ndarray:
        """(H, W) displacement along x, px."""
        return self.u[0]

    @property
    def uy(self) -> np.ndarray:
        """(H, W) displacement along y, px."""
        return self.u[1]

    @property
    def exx(self) -> np.ndarray:
        """(H, W) normal strain along x."""
        return self.strain[0]

    @property
    def eyy(self) -> np.ndarray:
        """(H, W) normal strain along y."""
        return self.strain[1]

    @property
    def exy(self) -> np.ndarray:
        """(H, W) shear strain (tensor component, half the engineering shear)."""
        return self.strain[2]

    def contrast_step_bound(self) -> np.ndarray:
        """(H, W) float64 bound of the displacement's bias next to a change of the
        grid's contrast between the two states (a stain, a shadow, a hole's edge), px,
        NaN where not valid: :func:`gridstrain.uncertainty.contrast_step_bound` of
        this measurement's transforms, the bound ``measure_series`` states per state.

        Raises
        ------
        ValueError
            A measurement that no longer holds its phase maps (``reference`` or
            ``deformed`` None).
        """
        if self.reference is None or self.deformed is None:
            raise ValueError("this measurement holds no phase maps (reference or "
                             "deformed is None): the contrast step's bound needs both "
                             "states' transforms; measure the pair again")
        return contrast_step_bound(self.reference.psi, self.deformed.psi, self.u,
                                   self.valid, sigma=self.sigma)

    def contrast_step_findings(self, *, noise=None, name: str = "deformed") -> list:
        """The ``"contrast.step"`` finding of :meth:`contrast_step_bound` where it
        exceeds the noise (:func:`gridstrain.uncertainty.contrast_step_findings`,
        the rule ``measure_series`` states each state's by), or none.

        Parameters
        ----------
        noise : Uncertainty, (2, H, W) array, mapping or (float, float), optional
            The displacement noise, px: what :func:`gridstrain.predict_uncertainty`
            returns (or its ``u_std``, or its ``median()``), maps
            ``{"ux_std", "uy_std"}``, or floors ``(std u_x, std u_y)``; default: not
            known, the bound's own median sets the level.
        name : str
            The state, in the sentence.
        """
        return contrast_step_findings(self.contrast_step_bound(), self.valid, noise=noise,
                                      name=name)

    def __repr__(self) -> str:
        H, W = self.valid.shape
        v = self.valid
        mu = [float(np.mean(c[v])) if v.any() else math.nan for c in self.u]
        return (f"Measurement({H}x{W}, {v.mean():.1%} valid, mean u = ({mu[0]:.4g}, "
                f"{mu[1]:.4g}) px, sigma={self.sigma:.4g} px, lagrangian={self.lagrangian}, "
                f"iterations={self.iterations})")



# The cubic splines of four maps (both transforms' real and imaginary parts, or the
# four phase derivatives) evaluated at once by gridstrain.kinematics._spline_kernels (numba, the
# "fast" extra) when installed: loaded on the first correction, never at import.
# False forces scipy's map_coordinates, one map at a time (what runs without numba).
_COMPILED = True


# The compiled loops run on blocks of this many rows (the prefilter's second half on
# blocks of this many columns), on the usable cores. The blocks do not depend on the
# number of cores, nor does the order in which a step's sums are added: the result is
# the same bit for bit on any number of threads.
_BLOCK_ROWS = 64
_BLOCK_COLUMNS = 128
# Maps of fewer pixels run their blocks on the calling thread alone
_THREADED_PIXELS = THREADED_PIXELS


def _by_blocks(n: int, size: int, fn, pixels: int) -> list:
    """``fn(i0, i1)`` for the blocks ``[i0, i1)`` of ``size`` indices that tile
    ``range(n)``, on up to the usable cores for a map of ``pixels`` pixels from
    :data:`_THREADED_PIXELS` (``fn`` must release the GIL: the compiled loops do);
    their results in the blocks' order."""
    blocks = [(i, min(i + size, n)) for i in range(0, n, size)]
    workers = check_workers(None) if pixels >= _THREADED_PIXELS else 1
    return map_leaves(lambda b: fn(*b), blocks, max(min(workers, len(blocks)), 1))


@functools.cache
def _load_kernels():
    """The module of compiled spline loops (:func:`gridstrain._runtime.compiled.load`), or None."""
    return compiled.load(__package__, "._spline_kernels")


def _kernels():
    """:func:`_load_kernels`, unless the compiled loops are switched off
    (:data:`_COMPILED`, which a test turns off to compare them with numpy's)."""
    return _load_kernels() if _COMPILED else None


class _Spline:
    """Real or complex 2-D maps ``(..., H, W)``, prefiltered once, evaluated together
    at many point sets.

    ``map_coordinates`` with ``prefilter=True`` would filter the whole map again at
    every call, as costly as the evaluation itself; the fixed-point iterations of
    :func:`deformation` evaluate the same deformed maps several times. Four real
    planes (two complex maps, or four real ones) of a cubic spline are prefiltered
    and evaluated by compiled loops when numba is installed, which compute each
    point's weights once for the four (about ten times faster than four
    ``map_coordinates``, the prefilter three to four times faster than
    ``spline_filter``; the same values to rounding within the padding,
    ``tests/test_lagrangian_interpolation.py``). A value that is not finite is
    taken as 0: a NaN would spread over whole rows and columns of coefficients.
    """

    def __init__(self, arr: np.ndarray, order: int | None = None):
        self.order = order = _SPLINE_ORDER if order is None else order
        arr = np.asarray(arr)
        self.lead = arr.shape[:-2]
        self.is_complex = np.iscomplexobj(arr)
        flat = arr.reshape(-1, *arr.shape[-2:])
        planes = [p for a in flat for p in ((a.real, a.imag) if self.is_complex else (a,))]
        Hp, Wp = (n + 2 * _SPLINE_PAD for n in arr.shape[-2:])
        kern = _kernels() if order == 3 and len(planes) == 4 else None
        self.kern = kern
        if kern is not None:
            # one plane a map (4, Hp, Wp): a row of points reads each map's rows at
            # unit stride (the compiled evaluation's runs); read from the maps
            # themselves (a complex map as its real view), not a copy
            self.coef = np.empty((4, Hp, Wp))
            dt = np.complex128 if self.is_complex else np.float64
            src = np.ascontiguousarray(flat, dtype=dt)
            src = src.view(np.float64) if self.is_complex else src
            coef = self.coef
            _by_blocks(Hp, _BLOCK_ROWS, lambda i0, i1: kern.prefilter_rows(
                src, self.is_complex, _SPLINE_PAD, coef, i0, i1), Hp * Wp)
            _by_blocks(Wp, _BLOCK_COLUMNS,
                       lambda j0, j1: kern.prefilter_columns(coef, j0, j1), Hp * Wp)
            return
        self.coef = []
        for p in planes:
            p = np.nan_to_num(p.astype(np.float64), copy=False, nan=0.0, posinf=0.0,
                              neginf=0.0)
            padded = np.pad(p, _SPLINE_PAD, mode="edge")
            self.coef.append(ndimage.spline_filter(padded, order, mode="nearest"))

    def __call__(self, coords: np.ndarray) -> np.ndarray:
        """Values ``(..., *points)`` at ``coords`` (2, *points) = (rows, columns) of
        the unpadded maps."""
        pts = coords.shape[1:]
        if self.kern is not None:
            c = np.asarray(coords, dtype=np.float64).reshape(2, 1, -1) if len(pts) != 2 \
                else np.asarray(coords, dtype=np.float64)
            out = np.empty((4, *c.shape[1:]))
            self.kern.cubic4_at(self.coef, float(_SPLINE_PAD), np.ascontiguousarray(c[0]),
                                np.ascontiguousarray(c[1]), out)
            out = out.reshape(4, *pts)
        else:
            shifted = coords + _SPLINE_PAD
            out = np.stack([ndimage.map_coordinates(c, shifted, order=self.order,
                                                    mode="nearest", prefilter=False)
                            for c in self.coef])
        if self.is_complex:
            out = out[0::2] + 1j * out[1::2]
        return out.reshape(*self.lead, *pts)


def _unwrap(wrapped: np.ndarray, valid: np.ndarray, pairs=None, around=None) -> np.ndarray:
    """scikit-image's ``unwrap_phase`` of ``wrapped`` over ``valid`` (0 elsewhere).

    Like scikit-image's, the result is defined up to one multiple of 2 pi per
    connected region (4-connected), which the fringe order chosen from the guess
    absorbs. Turned by a constant ``c`` (its circular mean), the map becomes
    ``s = wrap(wrapped - c)``; if no two valid neighbours of ``s`` (along a row or a
    column) differ by pi or more, scikit-image's reliability-guided unwrapping would
    join every pair of groups with the offset that makes them continuous in ``s``
    (each merge rounds the difference of two neighbours), so its result is ``s + c``
    up to those multiples. That is checked by two differences instead of sorting
    every edge: the common case of a displacement field spread over less than a
    fringe, whatever its mean. ``around`` (H, W), when given, is the phase a guess
    predicts (a record's previous state): each pixel is then taken the whole turns
    closest to it, and if no two valid neighbours of that map differ by pi or more it
    is the continuous map scikit-image's merges reach (the same proof, with the
    guess's smooth map in place of the constant), spread over any number of fringes.
    Otherwise scikit-image runs. ``pairs``: the valid neighbours along rows and along
    columns, when the caller has them. ``around`` may be given as a function that
    returns it, called only where it is needed.
    """
    # any constant would do for the proof; the circular mean of a subsample centres
    # the map so that a field spread over less than 2 pi shows no jump
    sub = wrapped[::4, ::4][valid[::4, ::4]]
    c = float(np.angle(np.sum(np.exp(1j * sub)))) if sub.size else 0.0
    kern = _kernels()
    if kern is not None and wrapped.dtype == np.float64:
        # the same operations in two passes at most, each stopped at its first jump
        s = np.empty(wrapped.shape)
        wrapped, valid = np.ascontiguousarray(wrapped), np.ascontiguousarray(valid)
        if kern.unwrap_by_turns(wrapped, valid, c, np.empty((0, 0)), s) == 0:
            return s
        if around is not None:
            near = np.ascontiguousarray(around() if callable(around) else around,
                                        dtype=np.float64)
            if kern.unwrap_by_turns(wrapped, valid, c, near, s, False) < 2:
                return s
            del near
        del s
        return _scikit_image_unwrap(wrapped, valid)
    # s = mod(wrapped - c + pi, 2 pi) - pi, in one buffer
    s = np.subtract(wrapped, c)
    s += np.pi
    np.mod(s, 2 * np.pi, out=s)
    s -= np.pi
    rows, cols = (valid[:, 1:] & valid[:, :-1], valid[1:] & valid[:-1]) if pairs is None \
        else pairs
    jumps = _jumps(s, rows, 1) or _jumps(s, cols, 0)
    if not jumps:
        # wrapped plus whole turns, as scikit-image adds them: rint((s + c - wrapped)
        # / 2 pi) turns, the same operations in s's buffer
        s += c
        s -= wrapped
        s /= 2 * np.pi
        np.rint(s, out=s)
        s *= 2 * np.pi
        s += wrapped
        np.copyto(s, 0.0, where=~valid)  # a masked write, without gathering indices
        return s
    if around is not None and callable(around):
        around = around()
    if around is not None and np.isfinite(around).all():
        # t = wrapped + 2 pi rint((around - wrapped) / 2 pi), in s's buffer
        np.subtract(around, wrapped, out=s)
        s /= 2 * np.pi
        np.rint(s, out=s)
        s *= 2 * np.pi
        s += wrapped
        if not (_jumps(s, rows, 1) or _jumps(s, cols, 0)):
            np.copyto(s, 0.0, where=~valid)
            return s
    return _scikit_image_unwrap(wrapped, valid)


def _scikit_image_unwrap(wrapped, valid):
    """scikit-image's ``unwrap_phase`` of ``wrapped`` over ``valid``, 0 elsewhere."""
    ma = np.ma.masked_array(wrapped, mask=~valid)
    return np.ma.filled(unwrap_phase(ma, rng=0), 0.0)


def _jumps(s: np.ndarray, pairs: np.ndarray, axis: int) -> bool:
    """Whether two neighbours along ``axis`` that ``pairs`` marks differ by pi or more."""
    d = np.diff(s, axis=axis)
    np.abs(d, out=d)
    big = np.greater_equal(d, np.pi)
    del d
    big &= pairs
    return bool(big.any())


class _Handover:
    """A guess field handed over to :func:`deformation`, which drops it once the
    fringe order is fixed: a field passed as a plain argument would stay referenced
    by the caller's call until :func:`deformation` returns (a whole (2, H, W) map
    through the large-displacement correction, the most memory of the kinematics)."""

    def __init__(self, field):
        self._field = field

    def take(self):
        field, self._field = self._field, None
        return field


def _guess_field(guess, reference, deformed, images):
    """The guess as a (2, H, W) field (a constant one broadcast), its source, and
    the coarse estimate (or None)."""
    shape = reference.shape
    if isinstance(guess, _Handover):
        guess = guess.take()
    zero = np.broadcast_to(np.zeros((2, 1, 1)), (2, *shape))
    if isinstance(guess, str):
        if guess != "auto":
            raise ValueError(f"guess must be 'auto', None, a (u_x, u_y) pair or a (2, H, W) "
                             f"field, got {guess!r}")
        if images is None:
            raise ValueError("guess='auto' needs the images; pass a guess with phase maps")
        ref_img, cur_img, mask = images
        ref_img = np.asarray(ref_img, dtype=np.float64)
        est = _CoarseReference(ref_img, reference.lattice, check_mask(mask, ref_img.shape)) \
            .decide(np.asarray(cur_img, dtype=np.float64), reference, deformed)
        if est.confident:
            shift = np.array(est.shift)
            return np.broadcast_to(shift[:, None, None], (2, *shape)), "auto", est
        return zero, "zero", est
    if guess is None:
        return zero, "zero", None
    g = np.asarray(guess, dtype=float)
    if g.shape == (2,):
        g = np.broadcast_to(g[:, None, None], (2, *shape))
    elif g.shape != (2, *shape):
        raise ValueError(f"guess must be a (u_x, u_y) pair or a field of shape "
                         f"{(2, *shape)}, got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError("guess must be finite")
    return g, "user", None


def deformation(reference: PhaseMaps, deformed: PhaseMaps, *, lagrangian: bool = True,
                guess=None, tol: float = 1e-6, max_iter: int = 50,
                _images=None) -> Measurement:
    """Displacement and strain between two phase-map sets of the same lattice.

    Parameters
    ----------
    reference, deformed : PhaseMaps
        From :func:`gridstrain.wft` (or a stack average) with the same lattice and
        window.
    lagrangian : bool
        Apply the large-displacement correction: solve
        ``u(X) = -(1/2pi) K^-1 (phi_def(X + u(X)) - phi_ref(X))`` by fixed point,
        and take the deformed-state derivatives at ``X + u``. Without it, eq. (34)
        as printed (``phi_def`` at ``X``), exact only to first order.
    guess : None, (2,) array_like or (2, H, W) array_like
        Initial displacement, px, that fixes the fringe order (a displacement is
        known from phases only up to a lattice period). Default: zero.
    tol : float
        Stop when the RMS error left in ``u`` over the valid pixels, bounded from
        the last step (see Notes), falls below ``tol`` px.
    max_iter : int
        Largest number of fixed-point iterations.

    Returns
    -------
    Measurement

    Notes
    -----
    The wrapped phase difference is unwrapped in space by scikit-image's
    ``unwrap_phase`` over the valid pixels (each connected region on its own; not
    called where the map, turned by its mean, shows no jump between valid
    neighbours, since its result is then known); each region's fringe order is the
    one closest to the guess. With the correction on,
    the residual ``phi_def(X + u) - phi_ref(X) + 2 pi K u`` is wrapped at every
    iteration, so any displacement is followed once the start is within half a
    period. The iterations start from the first-order solution with the deformed
    state's derivatives at ``X``, ``(2 pi K + D_def(X)) u = 2 pi K u_0`` with ``u_0``
    eq. (34) at ``X``, and each one multiplies the error by at most ``q``, the largest
    norm of ``(2 pi K)^-1 D_def`` (about the largest displacement gradient): they stop once
    ``q / (1 - q)`` times the RMS of the last step, a bound on the error left, is
    below ``tol`` (one or two iterations at strains of 1e-3). The strain then comes
    from the exact Lagrangian gradient
    ``G = (2 pi K + D_def(X + u))^-1 (D_ref - D_def(X + u))``, with ``D`` the 2x2
    phase-derivative matrices; to first order this is eq. (35),
    ``G = -(1/2pi) K^-1 (D_def - D_ref)``, which is what is used without the
    correction.
    """
    check_type(reference, "reference", PhaseMaps)
    check_type(deformed, "deformed", PhaseMaps)
    check_same_shape(deformed.shape, reference.shape, "deformed maps", "the reference")
    if reference.lattice != deformed.lattice:
        raise ValueError("reference and deformed maps must use the same lattice")
    tol = check_positive(tol, "tol")
    max_iter = check_int(max_iter, "max_iter")

    lattice = reference.lattice
    K = lattice.K
    g, source, coarse = _guess_field(guess, reference, deformed, _images)
    del guess  # g is the caller's field when one is given: not kept past the start
    valid = reference.valid & deformed.valid & np.all(np.isfinite(reference.dphi), axis=(0, 1))
    start = [_unwrapped_displacement(reference, deformed, valid, K, g)]
    gmed, order = _fringe_order_record(g, source, coarse)
    del g  # only its median is kept: a (2, H, W) field less in memory from here on

    iterations, step = 0, 0.0
    D_ref = reference.dphi.astype(np.float64, copy=False)
    if lagrangian:
        # the starting field is handed over, not kept here: the first step frees it
        u, iterations, step = _lagrangian_fixed_point(start.pop(), reference, deformed,
                                                      valid, tol, max_iter)
        strain, rotation, valid = _lagrangian_gradient(u, reference, deformed, D_ref)
    else:
        u = start.pop()
        strain, rotation = _strain_rotation(
            eulerian_gradient(K, deformed.dphi.astype(np.float64) - D_ref))
    del D_ref

    # computed in float64, returned in the maps' precision (gridstrain.conventions)
    dt = np.result_type(reference.dphi.dtype, deformed.dphi.dtype)
    u, strain, rotation = _outside_nan(valid, dt, u, strain, rotation)
    if order.confirmed and order.source == "image features" and \
            (parts := cut_into_parts(valid)):
        # the features' rigid shift fixed the part that carries them
        order = dataclasses.replace(order, confirmed=False,
                                    detail=f"{parts}; {order.detail}")
    return Measurement(u=u, strain=strain, rotation=rotation, valid=valid, lattice=lattice,
                       sigma=reference.sigma, lagrangian=bool(lagrangian),
                       iterations=iterations, step_rms=step, guess=gmed,
                       guess_source=source, reference=reference, deformed=deformed,
                       fringe_order=order)


def eulerian_gradient(K: np.ndarray, dD: np.ndarray) -> np.ndarray:
    """Displacement gradient (2, 2, ...) from the change ``dD`` (2, 2, ...) of the
    phase derivatives, without the large-displacement correction (eq. 35)."""
    return -solve_k(K, dD) / (2 * np.pi)


def small_strain(G: np.ndarray) -> np.ndarray:
    """The small-strain tensor ``(e_xx, e_yy, e_xy)`` (3, ...) of the gradient ``G``
    (2, 2, ...), tensor shear (:mod:`gridstrain.conventions`)."""
    return np.stack([G[0, 0], G[1, 1], 0.5 * (G[0, 1] + G[1, 0])])


def _strain_rotation(G):
    """The small strain (3, ...) and the rotation ``(du_y/dx - du_x/dy)/2`` of the
    gradient ``G`` (2, 2, ...)."""
    return small_strain(G), 0.5 * (G[1, 0] - G[0, 1])


def _outside_nan(valid, dtype, *maps):
    """The ``maps`` (fresh float64 arrays, changed in place) NaN outside ``valid``, in
    ``dtype``."""
    invalid = ~valid
    for a in maps:
        np.copyto(a, np.nan, where=invalid)
    return tuple(a.astype(dtype, copy=False) for a in maps)


def _real_view(psi: np.ndarray) -> np.ndarray:
    """The complex maps ``psi`` (2, H, W) as (2, H, 2W) float64, real and imaginary
    parts side by side: a view of them (of a complex128 copy where they are not)."""
    return np.ascontiguousarray(psi, dtype=np.complex128).view(np.float64)


def _phase_difference(ref_psi, cur_psi, out) -> None:
    """``out[j] = arg(cur_psi[j] conj ref_psi[j])`` (2, H, W), with numpy."""
    # one wave vector at a time: a complex product of (H, W), not of (2, H, W)
    real = np.empty(out.shape[1:], dtype=np.float64)
    for j in range(2):
        z = np.conjugate(ref_psi[j])
        z *= cur_psi[j]
        # np.angle, written in place: arctan2 of contiguous parts takes half the time
        # of the complex map's strided views, for the same values
        np.copyto(real, z.real)
        np.copyto(out[j], z.imag)
        del z
        np.arctan2(out[j], real, out=out[j])


def _unwrapped_displacement(reference, deformed, valid, K, g) -> np.ndarray:
    """(2, H, W) displacement of eq. (34) from the unwrapped phase difference, each
    connected valid region shifted by the whole periods that bring it closest to
    the guess ``g`` ((2, H, W), px)."""
    dphase = np.empty(reference.psi.shape, dtype=np.float64)
    kern = _kernels()
    if kern is not None and reference.psi.dtype == deformed.psi.dtype == np.complex128:
        # the product and its argument in one loop, no temporary
        kern.phase_difference(_real_view(reference.psi), _real_view(deformed.psi), dphase)
    else:
        _phase_difference(reference.psi, deformed.psi, dphase)
    # a rectangle of valid pixels is one region: no labels needed
    labels, n_regions = (None, 1) if filled_box(valid) else ndimage.label(valid)
    if n_regions == 0:
        raise ValueError("no valid pixel: the image is smaller than the window and its "
                         "margin, or the mask leaves nothing")
    pairs = (valid[:, 1:] & valid[:, :-1], valid[1:] & valid[:-1])  # both maps' jump checks
    # By eq. (34) the unwrapped phase in periods is -dphase / 2 pi = K u: a guess field
    # (a record's previous state) predicts -2 pi K g, around which a field spread over
    # many fringes unwraps without scikit-image
    constant = g.strides[1:] == (0, 0)  # a (u_x, u_y) pair broadcast: K g once
    for j in range(2):  # unwrapped in place
        # the guess's phase, computed only where the map turned by a constant jumps
        around = None if constant else \
            (lambda j=j: -2 * np.pi * (K[j, 0] * g[0] + K[j, 1] * g[1]))
        dphase[j] = _unwrap(dphase[j], valid, pairs, around)
        del around
    # fringe order per connected region, closest to the guess: the whole periods n
    # that bring K (u - g) closest to 0 are taken on it, and added back as
    # dphase + 2 pi n (u -> u - K^-1 n) before the one solve
    kg = K @ g[:, 0, 0] if constant else None
    for lab in range(1, n_regions + 1):
        sel = valid if n_regions == 1 else labels == lab
        n = np.empty(2)
        for j in range(2):
            if kern is not None and (n_j := _whole_turns(
                    kern, dphase[j], sel, g, K[j], kg[j] if constant else 0.0,
                    constant)) is not None:
                n[j] = n_j  # the median's whole number, without sorting
                continue
            t = dphase[j][sel]  # a fresh gather, sorted in place by the median
            t *= -1 / (2 * np.pi)
            if constant:
                n[j] = np.rint(median(t, overwrite_input=True) - kg[j])
            else:
                t -= K[j, 0] * g[0][sel] + K[j, 1] * g[1][sel]
                n[j] = np.rint(median(t, overwrite_input=True))
            del t
        for j in range(2):
            if n[j]:
                dphase[j][sel] += 2 * np.pi * n[j]
    u = solve_k(K, dphase)
    del dphase
    np.negative(u, out=u)
    u /= 2 * np.pi
    return u


# How far, in periods, every pixel's phase change from the guess must lie within the
# half-period either side of one whole number for that number to be taken as the one
# its median rounds to: far above the rounding by which the compiled loop's values
# may differ from numpy's (1e-15 period), far below the noise.
_TURNS_MARGIN = 1e-6


def _whole_turns(kern, dphase, sel, g, k, kg, constant):
    """``rint(median(t))`` of :func:`_unwrapped_displacement`'s ``t`` over ``sel``
    where every ``t`` lies within :data:`_TURNS_MARGIN` of the same half-period
    interval around a whole number (then every value, and so the median, rounds to
    it: rint is monotone), or None."""
    lo, hi, finite = kern.turns_range(np.ascontiguousarray(dphase), sel,
                                      g[:, :1, :1] if constant else g, float(k[0]),
                                      float(k[1]), float(kg), constant)
    if not finite or lo > hi:
        return None
    n = float(np.rint(lo))
    if lo - (n - 0.5) > _TURNS_MARGIN and (n + 0.5) - hi > _TURNS_MARGIN:
        return n
    return None


def _lagrangian_fixed_point(u, reference, deformed, valid, tol, max_iter):
    """Solve ``u(X) = -(1/2pi) K^-1 (phi_def(X + u) - phi_ref(X))`` by fixed point
    from ``u`` (eq. 34 at ``X``), the residual wrapped at every step; returns ``u``,
    the number of iterations and the RMS of the last step over the valid pixels, px.

    The start is the first-order (Newton) solution with the deformed state's
    derivatives at ``X``, ``(2 pi K + D_def(X)) u = 2 pi K u_0``: pointwise, no
    interpolation, and closer than ``u_0`` by about the strain (the error left is
    the change of ``D_def`` between ``X`` and ``X + u``: 4e-3 px RMS for an 11 px
    displacement of a noisy 12-bit pair, against 3e-2 px from ``u_0``). A step
    ``du = -(2 pi K)^-1 r`` takes the error ``e`` to ``-M e``, ``M = (2 pi K)^-1
    D_def`` between the two points, so ``|e| <= q / (1 - q) |du|`` after it, with ``q``
    the largest norm of ``M`` over the deformed state's valid pixels (about the
    largest displacement gradient): the iterations stop once that bound, as an RMS,
    is below ``tol``, or, where ``q >= 1`` (no contraction is known), once the step
    is.
    """
    shape = reference.shape
    K = reference.lattice.K
    two_pi_K = 2 * np.pi * K
    psi_cur = _Spline(deformed.psi)  # both wave vectors' maps, evaluated together
    nv = max(int(valid.sum()), 1)
    if psi_cur.kern is not None:  # the start and each step in one compiled loop
        kern = psi_cur.kern
        start = np.empty((2, *shape))
        u0 = np.ascontiguousarray(u, dtype=np.float64)
        d = np.ascontiguousarray(deformed.dphi, dtype=np.float64)
        cur_valid = np.ascontiguousarray(deformed.valid)
        m_of_d = np.linalg.inv(two_pi_K)
        a_med = _median_start(deformed, two_pi_K)
        q = max(_by_blocks(shape[0], _BLOCK_ROWS, lambda i0, i1: kern.newton_start(
            u0, d, cur_valid, two_pi_K, m_of_d, a_med, start, i0, i1), u0[0].size))
        u = start
        # the reference's maps as they are (their real view), unless they are complex64
        ref = _real_view(reference.psi)
        solve = np.ascontiguousarray(-np.linalg.inv(K) / (2 * np.pi))

        def block_step(i0, i1):
            prod = np.empty((4, i1 - i0, shape[1]))
            kern.residual_products(psi_cur.coef, float(_SPLINE_PAD), u, ref, valid, prod,
                                   i0, i1)
            # an array of their own: written over the products, the loop's vectorised
            # path would not run (numba's check of overlapping arrays)
            angles = np.empty((2, i1 - i0, shape[1]))
            kern.arctan2(prod[0], prod[1], angles[0])
            kern.arctan2(prod[2], prod[3], angles[1])
            return kern.fixed_point_update(angles, u, two_pi_K, solve, valid, i0, i1)

        def one_step():
            # the blocks' sums added in the blocks' order, whatever the threads
            return math.fsum(_by_blocks(shape[0], _BLOCK_ROWS, block_step, u[0].size))
    else:
        u = _newton_start(u, deformed, two_pi_K)
        q = _contraction(deformed, K)
        yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
        conj_ref = np.conj(reference.psi.astype(np.complex128, copy=False))
        coords = np.empty((2, *shape))
        r = np.empty_like(u)

        def one_step():
            np.add(yy, u[1], out=coords[0])
            np.add(xx, u[0], out=coords[1])
            at = psi_cur(coords)
            for j in range(2):
                # residual phi_def(X + u) - phi_ref(X) + 2 pi k.u, wrapped to (-pi, pi]:
                # the carrier's phase added as a real number rather than as exp(i .)
                r[j] = np.angle(at[j] * conj_ref[j])
                r[j] += two_pi_K[j, 0] * u[0] + two_pi_K[j, 1] * u[1]
                r[j] = np.pi - np.mod(np.pi - r[j], 2 * np.pi)
            du = -solve_k(K, r) / (2 * np.pi)
            du[:, ~valid] = 0.0
            u[...] += du
            return float(np.sum(du * du))

    gain = q / (1.0 - q) if q < 1.0 else 1.0
    iterations, step = 0, 0.0
    for iterations in range(1, max_iter + 1):  # noqa: B007
        step = math.sqrt(one_step() / nv)
        if gain * step < tol:
            break
    return u, iterations, step


# The median derivatives of the start's linear map from every _START_STRIDE-th row and
# column of a map of at least _START_SUBSAMPLED valid pixels (some 1000 of them then).
_START_STRIDE = 4
_START_SUBSAMPLED = 2**14


def _median_start(deformed, two_pi_K) -> np.ndarray:
    """``(2 pi K + D_med)^-1 2 pi K`` (2, 2), ``D_med`` the median of the deformed
    state's phase derivatives over its valid pixels (over every fourth row and column
    of them on a large map): the start's linear map for the
    field's mean gradient. A rotation of 10 degrees moves ``X + u`` by 0.17 |u| from
    the Eulerian start, half a period at 15 px from the centre: the start must take
    the mean gradient in wherever the local derivatives cannot be trusted."""
    v = deformed.valid
    # every _START_STRIDE-th row and column where the map has many valid pixels: the
    # mean gradient does not need each of them (1.7 -> 0.2 ms at 250 x 400 px), and
    # the start it gives is the one taken only where a pixel's own is a tenth of a
    # period off it
    step = _START_STRIDE if np.count_nonzero(v) >= _START_SUBSAMPLED else 1
    v = v[::step, ::step]
    D = np.zeros((2, 2))
    if v.any():
        for a in range(2):
            for b in range(2):
                # the gather is a fresh array: sorted in place, not copied again
                D[a, b] = median(deformed.dphi[a, b][::step, ::step][v].astype(
                    np.float64, copy=False), overwrite_input=True)
    A = np.linalg.solve(two_pi_K + D, two_pi_K)
    return A if np.all(np.isfinite(A)) else np.eye(2)


def _newton_start(u0, deformed, two_pi_K):
    """``(2 pi K + D_def(X))^-1 2 pi K u0``, pointwise; where the deformed state is
    valid at ``X`` but that start differs by more than a tenth of a period from the
    one with the median derivatives (:func:`_median_start`), the latter (a
    derivative spoilt by a low modulus must not move the start towards another
    fringe order); ``u0`` where the deformed state is not valid."""
    a_med = _median_start(deformed, two_pi_K)
    m0 = a_med[0, 0] * u0[0] + a_med[0, 1] * u0[1]
    m1 = a_med[1, 0] * u0[0] + a_med[1, 1] * u0[1]
    D = deformed.dphi.astype(np.float64, copy=False)
    b0 = two_pi_K[0, 0] * u0[0] + two_pi_K[0, 1] * u0[1]
    b1 = two_pi_K[1, 0] * u0[0] + two_pi_K[1, 1] * u0[1]
    a00 = two_pi_K[0, 0] + D[0, 0]
    a01 = two_pi_K[0, 1] + D[0, 1]
    a10 = two_pi_K[1, 0] + D[1, 0]
    a11 = two_pi_K[1, 1] + D[1, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        rdet = 1.0 / (a00 * a11 - a01 * a10)
        u = np.stack([(a11 * b0 - a01 * b1) * rdet, (a00 * b1 - a10 * b0) * rdet])
        # the change along each wave vector, in periods
        c0 = (two_pi_K[0, 0] * (u[0] - m0) + two_pi_K[0, 1] * (u[1] - m1)) / (2 * np.pi)
        c1 = (two_pi_K[1, 0] * (u[0] - m0) + two_pi_K[1, 1] * (u[1] - m1)) / (2 * np.pi)
        keep = (np.abs(c0) < 0.1) & (np.abs(c1) < 0.1)
    return np.where(deformed.valid, np.where(keep, u, np.stack([m0, m1])), u0)


def _contraction(deformed, K) -> float:
    """Largest Frobenius norm (a bound on the 2-norm) of ``(2 pi K)^-1 D_def`` over
    the deformed state's valid pixels: the fixed point's contraction factor."""
    v = deformed.valid
    if not v.any():
        return 0.0
    D = deformed.dphi[:, :, v].astype(np.float64)
    M = solve_k(K, D) / (2 * np.pi)
    q = float(np.sqrt(np.max(np.sum(M * M, axis=(0, 1)))))
    return q if math.isfinite(q) else math.inf


def _lagrangian_gradient(u, reference, deformed, D_ref):
    """The small strain (3, H, W) and the rotation (H, W) of the exact Lagrangian
    displacement gradient ``G`` with the deformed state's derivatives taken at
    ``X + u`` (:func:`_strain_rotation`), and the pixels valid in both states."""
    shape = reference.shape
    K = reference.lattice.K
    # Where Psi is exactly 0 (deep in a masked area) its derivatives are undefined;
    # a spline's prefilter would spread one NaN over whole rows: the spline takes them
    # as zeros (the pixels are invalid anyway)
    spline = _Spline(deformed.dphi)  # the four derivatives, evaluated together
    if spline.kern is not None:  # one compiled loop: validity, derivatives, G, strain
        strain = np.empty((3, *shape))
        rotation = np.empty(shape)
        valid = np.empty(shape, dtype=bool)
        box = filled_box(deformed.valid)
        args = (spline.coef, float(_SPLINE_PAD), np.ascontiguousarray(u, dtype=np.float64),
                np.ascontiguousarray(deformed.valid),
                np.array(box if box is not None else (0, 0, 0, 0), dtype=np.int64),
                np.ascontiguousarray(reference.valid),
                np.ascontiguousarray(D_ref, dtype=np.float64), 2 * np.pi * K, strain,
                rotation, valid)
        _by_blocks(shape[0], _BLOCK_ROWS,
                   lambda i0, i1: spline.kern.lagrangian_gradient(*args, i0, i1),
                   rotation.size)
        return strain, rotation, valid
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    coords = np.stack([yy + u[1], xx + u[0]])
    inside = ((coords[0] >= 0) & (coords[0] <= shape[0] - 1)
              & (coords[1] >= 0) & (coords[1] <= shape[1] - 1))
    cur_valid = ndimage.map_coordinates(deformed.valid.astype(np.float64), coords,
                                        order=1, mode="constant", cval=0.0)
    valid = reference.valid & inside & (cur_valid > 0.999)
    D_cur = spline(coords)
    # exact Lagrangian gradient: (2 pi K + D_cur) G = D_ref - D_cur, by Cramer's
    # rule map by map rather than through (2, 2, H, W) temporaries
    a00 = 2 * np.pi * K[0, 0] + D_cur[0, 0]
    a01 = 2 * np.pi * K[0, 1] + D_cur[0, 1]
    a10 = 2 * np.pi * K[1, 0] + D_cur[1, 0]
    a11 = 2 * np.pi * K[1, 1] + D_cur[1, 1]
    B = np.subtract(D_ref, D_cur, out=D_cur)
    rdet = 1.0 / (a00 * a11 - a01 * a10)
    G = np.empty((2, 2, *shape))
    G[0, 0] = (a11 * B[0, 0] - a01 * B[1, 0]) * rdet
    G[0, 1] = (a11 * B[0, 1] - a01 * B[1, 1]) * rdet
    G[1, 0] = (a00 * B[1, 0] - a10 * B[0, 0]) * rdet
    G[1, 1] = (a00 * B[1, 1] - a10 * B[0, 1]) * rdet
    return *_strain_rotation(G), valid


def _fringe_order_record(g, source, coarse):
    """The guess's median ``(u_x, u_y)`` and the FringeOrder record of how the fringe
    order was chosen."""
    if source == "zero":
        gmed = (0.0, 0.0)
    elif g.strides[1:] == (0, 0):  # one displacement, broadcast: its value
        gmed = (float(g[0, 0, 0]), float(g[1, 0, 0]))
    else:
        gmed = tuple(median(c) for c in g)
    if source == "user":
        order = FringeOrder("user", True, gmed, "the given guess")
    elif source == "auto":
        # the features' whole periods are used (the grid's modulus shows them), but
        # where nothing the light cannot imitate shows them too they are not confirmed
        order = _from_estimate(coarse, "image features", not coarse.light_doubt, gmed,
                               f"{coarse.light_doubt}; {coarse.reason}"
                               if coarse.light_doubt else coarse.reason)
    elif coarse is not None:
        order = _from_estimate(coarse, "smallest displacement", False, gmed,
                               f"image features undecided ({coarse.reason})")
    else:
        order = FringeOrder("smallest displacement", False, gmed, "guess=None")
    return gmed, order
