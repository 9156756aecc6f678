"""Each option of the measurement declared once (gridstrain.series.OPTIONS).

A contract over the declaration, parametrised over its entries, so that an option
added there cannot skip a step: it has a sample value here; it reaches the command
line (its flag, or the flags it is built from); its flag is a key of a TOML
configuration file; a recorded option replays to the same options from the result's
``parameters`` and from the configuration the command stores; a run-only one is
neither; a bad value gives one line naming the flag or the key; it is documented.
Then a small record measured, replayed by ``measure --config RESULT`` and by
``MeasureOptions.from_parameters``: the same maps, times and loads.
"""

from __future__ import annotations

import inspect
import json
import re
from pathlib import Path

import numpy as np
import pytest
import tifffile

from gridstrain import Lattice, measure_series
from gridstrain.cli import build_parser, main
from gridstrain.cli import measure as cli_measure
from gridstrain.models import synthetic
from gridstrain.results import load, read_attrs
from gridstrain.series import OPTIONS, MeasureOptions
from sequence_record import K, L, record

DOCS = Path(__file__).resolve().parents[1] / "docs"

# One valid value of every option other than its default; an option declared without
# one here fails test_every_option_has_a_sample.
SAMPLES = {
    "lattice": Lattice.from_pitch(5.0, angle=3.0),
    "sigma": 6.0,
    "sigma_pitches": 1.5,
    "method": "B",
    "margin": 3.0,
    "to_edges": True,
    "mask": np.ones((16, 16), dtype=bool),
    "lagrangian": False,
    "guess": (1.0, -2.0),
    "order": "independent",
    "max_saturation": 0.05,
    "bit_depth": 12,
    "outliers": "warn",
    "each_frame": True,
    "reference_frames": 2,
    "keep_order": True,
    "loads": "loads.csv",
    "load_column": "Standardkraft",
    "time_column": "Zeit",
    "loads_offset": 0.2,
    "frame_rate": 500.0,
    "noise_model": (8.0, 1280.0),
    "dtype": "float32",
    "output": "out.h5",
    "progress": lambda fraction, message: None,
    "scheduler": "tcp://127.0.0.1:8786",
    "timeout": 60.0,
}
# What a progress callback is: a Python callable, never a command-line value.
PYTHON_ONLY = {"progress"}
# One bad value of every flagged option: (on the command line or None where the
# flag takes no value, in a TOML file).
BAD = {
    "sigma": ("-1", -1), "sigma_pitches": ("0.5", 0.5), "method": ("Z", "Z"),
    "margin": ("0", 0), "to_edges": (None, "yes"), "order": ("backwards", "backwards"),
    "max_saturation": ("1.5", 1.5), "bit_depth": ("40", 40),
    "outliers": ("drop", "drop"), "each_frame": (None, 1),
    "reference_frames": ("0", 0), "keep_order": (None, "no"), "loads": ("", 3),
    "load_column": ("", 3), "time_column": ("", ""), "loads_offset": ("nan", "x"),
    "frame_rate": ("-10", -10), "dtype": ("float16", "float16"), "scheduler": ("", 5),
    "timeout": ("0", -1),
}
FLAGGED = [o for o in OPTIONS if o.flag is not None]


def _measure_flags() -> set[str]:
    parser = build_parser(["measure"])
    sub = next(a for a in parser._actions if a.dest == "command")
    return {s for a in sub.choices["measure"]._actions for s in a.option_strings}


def _toml(value) -> str:
    return cli_measure._toml_value(list(value) if isinstance(value, tuple) else value)


def test_every_option_has_a_sample():
    assert set(SAMPLES) == {o.name for o in OPTIONS}
    assert set(BAD) == {o.name for o in FLAGGED}


@pytest.mark.parametrize("o", OPTIONS, ids=[o.name for o in OPTIONS])
def test_option_reaches_the_command_line(o):
    flags = _measure_flags()
    if o.name in PYTHON_ONLY:
        assert o.flag is None
        assert not o.via
        assert not o.recorded
    elif o.flag is not None:
        assert o.flag in flags
        assert o.help, f"{o.flag} has no help"
    else:
        assert o.via
        assert set(o.via) <= flags, o.via


