"""
A pair of images: displacement and strain
=========================================

A reference image and a deformed image: displacement and strain maps.

The images are generated (the paper's grid model, eq. 1) so that the result can be
compared with the true field: a rigid translation plus a homogeneous strain of 1e-3.
Run: ``python examples/01_pair.py``.
"""

import matplotlib.pyplot as plt
import numpy as np

from gridstrain import Lattice, measure
from gridstrain.models import synthetic

lattice = Lattice.from_pitch(5.0)  # k1 = (1/5, 0), k2 = (0, 1/5) cycles/px
shape = (160, 160)
reference = synthetic.grid_image(shape, lattice, amplitude=1500.0)


def field(X, Y):
    """True displacement (px) of the material point at reference position (X, Y)."""
    return 0.3 + 1e-3 * X, -0.2 + 0.0 * Y


deformed = synthetic.grid_image(shape, lattice, amplitude=1500.0, displacement=field)

# noise-free images: the method itself is exact to about 1e-6 strain
result = measure(reference, deformed, lattice=lattice)
print(result)
print(f"mean exx = {np.nanmean(result.exx):.6f} (true 0.001)")
print(f"largest |eyy| = {np.nanmax(np.abs(result.eyy)):.1e} (true 0)")
print(f"valid pixels: {result.valid.mean():.0%} (a band of 4 sigma along the border "
      "is invalid: the window is cut there)")

# the same pair seen by a 12-bit camera (Poisson-Gaussian noise, Var = 0.28 l + 5)
rng = np.random.default_rng(0)
noisy = measure(synthetic.add_noise(reference, rng=rng), synthetic.add_noise(deformed, rng=rng),
                lattice=lattice)
print(f"with sensor noise: pixel-to-pixel std of exx = {np.nanstd(noisy.exx):.1e}")

# %%
# The pair and the maps measured from the noisy images: ``u_x`` grows along ``x``
# (the strain), ``exx`` is 1e-3 plus the noise of one image pair.
fig, axes = plt.subplots(1, 4, figsize=(12, 3), layout="constrained")
axes[0].imshow(reference[:40, :40], cmap="gray")
axes[0].set_title("reference (40 x 40 px)")
axes[1].imshow(deformed[:40, :40], cmap="gray")
axes[1].set_title("deformed")
im = axes[2].imshow(noisy.u[0], cmap="viridis")
fig.colorbar(im, ax=axes[2], label="px", shrink=0.8)
axes[2].set_title("$u_x$")
im = axes[3].imshow(1e6 * noisy.exx, cmap="viridis")
fig.colorbar(im, ax=axes[3], label="µε", shrink=0.8)
axes[3].set_title("$\\varepsilon_{xx}$")
for ax in axes:
    ax.set_axis_off()
plt.show()
