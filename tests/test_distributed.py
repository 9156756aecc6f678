"""Tests of gridstrain.series: methods A and B on a real Dask cluster.

The cluster is two single-threaded worker processes on the loopback interface
(127.0.0.1, nothing else). Every result is checked against the single-process
code (gridstrain.stacks, gridstrain.series) or a direct sum written here. The
reductions add the same terms in another order, so the results agree to the
rounding of float64 sums, not bit for bit: the tolerances below are a few hundred
times that rounding and many orders of magnitude below any physical effect.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tifffile
from numpy.testing import assert_allclose, assert_array_equal

distributed = pytest.importorskip("distributed")
dask = pytest.importorskip("dask")
da = pytest.importorskip("dask.array")
zarr = pytest.importorskip("zarr")

import gridstrain  # noqa: E402
from findings import said  # noqa: E402
from gridstrain import Lattice, stacks  # noqa: E402
from gridstrain.cli import main  # noqa: E402
from gridstrain.io import open_series, read_hdf5  # noqa: E402
from gridstrain.models import kirsch, synthetic  # noqa: E402
from gridstrain.phase import Window  # noqa: E402
from gridstrain.results import read_attrs  # noqa: E402
from gridstrain.series import _distributed as gd  # noqa: E402
from gridstrain.series import measure_series  # noqa: E402
from gridstrain.stacks.accumulate import PassPlan  # noqa: E402

LAT = Lattice.from_pitch(5.0)
N = 80  # px: 4-sigma margins leave a 40 x 40 valid centre at sigma = pitch = 5
AMP = 2400.0  # mean grey level, 12-bit
# Phases: the sums of unit phasors differ by ~1e-16 relative between summation
# orders, i.e. ~1e-16 rad; 1e-12 rad leaves room for a few thousand roundings.
PHASE_TOL = 1e-12  # rad
DPHI_TOL = 1e-12  # rad/px, same argument for the averaged derivatives
# Displacements and strains are linear in the phases (eqs. 34-35) with factors of
# order p / 2 pi ~ 1 px/rad: the phase tolerance carried through.
U_TOL = 1e-11  # px
STRAIN_TOL = 1e-12  # strain


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes on 127.0.0.1, closed after the module's tests."""
    # the spawned workers import gridstrain from this checkout, installed or not
    src = str(Path(gridstrain.__file__).resolve().parents[1])
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = src + (os.pathsep + old if old else "")
    try:
        # the scheduler's HTTP server on a free port: the default 8787 may be held by
        # another cluster on the machine, and the warning would fail the setup
        with dask.config.set({"distributed.comm.timeouts.connect": "10s"}), \
                distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                         host="127.0.0.1", dashboard_address=":0") as c:
            yield c
    finally:
        if old is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = old


@pytest.fixture(scope="module")
def client(cluster):
    with distributed.Client(cluster, set_as_default=False) as c:
        yield c


def _frames(T, rng, *, strain=0.0, hole=False, vibration=0.05, dtype=np.float64):
    """(T, N, N) noisy frames of a plate stretched by ``strain``, each frame shifted
    by a random rigid vibration (px); uint16 frames are 12-bit data stored x16."""
    c = ((N - 1) / 2, (N - 1) / 2)
    el = {"radius": 7.0, "remote_stress": 70e3 * strain, "centre": c}

    def refl(X, Y):
        return ((X - c[0]) ** 2 + (Y - c[1]) ** 2 >= 7.0**2).astype(float)

    out = []
    for _ in range(T):
        a = rng.normal(0.0, vibration, 2)

        def disp(X, Y, a=a):
            if hole:
                ux, uy = kirsch.displacement(X, Y, inside="extend", **el)
            else:
                ux, uy = strain * (X - c[0]), -0.3 * strain * (Y - c[1])
            return ux + 0.4 - a[0], uy - 0.2 - a[1]

        img = synthetic.grid_image((N, N), LAT, amplitude=AMP, displacement=disp,
                                   reflectance=refl if hole else None) + 100.0
        img = synthetic.add_noise(img, rng=rng, clip=True)
        out.append((img * 16).astype(np.uint16) if dtype == np.uint16 else img)
    return np.array(out, dtype=dtype)


