"""Photographs of a printed grid on a deforming specimen, for the acceptance tests.

Written with numpy alone. It shares no code and no model with
``gridstrain.models.synthetic``, ``tests/independent_grid.py`` or
``tests/sequence_record.py``: the tests that use it judge gridstrain against a
picture it was not written for. Its model of a picture:

The specimen, in its reference configuration (``X`` the column and ``Y`` the row of
the reference image, px, pixel centres at integers):

- paper of reflectance 1 printed with dark ink of reflectance ``ink`` (0.12);
- the print is a grid of lines of pitch ``pitch`` turned by ``angle`` on the
  specimen, or a checkerboard of squares of side ``pitch / 2`` (its fundamental
  wave vectors run along the diagonals, pitch ``pitch / sqrt(2)``);
- each line is flat-topped, "square": the ink covers a band of half-width ``h``
  about the line's axis, with edges blurred by the printer into a linear ramp of
  width ``edge`` (px) rounded by a smoothstep; the lines of the grid are ``0.35``
  pitch wide on average and each line has its own width, ``h (1 + 0.06 n)``, ``n``
  standard normal (a printer's banding);
- print defects: ink blots (dark discs of 0.6 to 2 px radius) and gaps where a line
  lacks ink (white discs), about one of each per 1500 px²; and a few dust specks
  (grey discs, 1 to 2.5 px radius, darkening by 60 %) lying on the specimen. All
  of them move with the specimen; a different ``specimen`` seed draws another
  specimen (another pattern of widths and defects);
- a crack (``deformed(..., crack=...)``) opens a gap in which the camera sees the
  crack's dark inside (reflectance 0.03).

The deformation: the material point ``X`` is seen at ``x = X + u(X)`` (``u``
Lagrangian, as gridstrain defines it). What the camera sees at ``x`` is the
specimen at ``X``, found by the fixed-point iteration ``X <- x - u(X)`` (40
iterations); where it does not settle to 1e-3 px (inside an opened crack, or
within about a pixel of its tip where the field folds) the crack's inside is seen.

The camera, fixed in the world:

- lighting fixed to the camera: a smooth gradient, ``1 + 0.15 (x - xc)/W - 0.10
  (y - yc)/H``, which does not move with the specimen;
- lens vignetting, the cos^4 law ``(1 + r²/f²)^-2`` with ``f`` 1.4 times the
  frame's diagonal (corners at about 72 %);
- each pixel integrates the light falling on its square area: the mean of 4 x 4
  sub-samples at offsets ``(k + 1/2)/4 - 1/2`` px (not a point sample);
- the sensor: white paper at the centre gives 3300 grey levels; the signal is
  ``gain`` (0.4 grey level per electron) times a Poisson count of electrons plus
  normal read noise of 3 grey levels std, rounded and clipped to ``[0, 4095]``
  (12 bits), stored as these values in ``uint16`` (not scaled to 16 bits).
"""

from __future__ import annotations

import numpy as np

FULL = 3300.0  # grey levels of white paper at the frame's centre
GAIN = 0.4  # grey levels per electron
READ = 3.0  # read noise, grey levels std
INK = 0.12
VOID = 0.03
SUB = 4  # sub-samples per pixel side


