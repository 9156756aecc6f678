"""Result files (xarray, exact reload), exports, the HTML report and the plot command."""

from __future__ import annotations

import base64
import dataclasses
import math
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass

import h5py
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

import gridstrain
from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.models import synthetic
from gridstrain.results import (
    MAP_FIELDS,
    SeriesResult,
    export_mat,
    export_vtk,
    load,
    read_attrs,
    save_csv,
    save_result,
)
from gridstrain.results._file import _nan_equal
from gridstrain.series import measure_series

LAT = Lattice.from_pitch(5.0)
N = 96
E0 = 1.5e-3  # homogeneous strain of the loaded states


def _frames(T, strain, rng, shift=(0.0, 0.0)):
    """(T, N, N) 12-bit frames of a grid stretched by ``strain`` along x, plus noise."""
    def disp(X, Y):
        return strain * (X - N / 2) + shift[0], 0.0 * Y + shift[1]

    img = synthetic.grid_image((N, N), LAT, amplitude=1500.0, displacement=disp) + 200.0
    return np.array([synthetic.add_noise(img, rng=rng) for _ in range(T)])


@pytest.fixture(scope="module")
def result():
    rng = np.random.default_rng(1402)
    ref = _frames(3, 0.0, rng)
    states = [_frames(3, E0, rng, (0.4, -0.2)), _frames(3, 2 * E0, rng, (0.8, -0.3))]
    return measure_series(ref, states, lattice=LAT)


# --------------------------------------------------------------------------- the file


def test_xarray_opens_the_file_with_dimensions_coordinates_and_units(result, tmp_path):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    path = save_result(result, tmp_path / "r.h5", pixel_size=0.04, unit="mm",
                       lossless=True)
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        assert ds["exx"].dims == ("state", "y", "x")
        assert list(ds["state"].values) == ["state 0", "state 1"]
        assert_array_equal(ds["x"].values, np.arange(N))
        assert ds["x"].attrs["units"] == "px"
        assert_allclose(ds["x_phys"].values, 0.04 * np.arange(N), rtol=1e-15)
        assert ds["x_phys"].attrs["units"] == "mm"
        assert "x_phys" in ds["exx"].coords  # physical coordinates ride along
        for name, var in ds.data_vars.items():
            assert "units" in var.attrs or var.dtype == bool, name
            assert var.attrs.get("long_name"), name
        assert ds["exx"].attrs["units"] == "1"
        assert ds["ux_phys"].attrs["units"] == "mm"
        assert ds["rotation"].attrs["units"] == "rad"
        assert ds["valid"].dtype == bool
        assert_array_equal(ds["exx"].values, result.exx)
        assert ds["vibration_shifts"].dims == ("series", "frame", "axis")
        assert ds["noise_theory_strain"].dims == ("state", "strain_component")
        assert_allclose(ds["lattice_k"].values, [LAT.k1, LAT.k2], rtol=1e-15)
        assert ds.attrs["method"] == "A"
        assert list(ds.attrs["pitches"]) == list(result.lattice.pitches)
        # the selection a user makes: the mean strain of state 1, in one line
        s1 = ds.sel(state="state 1")
        mean = float(s1["exx"].where(s1["valid"]).mean())
    v = result.valid[1]
    assert mean == pytest.approx(float(np.mean(result.exx[1][v])), rel=1e-12)


def test_load_returns_the_saved_result(result, tmp_path):
    path = save_result(result, tmp_path / "r.h5", phase_maps=True, lossless=True)
    back = load(path)
    assert isinstance(back, SeriesResult)
    for f in dataclasses.fields(SeriesResult):
        assert _nan_equal(getattr(back, f.name), getattr(result, f.name)), f.name
    assert _nan_equal(back, result)
    # one reference PhaseMaps shared by every state, as measure_series makes it
    assert back.measurements[0].reference is back.measurements[1].reference
    assert not back.u.flags.writeable  # frozen like the original
    # the comparison is not vacuous: one changed number is seen
    changed = dataclasses.replace(result, sigma=result.sigma + 1e-9)
    assert not _nan_equal(back, changed)
    # and a result without uncertainty maps keeps its None
    bare = dataclasses.replace(result, uncertainty=None, warnings=("a", "b"))
    assert _nan_equal(load(save_result(bare, tmp_path / "b.h5", phase_maps=True,
                                             lossless=True)), bare)
    # by default the phase maps (8 maps per series) are left out, and only they
    small = load(save_result(result, tmp_path / "s.h5", lossless=True))
    assert (tmp_path / "s.h5").stat().st_size < 0.6 * path.stat().st_size
    for m in small.measurements:
        assert m.reference is None
        assert m.deformed is None
    without = dataclasses.replace(result, measurements=tuple(
        dataclasses.replace(m, reference=None, deformed=None) for m in result.measurements))
    assert _nan_equal(small, without)


