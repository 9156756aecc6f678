"""``gridstrain export`` of an existing result: MATLAB, CSV, ParaView and NetCDF read
back by scipy, pandas, an XML parser and xarray equal the result's arrays, with the load
and time of every state and the derived strains."""

from __future__ import annotations

import base64
import dataclasses
import xml.etree.ElementTree as ET
import zlib

import h5py
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from gridstrain import Lattice, measure_series
from gridstrain.cli import main
from gridstrain.models import synthetic
from gridstrain.results import export_netcdf, load, save_result

LAT = Lattice.from_pitch(5.0)
N = 64
# names as other people's folders hold them: a comma, quotes, a line break, a control
# character, non-ASCII text and a formula-looking cell
NAMES = ("reference", 'step 1, "pre-load"', "step\n2 µε =1+1\x01")
LOADS = np.array([1.25, 2.5])  # kN
TIMES = np.array([0.5, 1.75])  # s


def _frames(strain, rng):
    """(2, N, N) 12-bit frames of the paper's grid model (eq. 1), stretched by ``strain``
    along x and ``strain / 3`` along y about the centre, with sensor noise."""
    def disp(X, Y):
        return strain * (X - N / 2), strain / 3 * (Y - N / 2)

    img = synthetic.grid_image((N, N), LAT, amplitude=1500.0, displacement=disp) + 200.0
    return np.array([synthetic.add_noise(img, rng=rng) for _ in range(2)])


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    rng = np.random.default_rng(41)
    res = measure_series(_frames(0.0, rng), [_frames(1e-3, rng), _frames(2e-3, rng)],
                         lattice=LAT)
    res = dataclasses.replace(res, names=NAMES, load=LOADS, load_unit="kN", time=TIMES)
    # lossless: the exports are compared with the stored values to the last bit
    path = save_result(res, tmp_path_factory.mktemp("export") / "r.h5", pixel_size=0.02,
                       unit="mm", lossless=True)
    return load(path), path


def _principal(exx, eyy, exy):
    """The closed form of Mohr's circle, written again here as the oracle."""
    c, r = (exx + eyy) / 2, np.sqrt(((exx - eyy) / 2) ** 2 + exy**2)
    return c + r, c - r


def test_export_writes_every_format_with_loads_times_and_derived_strains(stored, tmp_path,
                                                                         capsys):
    res, path = stored
    prefix = tmp_path / "out" / "test 1"
    prefix.parent.mkdir()
    assert main(["export", str(path), "--to", "mat,csv,vtk,netcdf", "-o", str(prefix)]) == 0
    printed = capsys.readouterr().out.split("\n")
    assert printed[:4] == [f"{prefix}.mat", f"{prefix}.csv", f"{prefix}.pvd", f"{prefix}.nc"]
    e1, e2 = _principal(np.asarray(res.exx), np.asarray(res.eyy), np.asarray(res.exy))

    from scipy.io import loadmat

    m = loadmat(f"{prefix}.mat")
    assert_array_equal(m["exx"], np.moveaxis(np.asarray(res.exx), 0, -1))  # exact
    assert_array_equal(m["load"].ravel(), LOADS)
    assert_array_equal(m["time"].ravel(), TIMES)
    assert str(m["units"]["load"][0, 0][0]) == "kN"
    assert [str(s[0]) for s in m["states"].ravel()] == list(NAMES[1:])
    # the same closed form on the same float64 numbers: 1e-18, rounding only
    assert_allclose(m["e1"], np.moveaxis(e1, 0, -1), rtol=0, atol=1e-15)
    assert_allclose(m["e2"], np.moveaxis(e2, 0, -1), rtol=0, atol=1e-15)
    assert m["e1_std"].shape == (N, N, 2)

    pd = pytest.importorskip("pandas")
    df = pd.read_csv(f"{prefix}.csv", keep_default_na=False)
    assert list(df.columns[:5]) == ["state", "load [kN]", "time [s]", "x [px]", "y [px]"]
    assert len(df) == int(np.asarray(res.valid).sum())
    for k, name in enumerate(NAMES[1:]):
        rows = df[df["state"] == name]
        assert len(rows) == int(np.asarray(res.valid[k]).sum())  # the name read back whole
        assert set(rows["load [kN]"]) == {LOADS[k]}
        assert set(rows["time [s]"]) == {TIMES[k]}
        x, y = rows["x [px]"].to_numpy(), rows["y [px]"].to_numpy()
        # 7 significant digits: 5e-7 relative (5e-10 on these 1e-3 strains)
        assert_allclose(rows["exx [-]"], res.exx[k][y, x], rtol=5e-7, atol=0)
        assert_allclose(rows["e1 [-]"], e1[k][y, x], rtol=5e-7, atol=0)
        assert_allclose(rows["ux [mm]"], res.ux[k][y, x] * 0.02, rtol=5e-7, atol=0)

    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    with xr.open_dataset(f"{prefix}.nc") as ds:
        assert_array_equal(ds["exx"].values, np.asarray(res.exx))
        assert_array_equal(ds["load"].values, LOADS)
        assert ds["load"].attrs["units"] == "kN"
        assert_array_equal(ds["time"].values, TIMES)
        assert list(ds["state"].values) == list(NAMES[1:])
        assert_allclose(ds["e1"].values, e1, rtol=0, atol=1e-15)
        assert ds["principal_angle"].attrs["units"] == "rad"
        assert ds["exx"].attrs["units"] == "1"
        assert_allclose(ds["ux_phys"].values, np.asarray(res.ux) * 0.02, rtol=1e-15)
    with h5py.File(f"{prefix}.nc", "r") as h5:
        assert "gridstrain" not in h5  # the clean copy: no result-object group