def _phase_error(a, b) -> float:
    """Largest phase difference of two PhaseMaps over the pixels valid in both, rad."""
    v = a.valid & b.valid
    return float(np.max(np.abs(np.angle(a.psi * np.conj(b.psi)))[:, v]))


def _check_maps(got, want):
    """Same maps to float rounding: validity exact, phases, moduli, derivatives."""
    assert_array_equal(got.valid, want.valid)
    assert got.psi.dtype == want.psi.dtype
    assert got.dphi.dtype == want.dphi.dtype
    v = want.valid
    if want.dphi.dtype == np.float32:
        # float32 results: the float64 sums, rounded to float32 at the end, may
        # round to neighbouring float32 values (4 ulp of 6e-8 relative)
        tol = 4 * float(np.finfo(np.float32).eps)
        phase_tol, rtol = tol, tol
        dphi_tol = tol * float(np.max(np.abs(want.dphi[..., v])))
    else:
        # moduli: grey levels, sums of T moduli ~1e3 each, rounding ~1e-16 relative
        phase_tol, rtol, dphi_tol = PHASE_TOL, 1e-12, DPHI_TOL
    assert _phase_error(got, want) < phase_tol
    assert_allclose(np.abs(got.psi), np.abs(want.psi), rtol=rtol)
    assert_allclose(got.dphi[..., v], want.dphi[..., v], rtol=0, atol=dphi_tol)


