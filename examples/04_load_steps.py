"""
Load steps from a folder of TIFFs
=================================

A folder of TIFFs per load step, measured as a lab would.

Writes a reference series (5 frames) and three load steps (one image each) of a
stretched plate as 16-bit TIFF files, then measures the whole series with
``measure_series`` (the function behind ``gridstrain measure``).
Run: ``python examples/04_load_steps.py [OUTDIR]`` (default: a temporary folder).
"""

import sys
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from gridstrain import Lattice
from gridstrain.io import write_tiff_series
from gridstrain.models import synthetic
from gridstrain.series import measure_series

lattice = Lattice.from_pitch(5.0)
shape = (128, 128)
rng = np.random.default_rng(4)
root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp())
root.mkdir(parents=True, exist_ok=True)


def frames(strain, n):
    def field(X, Y):
        return strain * (X - 64), 0 * Y

    img = synthetic.grid_image(shape, lattice, amplitude=1500.0, displacement=field)
    return [np.round(synthetic.add_noise(img, rng=rng)).astype(np.uint16) for _ in range(n)]


write_tiff_series(root / "ref", frames(0.0, 5))
steps = [1e-3, 2e-3, 3e-3]
for i, e in enumerate(steps, start=1):
    write_tiff_series(root / f"step{i}", frames(e, 1))

result = measure_series(root / "ref", [root / f"step{i}" for i in (1, 2, 3)],
                        lattice=lattice)
print(result)
for i, e in enumerate(steps):
    print(f"{result.names[i + 1]}: mean exx = {np.nanmean(result.exx[i]):.2e} (true {e:.0e})")
# how each state's whole number of periods was fixed: the first from the smallest
# displacement (nothing but the grid to go by), the others followed step by step
for name, order in zip(result.names[1:], result.fringe_orders, strict=True):
    print(f"{name}: fringe order from {order.source}, "
          f"{'confirmed' if order.confirmed else 'not confirmed'}")

# %%
# The strain maps of the three steps on common colour limits (µε), as
# ``result.plot`` draws them (a matplotlib Figure: ``maps.savefig("exx.png")``).
maps = result.plot("exx")

# %%
# The mean strain of each step against the imposed one.
fig, ax = plt.subplots(figsize=(4, 3), layout="constrained")
ax.plot(steps, [np.nanmean(e) for e in result.exx], "o", label="measured (mean)")
ax.plot([0, steps[-1]], [0, steps[-1]], "k--", lw=0.8, label="imposed")
ax.set_xlabel("imposed $\\varepsilon_{xx}$")
ax.set_ylabel("measured $\\varepsilon_{xx}$")
ax.legend()
plt.show()