def _field_data(path):
    root = ET.parse(path).getroot()
    fd = root.find("ImageData/FieldData")
    return {d.get("Name"): float(d.text) for d in fd.iter("DataArray")}, root


def _point_array(root, name):
    for da in root.iter("DataArray"):
        if da.get("Name") == name:
            text = da.text.strip()
            raw = zlib.decompress(base64.b64decode(text[44:]))  # after the 32-byte header
            return np.frombuffer(raw, "<f4").reshape(N, N)[::-1]  # bottom row first
    raise KeyError(name)


def test_paraview_states_carry_their_time_load_and_derived_strains(stored, tmp_path):
    res, path = stored
    assert main(["export", str(path), "--to", "vtk", "-o", str(tmp_path / "p")]) == 0
    steps = list(ET.parse(tmp_path / "p.pvd").getroot().iter("DataSet"))
    assert [float(d.get("timestep")) for d in steps] == list(TIMES)
    e1 = _principal(np.asarray(res.exx), np.asarray(res.eyy), np.asarray(res.exy))[0]
    for k, d in enumerate(steps):
        values, root = _field_data(tmp_path / d.get("file"))
        assert values == {"time [s]": TIMES[k], "load [kN]": LOADS[k]}
        # float32 for viewing: 6e-8 relative
        assert_allclose(_point_array(root, "e1 [-]"), e1[k], rtol=2e-7, atol=1e-12)
        # the name in the file's comment, its control character (which XML cannot
        # hold, and which the parser above would refuse) replaced, the rest kept
        text = (tmp_path / d.get("file")).read_text(encoding="utf-8")
        assert f"state: {NAMES[k + 1]}".replace("\x01", "\ufffd") in text


