"""Gaps in a record and impossible camera timing.

A record saved one file per frame is numbered by its file names: a dropped frame
(``f014``, ``f016``) must not shift the later states' times, and every missing,
off-step or out-of-order number is named; repeated numbers are refused. A camera
header whose timing is impossible (a trigger time of -4.3e9 s, a record rate of
5e-324, inf, nan, zero or negative) gives no times, or its frame rate's, with one
reading note naming the header field: never -inf, garbage or a numpy warning.

The oracle of every time is written here: a frame's number (the one in its file name,
or the camera's ``first + k``) less the record's first, over the rate. Frames come from
``tests/sequence_record.py`` (numpy only, ``independent_grid``; a coupon under growing
homogeneous strain, 12-bit Poisson-Gaussian camera), camera files from
``tests/camera_files.py`` (numpy only, the published layouts).
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys

import numpy as np
import pytest
import tifffile

from camera_files import write_cine, write_mraw
from findings import said
from gridstrain.io import FrameGap, open_series, record_numbering
from gridstrain.series import measure_series
from sequence_record import record

SHAPE = (64, 96)
RATE = 1000.0


@pytest.fixture(scope="module")
def frames():
    """(8, H, W) frames of the record, uint16 (12 bits stored x16)."""
    return record(8, SHAPE, strain=1e-3)


def _write(folder, frames, numbers, *, digits=3):
    folder.mkdir()
    for f, n in zip(frames, numbers, strict=True):
        tifffile.imwrite(folder / f"f{n:0{digits}d}.tif", f)
    return folder


# --------------------------------------------------------------------------- numbering


def test_numbering_names_every_break():
    r = record_numbering(["f013.tif", "f014.tif", "f016.tif", "f017.tif", "f021.tif"])
    assert r.numbers == (13, 14, 16, 17, 21)
    assert r.step == 1
    (gap,) = r.gaps
    assert gap.kind == "missing"
    assert gap.runs == ((15, 15), (18, 20))
    assert gap.count == 4
    assert str(gap).startswith("the record's file numbers skip 15, 18-20, the first "
                               "after f014.tif and before f016.tif: 4 frame(s) missing")
    # every fifth frame saved under its camera number: no gap; one dropped: named
    r = record_numbering([f"rec_{n}.tif" for n in (0, 5, 10, 20, 25)])
    assert r.step == 5
    assert [str(g) for g in r.gaps] == [
        "the record's file numbers skip 15 (every 5), the first after rec_10.tif and "
        "before rec_20.tif: 1 frame(s) missing (dropped by the camera?); each state is "
        "numbered, and timed by a frame rate, by its file's number"]
    # out of order (files listed by hand) and off the step
    r = record_numbering(["f1.tif", "f2.tif", "f4.tif", "f3.tif", "f5.tif", "f7.tif"])
    kinds = {g.kind: g for g in r.gaps}
    assert kinds["out of order"].runs == ((3, 3),)
    assert kinds["missing"].runs == ((6, 6),)
    assert "f3.tif" in str(kinds["out of order"])
    # a gap of 1e12 numbers is named without listing them one by one
    r = record_numbering(["f1.tif", "f2.tif", "f3.tif", "f1000000000000.tif"])
    assert r.gaps[0].count == 10**12 - 4
    assert "4-999999999999" in str(r.gaps[0])


def test_numbering_refuses_repeated_numbers_and_ignores_other_names():
    with pytest.raises(ValueError, match=r"repeat frame number\(s\) 14 \(f14\.tif, "
                                         r"f014\.tif for 14\).*nor the times can be trusted"):
        record_numbering(["f13.tif", "f14.tif", "f014.tif", "f15.tif"])
    # names varying in two groups (a run and a counter), several folders, one file
    assert record_numbering(["run1_f1.tif", "run2_f2.tif"]) is None
    assert record_numbering(["a/f1.tif", "b/f2.tif"]) is None
    assert record_numbering(["f1.tif"]) is None
    assert record_numbering(["ref.tif", "load.tif"]) is None
    assert isinstance(record_numbering(["f1.tif", "f2.tif", "f4.tif"]).gaps[0], FrameGap)


# --------------------------------------------------------------------------- measured


def test_a_dropped_frame_shifts_no_later_state(tmp_path, frames):
    """Files f010..f017 with f014 dropped: the states keep their own frames' times."""
    numbers = [10, 11, 12, 13, 15, 16, 17]
    folder = _write(tmp_path / "rec", frames[[0, 1, 2, 3, 5, 6, 7]], numbers)
    res = measure_series(None, folder, reference_frames=1, frame_rate=RATE)
    # oracle: each state's number less the reference's (10), over the rate; exact in
    # float64 (small integers over a power-of-ten rate, one rounding each way)
    np.testing.assert_allclose(res.time, (np.array(numbers[1:]) - 10) / RATE, rtol=1e-15)
    gaps = said(res.warnings, "frames.gap")
    assert gaps == ["the record's file numbers skip 14, the first after f013.tif and "
                    "before f015.tif: 1 frame(s) missing (dropped by the camera?); each "
                    "state is numbered, and timed by a frame rate, by its file's number"]


