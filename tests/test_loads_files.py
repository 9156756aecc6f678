"""A testing machine's export read as it comes (gridstrain.io.read_loads, ``--loads``).

The exports are written here as the machines' software writes them, by
:func:`_zwick` and :func:`_instron` below (numpy and the standard library only):

- a Zwick-like export (testXpert): a preamble of "name;value" lines, a header with
  the units in brackets and parentheses, ``;`` between the columns, a decimal
  comma, the time in ms and the force in kN, a ``µ`` in a header, Windows-1252
  (cp1252) bytes and CRLF line ends;
- an Instron-like export (Bluehill): UTF-8 with a byte-order mark, quoted cells,
  ``,`` between the columns, a preamble, the units in parentheses.

The log is sampled at 100 Hz; the camera takes 10 frames per second and its
trigger comes ``OFFSET`` s after the log started. The load is a smooth non-linear
law quantised to the export's last digit, so that every value written is an exact
decimal (``k / 10**d``) whose float is the oracle's: the oracle is then
``numpy.interp`` of those values at the camera's times plus the offset, written in
the test.

The image record is ``tests/sequence_record.py``'s: a coupon under a strain that
grows linearly from frame to frame (Poisson's ratio 0.3).
"""

from __future__ import annotations

import csv as csv_module
import hashlib
import json
import math

import numpy as np
import pytest
import tifffile

from camera_files import write_cine
from gridstrain import measure_series
from gridstrain.cli import main
from gridstrain.io import LoadsFile, read_loads
from gridstrain.post import elastic_constants, gauge
from gridstrain.results import load, read_attrs
from sequence_record import K, L, record

RATE_LOG = 100.0  # Hz, the machine's log
RATE_CAMERA = 10.0  # Hz
# the log started 0.2037 s before the camera's trigger: off the log's 10 ms grid, so
# that the states fall between its rows and the interpolation is exercised
OFFSET = 0.2037


def _force_n(t):
    """The load of the test, N: a ramp with a ripple (not a straight line, so that
    linear interpolation differs from the exact law and from the nearest row)."""
    return 800.0 * t + 40.0 * np.sin(2 * np.pi * 1.3 * t)


def _log(duration: float = 1.5):
    """``(t_ms, counts)``: whole ms, and the force in units of 0.1 N (the export's
    last digit, 0.0001 kN), rounded."""
    t_ms = np.round(np.arange(0.0, duration + 1e-9, 1 / RATE_LOG) * 1000.0).astype(np.int64)
    counts = np.round(_force_n(t_ms / 1000.0) * 10.0).astype(np.int64)
    return t_ms, counts


def _zwick(path, t_ms, counts, *, units_row: bool = False):
    """A Zwick-like export (see the module docstring); the force in kN, 4 decimals."""
    lines = ["Prüfprotokoll;Zugversuch DIN EN ISO 6892-1", "Prüfer;Müller",
             "Probe;A-17", "Breite [mm];10,00", "Dicke [mm];2,00", ""]
    if units_row:
        lines += ["Prüfzeit;Standardkraft;Dehnung", "ms;kN;µm/m"]
    else:
        lines += ["Zeit [ms];Standardkraft (kN);Dehnung [µm/m]"]
    for t, c in zip(t_ms.tolist(), counts.tolist(), strict=True):
        kn = f"{c / 10000:.4f}".replace(".", ",")
        lines.append(f"{t};{kn};{3 * t},5")
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("cp1252"))
    return path


def _instron(path, t_ms, counts, *, load_unit="N", time_unit="s", encoding="utf-8-sig"):
    """An Instron-like export (see the module docstring): the time in s, 3 decimals,
    the force in N, 1 decimal (the value written in the units named)."""
    lines = ['"Sample Name","A-17"', '"Test Date","2026-12-06"', "",
             f'"Time ({time_unit})","Extension (mm)","Load ({load_unit})"']
    for t, c in zip(t_ms.tolist(), counts.tolist(), strict=True):
        lines.append(f'"{t / 1000:.3f}","{t * 1e-4:.4f}","{c / 10:.1f}"')
    path.write_bytes(("\n".join(lines) + "\n").encode(encoding))
    return path


