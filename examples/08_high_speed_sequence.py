"""
A high-speed record: one state per frame
========================================

A camera record at 100 000 frames/s: each frame a state, the strain history of a
virtual gauge with its standard deviation.

The record starts static (5 frames: the reference, averaged), then a strain pulse
passes through the coupon: ``exx`` rises to 2e-3 and falls back, with Poisson's
contraction and a small rigid drift. The frames are generated (the paper's grid
model and a 12-bit camera's noise), so the gauge can be compared with the truth.
``measure_series(..., reference_frames=5, frame_rate=...)`` is ``gridstrain measure
record.tif --reference-frames 5 --frame-rate 100000``: every frame after the
reference is measured as a state of its own, never averaged with the others.
Run: ``python examples/08_high_speed_sequence.py``.
"""

import matplotlib.pyplot as plt
import numpy as np

from gridstrain import Lattice, measure_series
from gridstrain.models import synthetic
from gridstrain.post import gauge, history

lattice = Lattice.from_pitch(5.0)
H, W = 128, 160
STATIC, N = 5, 40  # static frames, then frames under load
RATE = 1e5  # frames per second
rng = np.random.default_rng(8)


def strain_at(k):
    """True exx of frame k: a smooth pulse over the loaded frames."""
    t = max(k - STATIC + 1, 0) / N
    return 2e-3 * np.sin(np.pi * t) ** 2


def frame(k):
    e = strain_at(k)
    drift = 0.01 * max(k - STATIC + 1, 0)  # px per frame: the coupon moves too

    def field(X, Y):
        return drift + e * (X - W / 2), -0.3 * e * (Y - H / 2)

    img = synthetic.grid_image((H, W), lattice, amplitude=1500.0, displacement=field)
    return synthetic.add_noise(img, rng=rng)  # Var = 0.28 l + 5 grey levels^2


record = np.stack([frame(k) for k in range(STATIC + N)])  # (T, H, W), as a TIFF stack
# the camera's noise from its datasheet: single frames then need no noise estimate;
# the record starts at rest, which fixes the first state's whole number of periods
result = measure_series(None, record, reference_frames=STATIC, frame_rate=RATE,
                        lattice=lattice, noise_model=(0.28, 5.0), guess=(0.0, 0.0))
print("warnings:", result.warnings or "none")
print(f"{result.n_states} states, {result.names[1]} ... {result.names[-1]}, "
      f"t = {result.time[0] * 1e6:.0f} to {result.time[-1] * 1e6:.0f} µs")

# %%
# A virtual gauge over the middle of the coupon: the mean of each strain over the
# valid pixels of a rectangle, with its standard deviation (the window correlates
# neighbouring pixels: it is not the spatial std over the square root of N).
g = gauge(result, region=(40, 30, 120, 98))
truth = np.array([strain_at(k) for k in range(STATIC, STATIC + N)])
z = np.abs(g.exx - truth) / g.exx_std
print(f"gauge exx std: {np.median(g.exx_std) * 1e6:.1f} µε; "
      f"largest |gauge - truth| = {z.max():.1f} std")

# %%
# The history: gauge readings with a band of two standard deviations, and the
# strain rate of a Savitzky-Golay filter over 7 frames.
h = history(g, window=7, order=2)
print(f"peak strain rate {np.max(h.exx_rate):.0f} /s (true "
      f"{2e-3 * np.pi / (N / RATE):.0f} /s)")
t_us = g.time * 1e6
fig, (ax, ax_rate) = plt.subplots(2, 1, figsize=(6, 5), sharex=True, layout="constrained")
ax.fill_between(t_us, (g.exx - 2 * g.exx_std) * 1e6, (g.exx + 2 * g.exx_std) * 1e6,
                alpha=0.3, label="gauge ± 2 std")
ax.plot(t_us, g.exx * 1e6, "o", ms=3, label=r"gauge $\varepsilon_{xx}$")
ax.plot(t_us, truth * 1e6, "k--", lw=0.8, label="true")
ax.plot(t_us, g.eyy * 1e6, "s", ms=3, label=r"gauge $\varepsilon_{yy}$")
ax.plot(t_us, -0.3 * truth * 1e6, "k:", lw=0.8)
ax.set_ylabel("strain (µε)")
ax.legend(fontsize=8)
ax_rate.fill_between(t_us, h.exx_rate - 2 * h.exx_rate_std, h.exx_rate + 2 * h.exx_rate_std,
                     alpha=0.3)
ax_rate.plot(t_us, h.exx_rate, "-", label=r"d$\varepsilon_{xx}$/dt")
ax_rate.set_xlabel("time (µs)")
ax_rate.set_ylabel("strain rate (1/s)")
ax_rate.legend(fontsize=8)
plt.show()