def test_an_unbroken_record_keeps_its_times_and_says_nothing(tmp_path, frames):
    folder = _write(tmp_path / "rec", frames[:4], [0, 1, 2, 3], digits=4)
    res = measure_series(None, folder, reference_frames=1, frame_rate=RATE)
    np.testing.assert_allclose(res.time, np.arange(1, 4) / RATE, rtol=1e-15)
    assert not said(res.warnings, "frames.gap")


def test_cli_refuses_repeated_numbers_in_one_line(tmp_path, frames):
    folder = _write(tmp_path / "rec", frames[:3], [1, 2, 3])
    tifffile.imwrite(folder / "f2.tif", frames[2])  # a second file numbered 2
    p = subprocess.run([sys.executable, "-m", "gridstrain.cli", "measure", str(folder),
                        "--reference-frames", "1", "--frame-rate", "1000",
                        "-o", str(tmp_path / "a.h5")], capture_output=True, text=True)
    assert p.returncode != 0
    assert "Traceback" not in p.stderr
    assert "repeat frame number(s) 2" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "a.h5").exists()


# --------------------------------------------------------------------------- cameras


def _patch(path, offset, fmt, value):
    with open(path, "r+b") as fh:
        fh.seek(offset)
        fh.write(struct.pack(fmt, value))


def test_cine_trigger_time_of_garbage_falls_back_to_its_frame_rate(tmp_path, frames):
    """A TriggerTime 4.3e9 s after the frames' stamps (its seconds all ones): the
    stamps are left out and the frames timed by FrameRate, (FirstImageNo + k) / rate."""
    raw = frames[:4] // 16
    path = write_cine(tmp_path / "rec.cine", raw, real_bpp=12, frame_rate=1000,
                      first_number=-1, trigger=100.0, times=(np.arange(4) - 1) / 1e3)
    _patch(path, 40, "<I", 0xFFFFFFFF)  # TriggerTime's seconds
    s = open_series(path, name="state")
    np.testing.assert_allclose(s.times, (np.arange(4) - 1) / 1000, rtol=1e-15)
    (note,) = [n for n in said(s.notes, "input") if "TriggerTime" in n]
    assert note.startswith("state: rec.cine: the header's TriggerTime")
    assert "-4.29e+09 s from the trigger" in note
    # no FrameRate either: no times at all
    _patch(path, 84 + 768, "<I", 0)
    s = open_series(path, name="state")
    assert s.times is None
    assert any("TriggerTime" in n and "read without times" in n
               for n in said(s.notes, "input"))


