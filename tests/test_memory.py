"""The memory budget: sizes, the memory available, and refusals before allocating.

The cgroup files are written here, in a temporary tree laid out as the kernel lays
out /sys/fs/cgroup; the decompression bomb is a deflate TIFF of zeros whose header
declares a frame larger than the budget.
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from gridstrain._runtime import memory as _memory
from gridstrain.cli import main
from gridstrain.io import MemoryBudgetError, check_fits, memory_budget, open_series, read_mask

GiB, MiB = 2**30, 2**20


@pytest.mark.parametrize(("text", "nbytes"), [("3G", 3 * GiB), ("500M", 500 * MiB),
                                              ("1.5GiB", 3 * GiB // 2), ("2048k", 2 * MiB),
                                              ("1000", 1000), (" 2 TB ", 2 * 2**40)])
def test_sizes(text, nbytes):
    assert _memory.parse_size(text) == nbytes


@pytest.mark.parametrize("text", ["", "0", "-1G", "3X", "G", "three", None, True])
def test_bad_sizes_name_the_option(text):
    with pytest.raises(ValueError, match="--memory-budget must be a positive size"):
        _memory.parse_size(text, name="--memory-budget")


def _write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_cgroup_v2_takes_the_tightest_level_and_counts_the_page_cache_free(tmp_path):
    # the job's own group: 1000 MiB limit, 400 used of which 100 are inactive cache;
    # its parent: 600 limit, 500 used -> 100 MiB free, the tighter of the two
    _write(tmp_path / "a/b/memory.max", f"{1000 * MiB}\n")
    _write(tmp_path / "a/b/memory.current", f"{400 * MiB}\n")
    _write(tmp_path / "a/b/memory.stat", f"anon 1\ninactive_file {100 * MiB}\n")
    _write(tmp_path / "a/memory.max", f"{600 * MiB}\n")
    _write(tmp_path / "a/memory.current", f"{500 * MiB}\n")
    _write(tmp_path / "memory.max", "max\n")  # the root: no limit
    _write(tmp_path / "memory.current", f"{10 * GiB}\n")
    free = _memory._cgroup_free(tmp_path, "/a/b", "memory.max", "memory.current",
                                "inactive_file")
    assert free == 100 * MiB
    _write(tmp_path / "a/memory.max", "max\n")
    free = _memory._cgroup_free(tmp_path, "/a/b", "memory.max", "memory.current",
                                "inactive_file")
    assert free == (1000 - 400 + 100) * MiB


def test_cgroup_v1_without_limit_is_no_limit(tmp_path):
    # v1 writes "no limit" as the largest page-aligned 64-bit value
    _write(tmp_path / "memory.limit_in_bytes", "9223372036854771712\n")
    _write(tmp_path / "memory.usage_in_bytes", f"{GiB}\n")
    assert _memory._cgroup_free(tmp_path, "/x", "memory.limit_in_bytes",
                                "memory.usage_in_bytes", "total_inactive_file") is None
    _write(tmp_path / "memory.limit_in_bytes", f"{3 * GiB}\n")
    _write(tmp_path / "memory.stat", f"total_inactive_file {GiB}\n")
    # a container sees its own group at the root of the mount
    assert _memory._cgroup_free(tmp_path, "/x", "memory.limit_in_bytes",
                                "memory.usage_in_bytes", "total_inactive_file") == 3 * GiB


def test_available_memory_is_the_least_source(monkeypatch):
    monkeypatch.setattr(_memory, "_cgroup_paths", lambda: ("/", "/"))
    monkeypatch.setattr(_memory, "_cgroup_free",
                        lambda root, *a: 2 * GiB if "memory" in str(root) else None)
    monkeypatch.setattr(_memory, "_proc_kib", lambda path, key: 5 * GiB)
    assert _memory.available_memory() == (2 * GiB, "the cgroup's memory.limit_in_bytes")
    with memory_budget("1G"):
        assert _memory.available_memory() == (GiB, "the memory budget")
    assert _memory.available_memory()[0] == 2 * GiB


def test_check_fits_says_need_availability_and_what_to_do():
    check_fits(MiB, what="x")  # a megabyte fits anywhere this runs
    with memory_budget("1G"), pytest.raises(MemoryBudgetError) as info:
        check_fits(3 * GiB, what="decoding f.tif", advice="crop it")
    assert str(info.value) == ("decoding f.tif needs about 3 GiB more memory, 1 GiB available "
                               "(the memory budget); crop it")


def _bomb(path, shape):
    """A deflate TIFF of zeros: a few kB on disk, ``shape`` uint16 once decoded."""
    tifffile.imwrite(path, np.zeros(shape, np.uint16), compression="zlib",
                     photometric="minisblack")


@pytest.fixture
def never_decoded(monkeypatch):
    def decode(*a, **k):
        raise AssertionError("a page was decoded")

    monkeypatch.setattr(tifffile.TiffPage, "asarray", decode)


def test_decompression_bomb_refused_from_its_header(tmp_path, never_decoded):
    bomb = tmp_path / "bomb.tif"
    _bomb(bomb, (2048, 4096))  # 16 MiB decoded, kB on disk
    assert bomb.stat().st_size < 200_000
    with memory_budget("8M"), pytest.raises(MemoryBudgetError,
                                            match=r"reference: decoding .*bomb\.tif \(2048 x "
                                                  r"4096 px of uint16, as its header"):
        open_series(bomb, name="reference")
    with memory_budget("8M"), pytest.raises(MemoryBudgetError, match="mask: decoding"):
        read_mask(bomb, (2048, 4096))


def test_decompression_bomb_is_one_line_on_the_command_line(tmp_path, capsys, never_decoded):
    bomb = tmp_path / "bomb.tif"
    _bomb(bomb, (2048, 4096))
    rc = main(["measure", str(bomb), str(bomb), "-o", str(tmp_path / "o.h5"),
               "--memory-budget", "8M"])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "needs about" in err
    assert "8 MiB available (the memory budget)" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bomb.tif"]


def test_measurement_refused_before_any_transform(tmp_path, capsys, monkeypatch):
    """The estimate of the whole measurement against a budget below it: refused
    before the first frame is transformed, with the estimate and what to do."""
    import gridstrain.series._loop as gp

    def never(*a, **k):
        raise AssertionError("a pass was run")

    monkeypatch.setattr(gp, "_run_pass", never)
    # what this process holds already is taken off the estimate: fixed here, so that
    # the memory earlier tests left in the test process does not decide the outcome
    monkeypatch.setattr(_memory, "resident_memory", lambda: 64 * 2**20)
    frames = np.full((2, 128, 160), 1000, np.uint16)
    tifffile.imwrite(tmp_path / "ref.tif", frames, photometric="minisblack")
    # the frames' check passes (2 x 40 kB); the measurement's fixed part does not
    rc = main(["measure", str(tmp_path / "ref.tif"), str(tmp_path / "ref.tif"), "-o",
               str(tmp_path / "o.h5"), "--pitch", "5", "--memory-budget", "1M",
               "--phase-maps"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert len(err.strip().splitlines()) == 1, err
    assert "measuring 1 state(s) of 128 x 160 px with method A" in err
    assert "1 MiB available (the memory budget)" in err
    assert "without --phase-maps" in err
    assert "--memory-budget" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ref.tif"]


def test_model_grows_with_pixels_methods_and_held_states():
    a = _memory.measurement_bytes((1024, 1024), method="A")
    assert _memory.measurement_bytes((2048, 2048), method="A") - a == \
        3 * (a - _memory.measurement_bytes((0, 0)))
    assert _memory.measurement_bytes((1024, 1024), method="C") > a
    held = [_memory.measurement_bytes((1024, 1024), n_states=n, held_states=True)
            for n in (1, 2, 3)]
    assert held[0] > a
    assert held[2] - held[1] == held[1] - held[0] > 0


@pytest.mark.parametrize("shape", [(96, 128), (700, 700), (1100, 1000), (1600, 1400)])
def test_contrast_step_model_covers_the_bounds_measured_peak(shape):
    """The contrast step's bound allocates a carrier's log-modulus gradients and a
    block of rows' material points beyond its inputs: the budget's figure for it
    (contrast_step_bytes) is at least the peak tracemalloc measures (80 bytes a pixel
    where one block holds the image; 1100 x 1000 px takes two blocks)."""
    import tracemalloc

    from gridstrain.uncertainty import contrast_step_bound, contrast_step_bytes

    rng = np.random.default_rng(3)
    ref = rng.normal(size=(2, *shape)) + 1j * rng.normal(size=(2, *shape)) + 3.0
    dfm = ref * (1.0 + 0.01 * rng.normal(size=(2, *shape)))
    u = rng.normal(0.0, 0.5, (2, *shape))
    valid = np.ones(shape, dtype=bool)
    # a first call on the same arrays: what a process sets up once (numba's compiled
    # loop, the thread pool its blocks run on) is not the bound's memory
    contrast_step_bound(ref, dfm, u, valid, sigma=5.0)
    tracemalloc.start()
    try:
        contrast_step_bound(ref, dfm, u, valid, sigma=5.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    model = contrast_step_bytes(shape)
    assert model >= peak
    assert model <= 1.3 * peak  # and not a blanket figure: within 30 % above it


def test_budget_check_counts_the_contrast_step(monkeypatch):
    """The estimate the budget checks holds the contrast step's temporaries beside
    the calibrated figures and the motion sums."""
    from gridstrain.series import _inputs
    from gridstrain.stacks.accumulate import motion_sums_bytes
    from gridstrain.uncertainty import contrast_step_bytes

    seen = []
    monkeypatch.setattr(_memory, "check_fits", lambda nbytes, **k: seen.append(nbytes))
    monkeypatch.setattr(_memory, "resident_memory", lambda: 0)

    class Series:
        shape, n_frames = (512, 640), 4

    _inputs._check_memory([Series(), Series()], method="A", held=False)
    assert seen == [_memory.measurement_bytes((512, 640), method="A")
                    + motion_sums_bytes((512, 640), 4) + contrast_step_bytes((512, 640))]
