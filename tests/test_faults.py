"""Faults and bad inputs: one line on stderr, a non-zero exit, nothing left behind.

Each case runs the command line as a user would and checks three things: exactly
one line on stderr, a non-zero exit code, and no output file and no temporary
file in the output folder. Then ``--overwrite``: gridstrain replaces only the
files it wrote, whatever folder it is pointed at.

The series are written here with numpy and tifffile only: a sinusoidal grid of
pitch 5 px (two crossed cosines, 12-bit levels stored x16 in uint16, Gaussian
noise of 5 levels), the loaded state translated by 0.3 px and stretched by 1e-3
along x. Nothing of gridstrain's generator is used.
"""

from __future__ import annotations

import errno
import io
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import tifffile

import gridstrain
from gridstrain import io as gio
from gridstrain.cli import main
from gridstrain.io import MARKER_NAME, read_hdf5
from gridstrain.io import _files as gio_files  # where gridstrain's writes call os and open

N, PITCH = 96, 5.0
SRC = str(Path(gridstrain.__file__).resolve().parents[1])


def _grid(shape, *, ux=0.0, strain=0.0, rng):
    """12-bit grid frames stored x16: A (1 + 0.8 (cos 2pi x/p + cos 2pi y/p) / 2)."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    x0 = xx - ux - strain * (xx - shape[1] / 2)  # reference point of each pixel
    img = 2000.0 * (1 + 0.4 * (np.cos(2 * np.pi * x0 / PITCH)
                               + np.cos(2 * np.pi * yy / PITCH)))
    img = np.clip(np.rint(img + rng.normal(0, 5, shape)), 0, 4095)
    return (img * 16).astype(np.uint16)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("faults")
    rng = np.random.default_rng(15)
    ref = np.stack([_grid((N, N), rng=rng) for _ in range(5)])
    load = np.stack([_grid((N, N), ux=0.3, strain=1e-3, rng=rng) for _ in range(5)])
    tifffile.imwrite(root / "ref.tif", ref, photometric="minisblack")
    tifffile.imwrite(root / "load.tif", load, photometric="minisblack")
    # a multi-page stack cut at 60 % of its bytes
    stack = root / "stack.tif"
    tifffile.imwrite(stack, ref, photometric="minisblack")
    raw = stack.read_bytes()
    (root / "truncated.tif").write_bytes(raw[: int(0.6 * len(raw))])
    tifffile.imwrite(root / "small.tif", ref[0, :16, :16], photometric="minisblack")
    return root


def _run(argv):
    try:
        return main([os.fspath(a) if isinstance(a, Path) else str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _one_line_failure(capsys, rc, folder: Path, *, expect_rc=2) -> str:
    err = capsys.readouterr().err
    assert rc == expect_rc, err
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1, err
    assert _leftovers(folder) == []  # no output, no temporary file
    return lines[0]


# ------------------------------------------------------------------ bad inputs


def test_truncated_stack_names_file_and_page(data, tmp_path, capsys):
    rc = _run(["measure", data / "truncated.tif", data / "load.tif", "-o",
               tmp_path / "o.h5", "--quiet"])
    line = _one_line_failure(capsys, rc, tmp_path)
    assert "truncated.tif" in line
    assert "page 1" in line  # the first page that cannot be read
    assert "truncated" in line


@pytest.mark.parametrize("compression", ["zstd", "lzw"])
def test_compressed_tiffs_are_read(data, tmp_path, compression):
    pytest.importorskip("imagecodecs")
    raw = tifffile.imread(data / "ref.tif")
    p = tmp_path / f"{compression}.tif"
    tifffile.imwrite(p, raw, photometric="minisblack", compression=compression)
    series = gio.open_series(p)
    np.testing.assert_array_equal(series.read(3, dtype=None), raw[3])  # lossless


def test_missing_codec_names_it_and_the_package(data, tmp_path):
    p = tmp_path / "z.tif"
    tifffile.imwrite(p, tifffile.imread(data / "ref.tif")[0], photometric="minisblack",
                     compression="zstd")
    out = tmp_path / "out"
    out.mkdir()
    # a Python without imagecodecs: the module is blocked before tifffile imports it
    code = textwrap.dedent(f"""
        import sys
        sys.modules["imagecodecs"] = None
        sys.modules["compression"] = None
        from gridstrain.cli import main
        sys.exit(main(["measure", {str(p)!r}, {str(data / 'load.tif')!r}, "-o",
                       {str(out / 'o.h5')!r}, "--quiet"]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=SRC), timeout=120)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "ZSTD" in r.stderr
    assert "pip install imagecodecs" in r.stderr
    assert _leftovers(out) == []


