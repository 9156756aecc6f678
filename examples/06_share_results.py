"""
Save, reopen, export and share a result
=======================================

Save a result, open it again, look at it and share it.

Measures two load steps of a stretched plate, writes the result file, reads it back
(with gridstrain and, when installed, with xarray), exports it for MATLAB, ParaView
and a spreadsheet, and writes the HTML report to open in a browser.
Run: ``python examples/06_share_results.py [OUTDIR]`` (default: a temporary folder).
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

import gridstrain
from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.post import write_report
from gridstrain.results import export

lattice = Lattice.from_pitch(5.0)
rng = np.random.default_rng(6)
root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp())
root.mkdir(parents=True, exist_ok=True)


def frames(strain, n):
    def field(X, Y):
        return strain * (X - 48), 0 * Y

    img = synthetic.grid_image((96, 96), lattice, amplitude=1500.0, displacement=field)
    return np.array([synthetic.add_noise(img, rng=rng) for _ in range(n)])


result = gridstrain.measure_series(frames(0.0, 3), [frames(1e-3, 3), frames(2e-3, 3)],
                                   lattice=lattice)
path = result.save(root / "maps.h5", pixel_size=0.04, unit="mm", overwrite=True)
again = gridstrain.load(path)
print(f"wrote {path}; read back: {again}")
print("the same maps:", np.array_equal(again.strain, result.strain, equal_nan=True))
for fmt, p in export(result, root / "maps", ["mat", "vtk", "csv"], pixel_size=0.04,
                     unit="mm", overwrite=True).items():
    print(f"exported {fmt}: {p.name}")
try:
    import xarray as xr

    with xr.open_dataset(path, engine="h5netcdf") as ds:
        step = ds.sel(state="state 1")
        print(f"xarray: mean exx of state 1 = {float(step.exx.where(step.valid).mean()):.3e}")
except ImportError:
    print("xarray is not installed (pip install 'gridstrain[xarray]')")
report = write_report(path, root / "report.html", overwrite=True)
print(f"report written: {report} (open it in a browser)")

# %%
# The maps of every state on colour limits they share (robust percentiles), as the
# report draws them.
maps = again.plot("exx")
maps.savefig(root / "exx.png")
print(f"figure written: {root / 'exx.png'}")
