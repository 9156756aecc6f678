"""Piecewise bilinear virtual fields over a rectangular mesh of the measured region.

The region's bounding box (pixel edges, not centres: every pixel's area lies inside)
is cut into ``ny x nx`` equal elements; a virtual displacement is given by its two
components at the ``(ny + 1) (nx + 1)`` nodes, degree of freedom ``2 n`` (``u*_x``) and
``2 n + 1`` (``u*_y``) at node ``n = row * (nx + 1) + col``, and interpolated with the
4-node bilinear shape functions (Pierron & Grédiac 2012, ch. 3). The virtual strains at
the pixel centres are then ``B_c U`` for ``c`` in ``(1, 2, 6)`` (``eps6* = du*_x/dy +
du*_y/dx``), three sparse ``(n_pixels, n_dof)`` matrices.

The kinematic conditions are written as ``U = T v``: the nodes of the gripped edge do
not move; those of the loaded edge move together along the load (one shared degree of
freedom, the last of ``v``, whose value ``u*_bar`` makes the external virtual work
``F u*_bar``) and not across it, so that only the measured component of the resultant
works; the other nodes are free. Degrees of freedom that no usable pixel sees (a node in a
hole) are left out.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: edge -> (axis of its normal: 0 x / 1 y, which end: 0 low / 1 high)
EDGES = {"left": (0, 0), "right": (0, 1), "top": (1, 0), "bottom": (1, 1)}
OPPOSITE = {"left": "right", "right": "left", "top": "bottom", "bottom": "top"}


class Mesh:
    """A rectangular mesh over the usable pixels and the virtual strains it gives.

    Parameters
    ----------
    rows, cols : (n,) int ndarray
        The usable pixels (row, column).
    pixel_size : float
        Side of a pixel, in the length unit of the result.
    elements : (int, int)
        ``(ny, nx)``: elements along y (rows) and x (columns).
    """

    def __init__(self, rows, cols, pixel_size: float, elements):
        ny, nx = elements
        self.ny, self.nx = ny, nx
        self.rows, self.cols = rows, cols
        self.pixel_size = pixel_size
        # the box's edges in physical units: pixel i covers [i - 1/2, i + 1/2] px
        self.x0 = (cols.min() - 0.5) * pixel_size
        self.y0 = (rows.min() - 0.5) * pixel_size
        self.hx = (cols.max() - cols.min() + 1) * pixel_size / nx
        self.hy = (rows.max() - rows.min() + 1) * pixel_size / ny
        x = cols * pixel_size
        y = rows * pixel_size
        ex = np.clip(((x - self.x0) // self.hx).astype(np.int64), 0, nx - 1)
        ey = np.clip(((y - self.y0) // self.hy).astype(np.int64), 0, ny - 1)
        xi = (x - self.x0) / self.hx - ex
        eta = (y - self.y0) / self.hy - ey
        n_pix = rows.size
        self.n_nodes = (ny + 1) * (nx + 1)
        self.n_dof = 2 * self.n_nodes
        # the 4 nodes of each pixel's element and their shape functions' derivatives
        corners = ((0, 0), (1, 0), (0, 1), (1, 1))  # (dx, dy) from the element's corner
        node = np.stack([(ey + dy) * (nx + 1) + ex + dx for dx, dy in corners], axis=1)
        dndx = np.stack([((2 * dx - 1) * (eta if dy else 1 - eta)) / self.hx
                         for dx, dy in corners], axis=1)
        dndy = np.stack([((2 * dy - 1) * (xi if dx else 1 - xi)) / self.hy
                         for dx, dy in corners], axis=1)
        r = np.repeat(np.arange(n_pix), 4)
        shape = (n_pix, self.n_dof)
        bx = sp.csr_matrix((dndx.ravel(), (r, 2 * node.ravel())), shape=shape)
        by = sp.csr_matrix((dndy.ravel(), (r, 2 * node.ravel() + 1)), shape=shape)
        b6 = sp.csr_matrix((np.concatenate([dndy.ravel(), dndx.ravel()]),
                            (np.concatenate([r, r]),
                             np.concatenate([2 * node.ravel(), 2 * node.ravel() + 1]))),
                           shape=shape)
        self.B = (bx, by, b6)

    def reduced(self, T) -> list:
        """``[B_c T]``, the virtual strains of the reduced degrees of freedom (kept for
        the last ``T``: every state shares it)."""
        cached = getattr(self, "_reduced", None)
        if cached is None or cached[0] is not T:
            self._reduced = (T, [(b @ T).tocsr() for b in self.B])
        return self._reduced[1]

    def _edge_nodes(self, edge: str) -> np.ndarray:
        axis, end = EDGES[edge]
        nodes = np.arange(self.n_nodes).reshape(self.ny + 1, self.nx + 1)
        if axis == 0:
            return nodes[:, -1 if end else 0]
        return nodes[-1 if end else 0, :]

    def kinematics(self, loaded_edge: str, load_direction: str) -> sp.csr_matrix:
        """``(n_dof, m)`` ``T``: admissible virtual displacements ``U = T v``, the last
        entry of ``v`` the loaded edge's displacement along the load."""
        gripped = self._edge_nodes(OPPOSITE[loaded_edge])
        loaded = self._edge_nodes(loaded_edge)
        along = 0 if load_direction == "x" else 1
        fixed = np.zeros(self.n_dof, dtype=bool)
        fixed[2 * gripped] = fixed[2 * gripped + 1] = True
        fixed[2 * loaded] = fixed[2 * loaded + 1] = True
        # a degree of freedom no usable pixel sees does nothing: left out
        seen = np.zeros(self.n_dof, dtype=bool)
        for b in self.B:
            seen |= np.asarray(abs(b).sum(axis=0)).ravel() > 0
        free = np.flatnonzero(~fixed & seen)
        rows = np.concatenate([free, 2 * loaded + along])
        cols = np.concatenate([np.arange(free.size), np.full(loaded.size, free.size)])
        return sp.csr_matrix((np.ones(rows.size), (rows, cols)),
                             shape=(self.n_dof, free.size + 1))