def test_huge_sigma_refused_with_the_limit(data, tmp_path, capsys):
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5",
               "--sigma", "1e6", "--quiet"])
    line = _one_line_failure(capsys, rc, tmp_path)
    # (96 - 1) / (2 * 4): the window's band of 4 sigmas on each side must leave a pixel
    assert "sigma must be at most 11.88 px" in line


def test_guess_beyond_the_image_refused(data, tmp_path, capsys):
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5",
               "--guess", "1e6", "1e6", "--quiet"])
    line = _one_line_failure(capsys, rc, tmp_path)
    assert "guess must lie within the frame" in line
    assert f"< {N} px" in line


def test_no_valid_pixel_is_not_a_result(data, tmp_path, capsys):
    # a specimen of 30 x 30 px: the band of 4 sigmas (20 px) inside its edge leaves
    # nothing
    mask = np.zeros((N, N), np.uint8)
    mask[30:60, 30:60] = 255
    tifffile.imwrite(tmp_path.parent / f"{tmp_path.name}_mask.tif", mask)
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5",
               "--mask", tmp_path.parent / f"{tmp_path.name}_mask.tif", "--quiet",
               "--pitch", "5"])
    line = _one_line_failure(capsys, rc, tmp_path)
    assert "no valid pixel" in line


@pytest.mark.parametrize("pitch", [None, "5"])
def test_tiny_image_says_too_small_with_the_minimum(data, tmp_path, capsys, pitch):
    extra = ["--pitch", pitch] if pitch else []
    rc = _run(["measure", data / "small.tif", data / "small.tif", "-o", tmp_path / "o.h5",
               "--quiet", *extra])
    line = _one_line_failure(capsys, rc, tmp_path)
    assert "16 x 16 px" in line
    assert "too small" in line
    if pitch:  # 2 * ceil(4 sigmas of 5 px) + 1
        assert "at least 41 x 41 px" in line


def test_mask_path_with_a_non_utf8_byte(data, tmp_path, capsys):
    name = os.fsdecode(b"mask\xff.tif")  # Python decodes the byte as a surrogate
    mask = np.full((N, N), 255, np.uint8)
    tifffile.imwrite(tmp_path / name, mask)
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5",
               "--mask", tmp_path / name, "--quiet"])
    assert rc == 0, capsys.readouterr().err
    # the file names the mask, its byte that is not UTF-8 written \xff
    attrs = read_hdf5(tmp_path / "o.h5")["attrs"]
    assert attrs["mask_file"] == str(tmp_path / "mask") + "\\xff.tif"


# ------------------------------------------------------------------ full disk


class _OsProxy:
    """``os`` for gridstrain.io, whose writes to files under ``folder`` fail (ENOSPC)."""

    def __init__(self, folder: Path):
        self._folder = str(folder)
        self._fds: set[int] = set()

    def __getattr__(self, name):
        return getattr(os, name)

    def open(self, path, flags, *args):
        fd = os.open(path, flags, *args)
        if os.fspath(path).startswith(self._folder):
            self._fds.add(fd)
        return fd

    def write(self, fd, data):
        if fd in self._fds:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return os.write(fd, data)


class _FullFile:
    """A text file whose writes fail with ENOSPC after 1000 characters."""

    def __init__(self, fh):
        self._fh, self._n = fh, 0

    def write(self, text):
        self._n += len(text)
        if self._n > 1000:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._fh.write(text)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()


def _disk_full_under(monkeypatch, folder: Path) -> None:
    """Every write of gridstrain.io into ``folder`` fails as on a full disk."""
    monkeypatch.setattr(gio_files, "os", _OsProxy(folder))

    def fake_open(path, *args, **kw):
        fh = open(path, *args, **kw)  # noqa: SIM115 (closed by the caller's with)
        return _FullFile(fh) if os.fspath(path).startswith(str(folder)) else fh

    monkeypatch.setattr(gio_files, "open", fake_open, raising=False)


