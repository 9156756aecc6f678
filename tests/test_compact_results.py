"""The precision a result file keeps of its maps (``gridstrain.results``): by default
float32 rounded to a tenth of each map's own predicted std at each pixel, compressed;
``lossless=True`` the maps as measured, bit for bit.

The oracle is the same measurement held in memory in float64 (``measure_series``
without ``output``): every stored value is compared with it at every pixel. The record is
drawn by the numpy-only generator of ``tests/sequence_record.py`` (a 12-bit
Poisson-Gaussian camera, one frame per state, the coupon strained and drifting), 160 x 192
px: the smallest size whose single frames give their own noise estimate, and hence std
maps (``estimate_noise_image`` needs 160 px a side).
"""

from __future__ import annotations

import zlib

import h5py
import numpy as np
import pytest
import tifffile
from numpy.testing import assert_array_equal

from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.results import ResultFile, load, save_result
from gridstrain.series import measure_series
from sequence_record import record

LAT = Lattice.from_pitch(5.0)
SHAPE = (160, 192)
MAPS = ("ux", "uy", "exx", "eyy", "exy", "rotation")
# the std each map is rounded from: the rotation (duy/dx - dux/dy)/2 has the std of
# exy = (dux/dy + duy/dx)/2 when the two derivatives are independent, as the noise
# model of gridstrain.uncertainty takes them
STD = {"ux": "ux_std", "uy": "uy_std", "exx": "exx_std", "eyy": "eyy_std",
       "exy": "exy_std", "rotation": "exy_std"}
PS = 0.02  # mm a pixel, for the maps in physical units


@pytest.fixture(scope="module")
def frames():
    return record(4, SHAPE, strain=2e-3)


@pytest.fixture(scope="module")
def held(frames):
    return measure_series(frames[0][None], [f[None] for f in frames[1:]], lattice=LAT,
                          guess=None)


@pytest.fixture(scope="module")
def files(held, frames, tmp_path_factory):
    d = tmp_path_factory.mktemp("compact")
    at_once = save_result(held, d / "at_once.h5", pixel_size=PS, unit="mm")
    lossless = save_result(held, d / "lossless.h5", pixel_size=PS, unit="mm", lossless=True)
    measure_series(frames[0][None], [f[None] for f in frames[1:]], lattice=LAT, guess=None,
                   output=ResultFile(d / "streamed.h5", pixel_size=PS, unit="mm"))
    return {"at_once": at_once, "lossless": lossless, "streamed": d / "streamed.h5"}


def _maps(held) -> dict:
    out = {name: getattr(held, name) for name in MAPS if name != "rotation"}
    out["rotation"] = np.stack([m.rotation for m in held.measurements])
    out["ux_phys"], out["uy_phys"] = held.ux * PS, held.uy * PS
    return out


def test_the_record_has_a_std_at_every_valid_pixel(held):
    # the rounding is bounded by the std: without one the checks below would be empty
    assert held.uncertainty is not None
    for name, std in held.uncertainty.items():
        s = std[held.valid]
        assert np.all(np.isfinite(s)), name
        assert np.all(s > 0), name
    assert held.valid.mean() > 0.4  # the margin leaves about half of 160 x 192 px