@dataclass(frozen=True, eq=False)
class _Later(SeriesResult):
    """A result class with the kinds of fields a later version may add."""

    records: tuple = ()
    extra: dict | None = None


def test_new_fields_are_saved_without_changing_the_file_code(result, tmp_path):
    later = _Later(**{f.name: getattr(result, f.name) for f in dataclasses.fields(result)},
                   records=(LAT, None, (1, 2.5), np.arange(3.0)),
                   extra={"order": [3, 1, 2], "map": np.ones((2, 2)), "none": None,
                          "names": ("a", "b"), "nested": {"deep": math.nan}})
    back = load(save_result(later, tmp_path / "l.h5", phase_maps=True, lossless=True))
    assert type(back) is _Later
    assert _nan_equal(back, later)


def test_load_refuses_what_is_not_a_result(tmp_path):
    (tmp_path / "t.h5").write_text("not HDF5")
    with pytest.raises(ValueError, match=r"t\.h5 is not a gridstrain result file"):
        load(tmp_path / "t.h5")
    with h5py.File(tmp_path / "other.h5", "w") as h5:
        h5["x"] = np.zeros(3)
    with pytest.raises(ValueError, match="no 'gridstrain' group"):
        load(tmp_path / "other.h5")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load(tmp_path / "none.h5")


def test_attributes_are_native_not_json(result, tmp_path):
    path = save_result(result, tmp_path / "r.h5", attrs={"config": "pitch = 5\n",
                                                         "options": {"a": [1, 2]}})
    with h5py.File(path, "r") as h5:
        assert h5.attrs["k1"].dtype == np.float64
        assert h5.attrs["sigma"] == result.sigma
        assert "_json_attrs" not in h5.attrs
        noise = h5["gridstrain/result/noise"]
        assert noise["theory_strain"].shape == (2, 3)
    a = read_attrs(path)
    assert a["config"] == "pitch = 5\n"
    assert a["options"] == {"a": [1, 2]}


# --------------------------------------------------------------------------- exports


def test_mat_export(result, tmp_path):
    from scipy.io import loadmat

    path = export_mat(result, tmp_path / "r.mat", pixel_size=0.02, unit="mm")
    m = loadmat(path)
    assert m["exx"].shape == (N, N, 2)  # (H, W, state): exx(:, :, k) in MATLAB
    assert_array_equal(m["exx"][..., 1], result.exx[1])
    assert_array_equal(m["valid"][..., 0].astype(bool), result.valid[0])
    assert_allclose(m["ux_phys"][..., 0], result.ux[0] * 0.02, rtol=1e-15)
    assert [str(s[0]) for s in m["states"].ravel()] == ["state 0", "state 1"]
    assert str(m["units"]["exx"][0, 0][0]) == "1"
    assert str(m["units"]["ux_phys"][0, 0][0]) == "mm"


def _vti_arrays(path) -> tuple[dict, ET.Element]:
    """Decode a .vti written with zlib-compressed binary arrays (VTK XML format)."""
    root = ET.parse(path).getroot()
    out = {}
    for da in root.iter("DataArray"):
        text = da.text.strip()
        header = base64.b64decode(text[:44])  # 4 UInt64 = 32 bytes = 44 base64 chars
        nblocks, _, _, csize = np.frombuffer(header, "<u8")
        assert nblocks == 1
        comp = base64.b64decode(text[44:])
        assert len(comp) == csize
        raw = zlib.decompress(comp)
        dtype = {"Float64": "<f8", "Float32": "<f4", "UInt8": "u1"}[da.get("type")]
        out[da.get("Name")] = np.frombuffer(raw, dtype).reshape(
            -1, int(da.get("NumberOfComponents", 1))).squeeze()
    return out, root