@pytest.mark.parametrize("what", ["hdf5", "csv", "figures"])
def test_disk_full_is_one_line_and_leaves_nothing(data, tmp_path, capsys, monkeypatch, what):
    out = tmp_path / "out"
    out.mkdir()
    argv = ["measure", data / "ref.tif", data / "load.tif", "--quiet"]
    if what == "hdf5":
        argv += ["-o", out / "o.h5"]
    else:  # the HDF5 file is written elsewhere; the second output meets the full disk
        argv += ["-o", tmp_path / "o.h5"]
        argv += ["--csv", out / "o.csv"] if what == "csv" else ["--figures", out / "figs"]
    _disk_full_under(monkeypatch, out)
    rc = _run(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert len(err.strip().splitlines()) == 1, err
    assert "no space left on device (ENOSPC); nothing was written" in err
    assert f"cannot write {out}" in err
    # no figure, no temporary file, not even the folder the run created; and the
    # result file the run had completed elsewhere is gone with the rest
    assert _leftovers(out) == []
    assert not (tmp_path / "o.h5").exists()


def test_file_size_limit_is_one_line_and_leaves_nothing(data, tmp_path):
    """A real RLIMIT_FSIZE (``ulimit -f``): the kernel refuses the write with EFBIG."""
    pytest.importorskip("resource")
    out = tmp_path / "out"
    out.mkdir()
    code = textwrap.dedent(f"""
        import resource, sys
        from gridstrain.cli import main
        resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))
        sys.exit(main(["measure", {str(data / 'ref.tif')!r}, {str(data / 'load.tif')!r},
                       "-o", {str(out / 'o.h5')!r}, "--quiet"]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=SRC), timeout=120)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "EFBIG" in r.stderr
    assert str(out / "o.h5") in r.stderr
    assert _leftovers(out) == []


# ------------------------------------------------------------------ signals and memory


def _signalled_in_first_write(data, out: Path, sig: str, *, written: bool):
    """``measure`` in its own process, sending itself ``sig`` from inside its first
    write of the output (after the bytes are written if ``written``): no timing."""
    first, second = ("real(fd, data)", f"os.kill(os.getpid(), signal.{sig})")
    if not written:
        first, second = second, first
    code = textwrap.dedent(f"""
        import os, signal, sys
        import gridstrain.io._files as gio
        from gridstrain.cli import main
        real = os.write
        def write(fd, data):
            {first}
            return {second}
        gio.os = type(sys)("os_proxy")
        gio.os.__dict__.update({{k: getattr(os, k) for k in dir(os)}})
        gio.os.write = write
        sys.exit(main(["measure", {str(data / 'ref.tif')!r}, {str(data / 'load.tif')!r},
                       "-o", {str(out / 'o.h5')!r}, "--quiet"]))
    """)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=SRC), timeout=120)


@pytest.mark.parametrize(("sig", "rc", "word"), [("SIGTERM", 143, "terminated"),
                                                 ("SIGINT", 130, "interrupted")])
def test_signal_during_the_write_cleans_up(data, tmp_path, sig, rc, word):
    out = tmp_path / "out"
    out.mkdir()
    r = _signalled_in_first_write(data, out, sig, written=False)
    assert r.returncode == rc, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert word in r.stderr
    assert _leftovers(out) == []  # the temporary file was removed


def test_memory_error_is_one_line(data, tmp_path, capsys, monkeypatch):
    import gridstrain.cli.measure as cm

    def exhausted(*a, **k):
        raise MemoryError

    monkeypatch.setattr(cm, "measure_series", exhausted)
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5"])
    line = _one_line_failure(capsys, rc, tmp_path)
    assert "out of memory" in line


def test_lost_scheduler_is_one_line(data, tmp_path, capsys, monkeypatch):
    comm = pytest.importorskip("distributed.comm")
    import gridstrain.cli.measure as cm

    def lost(*a, **k):
        raise comm.CommClosedError("in <TCP (closed)>: Stream is closed")

    monkeypatch.setattr(cm, "measure_series", lost)
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5",
               "--quiet"])
    line = _one_line_failure(capsys, rc, tmp_path)
    assert "the Dask cluster failed (CommClosedError" in line


# ------------------------------------------------------------------ --overwrite


def _tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


DEMO = ["demo", "--size", "96", "--pitch", "5", "--steps", "3", "--quiet"]


def test_demo_overwrite_keeps_the_users_files(tmp_path, capsys, monkeypatch):
    """``--out .`` with --overwrite, twice: the user's files stay, byte for byte."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / ".bashrc").write_text("alias ll='ls -l'\n")
    (tmp_path / "thesis").mkdir()
    (tmp_path / "thesis" / "chapter1.tex").write_text("mine")
    mine = _tree(tmp_path)
    for _ in range(2):
        assert _run([*DEMO, "--out", ".", "--overwrite"]) == 0, capsys.readouterr().err
    after = _tree(tmp_path)
    assert {k: after[k] for k in mine} == mine
    # only the demo's files besides, no stray temporary or ".old" folder
    assert sorted({p.name for p in tmp_path.iterdir()}) == sorted(
        [".bashrc", "thesis", MARKER_NAME, "record", "mask.tif", "loads.csv", "maps.h5",
         "truth.h5", "report.html"])


def test_demo_refuses_foreign_frames_even_with_overwrite(tmp_path, capsys):
    exp = tmp_path / "EXP"
    (exp / "record").mkdir(parents=True)
    (exp / "record" / "img_0001.tif").write_bytes(b"the user's frame")
    for flags in ([], ["--overwrite"]):
        rc = _run([*DEMO, "--out", exp, *flags])
        err = capsys.readouterr().err
        assert rc == 2
        assert len(err.strip().splitlines()) == 1
        assert "img_0001.tif was not written by gridstrain" in err
    assert _tree(exp) == {"record/img_0001.tif": b"the user's frame"}


def test_demo_refuses_its_own_file_once_changed(tmp_path, capsys):
    exp = tmp_path / "EXP"
    assert _run([*DEMO, "--out", exp]) == 0
    (exp / "truth.h5").write_bytes(b"edited by the user")
    rc = _run([*DEMO, "--out", exp, "--overwrite"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "truth.h5 has changed since gridstrain wrote it" in err
    assert (exp / "truth.h5").read_bytes() == b"edited by the user"


def test_figures_overwrite_replaces_only_gridstrain_figures(data, tmp_path, capsys):
    figs = tmp_path / "figs"
    figs.mkdir()
    (figs / "exx_state0.png").write_bytes(b"the user's own figure")
    argv = ["measure", data / "ref.tif", data / "load.tif", "--quiet", "--figures", figs]
    rc = _run([*argv, "-o", tmp_path / "a.h5", "--overwrite"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "exx_state0.png exists and was not written by gridstrain" in err
    assert _leftovers(figs) == ["exx_state0.png"]
    assert not (tmp_path / "a.h5").exists()
    # in a folder of the user's other files: written beside them, replaced alone
    (figs / "exx_state0.png").rename(figs / "notes.png")
    for _ in range(2):
        assert _run([*argv, "-o", tmp_path / "a.h5", "--overwrite"]) == 0
    manifest = json.loads((figs / MARKER_NAME).read_text())["files"]
    assert "notes.png" not in manifest
    assert (figs / "notes.png").read_bytes() == b"the user's own figure"


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def _refused(capsys, rc, folder: Path, kept) -> str:
    """The one line of a refusal that left ``folder`` holding ``kept`` only."""
    err = capsys.readouterr().err
    assert rc == 2, err
    assert len(err.strip("\n").split("\n")) == 1, err
    assert _leftovers(folder) == sorted(kept)  # no output, no temporary file
    return err.strip()


@pytest.mark.parametrize("what", ["result", "report"])
def test_overwrite_never_replaces_a_single_file_gridstrain_did_not_write(
        data, tmp_path, capsys, what):
    """``measure -o`` and ``report -o`` with --overwrite: the user's file of that name,
    or a link to one, is refused with one line and stays byte for byte; gridstrain's
    own file, listed in the folder's marker with its content, is replaced."""
    out = tmp_path / ("a.h5" if what == "result" else "r.html")
    src = tmp_path / "src.h5"
    if what == "result":
        argv = ["measure", data / "ref.tif", data / "load.tif", "--quiet", "-o", out]
    else:
        assert _run(["measure", data / "ref.tif", data / "load.tif", "--quiet", "-o",
                     src]) == 0
        argv = ["report", src, "-o", out]
    theirs = tmp_path / "thesis.tex"
    theirs.write_bytes(b"the user's thesis")
    for planted in ("file", "link"):
        if planted == "file":
            out.write_bytes(b"the user's own file of that name")
        else:
            out.unlink()
            out.symlink_to(theirs)
        before = _leftovers(tmp_path)
        rc = _run([*argv, "--overwrite"])
        line = _refused(capsys, rc, tmp_path, before)
        assert f"{out} exists and was not written by gridstrain" in line
        assert "--overwrite replaces only gridstrain's own outputs" in line
    assert out.is_symlink()
    assert theirs.read_bytes() == b"the user's thesis"
    out.unlink()
    # written by gridstrain: listed with its digest, then replaced by --overwrite
    assert _run(argv) == 0, capsys.readouterr().err
    listed = json.loads((tmp_path / MARKER_NAME).read_text())["outputs"]
    assert listed[out.name]["sha256"] == _sha256(out)
    assert listed[out.name]["size"] == out.stat().st_size
    assert _run([*argv, "--overwrite"]) == 0, capsys.readouterr().err
    listed = json.loads((tmp_path / MARKER_NAME).read_text())["outputs"]
    assert listed[out.name]["sha256"] == _sha256(out)
    # changed since by the user: refused, kept
    with open(out, "ab") as fh:
        fh.write(b"the user's note")
    edited = out.read_bytes()
    rc = _run([*argv, "--overwrite"])
    line = _refused(capsys, rc, tmp_path, _leftovers(tmp_path))
    assert "or has changed since" in line
    assert out.read_bytes() == edited


def test_a_gauge_csv_written_by_gridstrain_is_replaced(data, tmp_path, capsys):
    res = tmp_path / "a.h5"
    assert _run(["measure", data / "ref.tif", data / "load.tif", "--quiet", "-o", res]) == 0
    csv = tmp_path / "g.csv"
    for flags in ([], ["--overwrite"]):
        assert _run(["gauge", res, "-o", csv, *flags]) == 0, capsys.readouterr().err
    # a marker that is not gridstrain's lists nothing: the CSV is then refused
    (tmp_path / MARKER_NAME).write_text("my notes")
    rc = _run(["gauge", res, "-o", csv, "--overwrite"])
    line = _refused(capsys, rc, tmp_path, _leftovers(tmp_path))
    assert "was not written by gridstrain" in line


def test_signal_module_untouched_after_main(data, tmp_path):
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5",
          "--quiet"])
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_an_all_invalid_result_is_never_written(data, tmp_path, capsys, monkeypatch):
    """Whatever the cause, a state without one valid pixel is an error, not a file."""
    import dataclasses

    import gridstrain.kinematics.tracking as gp

    real = gp.Tracker.measure

    def all_invalid(self, *a, **k):  # a state measured, none of its pixels valid
        res, rec, notes = real(self, *a, **k)
        return dataclasses.replace(res, valid=np.zeros_like(res.valid)), rec, notes

    monkeypatch.setattr(gp.Tracker, "measure", all_invalid)
    # each state written as it is measured, and with every state held to the end
    for extra in ([], ["--phase-maps"]):
        rc = _run(["measure", data / "ref.tif", data / "load.tif", "-o", tmp_path / "o.h5",
                   "--quiet", *extra])
        line = _one_line_failure(capsys, rc, tmp_path)
        assert "load: no valid pixel, nothing written" in line  # the state, by its file


def test_killed_scheduler_is_one_line_within_bounded_time(data, tmp_path):
    """A real scheduler (its own process) killed once the first series is submitted:
    the command ends with one line, within Dask's reconnection timeout (3 s here),
    and writes nothing. The kill is tied to the submission, not to a time."""
    pytest.importorskip("distributed")
    out = tmp_path / "out"
    out.mkdir()
    code = textwrap.dedent(f"""
        import socket, subprocess, sys, time
        import dask
        from gridstrain.series import _distributed as gd
        from gridstrain.cli import main

        dask.config.set({{"distributed.comm.timeouts.connect": "3s"}})
        with socket.socket() as s:  # a free port for the scheduler
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        sched = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
             "--port", str(port), "--dashboard-address", "127.0.0.1:0"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(600):  # until it listens (at most 60 s)
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
                break
            except OSError:
                time.sleep(0.1)
        real = gd._submit_pass

        def submit(client, *a, **k):
            pending = real(client, *a, **k)
            sched.kill()
            sched.wait()
            return pending

        gd._submit_pass = submit
        try:
            rc = main(["measure", {str(data / 'ref.tif')!r}, {str(data / 'load.tif')!r},
                       "-o", {str(out / 'o.h5')!r}, "--quiet",
                       "--scheduler", f"tcp://127.0.0.1:{{port}}"])
        finally:
            sched.kill()
        sys.exit(rc)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=SRC), timeout=180)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "the Dask cluster failed" in r.stderr
    assert _leftovers(out) == []


# ------------------------------------------------------------------ forged markers


def _forge_marker(folder: Path, files: dict) -> None:
    (folder / MARKER_NAME).write_text(json.dumps({"gridstrain": "0.1.0", "files": files}))


def _digest_entry(path: Path) -> dict:
    import hashlib

    data = path.read_bytes()
    return {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def test_forged_marker_through_a_linked_directory_deletes_nothing(data, tmp_path, capsys):
    """A directory link inside the figures folder, pointing outside, and a marker
    listing the victim through it with its true size and digest: refused, in one
    line, before any work; the victim and the link stay."""
    outside = tmp_path / "outside"
    outside.mkdir()
    victim = outside / "exx_state0.png"
    victim.write_bytes(b"the user's thesis figure")
    figs = tmp_path / "figs"
    figs.mkdir()
    (figs / "sub").symlink_to(outside, target_is_directory=True)
    (figs / "direct.png").symlink_to(victim)
    for listed in ("sub/exx_state0.png", "direct.png"):
        _forge_marker(figs, {listed: _digest_entry(victim)})
        rc = _run(["measure", data / "ref.tif", data / "load.tif", "--quiet", "--figures",
                   figs, "-o", tmp_path / "a.h5", "--overwrite"])
        err = capsys.readouterr().err
        assert rc == 2, err
        assert len(err.strip().splitlines()) == 1, err
        assert "symbolic link" in err
        assert "never deletes" in err
        assert victim.read_bytes() == b"the user's thesis figure"
        assert (figs / "sub").is_symlink()
        assert (figs / "direct.png").is_symlink()
        assert not (tmp_path / "a.h5").exists()


def test_marker_listing_a_users_file_with_its_stamp_deletes_nothing(tmp_path):
    """A marker listing the user's file with its exact size and modification time
    (the stamp older markers held), or with a digest of other content: the file's
    content is not what gridstrain wrote, so it is never replaced or deleted."""
    folder = tmp_path / "figs"
    folder.mkdir()
    mine = folder / "exx_state0.png"
    mine.write_bytes(b"mine")
    st = mine.stat()
    other = tmp_path / "other"
    other.write_bytes(b"what gridstrain wrote once")
    for entry, message in (([st.st_size, st.st_mtime_ns], "without a content digest"),
                           (_digest_entry(other), "has changed since gridstrain wrote it")):
        _forge_marker(folder, {"exx_state0.png": entry})
        with pytest.raises(FileExistsError, match=message) as info:
            gio.OutputDirectory(folder, ["exx_state0.png"], overwrite=True).prepare()
        assert "\n" not in str(info.value)
        assert mine.read_bytes() == b"mine"


def test_marker_leaving_the_folder_is_not_a_manifest(tmp_path):
    folder = tmp_path / "figs"
    folder.mkdir()
    (tmp_path / "victim").write_bytes(b"v")
    _forge_marker(folder, {"../victim": _digest_entry(tmp_path / "victim")})
    with pytest.raises(ValueError, match="is not a gridstrain manifest"):
        gio.OutputDirectory(folder, ["a.png"], overwrite=True)
    assert (tmp_path / "victim").read_bytes() == b"v"


def test_own_files_are_replaced_by_their_digest(tmp_path):
    """What gridstrain wrote and listed is replaced with overwrite, whatever its
    modification time: the digest, not the stamp, recognises it."""
    folder = tmp_path / "figs"
    d = gio.OutputDirectory(folder, ["a.png", "sub/b.png"])
    d.prepare()
    d.write("a.png", b"first")
    d.write("sub/b.png", b"second")
    os.utime(folder / "a.png", ns=(0, 0))  # a copy (cp -r, unzip) changes the stamp
    again = gio.OutputDirectory(folder, ["a.png"], overwrite=True)
    again.prepare()
    assert sorted(p.name for p in folder.rglob("*") if p.is_file()) == [MARKER_NAME]


# ------------------------------------------------------------------ temporary files


def test_a_killed_run_leaves_a_temporary_file_that_the_next_run_removes(data, tmp_path):
    """SIGKILL inside the first write of the output (no clean-up can run): its
    temporary file stays; the next run into that folder removes it and writes."""
    out = tmp_path / "out"
    out.mkdir()
    r = _signalled_in_first_write(data, out, "SIGKILL", written=True)
    assert r.returncode == -signal.SIGKILL, r.stderr
    left = _leftovers(out)
    assert len(left) == 1
    assert left[0].startswith(".o.h5.")
    assert left[0].endswith(".tmp.h5")
    assert _run(["measure", data / "ref.tif", data / "load.tif", "-o", out / "o.h5",
                 "--quiet"]) == 0
    # the result and the marker listing it as gridstrain's (for --overwrite)
    assert _leftovers(out) == sorted([MARKER_NAME, "o.h5"])


def test_sweep_keeps_files_of_live_processes_and_others(tmp_path):
    """Only gridstrain's own pattern, from a process of this machine that ended."""
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)
        tag = gio_files._host_tag()
        names = {"dead": f".o.h5.{int(dead.stdout)}-{tag}-0123456789ab.tmp.h5",
                 "live": f".o.h5.{live.pid}-{tag}-0123456789ab.tmp.h5",
                 "other host": f".o.h5.{int(dead.stdout)}-00000000-0123456789ab.tmp.h5",
                 "user's": "o.h5.tmp.h5"}
        if tag == "00000000":  # pragma: no cover
            pytest.skip("this machine's tag is the other host's")
        for name in names.values():
            (tmp_path / name).write_bytes(b"x")
        removed = gio_files.sweep_temporary_files(tmp_path)
    finally:
        live.kill()
        live.wait()
    assert [p.name for p in removed] == [names["dead"]]
    assert sorted(_leftovers(tmp_path)) == sorted(n for k, n in names.items() if k != "dead")


# ------------------------------------------------------------------ a run that fails


class _FailingOs(_OsProxy):
    """``os`` whose writes to files ending in ``suffix`` fail (ENOSPC)."""

    def __init__(self, suffix: str):
        super().__init__(Path("/"))
        self._suffix = suffix

    def open(self, path, flags, *args):
        fd = os.open(path, flags, *args)
        if os.fspath(path).endswith(self._suffix):
            self._fds.add(fd)
        return fd


@pytest.mark.parametrize("failing", [".vti", ".html", ".mat"])
def test_a_failure_in_the_last_outputs_removes_every_output(data, tmp_path, capsys,
                                                            monkeypatch, failing):
    """The disk fills while the exports or the report are written, after the result
    file and the figures are complete: the run removes all it wrote (result,
    figures and their folder, exports, report, marker), then says one line."""
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(gio_files, "os", _FailingOs(failing))
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "--quiet", "-o", out / "o.h5",
               "--export", "csv,mat,vtk", "--report", out / "r.html", "--figures",
               out / "figs", "--csv", out / "rows.csv"])
    line = _one_line_failure(capsys, rc, out)
    assert "no space left on device (ENOSPC)" in line


def test_a_failure_keeps_what_was_there_before(data, tmp_path, capsys, monkeypatch):
    """The files of the folder that the run did not write stay, and so does an
    existing figures folder (only emptied of what the run added)."""
    out = tmp_path / "out"
    (out / "figs").mkdir(parents=True)
    (out / "notes.txt").write_text("mine")
    (out / "figs" / "sketch.png").write_bytes(b"mine too")
    monkeypatch.setattr(gio_files, "os", _FailingOs(".html"))
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "--quiet", "-o", out / "o.h5",
               "--figures", out / "figs", "--report", out / "r.html"])
    assert rc == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert _tree(out) == {"notes.txt": b"mine", "figs/sketch.png": b"mine too"}


