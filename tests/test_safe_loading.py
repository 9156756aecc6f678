"""Opening a result file from someone else: nothing in it is run, imported or trusted.

Each test edits one field of a file written by :func:`gridstrain.results.save_result`
and checks that :func:`gridstrain.load` (and the commands reading files) refuse it with
one message naming the file and the field, instead of importing, executing, reading
another file or computing with a value of the wrong kind.
"""

from __future__ import annotations

import json
import re
import socket
import sys
import tomllib

import h5py
import numpy as np
import pytest
import tifffile

from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.results import load, read_attrs, save_result
from gridstrain.results._file import _nan_equal
from gridstrain.series import measure_series
from independent_grid import camera, scene

LAT = Lattice.from_pitch(5.0)
N = 64


@pytest.fixture(scope="module")
def result():
    rng = np.random.default_rng(2611)

    def frames(strain):
        level, _ = scene((N, N), pitch=5.0, angle=0.0, hole=False, light=False,
                         displacement=lambda X, Y: (strain * (X - N / 2), 0.0 * Y))
        return np.array([camera(level, 1.0, 4.0, rng) for _ in range(3)])

    return measure_series(frames(0.0), [frames(1e-3), frames(2e-3)], lattice=LAT)


@pytest.fixture
def saved(result, tmp_path):
    return save_result(result, tmp_path / "r.h5", pixel_size=0.02, unit="mm",
                       attrs={"config": 'method = "A"\n'}, lossless=True)


def _refused(path, field, read=load):
    with pytest.raises(ValueError, match=re.escape(str(path))) as info:
        read(path)
    text = str(info.value)
    assert str(path) in text
    assert field in text
    assert len(text.splitlines()) == 1
    return text


def test_a_class_name_is_never_imported(saved, tmp_path, monkeypatch):
    """A module next to the file, named by ``_class``, is neither imported nor run."""
    marker = tmp_path / "ran"
    (tmp_path / "evilmod.py").write_text(f"open({str(marker)!r}, 'w').close()\n"
                                         "class Evil:\n    pass\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("evilmod.Evil", "this.s", "os.system", "gridstrain.cli.main"):
        with h5py.File(saved, "a") as h5:
            h5["gridstrain/result/noise"].attrs["_class"] = name
        text = _refused(saved, "/gridstrain/result/noise/_class")
        assert name in text
    assert not marker.exists()
    assert "evilmod" not in sys.modules
    assert "this" not in sys.modules


def test_the_file_round_trips_with_the_registry(result, saved):
    import dataclasses

    # the result saved is the one given, with the pixel size it was saved with
    assert load(saved).pixel_size == 0.02
    assert _nan_equal(load(saved), _without_phase_maps(
        dataclasses.replace(result, pixel_size=0.02, unit="mm")))


def _without_phase_maps(result):
    import dataclasses

    ms = tuple(dataclasses.replace(m, reference=None, deformed=None)
               for m in result.measurements)
    return dataclasses.replace(result, measurements=ms)


@pytest.mark.parametrize(("edit", "field"), [
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("sigma", "six"),
     "/gridstrain/result/sigma"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("sigma", np.nan),
     "/gridstrain/result/sigma"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("method", "<script>"),
     "/gridstrain/result/method"),
    # the measurements are written by columns: one value per state, named with its row
    (lambda h5: h5["gridstrain/result/measurements"].attrs.__setitem__(
        "iterations", np.array(["<b>3</b>"] * 2, dtype=h5py.string_dtype())),
     "/gridstrain/result/measurements/iterations[0]"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__("_type", "module"),
     "/gridstrain/result/_type"),
    (lambda h5: _replace(h5, "exx", np.zeros((2, N, N + 1))), "/exx"),
    (lambda h5: _replace(h5, "valid", np.zeros((2, N, N))), "/valid"),
    (lambda h5: _replace(h5, "mask", np.zeros((N, 3), bool)), "/mask"),
    (lambda h5: h5["gridstrain/result"].attrs.__setitem__(
        "n_frames", np.array([3, 3], np.int64)), "/gridstrain/result/n_frames"),
    (lambda h5: h5.attrs.__setitem__("pixel_size", "0.02<script>"), "/pixel_size"),
    (lambda h5: _replace(h5, "gridstrain/result", np.zeros(3)), "/gridstrain/result"),
    # linked from every measurement: named where it is first read
    (lambda h5: _replace(h5, "gridstrain/result/lattice", np.zeros(3)),
     "/measurements/lattice[0]: expected Lattice"),
])
def test_a_wrong_field_is_one_line_naming_the_file_and_the_field(saved, edit, field):
    with h5py.File(saved, "a") as h5:
        edit(h5)
    _refused(saved, field, read_attrs if field == "/pixel_size" else load)


def _replace(h5, name, data):
    del h5[name]
    h5[name] = data