def _closed_port() -> int:
    """A loopback port nothing listens on (bound, then released)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --------------------------------------------------------------------------- stacks


def test_multipage_tiff_stack_is_the_files_frames(tmp_path):
    rng = np.random.default_rng(1)
    frames = _frames(5, rng, dtype=np.uint16)
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, frames, photometric="minisblack")
    st = gd.as_dask_stack(path)
    # one task per frame, whole frames, the stored type
    assert st.shape == frames.shape
    assert st.dtype == np.uint16
    assert st.chunks == ((1,) * 5, (N,), (N,))
    assert_array_equal(st.compute(), frames)
    st2 = gd.as_dask_stack(open_series(path), chunk_frames=2, dtype=np.float32)
    assert st2.chunks[0] == (2, 2, 1)
    assert st2.dtype == np.float32
    assert_array_equal(st2.compute(), frames.astype(np.float32))


def test_zarr_stack_from_a_path_and_an_array(tmp_path):
    rng = np.random.default_rng(2)
    frames = _frames(4, rng)
    z = zarr.create_array(tmp_path / "frames.zarr", shape=frames.shape,
                          chunks=(2, N // 2, N), dtype=frames.dtype)
    z[:] = frames
    for source in (tmp_path / "frames.zarr", str(tmp_path / "frames.zarr"), z):
        st = gd.as_dask_stack(source)
        # spatial chunks are merged: each task needs a whole frame
        assert st.chunks == ((1,) * 4, (N,), (N,))
        assert_array_equal(st.compute(), frames)
    group = zarr.open_group(tmp_path / "group.zarr", mode="w")
    group.create_array("frames", shape=frames.shape, dtype=frames.dtype)[:] = frames
    with pytest.raises(ValueError, match="not a Zarr array"):
        gd.as_dask_stack(tmp_path / "group.zarr")
    assert_array_equal(gd.as_dask_stack(tmp_path / "group.zarr" / "frames").compute(), frames)


@pytest.mark.parametrize(("bad", "exc", "match"), [
    ({"source": np.zeros((2, 3, 8, 8))}, ValueError, "shape"),
    ({"source": np.zeros((2, 4, 8))}, ValueError, "8 x 8"),
    ({"source": np.zeros((2, 8, 8), dtype=bool)}, TypeError, "grey levels"),
    ({"source": 3.0}, TypeError, "got float"),
    ({"chunk_frames": 0}, ValueError, "chunk_frames"),
    ({"dtype": np.int32}, ValueError, "dtype"),
])
def test_as_dask_stack_refuses_bad_input(bad, exc, match):
    kw = {"source": np.zeros((2, 8, 8))} | bad
    with pytest.raises(exc, match=match):
        gd.as_dask_stack(kw.pop("source"), **kw)


def test_bad_options_are_named():
    st = gd.as_dask_stack(np.zeros((2, 16, 16)))
    with pytest.raises(ValueError, match="split_every"):
        gd.mean_image_dask(st, split_every=1)
    with pytest.raises(TypeError, match="lattice"):
        gd.method_b_dask(st, "pitch 5")
    with pytest.raises(ValueError, match="mask"):
        gd.method_a_dask(st, LAT, mask=np.ones((3, 3), dtype=bool))
    with pytest.raises(TypeError, match="scheduler"):
        measure_series(np.zeros((2, 16, 16)), np.zeros((2, 16, 16)), lattice=LAT,
                       scheduler=5)


# --------------------------------------------------------------------------- methods


def test_mean_is_a_direct_sum_and_method_a_matches_stacks(client):
    rng = np.random.default_rng(3)
    frames = _frames(9, rng, dtype=np.uint16)
    st = gd.as_dask_stack(frames, chunk_frames=2)
    # a direct float64 sum, frame by frame; 9 frames of <= 65520 sum exactly in
    # float64 (integers below 2**53), so only the final division rounds
    direct = sum(f.astype(np.float64) for f in frames) / 9
    mean = gd.mean_image_dask(st, split_every=2).compute(scheduler=client)
    assert mean.dtype == np.float64
    assert_array_equal(mean, direct)
    mask = np.ones((N, N), dtype=bool)
    mask[:, :6] = False
    got = gd.method_a_dask(st, LAT, mask=mask, split_every=2, client=client)
    want = stacks.method_a(frames, LAT, mask=mask)
    assert got.method == "A"
    assert got.n_frames == 9
    assert_array_equal(got.mean_image, want.mean_image)
    _check_maps(got.maps, want.maps)


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_method_b_per_frame_tasks_match_stacks(client, tmp_path, dtype):
    rng = np.random.default_rng(4)
    frames = _frames(7, rng, dtype=dtype, vibration=0.1)
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, frames, photometric="minisblack")
    mask = np.ones((N, N), dtype=bool)
    mask[-5:] = False
    # frames read by the workers from the TIFF, one task each, summed 3 at a time
    got = gd.method_b_dask(path, LAT, mask=mask, split_every=3, client=client)
    want = stacks.method_b(open_series(path).frames(dtype=None), LAT, mask=mask)
    assert got.method == "B"
    assert got.n_frames == 7
    assert got.mean_image is None
    _check_maps(got.maps, want.maps)
    # resultant lengths in [0, 1]: rounding of sums of 7 unit phasors
    assert_allclose(got.resultant, want.resultant, rtol=0, atol=1e-14)


def test_method_b_graph_is_a_tree_of_bounded_fan_in():
    # memory bound: no task ever receives more than split_every partial sums
    st = gd.as_dask_stack(np.random.default_rng(5).random((10, 16, 16)))
    graph = gd.method_b_dask(st, LAT, split_every=3, compute=False)
    deps = graph.__dask_graph__().get_all_dependencies()
    sums = [k for k in deps if "block_sums" in str(k)]
    adds = [k for k in deps if "merged" in str(k)]
    assert len(sums) == 10
    assert all(len(deps[k]) <= 3 for k in adds)
    # 10 leaves, 3 at a time: sums of 3, 3, 3 (the tenth waits), then of 3 + the
    # tenth's 1, then the last two
    assert len(adds) == 3 + 1 + 1


@pytest.mark.parametrize("name", ["a", "b"])
def test_dask_methods_screen_their_frames_as_the_bare_methods(client, name):
    """A frame of the loaded state among 10 reference frames (the numpy-only frames of
    test_screening): named by the cluster's method as by the bare one, chunks of
    several frames and a tree of records included."""
    from test_screening import LAT as SLAT
    from test_screening import STRAIN, grid_frames

    rng = np.random.default_rng(31)
    stack, _ = grid_frames(10, rng)
    load, _ = grid_frames(1, rng, strain=STRAIN)
    stack[6] = load[0]
    bare = getattr(stacks, f"method_{name}")(stack, SLAT)
    dask_method = getattr(gd, f"method_{name}_dask")
    st = gd.as_dask_stack(stack, chunk_frames=3)
    got = dask_method(st, SLAT, split_every=2, client=client)
    assert got.screening.flagged == bare.screening.flagged == (6,)
    assert got.screening.reasons == bare.screening.reasons
    assert said(got.warnings, "screening.flagged") == said(bare.warnings, "screening.flagged")
    assert said(got.warnings, "screening.flagged")
    quiet = dask_method(st, SLAT, split_every=2, screen=False, client=client)
    assert quiet.screening is None
    assert not said(quiet.warnings, "screening.flagged")
    assert_array_equal(quiet.maps.psi, got.maps.psi)  # the screening changes no number


@pytest.mark.parametrize("method", ["A", "B", "C"])
def test_several_states_at_once_match_single_process(client, method):
    """The cluster runs the same pass as this machine (gridstrain.stacks.accumulate): the
    maps agree to the rounding of sums added in another order."""
    rng = np.random.default_rng(6)
    ref = _frames(6, rng)
    states = [_frames(5, rng, strain=1e-3), _frames(5, rng, strain=2.5e-3)]
    want = measure_series(ref, states, lattice=LAT, method=method, guess=None)
    got = measure_series(ref, states, lattice=LAT, method=method, guess=None,
                         scheduler=client)
    assert_array_equal(got.valid, want.valid)
    for i, eps in enumerate((1e-3, 2.5e-3)):
        v = want.valid[i]
        assert v.mean() > 0.2
        assert_allclose(got.u[i][:, v], want.u[i][:, v], rtol=0, atol=U_TOL)
        assert_allclose(got.strain[i][:, v], want.strain[i][:, v], rtol=0, atol=STRAIN_TOL)
        # and the physics: the applied uniform strain, to the noise of a few frames
        # (a few 1e-5 at sigma = 5 px with 5-6 frames) and a common offset of the 40 x
        # 40 valid centre of these 80-px frames (-0.9e-4 to -1.0e-4 at both strains,
        # with both methods, with the state transformed at either carrier)
        assert abs(float(np.mean(got.strain[i][0][v])) - eps) < 1.5e-4
    assert_allclose(got.noise.split_u, want.noise.split_u, rtol=1e-6)


# --------------------------------------------------------------------------- pipeline


@pytest.mark.parametrize("method", ["A", "B"])
def test_pipeline_on_the_cluster_matches_single_process(client, method, monkeypatch):
    rng = np.random.default_rng(8)
    ref = _frames(11, rng, hole=True)
    states = [_frames(6, rng, strain=1e-3, hole=True),
              _frames(5, rng, strain=2e-3, hole=True)]
    # one frame per task on these short series (the graph is made in this process):
    # a reduction tree of several levels
    monkeypatch.setattr(gd, "_MIN_CHUNK_FRAMES", 1)
    want = measure_series(ref, states, lattice=LAT, method=method)
    got = measure_series(ref, states, lattice=LAT, method=method, scheduler=client)
    assert_array_equal(got.valid, want.valid)
    assert_array_equal(got.mask, want.mask)
    v = want.valid
    assert_allclose(got.u[:, :, v[0]], want.u[:, :, v[0]], rtol=0, atol=U_TOL)
    assert_allclose(got.strain[:, :, v[0]], want.strain[:, :, v[0]], rtol=0, atol=STRAIN_TOL)
    # the temporal variances: sums of squares of grey levels near 2000 less the square
    # of their sum, in another order; the difference cancels some 2000 times over a
    # variance near 2000 grey levels^2, so a reordering moves it by a few 1e-12 of
    # itself (3e-12 with numpy 2.4 and dask 2026.8 on an AVX2 machine); 1e-9 of a
    # noise variance changes no uncertainty a user reads
    assert_allclose(got.noise.sensor_variance, want.noise.sensor_variance, rtol=1e-9)
    for name, arr in want.uncertainty.items():
        assert_allclose(got.uncertainty[name], arr, rtol=1e-9, equal_nan=True)
    assert_allclose(got.reference_image, want.reference_image, rtol=1e-14)
    for a, b in zip(got.vibration, want.vibration, strict=True):
        assert_array_equal(a.shifts, b.shifts)  # computed on this machine either way


def test_a_saturated_frame_is_screened_before_the_cluster_sees_it(client, tmp_path):
    rng = np.random.default_rng(9)
    ref = _frames(4, rng, dtype=np.uint16)
    bad = ref.copy()
    bad[2, :30] = 4095 * 16  # 37 % of frame 2 saturated
    tifffile.imwrite(tmp_path / "ref.tif", ref, photometric="minisblack")
    tifffile.imwrite(tmp_path / "bad.tif", bad, photometric="minisblack")
    with pytest.raises(ValueError, match=r"^bad: frame 2 .*saturated"):
        measure_series(tmp_path / "ref.tif", tmp_path / "bad.tif", lattice=LAT,
                       scheduler=client, outliers="refuse")
    # by default the frame is left out of the workers' sums, and named
    got = measure_series(tmp_path / "ref.tif", tmp_path / "bad.tif", lattice=LAT,
                         scheduler=client)
    want = measure_series(tmp_path / "ref.tif", ref[[0, 1, 3]], lattice=LAT)
    assert got.n_frames == (4, 3)
    assert got.excluded == ((), (2,))
    assert any("frame 2 (" in w and "saturated" in w
               for w in said(got.warnings, "screening.flagged"))
    assert_allclose(got.u, want.u, rtol=0, atol=1e-9)  # px: the same frames, sums reordered


# --------------------------------------------------------------------------- command line


@pytest.fixture(scope="module")
def tiff_series(tmp_path_factory):
    root = tmp_path_factory.mktemp("series")
    rng = np.random.default_rng(10)
    (root / "ref").mkdir()
    for k, f in enumerate(_frames(4, rng, dtype=np.uint16)):
        tifffile.imwrite(root / "ref" / f"img{k}.tif", f, photometric="minisblack")
    tifffile.imwrite(root / "load.tif", _frames(4, rng, strain=1e-3, dtype=np.uint16),
                     photometric="minisblack")
    return root


def test_cli_with_the_test_cluster_address(cluster, tiff_series, tmp_path, capsys):
    root = tiff_series
    args = [str(root / "ref"), str(root / "load.tif"), "--pitch", "5", "--method", "B",
            "--quiet"]
    assert main(["measure", *args, "-o", str(tmp_path / "one.h5")]) == 0
    assert main(["measure", *args, "-o", str(tmp_path / "dask.h5"),
                 "--scheduler", cluster.scheduler_address]) == 0
    one, dist = read_hdf5(tmp_path / "one.h5"), read_hdf5(tmp_path / "dask.h5")
    config = tomllib.loads(read_attrs(tmp_path / "dask.h5")["config"])
    # where a run was computed is not part of the measurement: a result file never
    # stores (nor replays) a scheduler address
    assert "scheduler" not in config
    v = one["datasets"]["valid"]
    assert_array_equal(dist["datasets"]["valid"], v)
    for name, tol in (("ux", U_TOL), ("uy", U_TOL), ("exx", STRAIN_TOL)):
        assert_allclose(dist["datasets"][name][v], one["datasets"][name][v], rtol=0,
                        atol=tol)


def test_cli_unreachable_scheduler_is_one_line(tiff_series, tmp_path, capsys):
    address = f"tcp://127.0.0.1:{_closed_port()}"
    out = tmp_path / "maps.h5"
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        code = main(["measure", str(tiff_series / "ref"), str(tiff_series / "load.tif"),
                     "--pitch", "5", "--quiet", "-o", str(out), "--scheduler", address])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert "cannot reach a Dask scheduler" in err[-1]
    assert address in err[-1]
    assert not out.exists()


# --------------------------------------------------------------------------- without Dask


def test_missing_dask_is_a_clear_error(monkeypatch, tiff_series, tmp_path, capsys):
    for name in ("dask", "dask.array", "distributed", "zarr"):
        monkeypatch.setitem(sys.modules, name, None)  # "import dask" now fails
    with pytest.raises(gd.MissingDistributedError, match=r"gridstrain\[distributed\]") as e:
        gd.as_dask_stack(np.zeros((2, 8, 8)))
    assert isinstance(e.value, ImportError)
    assert isinstance(e.value, ValueError)
    with pytest.raises(ImportError, match=r"gridstrain\[distributed\]"), gd.connect("local"):
        pass
    # the pipeline refuses before reading a frame, the command line in one line
    with pytest.raises(ValueError, match=r"gridstrain\[distributed\]"):
        measure_series(np.zeros((2, 16, 16)), np.zeros((2, 16, 16)), lattice=LAT,
                       scheduler="local")
    code = main(["measure", str(tiff_series / "ref"), str(tiff_series / "load.tif"),
                 "--quiet", "-o", str(tmp_path / "m.h5"), "--scheduler", "local"])
    assert code == 2
    assert "pip install 'gridstrain[distributed]'" in capsys.readouterr().err


def test_core_imports_without_dask():
    code = ("import sys\n"
            "for m in ('dask', 'distributed', 'zarr'): sys.modules[m] = None\n"
            "import gridstrain, gridstrain.series, gridstrain.series, gridstrain.cli\n"
            "from gridstrain.cli import build_parser; build_parser()\n")
    src = str(Path(gridstrain.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=src)
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0, res.stderr


# --------------------------------------------------------------------------- local cluster


def _trim_threshold():
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


@pytest.mark.slow
def test_local_cluster_workers_keep_the_adaptive_malloc(monkeypatch):
    # Dask's default, 64 KiB, makes every transform 1.5 times slower; a nanny started
    # earlier in this process leaves it in the process's environment, which workers
    # would inherit
    key = "distributed.nanny.pre-spawn-environ"
    before = dict(dask.config.get(key))
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", str(before["MALLOC_TRIM_THRESHOLD_"]))
    with gd.connect("local", n_workers=1) as c:
        assert set(c.run(_trim_threshold).values()) == {None}
    assert dask.config.get(key) == before  # the user's configuration is left alone
    # and the environment as it was
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == str(before["MALLOC_TRIM_THRESHOLD_"])


@pytest.mark.slow
def test_scheduler_local_starts_and_stops_its_own_cluster():
    rng = np.random.default_rng(11)
    ref, cur = _frames(4, rng), _frames(4, rng, strain=1e-3)
    want = measure_series(ref, cur, lattice=LAT, method="B")
    got = measure_series(ref, cur, lattice=LAT, method="B", scheduler="local")
    v = want.valid[0]
    assert_allclose(got.u[0][:, v], want.u[0][:, v], rtol=0, atol=U_TOL)


# ------------------------------------------------------------------- faults


class _DyingSeries:
    """Frames of an array; the worker reading frame ``kill_at`` dies, once.

    The death is tied to a frame index and a flag file, not to a time: whichever
    worker reads that frame first exits at once (``os._exit``); the rerun finds
    the flag and reads on.
    """

    def __init__(self, frames, kill_at, flag):
        self._frames, self.kill_at, self.flag = frames, kill_at, str(flag)
        self.name = "dying"

    @property
    def n_frames(self):
        return len(self._frames)

    def frames(self, *, dtype=np.float64, start=0, stop=None):
        for t in range(start, len(self._frames) if stop is None else stop):
            if t == self.kill_at and not os.path.exists(self.flag):
                with open(self.flag, "w") as fh:
                    fh.write(str(os.getpid()))
                os._exit(1)
            yield self._frames[t].astype(dtype)


def _pass_here(series, plan):
    """The cluster's graph of one pass (the same chunks, merged by the same tree),
    computed in this process: the run without a death to compare with."""
    origin = gd._first_frame(series)
    leaf = dask.delayed(gd._chunk_pass, pure=True)
    parts = [leaf(series, a, b, plan, origin) for a, b in gd._frame_chunks(series.n_frames)]
    return dask.compute(gd._tree(parts, gd._merged, gd._SPLIT_EVERY),
                        scheduler="synchronous")[0]


def test_method_b_survives_a_worker_killed_mid_run(client, tmp_path, monkeypatch):
    """One of the two workers dies on frame 3 of 8: Dask reruns its task on the other
    (the inputs are on every worker) and the result is bit for bit that of a run
    without the death (same graph, same order of the sums)."""
    import cloudpickle

    monkeypatch.setattr(gd, "_MIN_CHUNK_FRAMES", 1)  # one frame per task: a tree

    # sent by value, should a worker be unable to import this test module
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    try:
        frames = _frames(8, np.random.default_rng(8))
        flag = tmp_path / "killed"
        plan = PassPlan(lattice=LAT, n_frames=8, method="B", window=Window(5.0, 4.0))
        killed = gd._submit_pass(client, _DyingSeries(frames, 3, flag), plan).result(
            timeout=120)
        assert flag.exists()  # a worker did die, on frame 3
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
        # the nanny's new worker registered before the next test uses the cluster, so
        # that no scatter meets a worker joining mid-way (an event, not a delay)
        client.wait_for_workers(2, timeout=120)
    # the run without the death: the same graph in this process, not a second
    # submission racing the cluster's recovery
    calm = _pass_here(_DyingSeries(frames, 3, flag), plan)
    assert killed.kept == calm.kept == list(range(8))
    kb, cb = killed.method_b(), calm.method_b()
    assert kb.n_frames == cb.n_frames == 8
    assert_array_equal(kb.maps.phase, cb.maps.phase)
    assert_array_equal(kb.maps.valid, cb.maps.valid)
    assert_array_equal(killed.statistics().mean, calm.statistics().mean)


def _blocked(name):
    distributed.Event(name).wait()  # until the test sets it
    return 1


def test_stalled_cluster_times_out_with_a_message(client):
    name = f"gridstrain-test-{os.getpid()}"
    pending = gd._Pending(client.submit(_blocked, name, pure=False), None,
                          "the statistics of state 0")
    try:
        with pytest.raises(TimeoutError, match=r"no result for the statistics of state 0 "
                                                r"within 0\.5 s"):
            pending.result(timeout=0.5)
    finally:
        distributed.Event(name, client=client).set()


@pytest.mark.parametrize(("n_frames", "tasks"),
                         [(1, 1), (7, 1), (32, 1), (64, 2), (100, 3), (512, 16), (1000, 16)])
def test_method_b_tasks_take_chunks_of_frames(n_frames, tasks):
    chunks = gd._frame_chunks(n_frames)
    # every frame exactly once, in order, in even chunks of at least
    # _MIN_CHUNK_FRAMES frames (fewer when the series is shorter), at most _PASS_TASKS
    assert [t for a, b in chunks for t in range(a, b)] == list(range(n_frames))
    assert len(chunks) == tasks
    sizes = [b - a for a, b in chunks]
    assert max(sizes) - min(sizes) <= 1


def test_scatter_to_a_frozen_worker_ends_at_the_timeout(client):
    """A worker stopped (SIGSTOP) while the inputs are sent to every worker: the
    scatter gives up at the deadline with one line naming --timeout, instead of
    waiting for the worker for ever. The worker is resumed afterwards."""
    import signal
    import time

    pids = client.run(os.getpid)
    frozen = sorted(pids.values())[0]
    os.kill(frozen, signal.SIGSTOP)
    try:
        with pytest.raises(TimeoutError, match=r"did not take the data of ref.*--timeout"):
            gd._scatter(client, np.zeros(1 << 20), time.monotonic() + 2.0, "ref")
    finally:
        os.kill(frozen, signal.SIGCONT)
