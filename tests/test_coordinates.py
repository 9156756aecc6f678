"""A result changed with ``dataclasses.replace`` is saved with its own maps."""

from __future__ import annotations

import csv
import dataclasses

import h5py
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from gridstrain import measure_series
from gridstrain.results import load

H, W = 192, 256
PITCH = 5.0  # px: a 0.2 mm grid at PS
PS = 0.04  # mm per px, not a power of two: px = mm / PS is not exact in binary
#: The axial strain of each loaded state and the specimen's law.
STRAINS = (0.5e-3, 1.0e-3, 1.5e-3, 2.0e-3)
NU, E_MPA, AREA = 0.3, 70_000.0, 20.0  # MPa, mm2
DT = 0.5  # s between states
NOISE = 5.0  # grey levels, std


def grid_image(exx: float, eyy: float, rng) -> np.ndarray:
    """A cross grid of pitch ``PITCH`` px under the homogeneous strain (exx, eyy).

    Assumptions: the grid model of the method's paper (eq. 1), ``2000 (1 + 0.4
    cos(2 pi X / p) + 0.4 cos(2 pi Y / p))``, sampled at the pixel centres (no pixel
    integration: it would only scale the contrast of a band-limited cosine); the
    material point ``X`` seen at ``x = (1 + exx) X`` (Lagrangian, so the small-strain
    tensor is exactly ``(exx, eyy, 0)``); white Gaussian noise of std ``NOISE``.
    """
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    X, Y = x / (1.0 + exx), y / (1.0 + eyy)
    level = 2000.0 * (1.0 + 0.4 * np.cos(2 * np.pi * X / PITCH)
                      + 0.4 * np.cos(2 * np.pi * Y / PITCH))
    return level + rng.normal(0.0, NOISE, level.shape)


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    """A tensile test of four states, its loads and times from a one-row-per-state file,
    saved with a pixel size of ``PS`` mm: ``(path, loaded result)``."""
    d = tmp_path_factory.mktemp("coordinates")
    rng = np.random.default_rng(41)
    ref = grid_image(0.0, 0.0, rng)
    states = [grid_image(e, -NU * e, rng) for e in STRAINS]
    loads = d / "loads.csv"
    with open(loads, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["load [N]", "time [s]"])
        for k, e in enumerate(STRAINS):
            w.writerow([E_MPA * AREA * e, DT * (k + 1)])
    res = measure_series(ref, states, guess=None, noise_model=(1e-6, NOISE**2),
                         loads=loads)
    path = res.save(d / "maps.h5", pixel_size=PS, unit="mm")
    return path, load(path)


# ----------------------------------------------------------------------------- saving


def test_a_replaced_result_is_saved_with_its_own_maps(result_file, tmp_path):
    """``dataclasses.replace(result, u=..., valid=...)`` then saved: the file holds the
    new maps (it held the measurements' again, silently)."""
    _, res = result_file
    u = np.asarray(res.u) + 1.0  # px: a rigid shift by one pixel
    valid = np.asarray(res.valid).copy()
    valid[:, :, : W // 2] = False
    strain = np.asarray(res.strain) * 2.0
    moved = dataclasses.replace(res, u=u, strain=strain, valid=valid)
    back = load(moved.save(tmp_path / "moved.h5", pixel_size=PS, unit="mm"))
    assert_array_equal(back.u, u)
    assert_array_equal(back.strain, strain)
    assert_array_equal(back.valid, valid)
    # the measurements come back with the maps the file holds
    assert_array_equal(back.measurements[2].u, u[2])
    with h5py.File(tmp_path / "moved.h5", "r") as h5:
        phys = np.asarray(h5["ux_phys"])
    assert_allclose(phys, u[:, 0] * PS, equal_nan=True)
    # one state too many: refused, not saved with the measurements' maps
    with pytest.raises(ValueError, match=r"result\.u must be a"):
        dataclasses.replace(res, u=np.concatenate([u, u[:1]])).save(tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()