def _oracle(times, t_ms, counts, *, scale=1e-4, offset=OFFSET):
    """The log's load at ``times + offset``, interpolated by numpy: kN by default."""
    return np.interp(np.asarray(times) + offset, t_ms / 1000.0, counts * scale)


CAMERA = np.arange(1, 10) / RATE_CAMERA  # the states' times, s: frames 1 to 9
STATES = [f"frame_{k}" for k in range(1, 10)]
# 1 µN: far below the export's 0.1 N digit, far above the rounding of ms -> s (1e-16 s
# times a slope of 1 kN/s)
ATOL_KN = 1e-9


def test_a_zwick_export_is_read_as_it_comes(tmp_path):
    t_ms, counts = _log()
    path = _zwick(tmp_path / "zwick.csv", t_ms, counts)
    table = read_loads(path, states=STATES, times=CAMERA, offset=OFFSET)
    want = _oracle(CAMERA, t_ms, counts)
    assert table.unit == "kN"
    np.testing.assert_allclose(table.load, want, rtol=0, atol=ATOL_KN)
    np.testing.assert_array_equal(table.time, CAMERA)
    # the test could fail: the nearest row of the log is 3 ms off, 2-3 N away
    nearest = counts[np.round((CAMERA + OFFSET) * RATE_LOG).astype(int)] * 1e-4
    assert np.max(np.abs(nearest - want)) > 1000 * ATOL_KN
    # against the law itself: linear interpolation errs by at most h^2/8 max|F''|
    # (h = 10 ms, |F''| <= 40 (2 pi 1.3)^2 N/s^2: 0.033 N), the export's rounding by
    # half its last digit (0.05 N)
    bound_kn = (0.01**2 / 8 * 40 * (2 * np.pi * 1.3) ** 2 + 0.05) * 1e-3
    exact_kn = _force_n(CAMERA + OFFSET) * 1e-3
    assert np.max(np.abs(table.load - exact_kn)) <= bound_kn
    s = table.source
    assert s["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert (s["encoding"], s["delimiter"], s["decimal"]) == ("cp1252", ";", ",")
    assert (s["load_column"], s["load_unit"], s["time_column"], s["time_unit"]) == \
        ("Standardkraft (kN)", "kN", "Zeit [ms]", "ms")
    assert s["header_row"] == 7  # after the preamble and its blank line
    assert s["rows"] == t_ms.size
    assert s["offset_s"] == OFFSET
    assert s["method"] == "linear interpolation in time"


def test_units_on_a_line_of_their_own(tmp_path):
    t_ms, counts = _log()
    path = _zwick(tmp_path / "zwick.csv", t_ms, counts, units_row=True)
    table = read_loads(path, states=STATES, times=CAMERA, offset=OFFSET)
    np.testing.assert_allclose(table.load, _oracle(CAMERA, t_ms, counts), rtol=0,
                               atol=ATOL_KN)
    assert table.source["time_unit"] == "ms"


@pytest.mark.parametrize(("written", "stored", "factor"), [
    # the definitions: 1 daN = 10 N, 1 mN = 1e-3 N, 1 kip = 1000 lbf; lb is lbf
    ("N", "N", 1.0), ("kN", "kN", 1.0), ("daN", "N", 10.0), ("mN", "N", 1e-3),
    ("lbf", "lbf", 1.0), ("lb", "lbf", 1.0), ("kip", "lbf", 1e3),
])
def test_force_units_are_converted(tmp_path, written, stored, factor):
    t_ms, counts = _log()
    path = _instron(tmp_path / "instron.csv", t_ms, counts, load_unit=written)
    table = read_loads(path, states=STATES, times=CAMERA, offset=OFFSET)
    assert table.unit == stored
    # the values written are counts / 10 in the written unit
    np.testing.assert_allclose(table.load, _oracle(CAMERA, t_ms, counts, scale=0.1 * factor),
                               rtol=1e-12)


@pytest.mark.parametrize(("written", "factor"), [
    ("s", 1.0), ("ms", 1e-3), ("min", 60.0), ("µs", 1e-6), ("sec", 1.0)])
def test_time_units_are_converted(tmp_path, written, factor):
    # one row per state: the file's time column, in its unit, less the offset
    text = f"Time ({written});Force (N)\n" + "".join(
        f"{k};{10 * k}\n" for k in range(1, 4))
    path = tmp_path / "log.csv"
    path.write_text(text, encoding="utf-8")
    table = read_loads(path, states=["a", "b", "c"], offset=0.5 * factor)
    np.testing.assert_allclose(table.time, (np.arange(1, 4) - 0.5) * factor, rtol=1e-12)
    np.testing.assert_array_equal(table.load, [10.0, 20.0, 30.0])


@pytest.mark.parametrize(("encoding", "delimiter"), [
    ("utf-16", "\t"),  # Excel's "Unicode text": UTF-16 with its byte-order mark, tabs
    ("utf-8-sig", ";"), ("cp1252", "\t"), ("utf-8", " ")])
def test_encodings_and_delimiters(tmp_path, encoding, delimiter):
    t_ms, counts = _log()
    sep = "   " if delimiter == " " else delimiter
    lines = ["Gerät: Zwick Z050", f"Zeit [µs]{sep}Kraft [N]"]
    lines += [f"{1000 * t}{sep}{c / 10:.1f}" for t, c in zip(t_ms, counts, strict=True)]
    path = tmp_path / "log.txt"
    path.write_bytes("\r\n".join(lines).encode(encoding))
    table = read_loads(path, states=STATES, times=CAMERA, offset=OFFSET)
    np.testing.assert_allclose(table.load, _oracle(CAMERA, t_ms, counts, scale=0.1),
                               rtol=1e-12)
    assert table.source["encoding"] == encoding
    assert table.source["time_unit"] == "µs"


def test_columns_chosen_by_name(tmp_path):
    # two force channels: the machine's and a second load cell
    text = ("Time (s),Force (kN),Load cell 2 (N)\n"
            + "".join(f"{k},{k},{100 * k + 1}\n" for k in range(4)))
    path = tmp_path / "log.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"2 columns could be the load .*--load-column"):
        read_loads(path, states=["a", "b"], times=[1.0, 2.0])
    t = read_loads(path, states=["a", "b"], times=[0.5, 2.5], load_column="load cell 2")
    assert t.unit == "N"
    np.testing.assert_allclose(t.load, [51.0, 251.0], rtol=1e-12)
    t = LoadsFile(path, load_column="Force (kN)", time_column="time").read(
        ["a", "b"], times=[0.5, 2.5])
    np.testing.assert_allclose(t.load, [0.5, 2.5], rtol=1e-12)


def _bad(tmp_path, data: bytes):
    path = tmp_path / "bad.csv"
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(("data", "match"), [
    # 0x81 is undefined in cp1252 and not UTF-8
    (b"Time (s);Force (N)\n0;1\n1;2\xb5\x81\n", r"row 3: byte 0x81 is neither UTF-8 nor "
     r"Windows-1252"),
    ("Time (s);Force (N)\n0;1\n".encode("utf-16-le"), r"row 1: holds NUL bytes.*UTF-16"),
    (b"Time (s);Force (N)\n0;1\n1;" + b"9" * (129 * 1024) + b"\n",
     r"row 3: field larger than field limit .*128 KiB"),
    (b"Time (s);Force (N)\n0;0\n1;0\n2;0,0\n", r"load column 'Force \(N\)' is 0 \(all zero\)"),
    (b"Time (s);Force (N)\n0;5\n1;5\n2;5\n", r"is 5 \(constant\)"),
    (b"Time (s);Force (N)\n0;1\n1;2\n0,5;3\n", r"row 4: the time goes backwards"),
    (b"Time (s);Force (N)\n0;1\n1;2\n1;3\n", r"row 4: the time goes backwards or stands"),
    (b"Time (s);Force\n0;1\n1;2\n", r"column 'Force' has no unit"),
    (b"Time (s);Force (kg)\n0;1\n1;2\n", r"'kg' .* is not a force unit"),
    (b"Time (s);Force (N)\n0;1\n1;1.000,5\n", r"row 3: column 'Force \(N\)' must hold a "
     r"finite number, got '1.000,5'"),
    (b"Time (s);Force (N)\n0;1\n1;1e999\n", r"row 3: column 'Force \(N\)' must hold a "
     r"finite number, got '1e999'"),
    (b"Sample;A1\nOperator;B\n", r"no header line followed by a row of numbers"),
], ids=["cp1252-undefined", "utf16-no-bom", "field-over-128KiB", "all-zero", "constant",
        "backwards", "stands-still", "no-unit", "unknown-unit", "thousands-separator",
        "overflow", "no-header"])
def test_bad_files_are_named_with_the_row(tmp_path, data, match):
    path = _bad(tmp_path, data)
    with pytest.raises(ValueError, match=match) as info:
        read_loads(path, states=["a", "b"], times=[0.2, 0.4])
    msg = str(info.value)
    assert str(path) in msg
    assert "\n" not in msg


def test_a_state_outside_the_log_is_refused_by_name(tmp_path):
    t_ms, counts = _log(duration=0.5)
    path = _zwick(tmp_path / "zwick.csv", t_ms, counts)
    # frame_3 at 0.3 s is at 0.5037 s on the log's clock, past its last row (0.5 s)
    with pytest.raises(ValueError, match=r"state 'frame_3' at 0.3 s on the camera's clock "
                       r"\(0.5037 s on the log's, offset 0.2037 s\) lies outside the log's "
                       r"time span, 0 to 0.5 s \(7 state"):
        read_loads(path, states=STATES, times=CAMERA, offset=OFFSET)
    # a negative offset: the camera started first, its first states precede the log
    with pytest.raises(ValueError, match=r"state 'frame_1'"):
        read_loads(path, states=STATES[:2], times=CAMERA[:2], offset=-0.15)


def test_the_elastic_fit_names_constant_loads(tmp_path):
    res = _result(tmp_path, noise_model=NOISE)[0]
    g = gauge(res, load=[5.0] * res.n_states, load_unit="kN")
    with pytest.raises(ValueError, match=r"all 5 kN: a modulus needs states at different "
                       "loads"):
        elastic_constants(g, area=20.0)


# --------------------------------------------------------------------------- measure

N_FRAMES = 6
AREA_MM2 = 20.0  # 10 mm x 2 mm, as in the preamble
STRAIN = 1e-3  # the record's strain at its last frame
# the record's camera noise in its stored grey levels (12-bit values stored x16)
NOISE = (16 * K, 256 * L)


def _result(tmp_path, **kw):
    """A record of N_FRAMES frames at 10 Hz measured with the Zwick export joined;
    ``(result, the record, the export)``."""
    rec = tmp_path / "rec.tif"
    if not rec.exists():
        tifffile.imwrite(rec, record(N_FRAMES, (96, 96), strain=STRAIN),
                         photometric="minisblack")
    t_ms, counts = _log()
    csv = _zwick(tmp_path / "zwick.csv", t_ms, counts)
    res = measure_series(None, rec, reference_frames=1, frame_rate=RATE_CAMERA,
                         loads=LoadsFile(csv, offset=OFFSET), **kw)
    return res, rec, csv


def test_measure_joins_the_log_and_records_how(tmp_path):
    out = tmp_path / "maps.h5"
    res, _, csv = _result(tmp_path, output=out)
    t_ms, counts = _log()
    cam = np.arange(1, N_FRAMES) / RATE_CAMERA  # frame k of the record at k / rate
    np.testing.assert_allclose(res.time, cam, rtol=0, atol=1e-15)
    np.testing.assert_allclose(res.load, _oracle(cam, t_ms, counts), rtol=0, atol=ATOL_KN)
    assert res.load_unit == "kN"
    back = load(out)
    np.testing.assert_array_equal(back.load, res.load)
    assert back.load_source == res.load_source
    assert back.load_source["sha256"] == hashlib.sha256(csv.read_bytes()).hexdigest()
    assert back.load_source["offset_s"] == OFFSET


def _cli(tmp_path, *extra):
    rec = tmp_path / "rec.tif"
    if not rec.exists():
        tifffile.imwrite(rec, record(N_FRAMES, (96, 96), strain=STRAIN),
                         photometric="minisblack")
    t_ms, counts = _log()
    csv = _zwick(tmp_path / "zwick.csv", t_ms, counts)
    out = tmp_path / "maps.h5"
    return main(["measure", str(rec), "--reference-frames", "1", "--frame-rate",
                 str(RATE_CAMERA), "--loads", str(csv), "--loads-offset", str(OFFSET),
                 "--load-column", "Standardkraft", "-o", str(out), "--quiet",
                 "--pixel-size", "0.1", "--unit", "mm", "--noise-model", str(NOISE[0]),
                 str(NOISE[1]), *extra]), out


def test_a_high_speed_record_is_joined_by_its_own_time_stamps(tmp_path):
    """A Phantom cine (``tests/camera_files.py``) at 1000 frames per second, two frames
    before the trigger and one frame's stamp 3 us late, against a 100 kHz log (times
    in µs) started 5 ms before the trigger: each state's load is the log's at the
    camera's own stamp plus the offset, the late stamp included."""
    n, rate, first = 5, 1000, -2
    stamps = (np.arange(n) + first) / rate
    stamps[3] += 3e-6
    cine = write_cine(tmp_path / "rec.cine", record(n, (64, 96), strain=1e-3) // 16,
                      real_bpp=12, frame_rate=rate, first_number=first, times=stamps)
    t_us = np.arange(0, 10_001, 10)  # 0 to 10 ms every 10 us, on the log's clock
    counts = np.round(_force_n(t_us * 1e-6) * 1e3 * 10).astype(np.int64)  # ramped x1000
    log = tmp_path / "log.txt"
    log.write_text("Time [µs]\tLoad [N]\n" + "".join(
        f"{t}\t{c / 10:.1f}\n" for t, c in zip(t_us, counts, strict=True)), encoding="utf-8")
    res = measure_series(None, cine, reference_frames=1, loads=LoadsFile(log, offset=5e-3))
    # TIME64 stamps are exact to 2**-32 s: far below the log's 10 us
    np.testing.assert_allclose(res.time, stamps[1:], rtol=0, atol=2.0**-32)
    want = np.interp(res.time + 5e-3, t_us * 1e-6, counts / 10)
    # 1 uN: the rounding of us -> s times a slope of 8e5 N/s is 1e-10 N
    np.testing.assert_allclose(res.load, want, rtol=0, atol=1e-6)
    assert res.load_source["time_unit"] == "µs"


def test_cli_measure_then_gauge_modulus_history(tmp_path, capsys):
    rc, out = _cli(tmp_path)
    assert rc == 0, capsys.readouterr().err
    config = read_attrs(out)["config"]
    assert 'load-column = "Standardkraft"' in config
    assert f"loads-offset = {OFFSET}" in config
    t_ms, counts = _log()
    cam = np.arange(1, N_FRAMES) / RATE_CAMERA
    want = _oracle(cam, t_ms, counts)
    np.testing.assert_allclose(load(out).load, want, rtol=0, atol=ATOL_KN)
    assert load(out).load_source["file"] == str(tmp_path / "zwick.csv")
    # the post commands join the same log to the result's times, with their options
    g = tmp_path / "g.csv"
    csv = tmp_path / "zwick.csv"
    rc = main(["gauge", str(out), "--loads", str(csv), "--loads-offset", str(OFFSET),
               "--time-column", "Zeit", "-o", str(g)])
    assert rc == 0, capsys.readouterr().err
    with open(g, newline="", encoding="utf-8") as fh:
        rows = list(csv_module.DictReader(fh))
    np.testing.assert_allclose([float(r["load [kN]"]) for r in rows], want, rtol=0,
                               atol=ATOL_KN)
    # a wrong offset puts the last states past the log: refused, one line
    capsys.readouterr()
    rc = main(["history", str(out), "--loads", str(csv), "--loads-offset", "1.2"])
    err = capsys.readouterr().err
    assert rc != 0
    assert "state 'rec[4]'" in err  # at 0.4 s, 1.6 s on the log's clock, past 1.5 s
    assert "outside the log's time span" in err
    assert err.count("\n") == 1
    rc = main(["modulus", str(out), "--loads", str(csv), "--loads-offset", str(OFFSET),
               "--area", str(AREA_MM2), "--json"])
    assert rc == 0, capsys.readouterr().err
    assert math.isfinite(json.loads(capsys.readouterr().out)["E"])


def test_a_replay_refuses_a_loads_file_changed_since(tmp_path, capsys):
    rc, out = _cli(tmp_path)
    assert rc == 0, capsys.readouterr().err
    again = ["measure", "--config", str(out), "-o", str(tmp_path / "again.h5"), "--quiet"]
    assert main([*again[:-1], "--json"]) == 0, capsys.readouterr().err
    # the JSON summary says how the file was read: the same record as the result's
    assert json.loads(capsys.readouterr().out)["loads"] == load(out).load_source
    # the same log, one row edited: the replay names the file and the two digests
    csv = tmp_path / "zwick.csv"
    csv.write_bytes(csv.read_bytes().replace(b"\r\n100;", b"\r\n100;9"))
    rc = main([*again[:-1], "--overwrite", "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0
    assert f"loads file {csv} has changed since {out} was measured" in err
    # given on the command line, it is taken as it is
    assert main([*again, "--overwrite", "--loads", str(csv)]) == 0, capsys.readouterr().err


def test_cli_measure_refuses_a_time_going_backwards(tmp_path, capsys):
    t_ms, counts = _log()
    t_ms = t_ms.copy()
    t_ms[50] = t_ms[48]  # a clock reset in the machine's log, row 50 + 8
    rec = tmp_path / "rec.tif"
    tifffile.imwrite(rec, record(3, (96, 96), strain=STRAIN), photometric="minisblack")
    csv = _zwick(tmp_path / "zwick.csv", t_ms, counts)
    out = tmp_path / "maps.h5"
    rc = main(["measure", str(rec), "--reference-frames", "1", "--frame-rate", "10",
               "--loads", str(csv), "-o", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0
    assert f"loads file {csv}, row 58: the time goes backwards" in err
    assert err.count("\n") == 1
    assert not out.exists()


def test_options_without_loads_are_refused(tmp_path, capsys):
    rec = tmp_path / "rec.tif"
    tifffile.imwrite(rec, record(2, (96, 96)), photometric="minisblack")
    rc = main(["measure", str(rec), "--reference-frames", "1", "--loads-offset", "0.2",
               "-o", str(tmp_path / "a.h5")])
    assert rc != 0
    assert "--loads-offset needs --loads" in capsys.readouterr().err



# "name;value" lines a testing machine writes above its header: each a header-shaped
# pair of text cells, some with numbers, units or dates in the value
PREAMBLE = ["Probe;A1", "Prüfgeschwindigkeit;2 mm/min", "Prüfer;Müller",
            "Datum;06.12.2026", "Prüfzeit;120 s", "Kraftaufnehmer;10 kN",
            "Norm;DIN EN ISO 6892-1", "Temperatur;23 °C", "Vorkraft;5 N",
            "Bemerkung;ohne"]


@pytest.mark.parametrize("n", range(1, 11))
@pytest.mark.parametrize("units_row", [False, True])
def test_a_preamble_of_name_value_lines_is_never_the_header(tmp_path, n, units_row):
    """1 to 10 ``name;value`` lines right above the header (no blank line between),
    the units in the header or on a line of their own: the header is the real one,
    the loads those written."""
    t_ms, counts = _log()
    head = (["Zeit;Standardkraft", "s;kN"] if units_row
            else ["Zeit [s];Standardkraft [kN]"])
    lines = PREAMBLE[:n] + head
    for t, c in zip(t_ms.tolist(), counts.tolist(), strict=True):
        lines.append(f"{t / 1000:.3f};{c / 10000:.4f}".replace(".", ","))
    path = tmp_path / "preamble.csv"
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("cp1252"))
    table = read_loads(path, states=STATES, times=CAMERA, offset=OFFSET)
    assert table.source["header_row"] == n + 1
    assert table.source["load_column"] == "Standardkraft" + ("" if units_row else " [kN]")
    assert table.unit == "kN"
    np.testing.assert_allclose(table.load, _oracle(CAMERA, t_ms, counts), rtol=0,
                               atol=ATOL_KN)


@pytest.mark.parametrize("decimal", [".", ","])
def test_one_column_with_either_decimal_mark(tmp_path, decimal):
    """A one-column export (a header, one value a state) with a decimal point or a
    decimal comma: the same loads, the column named, no delimiter claimed."""
    p = tmp_path / "one.csv"
    p.write_text("Kraft [kN]\n" + "".join(f"{v}\n".replace(".", decimal)
                                          for v in (0.7, 1.4, 2.1)), encoding="utf-8")
    t = read_loads(p, states=["a", "b", "c"])
    np.testing.assert_array_equal(t.load, [0.7, 1.4, 2.1])  # exact: parsed, not computed
    assert t.unit == "kN"
    assert t.source["decimal"] == decimal
    assert t.source["load_column"] == "Kraft [kN]"