def test_links_out_of_the_file_are_refused(saved, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as h5:
        h5["noise"] = np.zeros(3)
    with h5py.File(saved, "a") as h5:
        del h5["gridstrain/result/noise"]
        h5["gridstrain/result/noise"] = h5py.ExternalLink(str(other), "noise")
    text = _refused(saved, "/gridstrain/result/noise")
    assert "another file" in text


def test_a_link_cycle_is_refused(saved):
    with h5py.File(saved, "a") as h5:
        h5["gridstrain/result/noise/loop"] = h5py.SoftLink("/gridstrain/result/noise")
    _refused(saved, "/gridstrain/result/noise/loop")


def test_groups_nested_too_deep_are_refused_in_one_line(saved):
    # a file made to exhaust the reader's recursion (each level takes at least two of
    # Python's 1000 frames): one line, no traceback
    with h5py.File(saved, "a") as h5:
        g = h5["gridstrain/result"].create_group("deep")
        for _ in range(1000):
            g = g.create_group("d")
    text = _refused(saved, "/gridstrain/result")
    assert "nested too deep to read" in text


def test_a_file_declaring_more_than_the_memory_is_refused_before_reading(saved):
    # a chunked, compressed dataset declaring 2**50 bytes takes a few bytes on disk
    with h5py.File(saved, "a") as h5:
        h5["gridstrain/result"].create_dataset("huge", shape=(2**47,), dtype="f8",
                                               chunks=(2**20,), compression="gzip")
    text = _refused(saved, "GiB")
    assert "memory" in text


def test_the_commands_say_one_line(saved, capsys):
    with h5py.File(saved, "a") as h5:
        h5["gridstrain/result/noise"].attrs["_class"] = "os.system"
    for argv in (["report", str(saved), "-o", str(saved.with_suffix(".html"))],
                 ["plot", str(saved), "-o", str(saved.parent / "figs")]):
        assert main(argv) != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert str(saved) in err[0]
        assert "_class" in err[0]
    assert not saved.with_suffix(".html").exists()


# --------------------------------------------------------------------------- replay


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    d = tmp_path_factory.mktemp("series")
    rng = np.random.default_rng(26)
    for name, strain in (("ref", 0.0), ("def", 1e-3)):
        (d / name).mkdir()
        level, _ = scene((N, N), pitch=5.0, angle=0.0, hole=False, light=False,
                         displacement=lambda X, Y, e=strain: (e * (X - N / 2), 0.0 * Y))
        for k in range(2):
            tifffile.imwrite(d / name / f"f{k}.tif", camera(level, 1.0, 4.0, rng),
                             photometric="minisblack")
    return d


def test_a_result_file_replays_the_measurement_and_nothing_else(series, tmp_path, capsys):
    first = tmp_path / "first.h5"
    assert main(["measure", str(series / "ref"), str(series / "def"), "-o", str(first),
                 "--pitch", "5", "--sigma", "6", "--quiet"]) == 0
    # a crafted configuration: run-only keys aimed at the user's files and a cluster
    victims = {name: tmp_path / name for name in ("victim.csv", "victim.html", "victim.h5")}
    for path in victims.values():
        path.write_bytes(b"the user's own file")
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    listener.setblocking(False)
    port = listener.getsockname()[1]
    config = tomllib.loads(read_attrs(first)["config"])
    config.update(overwrite=True, csv=str(victims["victim.csv"]),
                  report=str(victims["victim.html"]), output=str(victims["victim.h5"]),
                  scheduler=f"tcp://127.0.0.1:{port}", timeout=1.0, quiet=False)
    text = "\n".join(f"{k} = {json.dumps(v)}" for k, v in config.items()) + "\n"
    with h5py.File(first, "a") as h5:
        h5.attrs["config"] = text
    again = tmp_path / "again.h5"
    capsys.readouterr()
    assert main(["measure", "--config", str(first), "-o", str(again), "--sigma", "7"]) == 0
    err = capsys.readouterr().err
    for path in victims.values():
        assert path.read_bytes() == b"the user's own file"
    with pytest.raises(BlockingIOError):  # nobody knocked
        listener.accept()
    listener.close()
    line = next(x for x in err.splitlines() if x.startswith("replaying"))
    assert str(first) in line
    ignored = line.split("ignored run-only ")[1].split(", ")
    assert set(ignored) == {"overwrite", "csv", "report", "output", "scheduler", "timeout",
                            "quiet"}
    assert "sigma from the command line" in line
    attrs = read_attrs(again)
    assert "reference" in attrs["config_keys"]
    assert "sigma" not in attrs["config_keys"]
    assert set(attrs["config_ignored"]) == set(ignored)
    stored = tomllib.loads(attrs["config"])
    assert not set(stored) & {"output", "scheduler", "csv", "report", "overwrite"}
    assert stored["sigma"] == 7.0
    # the measurement itself is replayed: same inputs, same lattice
    assert load(again).names == load(first).names
    # a measurement key of the wrong type is refused by name
    with h5py.File(first, "a") as h5:
        h5.attrs["config"] = text.replace("pitch = 5.0", 'pitch = "5<script>"')
    assert main(["measure", "--config", str(first), "-o", str(tmp_path / "x.h5"),
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert str(first) in err[0]
    assert "pitch" in err[0]


def test_a_toml_file_never_turns_on_overwrite(series, tmp_path, capsys):
    out = tmp_path / "m.h5"
    out.write_bytes(b"the user's own file")
    cfg = tmp_path / "run.toml"
    cfg.write_text(f'reference = "{series / "ref"}"\nstates = ["{series / "def"}"]\n'
                   f'output = "{out}"\npitch = 5\noverwrite = true\n')
    assert main(["measure", "--config", str(cfg), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "--overwrite" in err[0]
    assert out.read_bytes() == b"the user's own file"


def test_the_screening_trend_of_a_long_series_is_stored_and_read_back(tmp_path):
    # series of 4 frames or more carry the sequence test (screening.Trend): a result
    # class of its own, which the file must accept and rebuild like the others
    rng = np.random.default_rng(2612)
    level, _ = scene((N, N), pitch=5.0, angle=0.0, hole=False, light=False)
    stack = np.array([camera(level, 1.0, 4.0, rng) for _ in range(5)])
    res = measure_series(stack, [stack[::-1]], lattice=LAT)
    assert res.screening[0].trend is not None
    path = save_result(res, tmp_path / "long.h5")
    back = load(path)
    assert len(back.screening) == len(res.screening)
    for got, sent in zip(back.screening, res.screening, strict=True):
        assert _nan_equal(got.trend, sent.trend)  # NaN growth: no tiles in 64 px