def test_every_stored_map_is_within_a_tenth_of_its_std(held, files):
    v = held.valid
    with h5py.File(files["at_once"], "r") as h5:
        for name, want in _maps(held).items():
            ds = h5[name]
            assert ds.dtype == np.float32, name
            assert ds.compression == "gzip", name
            assert ds.shuffle, name
            got = ds[()].astype(np.float64)
            scale = PS if name.endswith("_phys") else 1.0
            std = held.uncertainty[STD[name.removesuffix("_phys")]] * scale
            stored_std = h5[STD[name.removesuffix("_phys")]][()].astype(np.float64) * scale
            err = np.abs(got - want)[v] / std[v]
            # the promise of the file: at most a tenth of the std, at every valid pixel,
            # of the std measured and of the std the file states alike
            assert err.max() <= 0.1, name
            assert (np.abs(got - want)[v] / stored_std[v]).max() <= 0.1, name
            # and it is a rounding, not a copy: most pixels moved by more than the
            # 2^-24 relative of a float32 cast (at |u| < 1 px, 6e-8 px; std >= 3e-3 px)
            assert np.mean(err > 1e-3) > 0.5, name
            # the largest error the file records is the one made, state by state, over
            # the smaller of the two stds (over every pixel with a std, valid or not:
            # both are NaN elsewhere)
            recorded = ds.attrs["rounding_max_error_over_std"]
            low = np.fmin(std, stored_std)
            use = np.isfinite(low) & np.isfinite(want)
            made = [float((np.abs(got[k] - want[k])[use[k]] / low[k][use[k]]).max())
                    for k in range(held.n_states)]
            np.testing.assert_allclose(recorded, made, rtol=1e-12)
            assert ds.attrs["rounding_std_variable"] == STD[name.removesuffix("_phys")]
            assert ds.attrs["rounding_std_fraction"] == 0.1
        for name, want in held.uncertainty.items():
            got = h5[name][()].astype(np.float64)
            # 5 mantissa bits kept: relative error at most 2^-6 (a std's own precision
            # is far coarser: the sensor model is fitted to a few percent)
            rel = np.abs(got - want)[v] / want[v]
            assert rel.max() <= 2.0**-6, name
            assert rel.max() > 2.0**-9, name  # rounded, not copied
        assert not h5.attrs["maps_lossless"]
    # gridstrain.load reads the same numbers, within the same bound
    back = load(files["at_once"])
    for name in ("ux", "uy", "exx", "eyy", "exy"):
        std = held.uncertainty[STD[name]]
        assert (np.abs(getattr(back, name) - getattr(held, name))[v] <= 0.1 * std[v]).all()


def test_nan_and_invalid_pixels_survive(held, files):
    with h5py.File(files["at_once"], "r") as h5:
        for name, want in {**_maps(held), **held.uncertainty}.items():
            assert_array_equal(np.isnan(h5[name][()]), np.isnan(want), err_msg=name)
        assert_array_equal(h5["valid"][()], held.valid)
        assert_array_equal(h5["mask"][()], held.mask)
        assert_array_equal(h5["reference_image"][()], held.reference_image)
    assert np.isnan(held.ux[~held.valid]).all()  # the invalid pixels are NaN to survive


def test_the_lossless_file_round_trips_bit_for_bit(held, files):
    back = load(files["lossless"])
    for name in ("u", "strain", "valid"):
        a, b = getattr(back, name), getattr(held, name)
        assert a.dtype == b.dtype
        assert_array_equal(a, b)
    for k, v in held.uncertainty.items():
        assert_array_equal(back.uncertainty[k], v)
    for a, b in zip(back.measurements, held.measurements, strict=True):
        assert_array_equal(a.rotation, b.rotation)
    with h5py.File(files["lossless"], "r") as h5:
        assert h5.attrs["maps_lossless"]
        assert h5["ux"].dtype == np.float64
        assert h5["ux"].compression is None
        assert_array_equal(h5["ux_phys"][()], held.ux * PS)


def test_written_state_by_state_or_at_once_the_file_holds_the_same(files):
    with h5py.File(files["at_once"], "r") as a, h5py.File(files["streamed"], "r") as b:
        def maps(h5):
            return sorted(k for k in h5 if isinstance(h5[k], h5py.Dataset)
                          and h5[k].shape[1:] == SHAPE)

        names = maps(a)
        assert maps(b) == names
        assert len(names) == 14  # 6 maps, 5 std maps, 2 in mm, valid
        for name in names:
            x, y = a[name][()], b[name][()]
            assert x.dtype == y.dtype, name
            assert x.tobytes() == y.tobytes(), name  # NaN included, bit for bit
            assert dict(a[name].attrs).keys() == dict(b[name].attrs).keys()
            if "rounding_max_error_over_std" in a[name].attrs:
                assert_array_equal(a[name].attrs["rounding_max_error_over_std"],
                                   b[name].attrs["rounding_max_error_over_std"])


def test_a_file_of_the_previous_layout_still_loads(held, tmp_path):
    """A file as gridstrain wrote it before the maps were rounded: float64 maps,
    uncompressed, with no attribute naming their precision."""
    path = save_result(held, tmp_path / "old.h5", lossless=True)
    with h5py.File(path, "a") as h5:
        for key in ("maps_lossless", "maps_precision"):
            del h5.attrs[key]
        for name in (*MAPS, "valid", *held.uncertainty):
            assert not any(k.startswith("rounding") for k in h5[name].attrs)
        assert h5["exx"].dtype == np.float64
        assert h5["exx"].compression is None
    for in_memory in (True, False):
        back = load(path, in_memory=in_memory)
        assert_array_equal(np.asarray(back.u), held.u)
        assert_array_equal(np.asarray(back.strain), held.strain)
        assert_array_equal(np.asarray(back.valid), held.valid)