def test_vtk_export_is_a_paraview_time_series(result, tmp_path):
    path = export_vtk(result, tmp_path / "r.pvd", pixel_size=0.02, unit="mm")
    assert path.name == "r.pvd"
    coll = ET.parse(path).getroot()
    steps = list(coll.iter("DataSet"))
    # one time step per state (no loads or times stored: their index)
    assert [float(d.get("timestep")) for d in steps] == list(range(result.n_states))
    files = [path.parent / d.get("file") for d in steps]
    assert all(f.is_file() for f in files)
    arrays, root = _vti_arrays(files[1])
    image = root.find("ImageData")
    assert image.get("WholeExtent") == f"0 {N - 1} 0 {N - 1} 0 0"
    assert image.get("Spacing").split()[:2] == ["0.02", "0.02"]
    # upright in ParaView: points run x fastest from the bottom row (y = N - 1) up to
    # row 0 at Y = 0, i.e. Y = -y * pixel size
    assert [float(v) for v in image.get("Origin").split()] == [0.0, -(N - 1) * 0.02, 0.0]
    assert image.find("Piece/PointData").get("Vectors") == "displacement [mm]"
    disp = arrays["displacement [mm]"].reshape(N, N, 3)[::-1]  # back to [y, x]
    assert_allclose(disp[..., 0], result.ux[1] * 0.02, rtol=1e-6)  # float32
    assert_allclose(disp[..., 1], -result.uy[1] * 0.02, rtol=1e-6)  # Y = -y
    assert_allclose(arrays["exx [-]"].reshape(N, N)[::-1], result.exx[1], rtol=1e-6)
    assert_allclose(arrays["exy [-]"].reshape(N, N)[::-1], -result.exy[1], rtol=1e-6)
    assert_array_equal(arrays["valid"].reshape(N, N)[::-1], result.valid[1])
    # the times become the time values
    from gridstrain.results import export_pvd

    p2 = export_pvd(result, tmp_path / "t.pvd", time=[0.5, 1.5])
    assert [float(d.get("timestep")) for d in ET.parse(p2).getroot().iter("DataSet")] == \
        [0.5, 1.5]


def test_vtk_export_in_vtk_reader(result, tmp_path):
    """Kitware's own XML readers, those ParaView uses (when vtk is installed)."""
    vtk = pytest.importorskip("vtkmodules.vtkIOXML")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    path = export_vtk(result, tmp_path / "r.pvd", pixel_size=0.02, unit="mm")
    reader = vtk.vtkXMLImageDataReader()
    reader.SetFileName(str(tmp_path / "r_vti" / "state_00001.vti"))
    reader.Update()
    img = reader.GetOutput()
    assert img.GetDimensions() == (N, N, 1)
    assert_allclose(img.GetSpacing()[:2], (0.02, 0.02))
    assert_allclose(img.GetOrigin()[:2], (0.0, -(N - 1) * 0.02))
    got = vtk_to_numpy(img.GetPointData().GetArray("exx [-]"))
    assert_allclose(got.reshape(N, N)[::-1], result.exx[1], rtol=1e-6)
    vec = img.GetPointData().GetVectors()
    assert vec.GetName() == "displacement [mm]"
    assert vec.GetNumberOfComponents() == 3
    assert path.is_file()


def test_csv_export_units_in_header_and_values(result, tmp_path):
    pd = pytest.importorskip("pandas")
    path = save_csv(result, tmp_path / "r.csv", pixel_size=0.02, unit="mm")
    df = pd.read_csv(path)
    assert list(df.columns[:10]) == ["state", "x [px]", "y [px]", "x [mm]", "y [mm]",
                                     "ux [px]", "ux [mm]", "uy [px]", "uy [mm]", "exx [-]"]
    assert "exx_std [-]" in df.columns
    assert len(df) == int(result.valid.sum())
    assert set(df["state"]) == set(result.names[1:])  # the states' names
    s1 = df[df["state"] == result.names[2]]
    x, y = s1["x [px]"].to_numpy(), s1["y [px]"].to_numpy()
    # 7 significant digits: half a unit of the 7th digit is at most 5e-7 relative,
    # 2e-9 on these 4e-3 strains and 1e-7 px on sub-pixel displacements, far below
    # any noise floor (1e-5 strain, 1e-3 px)
    assert_allclose(s1["exx [-]"], result.exx[1][y, x], rtol=5e-7, atol=0)
    assert_allclose(s1["ux [mm]"], result.ux[1][y, x] * 0.02, rtol=5e-7, atol=0)
    assert_allclose(s1["x [mm]"], x * 0.02, rtol=5e-7)
    # and much smaller than the shortest round-trip decimals of every float64
    full = save_csv(result, tmp_path / "full.csv", pixel_size=0.02, unit="mm", digits=None)
    assert path.stat().st_size < 0.7 * full.stat().st_size