def test_export_refuses_in_one_line(stored, tmp_path, capsys):
    path = stored[1]
    prefix = tmp_path / "q"
    assert main(["export", str(path), "--to", "mat,xls", "-o", str(prefix)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "--to must list formats among mat, vtk, csv, netcdf" in err
    assert main(["export", str(path), "--to", "csv", "-o", str(prefix)]) == 0
    before = (tmp_path / "q.csv").read_bytes()
    capsys.readouterr()
    # an existing file is not replaced without --overwrite, and nothing else is written
    assert main(["export", str(path), "--to", "mat,csv", "-o", str(prefix)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "q.csv" in err
    assert not (tmp_path / "q.mat").exists()
    assert (tmp_path / "q.csv").read_bytes() == before
    # the result file itself (a .nc result exported to netcdf next to it)
    nc = tmp_path / "r.nc"
    nc.write_bytes(path.read_bytes())
    assert main(["export", str(nc), "--to", "netcdf"]) == 2
    assert "is the result file itself" in capsys.readouterr().err


def test_paraview_reads_the_time_load_and_derived_strains(stored, tmp_path):
    """Kitware's XML reader, the one ParaView uses (the ``vtk`` test extra)."""
    vtk = pytest.importorskip("vtkmodules.vtkIOXML")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    res, path = stored
    assert main(["export", str(path), "--to", "vtk", "-o", str(tmp_path / "v")]) == 0
    reader = vtk.vtkXMLImageDataReader()
    reader.SetFileName(str(tmp_path / "v_vti" / "state_00001.vti"))
    reader.Update()
    img = reader.GetOutput()
    fd = img.GetFieldData()
    assert vtk_to_numpy(fd.GetArray("time [s]")).tolist() == [TIMES[1]]
    assert vtk_to_numpy(fd.GetArray("load [kN]")).tolist() == [LOADS[1]]
    e1 = _principal(np.asarray(res.exx), np.asarray(res.eyy), np.asarray(res.exy))[0]
    got = vtk_to_numpy(img.GetPointData().GetArray("e1 [-]")).reshape(N, N)[::-1]
    assert_allclose(got, e1[1], rtol=2e-7, atol=1e-12)  # float32 for viewing


def test_result_derived_and_finite_strains_of_one_state_and_of_all(stored):
    from gridstrain.kinematics import finite_strains, principal_strains

    res = stored[0]
    every, one = res.principal_strains(), res.principal_strains(1)
    assert every.e1.shape == (2, N, N)
    assert_array_equal(one.e1, every.e1[1])
    unc = res.uncertainty
    direct = principal_strains(res.exx[1], res.eyy[1], res.exy[1], exx_std=unc["exx_std"][1],
                               eyy_std=unc["eyy_std"][1], exy_std=unc["exy_std"][1])
    assert_array_equal(one.equivalent_std, direct.equivalent_std)
    f = res.finite_strains(0)
    g = finite_strains(res.exx[0], res.eyy[0], res.exy[0], res.measurements[0].rotation)
    assert_array_equal(f.Lxx, g.Lxx)
    assert_array_equal(res.finite_strains().Exy[0], g.Exy)
    # small strains: Green-Lagrange differs from exx by (exx^2 + (exy + w)^2) / 2,
    # below 5e-6 at the 2e-3 strains of this result
    valid = np.asarray(res.valid[0])
    assert np.nanmax(np.abs(f.Exx - res.exx[0])[valid]) < 5e-6
    with pytest.raises(ValueError, match="state must be an index of the 2 state"):
        res.principal_strains(2)


def test_the_command_lists_the_export_registry():
    """``gridstrain export --help`` names the formats without importing the results
    package: its list must be the registry's."""
    from gridstrain.cli import export as command
    from gridstrain.results import EXPORTS

    assert tuple(EXPORTS) == command._FORMATS


def test_every_export_carries_the_finite_strains_and_their_std(stored, tmp_path):
    """The Green–Lagrange and log maps of every format against the closed form applied
    here to the stored gradient, and the VTK shear's sign turned with Y = -y."""
    res, path = stored
    prefix = tmp_path / "f"
    assert main(["export", str(path), "--to", "mat,csv,vtk,netcdf", "-o", str(prefix)]) == 0
    exx, eyy, exy = (np.asarray(a) for a in (res.exx, res.eyy, res.exy))
    w = np.stack([np.asarray(m.rotation) for m in res.measurements])
    h01, h10 = exy - w, exy + w
    # E = (H + H^T + H^T H) / 2, the oracle
    gl = {"gl_xx": exx + (exx**2 + h10**2) / 2, "gl_yy": eyy + (h01**2 + eyy**2) / 2,
          "gl_xy": exy + (exx * h01 + h10 * eyy) / 2}
    from scipy.io import loadmat

    m = loadmat(f"{prefix}.mat")
    for name, want in gl.items():
        # float64 on the same numbers: rounding of 1e-3 strains, 1e-18
        assert_allclose(m[name], np.moveaxis(want, 0, -1), rtol=0, atol=1e-15)
    assert str(m["units"]["rotation_std"][0, 0][0]) == "rad"
    assert_allclose(m["rotation_std"], m["exy_std"], rtol=1e-12)  # the noise model's
    assert m["log_xy_std"].shape == (N, N, 2)
    pd = pytest.importorskip("pandas")
    df = pd.read_csv(f"{prefix}.csv", keep_default_na=False)
    for col in ("gl_xx [-]", "log_yy [-]", "gl_xy_std [-]", "rotation_std [rad]"):
        assert col in df.columns
    rows = df[df["state"] == NAMES[1]]
    x, y = rows["x [px]"].to_numpy(), rows["y [px]"].to_numpy()
    assert_allclose(rows["gl_yy [-]"], gl["gl_yy"][0][y, x], rtol=5e-7, atol=1e-13)
    _, root = _field_data(tmp_path / "f_vti" / "state_00000.vti")
    # float32 for viewing: 6e-8 relative of 1e-3 strains
    assert_allclose(_point_array(root, "gl_xy [-]"), -gl["gl_xy"][0], atol=1e-9)
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    with xr.open_dataset(f"{prefix}.nc") as ds:
        assert_allclose(ds["gl_xx"].values, gl["gl_xx"], rtol=0, atol=1e-15)
        assert "Green-Lagrange" in ds["gl_xx"].attrs["long_name"]
        assert ds["rotation_std"].attrs["units"] == "rad"


def test_maps_read_from_a_rounded_file_are_never_labelled_lossless(stored, tmp_path):
    res, _ = stored
    rounded = load(save_result(res, tmp_path / "rounded.h5"))
    assert rounded.maps_precision is not None
    assert "rounded" in rounded.maps_precision
    assert load(stored[1]).maps_precision is None  # the lossless file's: as measured
    export_netcdf(rounded, tmp_path / "again.nc")
    with h5py.File(tmp_path / "again.nc", "r") as h5:
        assert not bool(h5.attrs["maps_lossless"])
        assert "had rounded them" in str(h5.attrs["maps_precision"])
    # saved again losslessly, still said rounded, and read back as such
    again = save_result(rounded, tmp_path / "again.h5", lossless=True)
    with h5py.File(again, "r") as h5:
        assert not bool(h5.attrs["maps_lossless"])
    assert load(again).maps_precision is not None
    # the measured maps exported: lossless
    export_netcdf(res, tmp_path / "measured.nc")
    with h5py.File(tmp_path / "measured.nc", "r") as h5:
        assert bool(h5.attrs["maps_lossless"])


def test_a_streamed_result_carries_its_files_pixel_size_and_rounding(tmp_path):
    """``measure_series(output=ResultFile(...))``: the result's maps are read from the
    file it wrote, so it carries that file's pixel size and, rounded by default, says
    so in what it exports."""
    from gridstrain.results import ResultFile

    rng = np.random.default_rng(3)
    spec = ResultFile(tmp_path / "s.h5", pixel_size=0.02, unit="mm")
    res = measure_series(_frames(0.0, rng), [_frames(1e-3, rng)], lattice=LAT,
                         output=spec)
    assert (res.pixel_size, res.unit) == (0.02, "mm")
    assert "rounded" in res.maps_precision
    export_netcdf(res, tmp_path / "s.nc")
    with h5py.File(tmp_path / "s.nc", "r") as h5:
        assert not bool(h5.attrs["maps_lossless"])
    exact = measure_series(_frames(0.0, rng), [_frames(1e-3, rng)], lattice=LAT,
                           output=ResultFile(tmp_path / "e.h5", lossless=True))
    assert exact.maps_precision is None
    assert exact.pixel_size is None


def test_a_prefix_given_with_an_export_suffix_is_not_doubled(stored, tmp_path, capsys):
    """``-o maps.mat`` writes maps.mat (and maps.csv), never maps.mat.mat."""
    path = stored[1]
    assert main(["export", str(path), "--to", "mat,csv", "-o", str(tmp_path / "m.mat")]) == 0
    assert capsys.readouterr().out.split("\n")[:2] == [f"{tmp_path / 'm'}.mat",
                                                       f"{tmp_path / 'm'}.csv"]
    assert not (tmp_path / "m.mat.mat").exists()
    assert (tmp_path / "m.csv").exists()
    # a dot inside a name that is no export's suffix stays part of the name
    assert main(["export", str(path), "--to", "csv", "-o", str(tmp_path / "run.2")]) == 0
    assert (tmp_path / "run.2.csv").exists()
