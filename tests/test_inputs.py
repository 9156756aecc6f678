"""The inputs labs have: colour and JPEG frames, packed and compressed TIFFs, colour
masks, regions of interest, and a TOML configuration that replays a run."""

from __future__ import annotations

import tomllib

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
from numpy.testing import assert_allclose, assert_array_equal

from findings import said
from gridstrain.cli import main
from gridstrain.results import load, read_attrs
from gridstrain.series import measure_series

N = 96
P = 5.0  # grid pitch, px
E = 2e-3  # homogeneous strain along x of the loaded state
C = (N - 1) / 2


def _grid(strain=0.0, *, amp=1.0):
    """A cosine crossed grid of pitch P, stretched by ``strain`` along x, in [0, 1].

    Independent of gridstrain.models.synthetic: the loaded image at reference pixel x shows
    the pattern at x - u(x) with u = strain (x - C) (small strain, Lagrangian to
    first order), intensity 0.5 + 0.25 cos(2 pi x'/P) + 0.25 cos(2 pi y/P).
    """
    yy, xx = np.mgrid[0:N, 0:N].astype(float)
    xs = xx - strain * (xx - C)
    return 0.5 + 0.25 * amp * (np.cos(2 * np.pi * xs / P) + np.cos(2 * np.pi * yy / P))


def _u8(img, rng, noise=1.0):
    return np.clip(np.rint(20 + 200 * img + rng.normal(0, noise, img.shape)), 0, 255
                   ).astype(np.uint8)


def _same_maps(a, b, atol_strain):
    assert_array_equal(a.valid, b.valid)
    v = a.valid
    assert_allclose(a.strain[:, :, v[0]], b.strain[:, :, v[0]], rtol=0, atol=atol_strain)


