"""
Noise and uncertainty
=====================

Know the camera, then predict the uncertainty of every pixel.

A static stack of a grid with small vibrations gives the sensor noise model
``Var = K l + L`` (grey levels^2) by regressing the vibrations out of each pixel's
time series. From it, the standard deviation of the displacement and strain at every
pixel of a measurement follows from the window and the local modulus.
Run: ``python examples/03_noise_and_uncertainty.py``.
"""

import matplotlib.pyplot as plt
import numpy as np

from gridstrain import Lattice, estimate_noise, measure
from gridstrain.models import synthetic
from gridstrain.uncertainty import noise_variance_map, predict_uncertainty

lattice = Lattice.from_pitch(5.0)
shape, T = (128, 128), 16
rng = np.random.default_rng(2)
K_true, L_true = 0.28, 5.0
clean = synthetic.grid_image(shape, lattice, amplitude=1500.0)
stack = [synthetic.add_noise(clean, K=K_true, L=L_true, rng=rng) for _ in range(T)]

model = estimate_noise(stack, lattice)
print(model)
print(f"true K = {K_true}, L = {L_true}")

ref, cur = stack[0], stack[1]
res = measure(ref, cur, lattice=lattice, guess=None)
var = noise_variance_map(ref, K=model.K, L=model.L, sigma=res.sigma)
unc = predict_uncertainty(res.reference, res.deformed, variance_ref=var, variance_def=var,
                          valid=res.valid)
v = res.valid
print(f"predicted std of exx (median): {np.median(unc.strain_std[0][v]):.2e}")
print(f"measured  std of exx (no strain, all noise): {np.std(res.exx[v]):.2e}")

# %%
# Left: the predicted standard deviation of ``exx`` at every pixel (it follows the
# local contrast of the grid). Right: the measured ``exx`` of two images of a static
# grid, all noise, whose spread the prediction states.
fig, axes = plt.subplots(1, 2, figsize=(9, 3.5), layout="constrained")
im = axes[0].imshow(np.where(v, unc.strain_std[0], np.nan), cmap="magma")
fig.colorbar(im, ax=axes[0], shrink=0.8)
axes[0].set_title("predicted std of $\\varepsilon_{xx}$")
axes[1].hist(res.exx[v], bins=60, density=True, color="0.6")
s_pred = np.median(unc.strain_std[0][v])
x = np.linspace(-4 * s_pred, 4 * s_pred, 200)
axes[1].plot(x, np.exp(-0.5 * (x / s_pred) ** 2) / (s_pred * np.sqrt(2 * np.pi)), "k",
             label="Gaussian of the predicted std")
axes[1].set_xlabel("$\\varepsilon_{xx}$ measured on a static grid")
axes[1].legend(loc="upper left", fontsize="small")
axes[0].set_axis_off()
plt.show()