def test_xarray_opens_the_rounded_file_lazily_by_state(held, files):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    pytest.importorskip("dask")
    H, W = SHAPE
    n = held.n_states
    with xr.open_dataset(files["at_once"], engine="h5netcdf", chunks={}) as ds:
        ux = ds["ux"]
        assert ux.chunks == ((1,) * n, (H,), (W,))  # one chunk a state, as in the file
        assert ux.encoding["chunksizes"] == (1, H, W)
        assert ux.attrs["rounding_std_fraction"] == 0.1
        with h5py.File(files["at_once"], "r") as h5:
            assert_array_equal(ux[1].values, h5["ux"][1])
            assert_array_equal(ds["valid"].values, held.valid)
    with xr.open_dataset(files["at_once"]) as ds:  # the default engine opens it too
        assert ds["exx"].dims == ("state", "y", "x")


def test_a_dtype_is_for_a_lossless_file(tmp_path):
    with pytest.raises(ValueError, match=r"dtype=.*float32.* lossless=True"):
        ResultFile(tmp_path / "r.h5", dtype="float32")
    assert ResultFile(tmp_path / "r.h5", dtype="float32", lossless=True).lossless


def test_measure_stores_rounded_maps_unless_lossless(frames, tmp_path, capsys):
    for k, f in enumerate(frames[:2]):
        tifffile.imwrite(tmp_path / f"f{k}.tif", f, photometric="minisblack")
    for flags, lossless, dtype in (((), False, np.float32),
                                   (("--lossless",), True, np.float64),
                                   (("--dtype", "float32"), True, np.float32)):
        out = tmp_path / f"r{len(flags)}{lossless}.h5"
        rc = main(["measure", str(tmp_path / "f0.tif"), str(tmp_path / "f1.tif"), "-o", str(out),
                   "--pitch", "5", "--quiet", *flags])
        assert rc == 0, capsys.readouterr().err
        with h5py.File(out, "r") as h5:
            assert bool(h5.attrs["maps_lossless"]) is lossless, flags
            assert h5["exx"].dtype == dtype, flags


_COMPILED_PATHS = [pytest.param(False, id="numpy"), pytest.param(True, id="compiled")]


@pytest.mark.parametrize("compiled", _COMPILED_PATHS)
def test_rounding_to_the_std_keeps_the_bits_a_power_of_two_step_allows(compiled, monkeypatch):
    """Oracle: the step each value is rounded to, found by searching the powers of two
    (the largest q with q <= 2 f s), and the rounding done on Python floats; the
    std just below and at a power of two included, where a logarithm rounds up, and a
    std whose 2 f s is subnormal (no exponent bits to read). Both paths: numpy and the
    compiled loops."""
    from gridstrain.results import _precision
    from gridstrain.results._precision import STD_FRACTION, round_relative, round_to_std

    if compiled and _precision._load_kernels() is None:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(_precision, "_COMPILED", compiled)
    rng = np.random.default_rng(7)
    f = STD_FRACTION
    s = np.abs(rng.normal(size=(6, 7))) * 1e-4
    s[0, :3] = [2.0**-14 / (2 * f), np.nextafter(2.0**-14, 0.0) / (2 * f), 2.0**-40]
    s[4, 4] = 3e-310  # 2 f s subnormal
    v = rng.normal(size=s.shape) * 1e-2
    v[4, 4] = 7e-310  # a few steps of the subnormal std's
    v[1, 1], s[2, 2], s[3, 3] = np.nan, 0.0, np.nan  # kept as float32 holds them
    got, worst = round_to_std(v, s)
    errors = []
    for (i, j), x in np.ndenumerate(v):
        t = 2 * f * s[i, j]
        if not (np.isfinite(x) and np.isfinite(s[i, j]) and s[i, j] > 0):
            assert got[i, j] == np.float32(x) or np.isnan(x)
            continue
        q = 2.0 ** np.floor(np.log2(t))
        while q > t:  # the logarithm rounded up: one power lower
            q /= 2
        while 2 * q <= t:
            q *= 2
        want = np.float32(round(x / q) * q)
        assert got[i, j] == want, (i, j)
        errors.append(abs(float(want) - x) / s[i, j])
        if abs(x) / q < 2**23 and q >= 2.0**-149:  # float32 holds the value to its step
            assert errors[-1] <= f  # the bound of the module: half a step, f of the std
    # the 2**-40 std: float32 cannot hold the value to it, and the figure says so
    assert worst == max(errors) > f
    # 5 mantissa bits kept: relative error at most 2**-6, the value's power of two kept
    r = rng.normal(size=(5, 5)) * 10.0 ** rng.uniform(-6, 6, size=(5, 5))
    r[0, 0], r[0, 1], r[0, 2] = 0.0, np.inf, np.nan
    kept = round_relative(r).astype(np.float64)
    finite = np.isfinite(r) & (r != 0)
    assert np.all(np.abs(kept[finite] - r[finite]) <= 2.0**-6 * np.abs(r[finite]))
    m, _ = np.frexp(kept[finite])
    assert np.all((m * 2**6) % 1 == 0)  # no bit beyond the sixth significant one
    assert kept[0, 0] == 0
    assert kept[0, 1] == np.inf
    assert np.isnan(kept[0, 2])


