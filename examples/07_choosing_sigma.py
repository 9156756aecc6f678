"""
Choosing sigma: noise against spatial resolution
================================================

The window's standard deviation ``sigma`` trades noise for spatial resolution.
The strain noise falls as ``1/sigma^2`` while the smallest detail resolved, the
window's full width at half maximum ``d = 2.355 sigma``, grows as ``sigma``: their
product ``alpha = std(exx) d^2``, the metrological efficiency indicator, stays put.
It depends on the camera and the grid, not on ``sigma``.
Run: ``python examples/07_choosing_sigma.py``.
"""

import matplotlib.pyplot as plt
import numpy as np

from gridstrain import Lattice, measure
from gridstrain.models import synthetic

lattice = Lattice.from_pitch(5.0)
rng = np.random.default_rng(7)
clean = synthetic.grid_image((256, 256), lattice, amplitude=1500.0)
# two images of a static grid: every strain measured is noise
reference, current = (synthetic.add_noise(clean, rng=rng) for _ in range(2))

sigmas = np.array([5.0, 6.0, 8.0, 10.0, 12.0])
noise = []
for sigma in sigmas:
    res = measure(reference, current, lattice=lattice, sigma=sigma, guess=(0.0, 0.0))
    noise.append(np.std(res.exx[res.valid]))
noise = np.array(noise)
d = 2.355 * sigmas  # spatial resolution, px (window FWHM)
for s, n, a in zip(sigmas, noise, noise * d**2, strict=True):
    print(f"sigma = {s:4.1f} px: std(exx) = {n:.1e}, alpha = std * d^2 = {a:.3f} px^2")
slope = np.polyfit(np.log(sigmas), np.log(noise), 1)[0]
print(f"slope of log std(exx) against log sigma: {slope:.2f} (theory -2)")

# %%
# Left: the strain noise against sigma, with the ``1/sigma^2`` law through the
# first point. Right: what it costs, the spatial resolution. Pick the smallest
# sigma whose noise is below the strain resolution your test needs.
fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), layout="constrained")
axes[0].loglog(sigmas, noise, "o", label="measured")
axes[0].loglog(sigmas, noise[0] * (sigmas[0] / sigmas) ** 2, "k--", lw=0.8,
               label="$\\propto 1/\\sigma^2$")
axes[0].set_xlabel("$\\sigma$ (px)")
axes[0].set_ylabel("std of $\\varepsilon_{xx}$")
axes[0].legend()
axes[1].plot(sigmas, d, "o-")
axes[1].set_xlabel("$\\sigma$ (px)")
axes[1].set_ylabel("spatial resolution $d = 2.355\\,\\sigma$ (px)")
plt.show()