@pytest.mark.parametrize("o", FLAGGED, ids=[o.name for o in FLAGGED])
def test_option_is_a_configuration_key(o, tmp_path):
    given = o.record(o.check(SAMPLES[o.name], o.name))
    toml = tmp_path / "run.toml"
    toml.write_text(f"{o.key} = {_toml(given)}\n")
    read = cli_measure._read_config(str(toml)).options
    want = str(tmp_path / given) if o.kind == "path" else given
    assert read == {o.key: want}
    # the same value from the command line's flag
    args = ["measure", "r.tif", "d.tif", "-o", str(tmp_path / "o.h5")]
    args += [o.flag] if o.kind == "bool" else [o.flag, str(given)]
    opts = cli_measure._options(build_parser(["measure"]).parse_args(args))
    assert opts[o.key] == (str(Path(given).resolve()) if o.kind == "path" else given)


@pytest.mark.parametrize("o", OPTIONS, ids=[o.name for o in OPTIONS])
def test_recorded_option_replays(o, tmp_path):
    """From the result's parameters (through JSON, as the file stores them) and from
    the configuration the command stores, to the same options."""
    given = MeasureOptions(**{o.name: SAMPLES[o.name]})
    params = json.loads(json.dumps(given.parameters()))
    if not o.recorded:
        assert o.name not in params
        if o.flag is not None:
            text = cli_measure.config_text({o.key: o.record(getattr(given, o.name))})
            assert o.key not in text
        return
    again = MeasureOptions.from_parameters(params)
    assert again.parameters() == params
    assert params[o.name] != MeasureOptions().parameters()[o.name]  # the sample was kept
    if o.flag is not None:  # the configuration a result stores, read back by --config
        value = o.record(getattr(given, o.name))
        result = tmp_path / "stored.toml"
        result.write_text(cli_measure.config_text({o.key: value}))
        assert cli_measure._read_config(str(result)).options == {o.key: value}


