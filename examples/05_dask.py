"""
Method B on a Dask cluster
==========================

Method B on a Dask cluster (needs ``pip install "gridstrain[distributed]"``).

The per-frame transforms of a stack run as Dask tasks on a two-worker cluster on
this machine, and their sums are reduced in a tree; the result equals the
in-process method B to float rounding.
Run: ``python examples/05_dask.py``.
"""

import numpy as np

from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.series import as_dask_stack, connect, method_b_dask
from gridstrain.stacks import method_b

if __name__ == "__main__":  # Dask's worker processes re-import this file
    lattice = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(5)
    clean = synthetic.grid_image((96, 96), lattice, amplitude=1500.0)
    frames = np.stack([synthetic.add_noise(clean, rng=rng) for _ in range(8)])

    with connect("local", n_workers=2) as client:
        dist = method_b_dask(as_dask_stack(frames, chunk_frames=2), lattice, client=client)
    local = method_b(frames, lattice)
    v = dist.maps.valid
    diff = np.max(np.abs(dist.maps.dphi[:, :, v] - local.maps.dphi[:, :, v]))
    print(f"largest difference Dask - in process: {diff:.1e} rad/px")
