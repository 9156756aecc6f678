"""The virtual fields method with the noise-optimal special virtual fields.

Principle of virtual work, plane stress, static, no body force, thickness ``t``: for
every kinematically admissible virtual displacement ``u*``,

    t ∫_S sigma . eps* dS = F u*_bar,

``u*_bar`` the loaded edge's rigid virtual displacement along the load and ``F`` the
load (the resultant's component that works; the gripped edge does not move, the other
edges are free of traction). With ``sigma = C(p) eps`` linear in the parameters ``p``
(:mod:`._models`), the left side is ``sum_k p_k Z_k U`` with ``Z_k`` the row
``t a sum_pixels pairing_k(eps) . B U`` (``a`` a pixel's area, :mod:`._mesh`). Special
virtual fields ``U_k`` with ``Z_j U_k = delta_jk`` give ``p_k = F u*_bar(U_k)`` directly.

Among them, Avril & Pierron (2004) choose those that minimise the variance of ``p_k``:
with strain noise ``n`` (per pixel std ``s_c`` of component ``c``, correlation ``R_c``
between pixels, the components independent), ``p_k``'s error is
``-(sum_j p_j dZ_j) U_k = -t a sum_pixels n . C(p) eps*(U_k)``, of variance
``U_k' H U_k`` with ``H = (t a)^2 sum_c (C B)_c' S_c R_c S_c (C B)_c``
(``S_c = diag(s_c)``; ``R_c`` the identity for independent pixels). Minimising ``U' H U / 2`` under
``A U = e_k`` (``A`` the rows ``Z_k``) with Lagrange multipliers gives
``U = H^-1 A' (A H^-1 A')^-1 e_k`` and the parameters' covariance
``(A H^-1 A')^-1`` (the method's own variance, eta^2). ``H`` depends on ``p`` through
``C``: the fields are computed again from the new ``p`` until the ratio settles.

The fields depend on the noisy strains through ``A``: the estimate ``p = F (A H^-1
A')^-1 A H^-1 e`` (``e`` the loaded edge's degree of freedom) is a weighted least
squares with noisy regressors, whose ``A H^-1 A'`` holds the noise's share
``E[dA H^-1 dA']_jk = tr(H^-1 N_jk)`` (``N_jk`` the covariance of the noise of rows
``j`` and ``k``). Taken out, ``p = F (A H^-1 A' - N)^-1 A H^-1 e`` has no first-order
bias (errors in variables), and ``(A H^-1 A' - N)^-1`` is its covariance.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
import scipy.linalg as sla
import scipy.sparse as sp

from ._mesh import Mesh

#: Iterations of the optimal fields and the relative change of the ratio that stops them
MAX_ITERATIONS = 30
RTOL = 1e-9
#: A test whose equations are this close to dependent (smallest over largest eigenvalue
#: of the normalised A H^-1 A') cannot separate the parameters at all
RCOND = 1e-10
#: Refused below this: the weakest combination of the parameters is seen in ``A H^-1 A'``
#: less than ten times above the share the noise alone gives it (E[dA H^-1 dA']); the
#: share is taken out, but what is left is then mostly noise
SNR_MIN = 10.0


class NotIdentifiable(ValueError):
    """The measured fields cannot separate the material parameters (a uniform shear,
    an equibiaxial field...): only a combination of them is determined."""


def _operators(mesh: Mesh, strain: np.ndarray, std: np.ndarray, model, scale: float):
    """``Z`` rows ``(n_par, n_dof)`` and the per-component std ``s_c`` of ``H``."""
    voigt = np.array([strain[0], strain[1], 2.0 * strain[2]])
    rows = []
    for M in model.basis:
        w = M @ voigt  # eps . M eps* = (M eps) . eps*
        rows.append(scale * sum(b.T @ wc for b, wc in zip(mesh.B, w, strict=True)))
    return np.array(rows), (std[0], std[1], 2.0 * std[2])


def correlate(mesh: Mesh, values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``R values``: each column of ``(n_pixels, q)`` values at the mesh's pixels,
    convolved with the noise's correlation ``kernel`` (odd sides, even, 1 at its
    centre) over the image grid (zero off the pixels), read back at the pixels."""
    r0, c0 = mesh.rows.min(), mesh.cols.min()
    hb, wb = mesh.rows.max() - r0 + 1, mesh.cols.max() - c0 + 1
    ry, rx = min(kernel.shape[0] // 2, hb - 1), min(kernel.shape[1] // 2, wb - 1)
    cy, cx = kernel.shape[0] // 2, kernel.shape[1] // 2
    kernel = kernel[cy - ry:cy + ry + 1, cx - rx:cx + rx + 1]
    # padded by the kernel's reach, so that no lag it covers wraps around
    shape = (sfft.next_fast_len(hb + ry, real=True), sfft.next_fast_len(wb + rx,
                                                                           real=True))
    placed = np.zeros(shape)
    placed[np.ix_(np.arange(-ry, ry + 1) % shape[0], np.arange(-rx, rx + 1) % shape[1])] = \
        kernel
    spectrum = sfft.rfft2(placed).real  # an even kernel's transform is real
    r, c = mesh.rows - r0, mesh.cols - c0
    out = np.empty(values.shape)
    for j in range(0, values.shape[1], _CHUNK):
        part = values[:, j:j + _CHUNK]
        grid = np.zeros((part.shape[1], *shape))
        grid[:, r, c] = part.T
        conv = sfft.irfft2(sfft.rfft2(grid) * spectrum, s=shape)
        out[:, j:j + _CHUNK] = conv[:, r, c].T
    return out


#: Columns convolved at once
_CHUNK = 16


def _noise_blocks(mesh: Mesh, BT, std, correlation) -> list:
    """``(BT_a)' S_c R_c S_c BT_b`` for every component ``c`` and pair ``a <= b`` (``S_c``
    the std, ``R_c`` the noise's correlation between pixels, the identity when none is
    given): ``H`` is their sum weighted by the stiffness, the only part that changes
    between iterations."""
    blocks = []
    for c, s in enumerate(std):
        if correlation is None:
            D = sp.diags(s * s)
            blocks.append({(a, b): np.asarray((BT[a].T @ (D @ BT[b])).todense())
                           for a in range(3) for b in range(a, 3)})
            continue
        m = BT[0].shape[1]
        block = {(a, b): np.empty((m, m)) for a in range(3) for b in range(a, 3)}
        # a few columns at a time: (n_pixels, m) dense would not fit a large image
        for b in range(3):
            for j in range(0, m, _CHUNK):
                cols = BT[b][:, j:j + _CHUNK].toarray()
                Y = s[:, None] * correlate(mesh, s[:, None] * cols, correlation[c])
                for a in range(b + 1):
                    block[a, b][:, j:j + _CHUNK] = BT[a].T @ Y
        blocks.append(block)
    return blocks


def _noise_matrix(blocks, C, D, scale: float) -> np.ndarray:
    """``(t a)^2 sum_c (C B T)_c' diag(s_c^2) (D B T)_c``, ``(m, m)``: with ``C = D =
    C(p)`` the variance of the virtual work's noise, reduced (``H``)."""
    m = blocks[0][0, 0].shape[0]
    H = np.zeros((m, m))
    for c, block in enumerate(blocks):
        for (a, b), M in block.items():
            H += C[c, a] * D[c, b] * M
            if a != b:
                H += C[c, b] * D[c, a] * M.T
    return scale * scale * H


def special_fields(mesh: Mesh, T, strain, std, load: float, model, *, thickness: float,
                   correlation=None):
    """The noise-optimal special virtual fields of one set of strain maps.

    Parameters
    ----------
    mesh : Mesh
    T : (n_dof, m) sparse matrix
        The admissible virtual displacements (:meth:`Mesh.kinematics`).
    strain, std : (3, n_pixels) float64 ndarray
        ``exx, eyy, exy`` (tensor shear) at the mesh's pixels and their std.
    load : float
        The resultant that works, nonzero.
    model : stiffness model
    thickness : float
    correlation : sequence of 3 (2R+1, 2R+1) ndarray, optional
        The correlation of the noise of ``exx, eyy, exy`` between pixels ``d`` apart,
        1 at the centre; independent pixels when None.

    Returns
    -------
    p : (n_par,) float64 ndarray
    cov : (n_par, n_par) float64 ndarray
        The method's own covariance of ``p`` from the stated std.
    fields : (n_par, n_dof) float64 ndarray
        The special virtual fields (nodal displacements).
    iterations : int
    snr : float
        The smallest eigenvalue of ``A H^-1 A'`` against the share the noise gives it:
        how many times the weakest combination of the parameters is seen above the
        noise (squared).

    Raises
    ------
    NotIdentifiable
        When the equations of the parameters are dependent.
    """
    scale = thickness * mesh.pixel_size ** 2
    Z, sd = _operators(mesh, strain, std, model, scale)
    A = Z @ T  # (n_par, m), dense
    blocks = _noise_blocks(mesh, mesh.reduced(T), sd, correlation)
    p = model.guess()
    k = len(model.basis)
    eye = np.eye(A.shape[1])
    iteration = 0
    while iteration < MAX_ITERATIONS:
        iteration += 1
        C = model.stiffness(p)
        H = _noise_matrix(blocks, C, C, scale)
        # a vanishing safeguard: a field that no pixel strains costs nothing
        H[np.diag_indices_from(H)] += 1e-12 * np.trace(H) / H.shape[0]
        Hi = sla.cho_solve(sla.cho_factor(H), eye)
        HiA = Hi @ A.T  # (m, n_par)
        G = A @ HiA
        d = np.sqrt(np.abs(np.diag(G)))
        if not np.all(d > 0):
            raise NotIdentifiable("the measured strains do no virtual work: no field "
                                  "strains the measured region (zero or empty maps)")
        w, vecs = np.linalg.eigh(G / np.outer(d, d))
        if w[0] < RCOND * w[-1]:
            comb = vecs[:, -1] / d
            raise NotIdentifiable(
                f"the measured fields cannot separate E from nu: they give "
                f"{model.describe(comb / np.max(np.abs(comb)))}")
        # the noise's own share of G, E[dA H^-1 dA'] = tr(H^-1 N_jk'), N_jk the
        # covariance of the rows' noise: the fields are drawn from the noisy strains,
        # so that G holds it; taken out, the estimate has no first-order bias
        # (errors in variables)
        N = np.array([[np.sum(Hi * _noise_matrix(blocks, model.basis[i], model.basis[j],
                                                  scale))
                       for j in range(k)] for i in range(k)])
        Gc = G - N
        nw, nvecs = np.linalg.eigh(N)
        whiten = nvecs / np.sqrt(np.maximum(nw, nw[-1] * 1e-300))
        snr = float(np.linalg.eigvalsh(whiten.T @ Gc @ whiten)[0])
        if snr < SNR_MIN:
            comb = np.linalg.eigh(G / np.outer(d, d))[1][:, -1] / d
            raise NotIdentifiable(
                f"the measured fields cannot separate E from nu: they give "
                f"{model.describe(comb / np.max(np.abs(comb)))}; the other combination "
                f"of the stiffness stands only {max(snr, 0.0):.2g} times above the noise "
                f"(at least {SNR_MIN:g} needed: a heterogeneous field, more load or "
                f"less noise)")
        Gi = np.linalg.inv(Gc)
        V = HiA @ Gi  # (m, n_par): the (nearly) special fields, reduced
        p_new = load * V[-1, :]
        if not model.plausible(p_new):
            # the noise-optimal metric needs a stiffness: stop there
            p = p_new
            break
        done = abs(p_new[1] / p_new[0] - p[1] / p[0]) <= RTOL * max(1.0, abs(p[1] / p[0]))
        p = p_new
        if done:
            break
    fields = np.asarray((T @ V).T)
    return p, Gi, fields, iteration, snr


def virtual_work(mesh: Mesh, strain, std, p, fields, model, *, thickness: float,
                 correlation=None):
    """The internal virtual work of strain maps in given fields, and its noise variance.

    Parameters
    ----------
    strain, std : (3, n_pixels) float64 ndarray
    p : (n_par,) float64 ndarray
        The stiffness.
    fields : (n_fields, n_dof) float64 ndarray
        Nodal virtual displacements.

    Returns
    -------
    work, var : (n_fields,) float64 ndarray
        ``t a sum_pixels sigma(p) . eps*`` for each field and its variance from ``std``.
    """
    scale = thickness * mesh.pixel_size ** 2
    C = model.stiffness(p)
    virtual = np.stack([b @ fields.T for b in mesh.B])  # (3, n_pixels, n_fields)
    measured = np.array([strain[0], strain[1], 2.0 * strain[2]])
    sigma_star = np.einsum("cd,dpf->cpf", C, virtual)  # C symmetric: eps.C.eps*
    work = scale * np.einsum("cp,cpf->f", measured, sigma_star)
    noise = np.zeros(fields.shape[0])
    for c, s in enumerate((std[0], std[1], 2.0 * std[2])):
        x = s[:, None] * sigma_star[c]
        rx = x if correlation is None else correlate(mesh, x, correlation[c])
        noise += np.sum(x * rx, axis=0)
    return work, scale**2 * noise