# --------------------------------------------------------------------------- report


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def test_report_is_self_contained(result, tmp_path):
    path = save_result(result, tmp_path / "r.h5", pixel_size=0.02, unit="mm",
                       attrs={"config": 'method = "A"\n'})
    assert main(["report", str(path), "-o", str(tmp_path / "r.html")]) == 0
    text = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "<script" not in text
    assert not re.search(r"(src|href)=\"(https?:|//)", text)  # nothing fetched
    images = re.findall(r'<img class="figure" alt="([^"]+)" src="data:image/png;base64,',
                        text)
    for name in ("map of exx", "map of ux", "map of rotation", "uncertainty map of exx_std",
                 "vibrations of reference"):
        assert name in images
    assert "µε" in text
    assert 'method = "A"' in text  # the stored configuration


def _browse(page, profile, *extra):
    """Chromium's run on ``page`` (headless, offline, a fresh profile)."""
    return subprocess.run(
        [_chromium(), "--headless", "--no-sandbox", "--disable-gpu",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--no-first-run", f"--user-data-dir={profile}", *extra, page.as_uri()],
        capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.skipif(_chromium() is None, reason="headless Chromium is not installed")
# slow: a demo run and a browser; the page's content is checked in the default run by
# test_report_is_self_contained and test_report_escapes_everything_read_from_the_file
@pytest.mark.slow
def test_report_renders_in_headless_chromium(tmp_path):
    """The demo's report, as a browser shows it: no console error, the maps drawn."""
    demo = tmp_path / "demo"
    assert main(["demo", "--out", str(demo), "--size", "128", "--steps", "3",
                 "--quiet"]) == 0
    page = demo / "report.html"
    shot = tmp_path / "shot.png"
    proc = _browse(page, tmp_path / "profile", "--enable-logging=stderr", "--v=0",
                   "--window-size=1200,4000", f"--screenshot={shot}", "--dump-dom")
    assert proc.returncode == 0, proc.stderr[-2000:]
    console = [line for line in proc.stderr.splitlines()
               if "CONSOLE" in line or "Uncaught" in line]
    assert console == []
    dom = proc.stdout
    assert dom.count('<img class="figure"') >= 8  # the test's two, five maps, rotation
    assert "map of exx" in dom
    proc = _browse(page, tmp_path / "profile", "--window-size=1200,4000",
                   f"--screenshot={shot}")
    import imageio.v3 as iio

    img = iio.imread(shot)
    assert img.shape[:2] == (4000, 1200)
    # the maps are drawn: many pixels far from grey (the diverging colormap's reds and
    # blues, viridis' greens), not a blank page
    rgb = img[..., :3].astype(float)
    colourful = (rgb.max(axis=-1) - rgb.min(axis=-1)) > 80
    assert colourful.mean() > 0.01


# Markup that runs script wherever it reaches a page unescaped: as an element, as an
# attribute (the quotes close alt="..."), in a <pre>
_PAYLOAD = ("\"'><script>document.documentElement.setAttribute('data-pwned','s')</script>"
            "<img src=x onerror=\"document.documentElement.setAttribute('data-pwned','i')\">")
_STRUCTURE = {"_type", "_class", "_keys", "_tuple_attrs", "_list_attrs", "format_version",
              "_n", "_rows", "_none", "_const", "kind"}
# Strings the result classes check against their allowed values (a payload there is
# refused by load, tested below with the numeric fields)
_CHOICES = {"method", "source", "unit"}


def _poison_strings(h5) -> int:
    """Every text attribute of a result file (names, files, warnings, parameters,
    sources, the configuration, the provenance...) with the payload appended."""
    count = 0

    def poison(obj):
        nonlocal count
        for key in list(obj.attrs):
            v = obj.attrs[key]
            if key in _STRUCTURE or key in _CHOICES:
                continue
            if isinstance(v, str):
                obj.attrs[key] = v + _PAYLOAD
                count += 1
            elif isinstance(v, np.ndarray) and v.dtype.kind == "O":
                obj.attrs[key] = np.array([x + _PAYLOAD for x in v],
                                          dtype=h5py.string_dtype())
                count += 1

    poison(h5)
    h5["gridstrain"].visititems(lambda _name, obj: poison(obj))
    return count


def test_report_escapes_everything_read_from_the_file(result, tmp_path, capsys):
    """A result file crafted with markup in every string renders as text; the fields
    that must be numbers (method, frames, bit depth, iterations, pixel size) are
    refused in one line, before any HTML is written."""
    path = save_result(result, tmp_path / "r.h5", pixel_size=0.02, unit="mm",
                       attrs={"config": 'method = "A"\n', "created": "today"})
    with h5py.File(path, "a") as h5:
        assert _poison_strings(h5) > 20
    page = tmp_path / "r.html"
    assert main(["report", str(path), "-o", str(page)]) == 0, capsys.readouterr().err
    text = page.read_text(encoding="utf-8")
    assert "<script" not in text
    assert re.findall(r"<img (?!class=\"figure\")", text) == []
    assert "<img src=x" not in text
    # the payload is there, as text, in the names, the files and the configuration
    assert text.count("&lt;script&gt;") > 10
    assert "vibrations of state 0&#34;&#39;&gt;&lt;script&gt;" in text  # in an alt
    for field, value in (("gridstrain/result", ("method", _PAYLOAD)),
                         ("gridstrain/result", ("n_frames", _PAYLOAD)),
                         ("gridstrain/result", ("bit_depth", [_PAYLOAD] * 3)),
                         ("gridstrain/result/measurements",  # a column, one per state
                          ("iterations", [_PAYLOAD] * 2)),
                         ("/", ("pixel_size", _PAYLOAD)), ("/", ("unit", _PAYLOAD))):
        bad = tmp_path / f"bad_{value[0]}.h5"
        shutil.copy(path, bad)
        with h5py.File(bad, "a") as h5:
            if value[0] in h5[field]:  # a tuple holding None is a group
                del h5[field][value[0]]
            h5[field].attrs[value[0]] = value[1]
        out = bad.with_suffix(".html")
        assert main(["report", str(bad), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert str(bad) in err[0]
        assert value[0] in err[0]
        assert not out.exists()
    if _chromium() is None:
        pytest.skip("headless Chromium is not installed")
    # no script runs, even without the page's own policy forbidding scripts
    bare = tmp_path / "bare.html"
    bare.write_text(re.sub(r"<meta http-equiv=\"Content-Security-Policy\"[^>]*>", "", text),
                    encoding="utf-8")
    assert "Content-Security-Policy" not in bare.read_text(encoding="utf-8")
    control = tmp_path / "control.html"
    control.write_text(f"<!DOCTYPE html><html><body><p>{_PAYLOAD}</p></body></html>")
    for page_, pwned in ((bare, False), (page, False), (control, True)):
        proc = _browse(page_, tmp_path / "profile", "--dump-dom",
                       "--virtual-time-budget=2000")
        assert proc.returncode == 0, proc.stderr[-2000:]
        dom = proc.stdout
        assert ("data-pwned" in dom.split(">", 2)[1]) is pwned, dom[:300]


# --------------------------------------------------------------------------- plot command


def test_plot_command(result, tmp_path, capsys):
    path = save_result(result, tmp_path / "r.h5", pixel_size=0.02, unit="mm")
    out = tmp_path / "figs"
    # the point in the file's unit, as gauge's: the pixel (48, 48) at 0.02 mm
    assert main(["plot", str(path), "-o", str(out), "--limits", "robust", "--dpi", "60",
                 "--point", "0.96", "0.96"]) == 0
    names = sorted(p.name for p in out.glob("*.png"))
    assert names == sorted(["ux.png", "uy.png", "exx.png", "eyy.png", "exy.png",
                            "rotation.png", "history.png"])
    assert main(["plot", str(path), "-o", str(out)]) == 2  # no silent overwrite
    assert "earlier gridstrain run" in capsys.readouterr().err
    # the derived strains, in percent
    out = tmp_path / "derived"
    assert main(["plot", str(path), "-o", str(out), "--maps", "e1,principal_angle,e1_std",
                 "--strain-units", "%", "--dpi", "40"]) == 0
    assert sorted(p.name for p in out.glob("*.png")) == [
        "e1.png", "e1_std.png", "history.png", "principal_angle.png"]


def test_common_limits_span_every_state(result):
    from gridstrain.post._plotting import quantity, state_norm

    fig = result.plot("exx")
    maps = [ax.get_images()[1] for ax in fig.axes[:2]]
    assert maps[0].norm is maps[1].norm  # one norm for all states
    values, unit = quantity(result, "exx")
    assert unit == "µε"
    v = values[result.valid]
    # tension in both states: all positive, a linear norm over the whole range
    norm, diverging = state_norm(values, result.valid, limits="common")
    assert not diverging
    assert (norm.vmin, norm.vmax) == (pytest.approx(v.min()), pytest.approx(v.max()))
    # the default, robust: the 0.5th and 99.5th percentiles of the same values
    norm, _ = state_norm(values, result.valid)
    lo, hi = np.percentile(v, [0.5, 99.5])
    assert (norm.vmin, norm.vmax) == (pytest.approx(lo), pytest.approx(hi))
    # a field of both signs keeps white at zero, on symmetric limits
    norm, diverging = state_norm(np.array([-1.0, 3.0]), np.array([True, True]),
                                 limits="common")
    assert diverging
    assert norm(0.0) == pytest.approx(0.5)
    assert norm(-3.0) == pytest.approx(0.0)


@pytest.mark.parametrize("argv", [["report", "NOTRESULT"], ["plot", "NOTRESULT"]])
def test_new_commands_refuse_a_file_that_is_not_a_result(argv, tmp_path, capsys):
    bad = tmp_path / "x.h5"
    bad.write_text("hello")
    argv = [str(bad) if a == "NOTRESULT" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "is not a gridstrain result file" in err[0]


# --------------------------------------------------------------------------- Python use


def test_top_level_names_and_xarray(result):
    pytest.importorskip("xarray")
    assert gridstrain.measure_series is measure_series
    assert gridstrain.load is load
    assert callable(gridstrain.method_a)
    assert callable(gridstrain.method_b)
    ds = result.to_xarray(pixel_size=0.5, unit="um")
    assert ds["ux_phys"].attrs["units"] == "um"
    assert_array_equal(ds["eyy"].values, result.eyy)
    for name in MAP_FIELDS:
        assert ds[name].dims == ("state", "y", "x")


def test_a_field_this_version_does_not_know_is_refused_by_name(result, tmp_path):
    path = save_result(result, tmp_path / "r.h5")
    with h5py.File(path, "a") as h5:
        h5["gridstrain/result/noise"].attrs["from_the_future"] = 1.0
    with pytest.raises(ValueError, match=r"fields from_the_future .* newer version"):
        load(path)


def test_measure_figures_share_one_norm_per_quantity(result, tmp_path, monkeypatch):
    from gridstrain.post import _plotting as plotting

    seen = []
    real = plotting.plot_map

    def spy(values, **kw):
        seen.append((kw["label"], kw["norm"], kw["unit"]))
        return real(values, **kw)

    monkeypatch.setattr(plotting, "plot_map", spy)
    plotting.save_figures(result, tmp_path / "figs")
    by_label = {}
    for label, norm, unit in seen:
        by_label.setdefault(label, set()).add((id(norm), unit))
    assert len(by_label) == 5
    assert all(len(v) == 1 for v in by_label.values())  # the same for both states
    # e_xx in µε, its norm covering the larger strain of state 1 (2 E0 against E0)
    ((_, unit),) = by_label[r"$\varepsilon_{xx}$"]
    assert unit == "µε"
    norm = next(n for label, n, _ in seen if label == r"$\varepsilon_{xx}$")
    assert norm.vmax > 1.5 * E0 * 1e6


def _stretched_pair(strain, size, rng):
    """Two noisy frames of a cross grid of :data:`LAT`, ``size`` px square, stretched
    by ``strain`` along x (mean 200 + 1500-grey-level grid, the synthetic noise)."""
    img = synthetic.grid_image((size, size), LAT, amplitude=1500.0,
                               displacement=lambda X, Y: (strain * X, 0.0 * Y)) + 200.0
    return np.array([synthetic.add_noise(img, rng=rng) for _ in range(2)])


def test_report_of_a_long_sequence_stays_one_readable_page(tmp_path):
    """Beyond 12 states: the maps of six states, histories and one row per state."""
    from matplotlib.figure import Figure

    from gridstrain.post._report import _figure, render_report

    rng = np.random.default_rng(29)
    n = 13
    size = 48

    def frames(strain):
        return _stretched_pair(strain, size, rng)

    res = measure_series(frames(0.0), [frames(1e-4 * (k + 1)) for k in range(n)],
                         lattice=LAT, order="independent", guess=(0.0, 0.0))
    text = render_report(res)
    assert f"6 of the {n} states" in text
    assert text.count('alt="map of ') == 6  # one figure per map, six states in each
    assert 'alt="strain of the states"' in text
    assert 'alt="displacement of the states"' in text
    # one table with a row per state (its means and noise floor together), one
    # with a row per image series
    tables = re.findall(r"<table>(.*?)</table>", text, flags=re.S)
    (states,) = [t for t in tables if "mean ε_xx" in t]
    assert "noise ε_xx" in states
    assert states.count("<tr>") == n + 1
    (series,) = [t for t in tables if "sensor variance" in t]
    assert series.count("<tr>") == n + 2
    # the reference's and the six shown states' shifts, not one figure per series
    assert text.count('alt="vibrations of ') == 7
    # a tall figure is drawn no taller than 4000 px
    fig = Figure(figsize=(4.0, 100.0))
    fig.add_subplot().plot([0, 1])
    png = base64.b64decode(_figure(fig, "tall")["png"])
    assert int.from_bytes(png[20:24], "big") <= 4000


def test_report_of_a_long_loaded_sequence_titles_each_state_with_its_own_load(
        tmp_path, monkeypatch):
    """Beyond 12 states with loads and times (a machine's log): each drawn state's
    panel carries its own load and time, the maps' title says which of all the
    states are shown, and the histories keep their time axis (no state-index ticks
    laid over seconds)."""
    import dataclasses

    from gridstrain.post import _report

    rng = np.random.default_rng(31)
    n, size = 15, 48

    def frames(strain):
        return _stretched_pair(strain, size, rng)

    res = measure_series(frames(0.0), [frames(1e-4 * (k + 1)) for k in range(n)],
                         lattice=LAT, order="independent", guess=(0.0, 0.0))
    load = 0.25 * np.arange(1, n + 1)  # kN
    time = 2.0 * np.arange(1, n + 1)  # s
    res = dataclasses.replace(res, load=load, load_unit="kN", time=time)
    drawn = []
    figure = _report._figure
    monkeypatch.setattr(_report, "_figure",
                        lambda fig, alt, *a: drawn.append((alt, fig)) or figure(fig, alt, *a))
    text = _report.render_report(res)
    assert f"6 of the {n} states" in text
    (exx,) = [fig for alt, fig in drawn if alt == "map of exx"]
    shown = _report._shown_states(n)
    titles = [ax.get_title() for ax in exx.axes if ax.get_title()]
    assert len(titles) == len(shown)
    for i, title in zip(shown, titles, strict=True):
        assert f"t = {time[i]:.4g} s" in title
        assert f"{load[i]:.4g} kN" in title
    assert f"6 of {n} states shown" in exx.get_suptitle()
    (history,) = [fig for alt, fig in drawn if alt == "strain of the states"]
    ax = history.axes[0]
    assert ax.get_xlabel() == "time (s)"
    lo, hi = ax.get_xlim()
    # the seconds drawn, not state indices
    assert lo < time[0]
    assert time[-1] < hi