@pytest.mark.parametrize("shape", [(250, 400), (7,), ()])
def test_the_compiled_rounding_gives_the_numpy_paths_bits(shape, monkeypatch):
    """The compiled loops against the numpy path, bit for bit: maps of every scale
    (1e-12 to 1e3), with NaN, infinities, zeros, negative and zero stds, subnormal
    values and stds, values a rounding step's half off a step, and the largest error."""
    from gridstrain.results import _precision

    if _precision._load_kernels() is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(11)
    n = int(np.prod(shape))
    scale = 10.0 ** rng.uniform(-12, 3, size=n)
    v = rng.normal(size=n) * scale
    s = np.abs(rng.normal(size=n)) * scale * 10.0 ** rng.uniform(-3, 1, size=n)
    special = [np.nan, np.inf, -np.inf, 0.0, -0.0, 5e-324, -3e-310, 1e38, -3.3e38]
    for k, x in enumerate(special[: n // 3]):
        v[3 * k] = x
        s[3 * k + 1] = [np.nan, np.inf, 0.0, -1.0, 5e-324, 3e-310, 1e30, 2.0, 0.5][k]
    if n > 40:  # values exactly halfway between two steps: round half to even
        q = 2.0 ** np.floor(np.log2(2 * _precision.STD_FRACTION * s[30:40]))
        v[30:40] = (np.arange(10) + 0.5) * q
    v, s = v.reshape(shape), s.reshape(shape)
    got = {}
    for compiled in (False, True):
        monkeypatch.setattr(_precision, "_COMPILED", compiled)
        got[compiled] = (*_precision.round_to_std(v, s), _precision.round_relative(v),
                         _precision.round_relative(s, bits=0))
    for a, b in zip(got[False], got[True], strict=True):
        assert_array_equal(np.atleast_1d(a).view(np.uint8), np.atleast_1d(b).view(np.uint8))
    with pytest.raises(ValueError, match="fit float32"):
        _precision.round_to_std(np.full(shape, 1e39), np.ones(shape))
    monkeypatch.setattr(_precision, "_COMPILED", False)
    with pytest.raises(ValueError, match="fit float32"):
        _precision.round_to_std(np.full(shape, 1e39), np.ones(shape))


@pytest.mark.parametrize("scale", [1.0, 0.0125, 3e5])
def test_rounding_to_the_smaller_std_is_the_products_rounded(scale, monkeypatch):
    """A map rounded against the smaller of its measured and stored std, in a physical
    unit (``scale``), by the compiled loop: the bits of the numpy path's ``fmin``, its
    products by the scale and :func:`round_to_std`; with NaN on either std, stored stds
    above and below the measured ones, zeros, infinities and a subnormal step (which
    the scalar loop rounds)."""
    from gridstrain.results import _precision

    if _precision._load_kernels() is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(17)
    n = 500
    v = rng.normal(size=n) * 10.0 ** rng.uniform(-6, 2, size=n)
    s = np.abs(rng.normal(size=n)) * 10.0 ** rng.uniform(-7, 1, size=n)
    stored = _precision.round_relative(s)
    v[:6] = [np.nan, np.inf, 0.0, -0.0, 1e-310, 3.0]
    s[6:12] = [np.nan, 0.0, np.inf, -1.0, 1e-320, 2.0]
    stored[12:15] = [np.nan, 0.0, np.inf]
    got = {}
    for compiled in (False, True):
        monkeypatch.setattr(_precision, "_COMPILED", compiled)
        got[compiled] = _precision.round_to_least_std(v, s, stored, scale=scale)
    want = _precision.round_to_std(v * scale, np.fmin(s, stored) * scale)
    for g in got.values():
        assert_array_equal(g[0].view(np.uint32), want[0].view(np.uint32))
        assert np.float64(g[1]).tobytes() == np.float64(want[1]).tobytes()


@pytest.mark.parametrize("deflate", ["isal", "zlib"])
def test_a_chunk_encoded_by_the_compiled_loops_is_the_one_hdf5_writes(deflate, held, tmp_path,
                                                                      monkeypatch):
    """Each compressed map's chunk (rounded maps, std maps, maps in physical units, the
    validity), shuffled, deflated and checksummed by gridstrain's loops and written
    directly, decodes through HDF5's own filters (checksum verified) to the values
    HDF5's filter pipeline stores, deflated by ISA-L or by zlib. With zlib the
    compressed bytes themselves are compared, where Python's zlib is HDF5's (another
    zlib build may deflate otherwise, validly); ISA-L's are other bytes, of the same
    format."""
    from gridstrain.results import _layout, _precision

    if _precision._load_kernels() is None:
        pytest.skip("numba is not installed")
    if deflate == "isal":
        pytest.importorskip("isal")
        monkeypatch.setattr(_layout, "_DEFLATE", None)  # chosen again: ISA-L's
        assert _layout._deflate() is not zlib.compress
    else:
        monkeypatch.setattr(_layout, "_DEFLATE", zlib.compress)
    levels = []  # the deflate level of each map written directly (None: by HDF5)
    decide = _layout._deflate_level

    def counted(ds, arr):
        levels.append(decide(ds, arr))
        return levels[-1]

    monkeypatch.setattr(_layout, "_deflate_level", counted)
    paths = {}
    for compiled in (False, True):
        monkeypatch.setattr(_precision, "_COMPILED", compiled)
        paths[compiled] = save_result(held, tmp_path / f"{compiled}.h5", pixel_size=PS,
                                      unit="mm")
    # the compiled run wrote its compressed maps directly (this test is about them)
    assert sum(v is not None for v in levels) >= 4
    with h5py.File(paths[False], "r") as a, h5py.File(paths[True], "r") as b:
        names = [n for n, d in a.items() if isinstance(d, h5py.Dataset)
                 and d.compression == "gzip" and d.ndim == 3 and d.chunks[0] == 1]
        # HDF5's deflate of the first chunk (its last 4 bytes the checksum) against
        # Python's zlib at the same level
        _, raw = a[names[0]].id.read_direct_chunk((0, 0, 0))
        level = a[names[0]].compression_opts
        same_zlib = deflate == "zlib" and \
            zlib.compress(zlib.decompress(raw[:-4]), level) == raw[:-4]
        assert {"ux", "exx_std", "ux_phys", "valid"} <= set(names)
        for name in names:
            assert b[name].id.get_create_plist().get_nfilters() == 3
            for k in range(a[name].shape[0]):
                assert_array_equal(b[name][k], a[name][k])  # Fletcher-32 checked
            if same_zlib:
                for k in range(a[name].shape[0]):
                    want = a[name].id.read_direct_chunk((k, 0, 0))
                    assert b[name].id.read_direct_chunk((k, 0, 0)) == want, (name, k)


@pytest.mark.parametrize("compiled", [False, True])
def test_a_std_too_small_for_any_step_keeps_the_value(compiled, monkeypatch):
    """A std whose step underflows to 0 (5e-324), or a value so large against its std
    that the step lies below its last float64 bit, keeps the value as float32 casts
    it: never a step of 0.5 or an infinity for a finite value; the error attribute
    says how far float32 is then from a tenth of the std."""
    from gridstrain.results import _precision

    if compiled and _precision._load_kernels() is None:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(_precision, "_COMPILED", compiled)
    v = np.array([0.3, 1.0, 1e10, 0.3, 2.0])
    s = np.array([5e-324, 1e-318, 1e-300, 1e-323, 1e-9])
    rounded, worst = _precision.round_to_std(v, s)
    assert_array_equal(rounded, v.astype(np.float32))
    assert worst == np.inf  # float32 cannot hold 0.3 to a tenth of 5e-324