def _smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _band(a, halfwidth, edge, pitch):
    """Ink coverage of the line family whose axes sit at integer ``a`` (in periods).

    ``halfwidth`` is an array indexed by line number (offset by its middle)."""
    k = np.rint(a)
    d = np.abs(a - k) * pitch  # px from the nearest line's axis
    h = halfwidth[(k.astype(np.int64) + halfwidth.size // 2) % halfwidth.size]
    return _smoothstep((h - d) / edge + 0.5)


def _discs(X, Y, centres, radii, soft=0.6):
    """Coverage of soft-edged discs (union)."""
    out = np.zeros_like(X)
    for (cx, cy), r in zip(centres, radii, strict=True):
        near = (np.abs(X - cx) < r + 2) & (np.abs(Y - cy) < r + 2)
        if near.any():
            d = np.hypot(X[near] - cx, Y[near] - cy)
            out[near] = np.maximum(out[near], _smoothstep((r - d) / soft + 0.5))
    return out


class Specimen:
    """A printed specimen: its pattern, drawn once from ``seed``.

    Parameters
    ----------
    shape : (H, W) of the frames it is photographed in, px.
    pitch : float, px. angle : float, degrees. kind : "grid" or "checker".
    edge : float, width of the printed lines' blurred edges, px.
    seed : int, the specimen (line widths, defects, dust).
    """

    def __init__(self, shape, *, pitch=6.4, angle=0.6, kind="grid", edge=1.2, seed=0):
        rng = np.random.default_rng(seed)
        self.shape, self.pitch, self.kind, self.edge = shape, pitch, kind, edge
        self.theta = np.deg2rad(angle)
        base = (0.35 if kind == "grid" else 0.5) * pitch / 2
        wobble = 0.06 if kind == "grid" else 0.03
        self.h1 = base * (1 + wobble * rng.standard_normal(512))
        self.h2 = base * (1 + wobble * rng.standard_normal(512))
        H, W = shape
        n = max(1, int(H * W / 1500))
        lo = np.array([-0.1 * W, -0.1 * H])
        span = np.array([1.2 * W, 1.2 * H])
        self.blots = (lo + span * rng.random((n, 2)), rng.uniform(0.6, 2.0, n))
        self.gaps = (lo + span * rng.random((n, 2)), rng.uniform(0.6, 2.0, n))
        m = 6
        self.dust = (lo + span * rng.random((m, 2)), rng.uniform(1.0, 2.5, m))

    def reflectance(self, X, Y):
        """Reflectance of the specimen's point ``(X, Y)`` (reference px)."""
        c, s = np.cos(self.theta), np.sin(self.theta)
        a = (c * X + s * Y) / self.pitch
        b = (-s * X + c * Y) / self.pitch
        if self.kind == "grid":
            c1 = _band(a, self.h1, self.edge, self.pitch)
            c2 = _band(b, self.h2, self.edge, self.pitch)
            ink = 1 - (1 - c1) * (1 - c2)
        else:  # square waves of half-period bands: their exclusive or is a checkerboard
            c1 = _band(a, self.h1, self.edge, self.pitch)
            c2 = _band(b, self.h2, self.edge, self.pitch)
            ink = c1 + c2 - 2 * c1 * c2
        ink = np.maximum(ink, _discs(X, Y, *self.blots))
        ink = ink * (1 - _discs(X, Y, *self.gaps))
        refl = 1 - (1 - INK) * ink
        return refl * (1 - 0.6 * _discs(X, Y, *self.dust))


def _erf(z):
    """erf to 1.2e-7 (Numerical Recipes' erfc by Chebyshev fitting)."""
    t = 1 / (1 + 0.5 * np.abs(z))
    poly = (-1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (
        -0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (
            -0.82215223 + t * 0.17087277)))))))))
    return np.sign(z) * (1 - t * np.exp(-z * z + poly))


def _subsamples(shape):
    H, W = shape
    off = (np.arange(SUB) + 0.5) / SUB - 0.5
    y = (np.arange(H)[:, None] + off[None, :]).reshape(-1)
    x = (np.arange(W)[:, None] + off[None, :]).reshape(-1)
    return np.meshgrid(x, y)  # (H*SUB, W*SUB), row-major as the frame


def _camera_light(x, y, shape):
    H, W = shape
    xc, yc = (W - 1) / 2, (H - 1) / 2
    f = 1.4 * np.hypot(H, W)
    light = 1 + 0.15 * (x - xc) / W - 0.10 * (y - yc) / H
    return light * (1 + ((x - xc) ** 2 + (y - yc) ** 2) / f**2) ** -2


def expected_levels(specimen, displacement=None):
    """Noise-free expected grey levels of a photograph, ``(H, W)`` float.

    ``displacement(X, Y) -> (u_x, u_y)`` px, Lagrangian; None for the reference.
    """
    H, W = specimen.shape
    x, y = _subsamples(specimen.shape)
    X, Y = x.copy(), y.copy()
    void = np.zeros(x.shape, dtype=bool)
    if displacement is not None:
        for _ in range(40):
            ux, uy = displacement(X, Y)
            X, Y = x - ux, y - uy
        ux, uy = displacement(X, Y)
        void = np.hypot(X + ux - x, Y + uy - y) > 1e-3
    refl = np.where(void, VOID, specimen.reflectance(X, Y))
    light = FULL * refl * _camera_light(x, y, specimen.shape)
    return light.reshape(H, SUB, W, SUB).mean(axis=(1, 3))