def test_rgb_tiff_series_gives_the_maps_of_its_luminance(tmp_path):
    rng = np.random.default_rng(3)
    ref = [_u8(_grid(), rng) for _ in range(2)]
    cur = [_u8(_grid(E), rng) for _ in range(2)]
    for name, frames in (("ref", ref), ("cur", cur)):
        (tmp_path / name).mkdir()
        (tmp_path / f"{name}_grey").mkdir()
        for k, g in enumerate(frames):
            # a colour camera seeing a grey grid: R, G, B differ by gain and offset
            rgb = np.stack([g, np.clip(g * 0.9 + 12, 0, 255), g // 2], axis=-1
                           ).astype(np.uint8)
            tifffile.imwrite(tmp_path / name / f"f{k}.tif", rgb, photometric="rgb")
            tifffile.imwrite(tmp_path / f"{name}_grey" / f"f{k}.tif", g,
                             photometric="minisblack")
    colour = measure_series(tmp_path / "ref", tmp_path / "cur", lattice=None)
    assert any("colour frames (RGB)" in w for w in said(colour.warnings, "input"))

    def lum(frames):
        rgb = [np.stack([g, np.clip(g * 0.9 + 12, 0, 255).astype(np.uint8), g // 2],
                        axis=-1).astype(float) for g in frames]
        return np.array([0.2126 * c[..., 0] + 0.7152 * c[..., 1] + 0.0722 * c[..., 2]
                         for c in rgb])

    by_hand = measure_series(lum(ref), lum(cur))
    # the same floating-point numbers in both paths, up to the order of the sums
    _same_maps(colour, by_hand, atol_strain=1e-12)
    # grey frames R = G = B: the luminance is the grey level (the weights sum to 1)
    grey_rgb = tmp_path / "grey_rgb"
    grey_rgb.mkdir()
    for k, g in enumerate(cur):
        tifffile.imwrite(grey_rgb / f"f{k}.tif", np.stack([g] * 3, -1), photometric="rgb")
    a = measure_series(tmp_path / "ref_grey", grey_rgb)
    b = measure_series(tmp_path / "ref_grey", tmp_path / "cur_grey")
    _same_maps(a, b, atol_strain=1e-12)
    # and the strain is the one imposed: noise of ~1 grey level over 2 frames, T = 2
    assert float(np.mean(b.exx[0][b.valid[0]])) == pytest.approx(E, abs=1e-4)


def test_jpeg_pair(tmp_path):
    rng = np.random.default_rng(4)
    for name, strain in (("ref.jpg", 0.0), ("def.jpg", E)):
        g = _u8(_grid(strain), rng)
        iio.imwrite(tmp_path / name, np.stack([g, g, g], -1), quality=95)
    res = measure_series(tmp_path / "ref.jpg", tmp_path / "def.jpg")
    assert any("JPEG" in w for w in said(res.warnings, "input"))
    # oracle: the decoded JPEG pixels, made grey by hand
    decoded = [iio.imread(tmp_path / n).astype(float) @ [0.2126, 0.7152, 0.0722]
               for n in ("ref.jpg", "def.jpg")]
    _same_maps(res, measure_series(decoded[0], decoded[1]), atol_strain=1e-12)
    # JPEG's block noise at quality 95 leaves the mean strain within 1e-4 of E
    assert float(np.mean(res.exx[0][res.valid[0]])) == pytest.approx(E, abs=1e-4)


def test_packed_10_bit_and_lzw_tiffs_give_the_maps_of_plain_tiffs(tmp_path):
    rng = np.random.default_rng(5)
    frames = {n: np.clip(np.rint(100 + 800 * _grid(s) + rng.normal(0, 2, (N, N))), 0, 1023
                         ).astype(np.uint16) for n, s in (("ref", 0.0), ("def", E))}
    results = {}
    for kind, opts in (("plain", {}), ("packed", {"bitspersample": 10}),
                       ("lzw", {"compression": "lzw"})):
        paths = []
        for name, img in frames.items():
            p = tmp_path / f"{name}_{kind}.tif"
            tifffile.imwrite(p, img, photometric="minisblack", **opts)
            paths.append(p)
        results[kind] = measure_series(*paths)
    assert results["packed"].bit_depth == (10, 10)  # the file says it
    for kind in ("packed", "lzw"):
        # the same integers decoded: the same maps, bit for bit
        assert_array_equal(results[kind].strain, results["plain"].strain)


# --------------------------------------------------------------------------- the CLI


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    d = tmp_path_factory.mktemp("series")
    rng = np.random.default_rng(6)
    for name, s in (("ref", 0.0), ("def", E)):
        (d / name).mkdir()
        for k in range(2):
            img = np.rint(200 + 3000 * _grid(s) + rng.normal(0, 3, (N, N))).astype(np.uint16)
            tifffile.imwrite(d / name / f"f{k}.tif", img, photometric="minisblack")
    return d


def _measure(series, tmp_path, *extra):
    out = tmp_path / "m.h5"
    rc = main(["measure", str(series / "ref"), str(series / "def"), "-o", str(out),
               "--pitch", "5", "--quiet", *map(str, extra)])
    return rc, out


def test_rgba_mask_gives_the_maps_of_a_grey_mask(series, tmp_path):
    m = np.zeros((N, N), bool)
    m[10:86, 8:80] = True
    iio.imwrite(tmp_path / "grey.png", (m * 255).astype(np.uint8))
    rgba = np.zeros((N, N, 4), np.uint8)
    rgba[..., :3] = (255, 0, 0)  # red paint everywhere, the specimen opaque
    rgba[m, 3] = 255
    iio.imwrite(tmp_path / "rgba.png", rgba)
    maps = []
    for name in ("grey.png", "rgba.png"):
        d = tmp_path / name.split(".")[0]
        d.mkdir()
        rc, out = _measure(series, d, "--mask", tmp_path / name)
        assert rc == 0
        maps.append(load(out))
    assert_array_equal(maps[0].mask, maps[1].mask)
    assert_array_equal(maps[0].strain, maps[1].strain)
    assert not maps[0].valid[0][~m].any()


def test_rectangle_and_polygon_roi(series, tmp_path):
    rc, out = _measure(series, tmp_path, "--roi", 20, 10, 90, 80)
    assert rc == 0
    r = load(out)
    yy, xx = np.mgrid[0:N, 0:N]
    inside = (xx >= 20) & (xx < 90) & (yy >= 10) & (yy < 80)
    assert not r.valid[0][~inside].any()
    assert r.valid[0].sum() > 200  # the margin of 4 sigma leaves a core
    out.unlink()
    rc, out = _measure(series, tmp_path, "--roi-polygon", "0,0", "95,0", "0,95")
    assert rc == 0
    r = load(out)
    # the triangle x + y <= 95: nothing valid on the far side of its hypotenuse
    assert not r.valid[0][xx + yy > 96].any()
    assert r.valid[0].any()


@pytest.mark.parametrize(("extra", "message"), [
    (["--roi", "20", "10", "200", "80"], "inside the 96 x 96 px image"),
    (["--roi-polygon", "0,0", "10,10"], "at least 3 vertices"),
    (["--roi-polygon", "0,0", "10;10", "5,5"], "x,y pairs"),
    (["--export", "mat,xls"], "mat, vtk, csv"),
])
def test_bad_roi_and_export_are_one_line(series, tmp_path, capsys, extra, message):
    rc, out = _measure(series, tmp_path, *extra)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1
    assert message in err[0]
    assert not out.exists()


def test_config_holds_inputs_and_the_result_replays_the_run(series, tmp_path, capsys):
    cfg = tmp_path / "run.toml"
    cfg.write_text(f'reference = "{series / "ref"}"\nstates = ["{series / "def"}"]\n'
                   'output = "first.h5"\npitch = 5\nsigma = 6.0\nroi = [5, 5, 90, 90]\n'
                   'roi-polygon = [[0, 0], [95, 0], [95, 95], [0, 95]]\n'
                   'export = ["mat", "vtk", "csv"]\nreport = "first.html"\nquiet = true\n')
    assert main(["measure", "--config", str(cfg)]) == 0, capsys.readouterr().err
    first = tmp_path / "first.h5"
    for ext in (".mat", ".pvd", ".csv", ".html"):
        assert first.with_suffix(ext).is_file()
    stored = tomllib.loads(read_attrs(first)["config"])
    assert stored["reference"] == str(series / "ref")
    assert stored["states"] == [str(series / "def")]
    assert stored["sigma"] == 6.0
    assert stored["roi"] == [5, 5, 90, 90]
    assert "quiet" not in stored  # how to run, not what to measure
    assert "report" not in stored  # a replay does not write over the first report
    # replay from the result file itself, into another output
    again = tmp_path / "again.h5"
    assert main(["measure", "--config", str(first), "-o", str(again), "--quiet",
                 "--export", "csv"]) == 0, capsys.readouterr().err
    assert again.with_suffix(".csv").is_file()
    assert not again.with_suffix(".mat").exists()  # the command line wins
    a, b = load(first), load(again)
    assert_array_equal(a.strain, b.strain)
    assert_array_equal(a.valid, b.valid)
    assert a.sigma == b.sigma == 6.0


def test_inputs_missing_is_one_line(tmp_path, capsys):
    (tmp_path / "c.toml").write_text('output = "x.h5"\n')
    assert main(["measure", "--config", str(tmp_path / "c.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "inputs are missing" in err[0]