# ------------------------------------------------------------------ signals at any moment


_HOLD = """
import os, sys, time
import gridstrain.cli.measure as cm
from gridstrain.cli import main
real = cm._print
def hold(*a, **k):  # every output written: held here until the signal comes
    real(*a, **k)
    time.sleep(60)
cm._print = hold
print("started", flush=True)
sys.exit(main(sys.argv[1:]))
"""


def _signal_cases():
    """SIGINT at every moment; SIGTERM, handled by the same code, at two of them in the
    default run and at the others in the slow one."""
    for sig, rc, word in ((signal.SIGINT, 130, "interrupted"),
                          (signal.SIGTERM, 143, "terminated")):
        for delay in (0.1, 0.5, 1.0, 2.5):
            slow = sig == signal.SIGTERM and delay in (0.5, 2.5)
            yield pytest.param(delay, sig, rc, word,
                               marks=pytest.mark.slow if slow else (),
                               id=f"{int(sig)}-{rc}-{word}-{delay}")


@pytest.mark.parametrize(("delay", "sig", "rc", "word"), list(_signal_cases()))
def test_a_signal_at_any_moment_is_one_line_and_leaves_nothing(data, tmp_path, delay, sig,
                                                               rc, word):
    """The command started in its own process, the signal sent ``delay`` seconds after
    it started: while the modules load, the series are read, the outputs are
    written or once they are all written. The outcome does not depend on when:
    one line, exit 130 (SIGINT) or 143 (SIGTERM), nothing left in the folder."""
    import time

    out = tmp_path / "out"
    out.mkdir()
    argv = ["measure", data / "ref.tif", data / "load.tif", "--quiet", "-o", out / "o.h5",
            "--figures", out / "figs", "--export", "mat,csv", "--report", out / "r.html"]
    p = subprocess.Popen([sys.executable, "-c", _HOLD, *map(str, argv)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=SRC))
    assert p.stdout.readline() == "started\n"
    time.sleep(delay)
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    assert p.returncode == rc, err
    assert len(err.strip().splitlines()) == 1, err
    assert word in err
    assert _leftovers(out) == []