def photograph(specimen, displacement=None, *, rng):
    """One 12-bit photograph, ``(H, W)`` uint16 holding 0..4095."""
    level = expected_levels(specimen, displacement)
    electrons = rng.poisson(level / GAIN)
    dn = np.rint(GAIN * electrons + rng.normal(0.0, READ, level.shape))
    return np.clip(dn, 0, 4095).astype(np.uint16)


# Displacement fields, Lagrangian, px. Each returns (u_x, u_y) of (X, Y).

def rotation(deg, centre):
    """Rigid rotation by ``deg`` (counter-clockwise seen with y down: x towards y)."""
    t = np.deg2rad(deg)
    c, s = np.cos(t), np.sin(t)
    xc, yc = centre

    def u(X, Y):
        dx, dy = X - xc, Y - yc
        return (c - 1) * dx - s * dy, s * dx + (c - 1) * dy

    return u


def stretch(exx, eyy, centre):
    """Homogeneous strain ``exx``, ``eyy`` (engineering, small = large here) about ``centre``."""
    xc, yc = centre

    def u(X, Y):
        return exx * (X - xc), eyy * (Y - yc)

    return u


def edge_crack(opening, y_crack, x_tip):
    """An edge crack from the left edge along ``Y = y_crack`` to its tip at ``x_tip``.

    ``u_y = opening * theta / (2 pi)``, ``theta`` the angle about the tip from the
    crack's extension (``atan2(Y - y_crack, X - x_tip)``): the faces are moved apart
    by ``opening`` all along the crack, the field is continuous ahead of the tip,
    and it is harmonic (the window's smoothing leaves it unchanged away from the
    crack and its tip). A Volterra climb dislocation's field in its harmonic form.
    """

    def u(X, Y):
        th = np.arctan2(Y - y_crack, X - x_tip)
        return np.zeros_like(X), opening * th / (2 * np.pi)

    return u


def strain_bands(amplitude, width, centre):
    """Gaussian strain bands of standard deviation ``width`` px, peak ``amplitude``:
    ``e_xx`` a band across x at ``x = xc``, ``e_yy`` and ``e_xy`` bands across y at
    ``y = yc``. ``u_x = f(X) + 2 g(Y)``, ``u_y = g(Y)`` with ``f' = g' = `` the band.

    Returns ``(u, strain)``; ``strain(X, Y) -> (exx, eyy, exy)``.
    """
    xc, yc = centre
    a, w = amplitude, width

    def prim(t):  # integral of a exp(-t²/2w²) from 0
        return a * w * np.sqrt(np.pi / 2) * _erf(t / (np.sqrt(2) * w))

    def u(X, Y):
        return prim(X - xc) + 2 * prim(Y - yc), prim(Y - yc)

    def strain(X, Y):
        gx = a * np.exp(-((X - xc) ** 2) / (2 * w * w))
        gy = a * np.exp(-((Y - yc) ** 2) / (2 * w * w))
        return gx, gy, gy  # exy = (du_x/dy + du_y/dx)/2 = (2 g')/2

    return u, strain


def strain_bump(amplitude, width, centre):
    """A round Gaussian bump of ``e_xx``, standard deviation ``width`` px, peak
    ``amplitude`` at ``centre``: ``u_x = a w sqrt(pi/2) exp(-dy²/2w²) erf(dx / sqrt(2)
    w)``, ``u_y = 0``. Returns ``(u, strain)`` as :func:`strain_bands`."""
    xc, yc = centre
    a, w = amplitude, width
    c = a * w * np.sqrt(np.pi / 2)

    def u(X, Y):
        return c * np.exp(-((Y - yc) ** 2) / (2 * w * w)) * _erf((X - xc) / (np.sqrt(2) * w)), \
            np.zeros_like(Y)

    def strain(X, Y):
        gy = np.exp(-((Y - yc) ** 2) / (2 * w * w))
        exx = a * gy * np.exp(-((X - xc) ** 2) / (2 * w * w))
        exy = -0.5 * c * (Y - yc) / (w * w) * gy * _erf((X - xc) / (np.sqrt(2) * w))
        return exx, np.zeros_like(X), exy

    return u, strain


def compose(*fields):
    """Sum of displacement fields."""

    def u(X, Y):
        ux, uy = np.zeros_like(X), np.zeros_like(Y)
        for f in fields:
            a, b = f(X, Y)
            ux, uy = ux + a, uy + b
        return ux, uy

    return u