@pytest.mark.parametrize("rate", [5e-324, float("inf"), float("nan"), -1000.0, 0.0])
def test_mraw_impossible_record_rate_gives_no_times(tmp_path, frames, rate):
    path = write_mraw(tmp_path / "rec.mraw", frames[:3] // 16, color_bit=16,
                      frame_rate=rate, start_frame=-1)
    s = open_series(path, name="state")
    np.testing.assert_array_equal(s.read(1, dtype=None), frames[1] // 16)
    assert s.times is None
    assert s.frame_rate is None
    (note,) = s.notes
    assert note.startswith("state: rec.cih: the header's 'Record Rate(fps)' is ")
    assert "not a record rate" in note


def test_mraw_start_frame_of_garbage_gives_no_times(tmp_path, frames):
    path = write_mraw(tmp_path / "rec.mraw", frames[:3] // 16, color_bit=16,
                      frame_rate=1000, start_frame=-4_300_000_000)
    s = open_series(path, name="state")
    assert s.times is None
    (note,) = s.notes
    assert "'Start Frame' (-4300000000)" in note


def test_cli_measures_a_record_of_absurd_rate_without_times(tmp_path, frames):
    """Exit 0, the frames measured, no time stored and the field named once; no numpy
    warning on the way (the test's interpreter turns any warning into an error)."""
    path = write_mraw(tmp_path / "rec.mraw", frames[:3] // 16, color_bit=16,
                      frame_rate=5e-324, start_frame=-1)
    p = subprocess.run([sys.executable, "-W", "error", "-m", "gridstrain.cli", "measure",
                        str(path), "--reference-frames", "1", "-o", str(tmp_path / "a.h5"),
                        "--json"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    assert all(st.get("time_s") is None for st in s["states"])
    assert sum("'Record Rate(fps)'" in w for w in said(s, "input")) == 1


# --------------------------------------------------------------------------- a loads file


def _loads(path, labels):
    """A state column naming ``labels``, the load of each the frame number in kN (the
    oracle: a state's load is its own number, whatever the rows' order)."""
    rows = "".join(f"{s};{int(s[1:])}\n" for s in labels)
    path.write_text("state;load [kN]\n" + rows)
    return path


def test_a_state_column_names_the_frames_the_record_lacks(tmp_path, frames):
    """The testing machine's table lists every frame the camera was triggered for: the
    reference's (f010) and the one the camera dropped (f014) too. Their rows are
    skipped and said by code; every measured state gets its own row's load."""
    numbers = [10, 11, 12, 13, 15, 16, 17]
    folder = _write(tmp_path / "rec", frames[[0, 1, 2, 3, 5, 6, 7]], numbers)
    labels = [f"f{n:03d}" for n in (10, 11, 12, 13, 14, 17, 16, 15)]  # rows 2 to 9
    csv = _loads(tmp_path / "loads.csv", labels)
    # and a last row naming the reference as gridstrain does: skipped, as a result's
    # commands skip it
    csv.write_text(csv.read_text() + "reference;0\n")
    res = measure_series(None, folder, reference_frames=1, loads=csv)
    assert res.names[1:] == ("f011", "f012", "f013", "f015", "f016", "f017")
    np.testing.assert_array_equal(res.load, [11, 12, 13, 15, 16, 17])
    (told,) = [w for w in said(res.warnings, "input") if "loads file" in w]
    assert told.figures["states"] == ["f010", "f014"]
    assert told.figures["rows"] == [2, 6]  # as a text editor numbers the lines
    assert "dropped by the camera" in told


@pytest.mark.parametrize(("extra", "match"), [
    ("f018", r"row 9: state 'f018' is not one of the states measured"),  # after the last
    ("f14", r"state 'f14' is not one of"),  # not written as the record's numbers
    ("g014", r"state 'g014' is not one of"),  # another name
])
def test_a_state_column_still_refuses_what_is_not_a_frame_the_record_lacks(tmp_path, extra,
                                                                           match):
    from gridstrain.io import read_loads

    states = ["f011", "f012", "f013", "f015"]
    csv = _loads(tmp_path / "loads.csv", [*states, "f014", "f010", "f016", extra])
    with pytest.raises(ValueError, match=match):
        read_loads(csv, states=[*states, "f016"])
    # and a state without its row, whatever the rows skipped
    with pytest.raises(ValueError, match=r"no row for 1 state\(s\) \(f016\)"):
        read_loads(_loads(tmp_path / "l2.csv", [*states, "f014"]), states=[*states, "f016"])


def test_a_command_reading_a_result_says_the_rows_it_skips(tmp_path, frames, capsys):
    from gridstrain.cli import main

    numbers = [10, 11, 12, 13, 15, 16, 17]
    folder = _write(tmp_path / "rec", frames[[0, 1, 2, 3, 5, 6, 7]], numbers)
    out = tmp_path / "maps.h5"
    assert main(["measure", str(folder), "--reference-frames", "1", "-o", str(out),
                 "--quiet"]) == 0
    csv = _loads(tmp_path / "loads.csv", [f"f{n:03d}" for n in range(10, 18)])
    capsys.readouterr()
    table = tmp_path / "gauge.csv"
    assert main(["gauge", str(out), "--loads", str(csv), "-o", str(table)]) == 0
    got = capsys.readouterr()
    # one line on stderr naming the rows skipped; the gauge's loads are the states' own
    (line,) = got.err.strip().splitlines()
    assert line.startswith("gridstrain gauge: warning: loads file loads.csv: ")
    assert "f010" in line
    assert "f014" in line
    rows = [line.split(",") for line in table.read_text().splitlines()]
    assert rows[0][:2] == ["state", "load [kN]"]
    assert [(r[0], float(r[1])) for r in rows[1:]] == [
        (f"f{n:03d}", float(n)) for n in (11, 12, 13, 15, 16, 17)]