@pytest.mark.parametrize("o", FLAGGED, ids=[o.name for o in FLAGGED])
def test_a_bad_value_is_one_line_naming_it(o, tmp_path, capsys):
    cli, toml = BAD[o.name]
    base = ["measure", str(tmp_path / "r.tif"), str(tmp_path / "d.tif"), "-o",
            str(tmp_path / "o.h5"), "--quiet"]
    if cli is not None:
        assert main([*base, o.flag, cli]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert o.flag in err[0], err
    conf = tmp_path / "bad.toml"
    conf.write_text(f"{o.key} = {_toml(toml)}\n")
    assert main([*base, "--config", str(conf)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"config {conf}: {o.key}" in err[0], err
    assert not (tmp_path / "o.h5").exists()


def test_an_unknown_keyword_names_the_close_ones():
    ref = np.zeros((16, 16))
    with pytest.raises(TypeError, match=r"unknown option 'frame_rates'; did you mean "
                                        r"frame_rate\?"):
        measure_series(ref, ref, frame_rates=10.0)
    with pytest.raises(TypeError, match="options must be a MeasureOptions"):
        measure_series(ref, ref, {"sigma": 5.0})
    with pytest.raises(ValueError, match="give sigma or sigma_pitches, not both"):
        measure_series(ref, ref, MeasureOptions(sigma=5.0), sigma_pitches=1.5)


@pytest.mark.parametrize(("given", "flags", "says"), [
    ({"frame_rate": 10.0}, ["--frame-rate", "10"],
     "{frame_rate} needs one frame per state ({each_frame})"),
    ({"load_column": "F"}, ["--load-column", "F"], "{load_column} needs {loads}"),
    ({"sigma": 5.0, "sigma_pitches": 1.5}, ["--sigma", "5", "--sigma-pitches", "1.5"],
     "give {sigma} or {sigma_pitches}, not both"),
    ({"to_edges": True, "method": "B"}, ["--to-edges", "--method", "B"],
     "{to_edges} needs method 'A'"),
])
def test_options_checked_together_name_them(given, flags, says, tmp_path, capsys):
    """The checks between options: in Python by keyword, on the command line by flag,
    before any frame is read (the inputs here do not exist)."""
    by_name = {o.name: o for o in OPTIONS}
    with pytest.raises(ValueError, match=re.escape(says.format(**{n: n for n in by_name}))):
        measure_series(str(tmp_path / "r.tif"), str(tmp_path / "d.tif"), **given)
    assert main(["measure", str(tmp_path / "r.tif"), str(tmp_path / "d.tif"), "-o",
                 str(tmp_path / "o.h5"), "--quiet", *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert says.format(**{n: o.flag for n, o in by_name.items()}) in err[0], err


def test_options_with_overrides_are_the_keywords():
    """``measure_series(ref, cur, options, **overrides)`` measures as the keywords do."""
    lat = Lattice.from_pitch(5.0)
    ref = synthetic.grid_image((64, 64), lat)
    cur = synthetic.grid_image((64, 64), lat, displacement=lambda X, Y: (1e-3 * X, 0 * Y))
    by_keywords = measure_series(ref, cur, lattice=lat, guess=None, sigma=6.0)
    base = MeasureOptions(lattice=lat, guess=None, sigma=9.0)
    by_options = measure_series(ref, cur, base, sigma=6.0)
    assert by_options.parameters == by_keywords.parameters
    assert by_options.parameters["sigma"] == 6.0
    np.testing.assert_array_equal(by_options.strain, by_keywords.strain)
    # a lattice overridden by None is detected, whatever the options it replaces
    detected = measure_series(ref, cur, base, lattice=None, sigma=6.0)
    assert detected.lattice_detected
    assert detected.parameters["lattice"] is None


def test_every_option_is_documented():
    doc = measure_series.__doc__
    text = (DOCS / "user_guide" / "measure_options.rst").read_text(encoding="utf-8")
    for o in OPTIONS:
        assert f"\n    {o.name} : " in doc, o.name
        assert f"``{o.name}``" in text, o.name
        if o.flag is not None:
            assert f"``{o.flag}``" in text, o.flag
    # the page's table is the declaration's, written by the command
    assert cli_measure.options_table() in text
    # help() and editors see every keyword the overrides take, with its default
    shown = list(inspect.signature(measure_series).parameters.values())[3:]
    assert [(p.name, p.default) for p in shown] == [(o.name, o.default) for o in OPTIONS]


def _log(path: Path) -> Path:
    """A testing machine's log at 100 Hz, time in s, its force a ramp (N)."""
    t = np.arange(0, 151) / 100.0
    path.write_text("time (s);force (N)\n" + "".join(f"{a:.2f};{800 * a:.3f}\n" for a in t))
    return path


def test_a_replay_measures_the_same(tmp_path, capsys):
    """measure -> measure --config RESULT and -> MeasureOptions.from_parameters: the
    same maps, times and loads, the loads and frame rate recorded."""
    rec = tmp_path / "rec.tif"
    tifffile.imwrite(rec, record(3, (64, 80), strain=1e-3), photometric="minisblack")
    log = _log(tmp_path / "log.csv")
    first = tmp_path / "a.h5"
    args = ["measure", str(rec), "--reference-frames", "1", "--frame-rate", "10",
            "--loads", str(log), "--loads-offset", "0.05", "--time-column", "time",
            "--sigma-pitches", "1.2", "--margin", "3", "--noise-model", str(16 * K),
            str(256 * L), "--lossless", "--quiet"]
    assert main([*args, "-o", str(first)]) == 0, capsys.readouterr().err
    a = load(first)
    p = a.parameters
    assert (p["frame_rate"], p["each_frame"], p["reference_frames"]) == (10.0, True, 1)
    assert (p["loads"], p["loads_offset"], p["time_column"]) == (str(log), 0.05, "time")
    config = read_attrs(first)["config"]
    assert "frame-rate = 10.0" in config
    assert "reference-frames = 1" in config
    assert main(["measure", "--config", str(first), "-o", str(tmp_path / "b.h5"),
                 "--lossless", "--quiet"]) == 0, capsys.readouterr().err
    b = load(tmp_path / "b.h5")
    assert b.parameters == p
    for field in ("u", "strain"):
        np.testing.assert_array_equal(np.asarray(getattr(b, field)),
                                      np.asarray(getattr(a, field)))
    np.testing.assert_array_equal(b.time, a.time)
    np.testing.assert_array_equal(b.load, a.load)
    # in Python: the recorded options, the same inputs
    c = measure_series(None, str(rec), MeasureOptions.from_parameters(p))
    assert c.parameters == p
    np.testing.assert_array_equal(np.asarray(c.u), np.asarray(a.u))
    np.testing.assert_array_equal(c.load, a.load)


def test_to_edges_help_says_what_the_continuation_gets_exact():
    """The continuation measures a strain linear in space exactly at the edge pixels
    (tests/test_edges.py) and does not carry the grid's harmonics: the help says
    both, not a bias from the strain's gradient."""
    o = next(o for o in OPTIONS if o.name == "to_edges")
    for text in (o.help, o.doc):
        assert "linear in space" in text
        assert "harmonics" in text
        assert "gradient" not in text
