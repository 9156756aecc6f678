"""Tests of gridstrain.post: maps centred on zero, transparent invalid pixels, PNGs."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
from matplotlib.colors import CenteredNorm
from numpy.testing import assert_allclose, assert_array_equal

from gridstrain import Lattice
from gridstrain.io import MARKER_NAME
from gridstrain.models import synthetic
from gridstrain.post import (
    figure_names,
    map_norm,
    plot_map,
    plot_shifts,
    save_figure,
    save_figures,
)
from gridstrain.series import measure_series

LAT = Lattice.from_pitch(5.0)


def _images(fig):
    return [im for ax in fig.axes for im in ax.get_images()]


def test_map_is_sequential_for_one_sign_and_invalid_is_transparent(rng):
    values = rng.normal(2e-3, 4e-4, (40, 50))  # a tensile strain: all positive
    valid = np.ones((40, 50), bool)
    valid[10:20, 10:30] = False
    values[~valid] = np.nan
    values[0, :3] = -3e-4  # a few noise pixels of the other sign: 0.2 % of them
    bg = synthetic.grid_image((40, 50), LAT)
    fig = plot_map(values, valid=valid, background=bg, label="e", unit="")
    grey, data = _images(fig)  # the grid image under the map
    assert grey.get_cmap().name == "gray"
    norm = data.norm
    # sequential over the robust range: the negative pixels do not centre the map
    assert not isinstance(norm, CenteredNorm)
    assert data.get_cmap().name.startswith("viridis")
    assert_allclose((norm.vmin, norm.vmax),
                    np.percentile(values[valid], [0.5, 99.5]), rtol=1e-12)
    arr = data.get_array()
    assert_array_equal(np.ma.getmaskarray(arr), ~valid)
    rgba = data.get_cmap()(np.ma.masked_invalid([np.nan]))
    assert rgba[0, 3] == 0.0  # bad (invalid) pixels are fully transparent
    cbar_label = fig.axes[1].get_ylabel()
    assert "dimensionless" in cbar_label


def test_both_signs_that_matter_give_a_diverging_map_ticked_on_both_halves(rng):
    values = np.linspace(-400.0, 2900.0, 40 * 50).reshape(40, 50)  # 12 % below zero
    fig = plot_map(values, label="e", unit="µε")
    (data,) = _images(fig)
    assert isinstance(data.norm, CenteredNorm)
    assert data.norm(0.0) == pytest.approx(0.5)  # white is zero
    assert data.get_cmap().name.startswith("RdBu_r")
    cbar = fig.axes[1]
    fig.canvas.draw()
    ticks = [t for t in cbar.get_yticks() if data.norm.vmin <= t <= data.norm.vmax]
    assert min(ticks) < 0 < max(ticks)
    # 3 % below zero is noise, not a sign that matters: sequential
    assert not isinstance(map_norm(np.linspace(-100.0, 2900.0, 1000)), CenteredNorm)


def test_plot_of_many_states_is_at_most_4000_px_tall(rng):
    from types import SimpleNamespace

    from gridstrain.post import capped_dpi, chosen_states, plot_states

    n, H, W = 200, 40, 60
    exx = rng.normal(1e-3, 1e-4, (n, H, W))
    fake = SimpleNamespace(
        n_states=n, shape=(H, W), valid=np.ones((n, H, W), bool),
        reference_image=rng.uniform(0, 1, (H, W)), names=("ref", *(f"s{i}" for i in range(n))),
        get_map=lambda name: exx, uncertainty=None)
    picked = chosen_states(n)
    assert picked[0] == 0
    assert picked[-1] == n - 1
    assert len(picked) == 12
    fig = plot_states(fake, "exx")
    assert sum(1 for ax in fig.axes if ax.get_images()) == 12
    height = fig.get_size_inches()[1]  # 4 rows of panels: 11.9 in
    assert capped_dpi(fig, 300) == 300  # 3560 px
    assert height * capped_dpi(fig, 1200) == pytest.approx(4000)  # not 14,240 px


def test_map_axes_in_physical_units_and_offset(rng):
    values = rng.normal(3.0, 0.1, (30, 60))
    fig = plot_map(values, label="u", unit="mm", pixel_size=0.04, length_unit="mm",
                   offset=3.0)
    (data,) = _images(fig)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x (mm)"
    assert ax.get_ylabel() == "y (mm)"
    # pixel j covers [j - 1/2, j + 1/2] (gridstrain.conventions), row 0 at the top
    assert_allclose(data.get_extent(), (-0.02, 59.5 * 0.04, 29.5 * 0.04, -0.02))
    assert_allclose(np.ma.getdata(data.get_array()), values - 3.0)
    assert "mean 3 mm removed" in fig.axes[1].get_ylabel()


def test_bad_map_arguments():
    with pytest.raises(ValueError, match="2-D"):
        plot_map(np.zeros(5))
    with pytest.raises(ValueError, match="valid must have the shape"):
        plot_map(np.zeros((4, 4)), valid=np.ones((3, 3), bool))
    with pytest.raises(ValueError, match="limit"):
        plot_map(np.zeros((4, 4)), limit=-1.0)
    with pytest.raises(ValueError, match="shifts"):
        plot_shifts(np.zeros((4, 3)))


def test_shifts_plot_shows_the_series(rng, tmp_path):
    shifts = rng.normal(0, 0.01, (12, 2))
    fig = plot_shifts(shifts, title="reference")
    a, b = fig.axes
    assert_allclose(a.get_lines()[0].get_ydata(), shifts[:, 0])
    assert_allclose(b.get_lines()[0].get_ydata(), shifts[:, 1])
    assert_array_equal(a.get_lines()[0].get_xdata(), np.arange(12))  # frame index
    path = save_figure(fig, tmp_path / "v.png")
    img = iio.imread(path)
    assert img.shape[:2] == (480, 640)  # 6.4 x 4.8 in at 100 dpi
    assert [p.name for p in tmp_path.iterdir()] == ["v.png"]  # no temporary left
    with pytest.raises(FileExistsError):
        save_figure(fig, path)
    with pytest.raises(ValueError, match=r"must end in \.png"):
        save_figure(fig, tmp_path / "v.pdf")  # PNG bytes under a PDF's name: refused


def test_save_figures_count_and_names(tmp_path):
    ref = synthetic.grid_image((64, 64), LAT)
    states = [synthetic.grid_image((64, 64), LAT,
                                   displacement=lambda X, Y, s=s: (s * X, 0 * Y))
              for s in (1e-3, 2e-3)]
    res = measure_series(ref, states, lattice=LAT, guess=None)
    paths = save_figures(res, tmp_path / "figs", pixel_size=0.04, unit="mm")
    names = figure_names(2)
    assert len(paths) == len(names) == 2 * 5 + 3
    assert [p.name for p in paths] == names
    # the figures and the marker listing them, nothing else
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == sorted(
        [*names, MARKER_NAME])
    for p in paths:
        assert iio.imread(p).ndim == 3
    with pytest.raises(FileExistsError, match="overwrite"):
        save_figures(res, tmp_path / "figs")
    with pytest.raises(FileNotFoundError, match="parent"):
        save_figures(res, tmp_path / "no" / "figs")
    with pytest.raises(ValueError, match="unit"):
        save_figures(res, tmp_path / "f2", pixel_size=0.04)


@pytest.fixture(scope="module")
def sheared():
    """Two states of a 64 x 64 grid (the paper's model, eq. 1) under a uniform strain
    with shear: exx = 1.5e-3 s, eyy = -0.5e-3 s, exy = 0.4e-3 s (s = 1, 2)."""
    rng = np.random.default_rng(8)

    def frames(s):
        def disp(X, Y):
            x, y = X - 32, Y - 32
            return s * (1.5e-3 * x + 0.8e-3 * y), s * (-0.5e-3 * y)

        img = synthetic.grid_image((64, 64), LAT, amplitude=1500.0,
                                   displacement=disp) + 200.0
        return np.array([synthetic.add_noise(img, rng=rng) for _ in range(2)])

    return measure_series(frames(0.0), [frames(1.0), frames(2.0)], lattice=LAT)


def test_derived_strains_drawn_in_percent_and_degrees(sheared):
    from gridstrain.post import plot_history, plot_states

    res = sheared
    exx, eyy, exy = (np.asarray(a) for a in (res.exx, res.eyy, res.exy))
    # Mohr's circle, written here: the oracle of what the panels hold
    e1 = (exx + eyy) / 2 + np.sqrt(((exx - eyy) / 2) ** 2 + exy**2)
    angle = np.degrees(np.arctan2(exy, (exx - eyy) / 2) / 2)
    fig = plot_states(res, "e1", microstrain="%")
    # each panel: the reference image, then the map over it
    drawn = [ax.get_images()[1] for ax in fig.axes if len(ax.get_images()) == 2]
    assert len(drawn) == 2
    for k, im in enumerate(drawn):
        valid = ~np.ma.getmaskarray(im.get_array())
        # the same float64 numbers, scaled: rounding only (1e-16 of 0.3 %)
        assert_allclose(im.get_array().data[valid], 100 * e1[k][valid], rtol=1e-12)
    assert "(%)" in fig.axes[-1].get_ylabel()  # the colour bar
    fig = plot_states(res, "principal_angle")
    im = next(ax.get_images()[1] for ax in fig.axes if len(ax.get_images()) == 2)
    valid = ~np.ma.getmaskarray(im.get_array())
    assert_allclose(im.get_array().data[valid], angle[0][valid], rtol=1e-12)
    assert "(deg)" in fig.axes[-1].get_ylabel()
    # the history of a gauge's e1, in percent, with error bars of its std
    fig = plot_history(res, names=("e1",), microstrain="%")
    line = fig.axes[0].get_lines()[0]
    from gridstrain.post import gauge

    p = gauge(res).principal_strains()
    assert_allclose(line.get_ydata(), 100 * p.e1, rtol=1e-12)
    assert fig.axes[0].get_ylabel() == "strain (%)"
    # the truth, e1 of the applied tensor (1.58e-3 s), within 4 stated std (2.7e-4 on
    # the 530 valid pixels of two 2-frame 64 px states: e1 follows exx here)
    truth = np.array([1.0, 2.0]) * (0.5e-3 + np.hypot(1.0e-3, 0.4e-3))
    assert np.all(np.abs(p.e1 - truth) < 4 * p.e1_std)


def test_finite_strains_drawn_as_maps_and_histories(sheared):
    """The Green–Lagrange maps drawn are ``E = (H + H^T + H^T H) / 2`` of the stored
    gradient (written here), the history's curve the gauge's finite strain."""
    from gridstrain.post import gauge, plot_history, plot_states

    res = sheared
    exx, exy = np.asarray(res.exx), np.asarray(res.exy)
    w = np.stack([np.asarray(m.rotation) for m in res.measurements])
    gl_xx = exx + (exx**2 + (exy + w) ** 2) / 2
    fig = plot_states(res, "gl_xx")
    drawn = [ax.get_images()[1] for ax in fig.axes if len(ax.get_images()) == 2]
    for k, im in enumerate(drawn):
        valid = ~np.ma.getmaskarray(im.get_array())
        # µε of the same float64 numbers: rounding only
        assert_allclose(im.get_array().data[valid], 1e6 * gl_xx[k][valid], rtol=1e-12)
    assert "µε" in fig.axes[-1].get_ylabel()
    std = plot_states(res, "rotation_std")
    assert "mrad" in std.axes[-1].get_ylabel()
    fig = plot_history(res, names=("gl_xx", "log_xx"))
    f = gauge(res, finite=True).finite_strains()
    curves = [c.lines[0].get_ydata() for c in fig.axes[0].containers]  # the errorbars
    assert_allclose(curves[0], 1e6 * f.Exx, rtol=1e-12)
    assert_allclose(curves[1], 1e6 * f.Lxx, rtol=1e-12)
