"""
A tensile coupon: Young's modulus and Poisson's ratio
=====================================================

Ten load steps of a tensile test, one image each, the load cell's record in a CSV
file: a virtual gauge, then E and ν with their 95 % intervals and the stress-strain
curve.

The coupon is aluminium (E = 70 GPa, ν = 0.33, cross-section 20 mm²) loaded from
300 to 3000 N; the images are generated (the paper's grid model and a 12-bit
camera's noise), so the constants can be compared with the truth. The same from the
command line::

   gridstrain measure ref/ steps/ --each-frame --loads loads.csv -o maps.h5
   gridstrain modulus maps.h5 --region 50 40 190 136 --area 20 --plot ss.png

Run: ``python examples/09_tensile_coupon.py [OUTDIR]`` (default: a temporary folder).
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

from gridstrain import Lattice, measure_series
from gridstrain.io import write_tiff_series
from gridstrain.models import synthetic
from gridstrain.post import elastic_constants, gauge, plot_stress_strain

lattice = Lattice.from_pitch(5.0)
H, W = 176, 240
E, NU, AREA = 70e3, 0.33, 20.0  # MPa, -, mm²
loads = np.linspace(300.0, 3000.0, 10)  # N
rng = np.random.default_rng(9)


def image(strain):
    def field(X, Y):
        return strain * (X - W / 2), -NU * strain * (Y - H / 2)

    img = synthetic.grid_image((H, W), lattice, amplitude=1500.0, displacement=field)
    return synthetic.add_noise(img, rng=rng)  # Var = 0.28 l + 5 grey levels^2


# a lab's folders: 5 images of the unloaded coupon (averaged: the reference), then
# one image per load step, numbered by the camera
folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp())
folder.mkdir(parents=True, exist_ok=True)
write_tiff_series(folder / "ref", [image(0.0) for _ in range(5)], prefix="ref_")
write_tiff_series(folder / "steps", (image(f / AREA / E) for f in loads), prefix="step_",
                  start=1, digits=2)
# the load cell's record, as a test rig writes it: one row per step, in order
(folder / "loads.csv").write_text(
    "# tensile test, load cell 5 kN\nload [N],time [s]\n"
    + "".join(f"{f:.1f},{2.0 * (i + 1):.1f}\n" for i, f in enumerate(loads)))

# sigma = 8 px: the strain is homogeneous, so a wide window costs no resolution
result = measure_series(folder / "ref", folder / "steps", each_frame=True,
                        loads=folder / "loads.csv", sigma=8.0, noise_model=(0.28, 5.0),
                        guess=(0.0, 0.0))
print(f"{result.n_states} states ({result.names[1]} to {result.names[-1]}), loads "
      f"{result.load[0]:g} to {result.load[-1]:g} {result.load_unit}; warnings: "
      f"{result.warnings or 'none'}")

# %%
# A virtual gauge over the coupon's middle: each strain's mean over the valid
# pixels of the rectangle, with its standard deviation, one row per step (µε). The
# loads come with the result.
g = gauge(result, region=(50, 40, 190, 136))
print(g.table())

# %%
# Young's modulus and Poisson's ratio: the axial and transverse strains fitted as
# straight lines of the stress (load / area, MPa), weighted by the gauge's std.
c = elastic_constants(g, area=AREA)
print(f"E = {c.E / 1e3:.2f} GPa, 95 % interval [{c.E_ci[0] / 1e3:.2f}, "
      f"{c.E_ci[1] / 1e3:.2f}] (true {E / 1e3:.0f})")
print(f"nu = {c.nu:.3f}, 95 % interval [{c.nu_ci[0]:.3f}, {c.nu_ci[1]:.3f}] "
      f"(true {NU}); intervals from the {c.interval_basis}")

# %%
# The stress-strain curves with the fitted lines, as ``gridstrain modulus --plot``
# draws them (a matplotlib Figure: ``curve.savefig("ss.png")``).
curve = plot_stress_strain(c)
