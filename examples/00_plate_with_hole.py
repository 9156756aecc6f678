"""
A plate with a hole in tension
==============================

What gridstrain is for, in one figure: the strain map of an aluminium plate with a
hole, measured from noisy camera images of the grid bonded to it (eight frames per
state, averaged), next to the analytic (Kirsch) field, on smaller images with a
window of sigma = 2 pitches. ``gridstrain demo`` runs a whole tensile test instead:
load steps, the testing machine's log, E and nu.
Run: ``python examples/00_plate_with_hole.py``.
"""

import matplotlib.pyplot as plt
import numpy as np

from gridstrain import Lattice, measure_series
from gridstrain.models import kirsch, synthetic

n, radius = 320, 32.0
centre = (n / 2, n / 2)
# a remote stress of 100 MPa on 70 GPa aluminium: 1.4e-3 far from the hole
elastic = {"radius": radius, "remote_stress": 100.0, "centre": centre}
lattice = Lattice.from_pitch(5.0)
rng = np.random.default_rng(0)


def specimen(X, Y):
    """Reflectance: the grid on the plate, black in the hole."""
    return ((X - centre[0]) ** 2 + (Y - centre[1]) ** 2 >= radius**2).astype(float)


def loaded(X, Y):
    return kirsch.displacement(X, Y, inside="extend", **elastic)


def camera(field, frames=8):
    img = synthetic.grid_image((n, n), lattice, amplitude=1500.0, displacement=field,
                               reflectance=specimen) + 100.0
    # a 12-bit camera's Poisson-Gaussian noise, Var = 0.28 l + 5 (grey levels^2)
    return np.array([synthetic.add_noise(img, rng=rng) for _ in range(frames)])


reference, deformed = camera(None), camera(loaded)
yy, xx = np.mgrid[0:n, 0:n].astype(float)
mask = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 > (radius + 1) ** 2
result = measure_series(reference, [deformed], lattice=lattice, mask=mask, sigma=10.0)
exx, v = result.exx[0], result.valid[0]
true_exx = kirsch.strain(xx, yy, **elastic)[0]
print(f"RMS error of exx: {np.sqrt(np.mean((exx - true_exx)[v] ** 2)):.1e} "
      f"(largest strain {np.nanmax(true_exx[v]):.1e})")

# %%
# The measured map and the truth, in microstrain (µε), on the same colour scale. The
# band along the border and around the hole is invalid: the window is cut there.
fig, axes = plt.subplots(1, 3, figsize=(10, 3.4), layout="constrained")
axes[0].imshow(reference[0, 128:192, 48:112], cmap="gray")
axes[0].set_title("the grid (64 x 64 px crop)")
lo, hi = 1e6 * np.percentile(true_exx[v], [0.5, 99.5])
for ax, values, title in ((axes[1], exx, "measured"),
                          (axes[2], np.where(v, true_exx, np.nan), "Kirsch (truth)")):
    im = ax.imshow(1e6 * values, cmap="viridis", vmin=lo, vmax=hi)
    ax.set_title(f"$\\varepsilon_{{xx}}$, {title}")
fig.colorbar(im, ax=axes[1:], label="µε", shrink=0.9)
for ax in axes:
    ax.set_axis_off()
plt.show()