def test_an_interrupt_dropped_by_a_finaliser_is_raised_again():
    """SIGINT handled while a finaliser runs (Python prints and drops exceptions
    raised there): the interrupt still ends the command, raised again once the
    finaliser has returned, and nothing is printed."""
    import time

    from gridstrain import cli

    class Finalised:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler runs here, inside the finaliser

    hook = sys.unraisablehook
    with pytest.raises(KeyboardInterrupt), cli._signals():  # noqa: PT012
        Finalised()  # dropped at once: its __del__ runs and the exception is dropped
        for _ in range(200):  # raised again within a millisecond or so
            time.sleep(0.01)
    assert signal.getsignal(signal.SIGALRM) is signal.SIG_DFL
    assert sys.unraisablehook is hook


def test_an_interrupt_that_surfaces_as_another_error_is_still_the_interrupt(
        data, tmp_path, capsys, monkeypatch):
    """SIGINT landing while an extension module initialises makes its import fail with
    ImportError (the interrupt is swallowed into it): the signal, not the error it
    turned into, decides the outcome: one line, exit 130, nothing left."""
    import gridstrain.cli.measure as cm

    def interrupted_import(*args, **kwargs):
        try:
            signal.raise_signal(signal.SIGINT)  # delivered here: the handler raises
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None
        raise AssertionError("the handler did not raise")

    monkeypatch.setattr(cm, "measure_series", interrupted_import)
    out = tmp_path / "out"
    out.mkdir()
    rc = _run(["measure", data / "ref.tif", data / "load.tif", "--quiet", "-o", out / "o.h5"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 130, err
    assert len(err) == 1, err
    assert "interrupted" in err[0]
    assert _leftovers(out) == []


class _ClosedPipe(io.StringIO):
    """A stdout whose reader has gone (``gridstrain measure ... | head -1``)."""

    def write(self, text):
        raise BrokenPipeError(32, "Broken pipe")


def test_a_closed_pipe_keeps_the_outputs_it_replaced(data, tmp_path, monkeypatch, capsys):
    """``measure -o a.h5 --overwrite | head -1``: the reader leaving breaks no output.
    The new result was complete once renamed into place; removing it as a failed run's
    would lose both it and the file it replaced."""
    out = tmp_path / "a.h5"
    argv = ["measure", data / "ref.tif", data / "load.tif", "-o", out]
    assert _run([*argv, "--quiet"]) == 0, capsys.readouterr().err
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    assert _run([*argv, "--overwrite"]) == 141  # a pipe's status: 128 + SIGPIPE
    monkeypatch.undo()
    assert gridstrain.load(out).n_states == 1
    assert "Traceback" not in capsys.readouterr().err
