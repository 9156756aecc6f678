"""
A cantilever beam: E and ν by the virtual fields method
=======================================================

A beam built in at one end and loaded by a shear force at the other bends: its
strains vary along and across it, so one test holds both elastic constants, and no
gauge reads them. The principle of virtual work over the strain maps and the load
gives them: ``gridstrain.identify`` takes the virtual fields that the noise affects
least (Avril & Pierron), and states E and ν with their 95 % intervals.

The strain maps here are the exact plane-stress solution of the beam (Timoshenko &
Goodier), aluminium (E = 70 GPa, ν = 0.33), 10 mm deep, 40 mm long, 2 mm thick, four
load steps of 25 to 100 N, with white noise of 100 µε per pixel as a measurement
gives. The maps of a measurement stop a few window widths short of the specimen's
free edges, which leaves out the load carried there: from a result file, the region
used must reach them (``gridstrain identify`` refuses otherwise). The command::

   gridstrain identify maps.h5 --thickness 2 --loaded-edge left --load-direction y \
       --loads loads.csv --json

Run: ``python examples/11_virtual_fields.py``.
"""

import numpy as np

from gridstrain.identify import NotIdentifiable, virtual_fields

E, NU = 70e3, 0.33  # MPa, -
H, W, PIXEL, THICKNESS = 48, 192, 10.0 / 48, 2.0  # px, px, mm, mm
loads = np.array([25.0, 50.0, 75.0, 100.0])  # N: the +y force on the left end
noise = 1e-4  # strain std per pixel
rng = np.random.default_rng(0)


def beam(load):
    """exx, eyy, exy of the beam: sigma_xx = -F x y / (I t), sigma_xy = -F (c^2 - y^2) /
    (2 I t), sigma_yy = 0, x from the loaded end, y from the axis (down)."""
    rows, cols = np.indices((H, W), dtype=np.float64)
    c = H * PIXEL / 2
    x, y = (cols + 0.5) * PIXEL, (rows + 0.5) * PIXEL - c
    inertia = 2 * c**3 / 3
    sxx = -load * x * y / (inertia * THICKNESS)
    sxy = -load * (c * c - y * y) / (2 * inertia * THICKNESS)
    return np.stack([sxx / E, -NU * sxx / E, sxy * (1 + NU) / E])


strain = np.stack([beam(f) for f in loads])
strain += rng.normal(0.0, noise, strain.shape)
std = np.full_like(strain, noise)  # a result's exx_std, eyy_std, exy_std maps

fit = virtual_fields(strain, std, loads, thickness=THICKNESS, loaded_edge="left",
                     load_direction="y", pixel_size=PIXEL, unit="mm", load_unit="N")
print(f"E  = {fit.E:.0f} {fit.stress_unit}, 95 % interval "
      f"[{fit.E_interval[0]:.0f}, {fit.E_interval[1]:.0f}] (truth {E:.0f})")
print(f"nu = {fit.nu:.4f}, 95 % interval [{fit.nu_interval[0]:.4f}, "
      f"{fit.nu_interval[1]:.4f}] (truth {NU})")
print(f"{fit.n_pixels} px, {fit.elements[0]} x {fit.elements[1]} elements; each state "
      f"alone: E = {', '.join(f'{v:.0f}' for v in fit.E_states)} MPa")

# a uniform shear holds only G: the command says so instead of printing a number
shear = np.zeros_like(strain)
shear[:, 2] = loads[:, None, None] / (H * PIXEL * THICKNESS) * (1 + NU) / E
try:
    virtual_fields(shear, std, loads, thickness=THICKNESS, loaded_edge="right",
                   load_direction="y", pixel_size=PIXEL)
except NotIdentifiable as exc:
    print(f"uniform shear: {exc}")
