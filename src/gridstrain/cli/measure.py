"""``gridstrain measure``: strain maps from a lab's image series.

The command only parses, draws progress and prints; the work is
:func:`gridstrain.series.measure_series`, :func:`gridstrain.results.save_result`
and :func:`gridstrain.post.save_figures`.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import re
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import h5py

from .. import __version__
from .._progress import bar
from .._runtime.memory import memory_budget, parse_size
from .._validation import check_positive
from ..io import (
    FrameSeries,
    OutputDirectory,
    open_series,
    read_mask,
    read_noise_model,
    roi_mask,
    state_inputs,
)
from ..results import (
    EXPORTS,
    MAP_FIELDS,
    ResultFile,
    SeriesResult,
    export,
    save_csv,
    save_result,
)
from ..series import (
    OPTIONS,
    MeasureOptions,
    Option,
    check_together,
    empty_state_message,
    measure_series,
    reference_lattice,
    state_names,
)
from ._common import (
    LATTICE_OPTIONS,
    add_option,
    check_output_file,
    lattice_option,
    make_folder,
    quiet_dask_logs,
    xy_pairs,
)
from ._summary import jsonable, report_lines, summary

_EXPORTS = tuple(EXPORTS)

_EXAMPLE = """example:
  gridstrain measure ref/ load1/ load2/ -o maps.h5 --mask mask.tif \\
      --pixel-size 0.04 --unit mm --report report.html --export mat,vtk,csv

REF and DEF are each an image file (TIFF, one frame or one per page; PNG, BMP,
JPEG; colour frames are read as their luminance), a video, a high-speed camera
record (Phantom .cine; Photron .mraw with its .cihx/.cih beside it), a directory
of images or a quoted glob ("run3/*.tif"); one DEF per loaded state. Options may also come from
--config FILE.toml, whose keys are the long option names (reference = "ref/",
states = ["load1/", "load2/"], pixel-size = 0.04, method = "B", roi = [10, 10, 300,
200], roi-polygon = [[10, 10], [300, 20], [150, 200]]...); paths in it are relative
to the file; options on the command line win; overwrite only from --overwrite.
Every result file stores the configuration of its run: 'gridstrain measure --config
RESULT.h5 -o again.h5' measures the same inputs with the same options, and takes
nothing else from the file (no output, overwrite, scheduler or timeout)."""


def _path(value, name):
    if not isinstance(value, str) or not value:
        raise ValueError(f"{name} must be a non-empty path, got {value!r}")
    return value


def _text(value, name):
    if not isinstance(value, str) or not value:
        raise ValueError(f"{name} must be a non-empty string, got {value!r}")
    return value


def _switch(value, name):
    return bool(value)


def _positive(value, name):
    return None if value is None else check_positive(value, name)


def _given(value, name):
    return value  # checked with the options it goes with (_checked)


# The command's own options: those it turns into measure_series's (the grid, the mask,
# the guess, the noise model, the output) and those of its outputs and report. Each
# is a flag and a configuration key (the flag without its dashes); recorded=False: how
# to run, never stored in a result, never taken from one (a result file from someone
# else replays the measurement and nothing else). A TOML file the user writes may set
# them, except ``overwrite``, which only --overwrite on the command line turns on.
_COMMAND_OPTIONS: tuple[Option, ...] = (
    *LATTICE_OPTIONS,
    Option("mask", None, _path, "", flag="--mask", kind="path", metavar="FILE",
           help="specimen mask image (nonzero = specimen), reference configuration"),
    Option("roi", None, _given, "", flag="--roi", kind="roi",
           metavar=("X0", "Y0", "X1", "Y1"),
           help="rectangle of interest, px: columns X0 <= x < X1, rows Y0 <= y < Y1 (with "
           "--mask: both)"),
    Option("roi_polygon", None, _given, "", flag="--roi-polygon", kind="polygon",
           metavar="X,Y", help="polygon of interest, its vertices as x,y in px (at least 3)"),
    Option("no_lagrangian", False, _switch, "", flag="--no-lagrangian", kind="bool",
           help="turn the large-displacement correction off"),
    Option("guess", None, _given, "", flag="--guess", kind="pairs", metavar=("UX", "UY"),
           help="displacement fixing the fringe order (the whole number of periods), px: "
           "once for the first state (series order; the others follow it) or for every "
           "state (independent order), or once per state (default: the previous state, "
           "else printed features, else the smallest displacement, flagged)"),
    Option("noise", None, _path, "", flag="--noise", kind="path", metavar="FILE.h5",
           group="noise",
           help="camera noise model written by 'gridstrain noise -o FILE.h5'"),
    Option("noise_model", None, _given, "", flag="--noise-model", kind="pair",
           metavar=("K", "L"), group="noise",
           help="camera noise Var = K l + L in the STORED grey levels of the images (K grey "
           "levels, L grey levels^2; for 12-bit data stored x16, 16 and 256 times the "
           "sensor's)"),
    Option("output", None, _path, "", flag="--output", kind="path", metavar="OUT.h5",
           group="output", recorded=False, help="output HDF5 file"),
    Option("pixel_size", None, _positive, "", flag="--pixel-size", kind="float",
           metavar="SIZE", group="output",
           help="pixel size on the specimen, in --unit (adds ux_phys, uy_phys)"),
    Option("grid_pitch", None, _positive, "", flag="--grid-pitch", kind="float",
           metavar="PITCH", group="output",
           help="the grid's printed pitch on the specimen, in --unit, instead of "
           "--pixel-size: the pixel size is PITCH / the pitch detected in px"),
    Option("unit", None, _text, "", flag="--unit", metavar="UNIT", group="output",
           help="length unit of --pixel-size or --grid-pitch (e.g. mm)"),
    Option("csv", None, _path, "", flag="--csv", kind="path", metavar="FILE",
           group="output", recorded=False,
           help="also write one CSV row per valid pixel"),
    Option("figures", None, _path, "", flag="--figures", kind="path", metavar="DIR",
           group="output", recorded=False, help="also write PNG maps into DIR"),
    Option("export", None, _given, "", flag="--export", kind="formats",
           metavar="FORMATS", group="output", recorded=False,
           help="also write mat (MATLAB), vtk (ParaView: a .pvd time series of .vti), csv "
           "and/or netcdf (a clean NetCDF-4 copy) next to the output, comma-separated "
           "(e.g. mat,vtk); gridstrain export does the same later"),
    Option("phase_maps", False, _switch, "", flag="--phase-maps", kind="bool",
           group="output",
           help="also store the phase maps of every series in the output (about 3x the "
           "file; gridstrain.load then gives them back). Holds every state's maps in "
           "memory until the end: without it each state is written as soon as it is "
           "measured"),
    Option("lossless", False, _switch, "", flag="--lossless", kind="bool", group="output",
           recorded=False,
           help="store the maps exactly as measured (float64 unless the frames are "
           "float32), uncompressed: 24x the default file on a record of one-frame states. "
           "By default each map is stored in float32 rounded to a tenth of its own "
           "predicted std at each pixel (rotation: exy's), the std maps to 1.6 %%, "
           "compressed"),
    Option("report", None, _path, "", flag="--report", kind="path", metavar="FILE.html",
           group="output", recorded=False,
           help="also write a self-contained HTML report of the run"),
    Option("overwrite", False, _switch, "", flag="--overwrite", kind="bool",
           group="output", recorded=False,
           help="replace the output files an earlier gridstrain run wrote, unchanged since "
           "(never another file)"),
    Option("quiet", False, _switch, "", flag="--quiet", kind="bool", group="output",
           recorded=False, help="no progress bar and no report"),
    Option("json", False, _switch, "", flag="--json", kind="bool", group="output",
           recorded=False, help="print a JSON summary on stdout instead of the report"),
)

# Every flag of the command that is an option of the measurement or of its outputs, by
# its configuration key: measure_series's own (gridstrain.series.OPTIONS) and the
# command's.
_FLAGGED = {o.key: o for o in (*OPTIONS, *_COMMAND_OPTIONS) if o.flag is not None}
# The keys of a TOML configuration file (``pixel-size`` or ``pixel_size``), with the
# type each must have there: the inputs, then every flagged option.
_CONFIG_KEYS = {"reference": "source", "states": "sources",
                **{key: o.kind for key, o in _FLAGGED.items()}}
# How to run, not what to measure (see _COMMAND_OPTIONS).
_RUN_ONLY = tuple(key for key, o in _FLAGGED.items() if not o.recorded)
_SWITCHES = tuple(key for key, o in _FLAGGED.items() if o.kind == "bool")
_MEASURED = {o.name: o for o in OPTIONS}

# The sections of the help, by an option's group.
_GROUPS = (
    ("window", "grid and window"),
    ("specimen", "specimen and kinematics"),
    ("sequence", "sequences (one image per load step or camera frame)"),
    ("noise", "noise (default: measured in each series; from the image itself for single "
     "frames)"),
    ("output", "output"),
    ("distributed", "distributed (needs gridstrain[distributed])"),
)


def register(sub) -> None:
    p = sub.add_parser(
        "measure", help="displacement and strain maps from image series",
        description="Measure displacement and strain maps of loaded states against a "
        "reference, from series of grid images; diagnose vibrations and state the noise "
        "floor. Writes one HDF5 file.", epilog=_EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("reference", metavar="REF", nargs="?",
                   help="reference series (or reference = ... in the config)")
    p.add_argument("states", metavar="DEF", nargs="*",
                   help="loaded state series, in order (or states = [...] in the config)")
    groups = {key: p.add_argument_group(title) for key, title in _GROUPS}
    for o in _FLAGGED.values():
        add_option(groups[o.group], o)
    out = groups["output"]
    out.add_argument("--memory-budget", type=_size, metavar="SIZE",
                     help="memory the run may use, e.g. 3G or 500M (default: the memory "
                     "available, the least of the system's and the cgroup's limit); a run "
                     "estimated to need more is refused before it starts")
    out.add_argument("--config", metavar="FILE.toml", help="read options from a TOML file")
    p.set_defaults(func=run)


def _first_sentence(doc: str) -> str:
    """The first sentence of a parameter's text (its type line left out)."""
    text = " ".join(line.strip() for line in doc.splitlines()[1:])
    return re.split(r"(?<!e\.g)\. ", text)[0].rstrip(".") + "."


def options_table() -> str:
    """The reStructuredText table of every option of the command, from the
    declarations: its flag and configuration key, the measure_series keyword it gives,
    whether a replay takes it from a result, and its help. The documentation's
    page of options (``docs/user_guide/measure_options.rst``) holds it as written."""
    feeds = {flag: o.name for o in OPTIONS for flag in o.via}
    rows = [("Flag (configuration key)", "``measure_series``", "Replayed", "What it sets")]
    for key, o in _FLAGGED.items():
        python = o.name if o.name in _MEASURED else feeds.get(o.flag)
        rows.append((f"``{o.flag}`` (``{key}``)", f"``{python}``" if python else "",
                     "yes" if o.recorded else "no (run-only)", o.help.replace("%%", "%")))
    for o in OPTIONS:
        if o.flag is None:
            via = ", ".join(f"``{f}``" for f in o.via) or "(Python only)"
            # the command replays what it gave from the flags it stores
            kept = [f for f in o.via if f[2:] in _FLAGGED and _FLAGGED[f[2:]].recorded]
            replayed = ("yes" if kept and len(kept) == len(o.via) else
                        "only " + ", ".join(f"``{f}``" for f in kept) if kept else
                        "no (run-only)")
            rows.append((via, f"``{o.name}``", replayed,
                         _first_sentence(o.doc)))
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 24 18 12 46", ""]
    for row in rows:
        lines.append(f"   * - {row[0]}")
        lines.extend(f"     - {cell}" for cell in row[1:])
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- options


def _config_value(key: str, value, kind: str, base: Path, where: str):
    def bad(expected):
        return ValueError(f"{where}: {key} must be {expected}, got {value!r}")

    if kind in ("float", "int"):
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or (kind == "int" and not isinstance(value, int)):
            raise bad("an integer" if kind == "int" else "a number")
        return float(value) if kind == "float" else int(value)
    if kind == "pairs":  # one pair, or a list of pairs (one per state)
        if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
            return [_config_value(key, v, "pair", base, where) for v in value]
        return [_config_value(key, value, "pair", base, where)]
    if kind == "pair":
        if not isinstance(value, list) or len(value) != 2 or any(
                isinstance(v, bool) or not isinstance(v, int | float) for v in value):
            raise bad("a list of two numbers")
        return [float(v) for v in value]
    if kind == "bool":
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if kind == "roi":
        if not isinstance(value, list) or len(value) != 4 or any(
                isinstance(v, bool) or not isinstance(v, int) for v in value):
            raise bad("a list of four integers [x0, y0, x1, y1]")
        return list(value)
    if kind == "polygon":
        if not isinstance(value, list) or any(
                not isinstance(v, list) or len(v) != 2 or any(
                    isinstance(c, bool) or not isinstance(c, int | float) for c in v)
                for v in value):
            raise bad("a list of [x, y] vertices")
        return [[float(c) for c in v] for v in value]
    if kind == "formats":
        return _formats(value, f"{where}: {key}")
    if kind == "source":
        if isinstance(value, list) and value and all(isinstance(v, str) and v
                                                     for v in value):
            return [_config_value(key, v, "path", base, where) for v in value]
        return _config_value(key, value, "path", base, where)
    if kind == "sources":
        if not isinstance(value, list) or not value:
            raise bad("a list of series (each a path, a glob or a list of files)")
        return [_config_value(key, v, "source", base, where) for v in value]
    if kind == "method":
        if not isinstance(value, str) or value.upper() not in ("A", "B", "C"):
            raise bad('"A", "B" or "C"')
        return value.upper()
    if not isinstance(value, str) or not value:
        raise bad("a non-empty string")
    if kind == "path":
        p = Path(os.path.expanduser(value))
        return str(p if p.is_absolute() else base / p)
    return value


def _formats(value, where: str) -> list[str]:
    items = value.split(",") if isinstance(value, str) else value
    if not isinstance(items, list) or not items or any(
            not isinstance(v, str) or v.strip().lower() not in _EXPORTS for v in items):
        raise ValueError(f"{where} must list formats among {', '.join(_EXPORTS)} (e.g. "
                         f"mat,vtk), got {value!r}")
    return list(dict.fromkeys(v.strip().lower() for v in items))


def _polygon(values) -> list[list[float]]:
    return xy_pairs(values, "--roi-polygon")


@dataclass(frozen=True)
class _Config:
    """The options a ``--config`` file gave, and the keys it had that were not taken."""

    path: Path
    options: dict
    from_result: bool
    ignored: tuple = ()

    def taken(self, opts: dict) -> list[str]:
        """The keys of the file whose values the run uses (the command line gave no
        other)."""
        return [k for k in self.options if opts.get(k) == self.options[k]]


# A configuration nests one level (the lists of states and guesses): thousands of
# levels are a file made to crash its reader, refused in one line.
_TOO_DEEP = ("arrays or tables nested too deep to read (a gridstrain configuration "
             "nests one level)")


def _read_config(path: str) -> _Config:
    p = Path(os.path.expanduser(path))
    if not p.is_file():
        raise FileNotFoundError(f"config file {p} does not exist")
    from_result = h5py.is_hdf5(p)
    if from_result:  # a result file: the configuration of its run
        from ..results import read_attrs

        text = read_attrs(p).get("config")
        if not isinstance(text, str):
            raise ValueError(f"config {p}: this HDF5 file holds no gridstrain configuration")
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{p}: /config: not valid TOML ({exc})") from None
        except RecursionError:
            raise ValueError(f"{p}: /config: {_TOO_DEEP}") from None
    else:
        try:
            with open(p, "rb") as fh:
                data = tomllib.load(fh)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"config {p}: not valid TOML ({exc})") from None
        except RecursionError:
            raise ValueError(f"config {p}: {_TOO_DEEP}") from None
    where = f"{p}: /config" if from_result else f"config {p}"
    out, ignored = {}, []
    for key, value in data.items():
        name = key.replace("_", "-")
        if name not in _CONFIG_KEYS:
            raise ValueError(f"{where}: unknown key {key!r}; allowed keys are "
                             f"{', '.join(sorted(_CONFIG_KEYS))}")
        if from_result and name in _RUN_ONLY:
            ignored.append(name)
            continue
        if name == "overwrite":
            raise ValueError(f"{where}: overwrite is not taken from a file; pass "
                             "--overwrite on the command line")
        value = _config_value(key, value, _CONFIG_KEYS[name], p.parent, where)
        out[name] = _checked_value(name, value, f"{where}: {key}")
    return _Config(p, out, from_result, tuple(ignored))


def _replay_line(config: _Config, opts: dict) -> str:
    """What a replay took from the result file, what the command line gave instead,
    and what it left."""
    taken = config.taken(opts)
    line = f"replaying the measurement of {config.path}: " + (
        ", ".join(taken) if taken else "no option") + " from the file"
    over = [k for k in config.options if k not in taken]
    if over:
        line += f"; {', '.join(over)} from the command line"
    if config.ignored:
        line += f"; ignored run-only {', '.join(config.ignored)}"
    return line


def _checked_value(key: str, value, label: str):
    """``value`` of option ``key`` by its declaration's check, its errors naming
    ``label`` (the flag, or the configuration file and key), as a configuration file
    writes it."""
    o = _FLAGGED.get(key)
    return value if o is None else o.record(o.check(value, label))


def _options(args, config: _Config | None = None) -> dict:
    """The options of the command line over those of the config file."""
    opts = dict(config.options) if config else {}
    for name in _CONFIG_KEYS:
        value = getattr(args, name.replace("-", "_"))
        if name == "states" and not value:
            continue
        if name == "export" and value is not None:
            value = _formats(value, "--export")
        if name == "roi-polygon" and value is not None:
            value = _polygon(value)
        if value is not None:
            if name == "guess":
                value = [list(v) for v in value]
            value = list(value) if isinstance(value, tuple) else value
            opts[name] = _checked_value(name, value, f"--{name}")
    record = opts.get("reference-frames") is not None
    if not opts.get("reference") or not (opts.get("states") or record):
        raise ValueError("the inputs are missing: give REF and at least one DEF (or "
                         "reference = ... and states = [...] in the config file; with "
                         "--reference-frames N, REF is the record)")
    for name in _SWITCHES:
        opts[name] = bool(opts.get(name, False))
    for key, o in _FLAGGED.items():  # the measurement's defaults, recorded as such
        if o.name not in _MEASURED or opts.get(key) is not None:
            continue
        default = o.default if o.command_default is None else o.command_default
        if default is not None and (o.recorded or o.command_default is not None):
            opts[key] = o.record(default)
    if not opts.get("output"):
        raise ValueError("the output file is missing: pass -o OUT.h5 (or output = ... in "
                         "the config file)")
    return opts


def _check_outputs(opts: dict, n_states: int, inputs: set[Path]) -> None:
    """Refuse, before any work, what would fail or clobber at the end."""
    out = Path(os.path.expanduser(opts["output"]))
    _check_distinct(opts, out)
    check_output_file(out, "output file", opts["overwrite"], inputs)
    if opts.get("csv"):
        csv = Path(os.path.expanduser(opts["csv"]))
        check_output_file(csv, "CSV file", opts["overwrite"], inputs)
    if opts.get("figures"):
        # only figures an earlier run wrote there are replaced (its marker lists them)
        from ..post import figure_names  # matplotlib only when figures are asked

        figures = Path(os.path.expanduser(opts["figures"]))
        make_folder(figures.parent, "figures directory")  # the folder itself: save_figures
        OutputDirectory(figures, figure_names(n_states), overwrite=opts["overwrite"],
                        what="figures directory")
    for f in opts.get("export") or ():
        check_output_file(_export_path(out, f), f"{f} export", opts["overwrite"], inputs)
    if opts.get("report"):
        check_output_file(Path(os.path.expanduser(opts["report"])), "report file",
                          opts["overwrite"], inputs)


def _check_distinct(opts: dict, out: Path) -> None:
    """Refuse two of the run's files under one name: the second written would replace
    the first (with --overwrite, silently: a report in place of the result)."""
    named = [("-o", out)]
    if opts.get("csv"):
        named.append(("--csv", Path(os.path.expanduser(opts["csv"]))))
    named += [(f"--export {f}", _export_path(out, f)) for f in opts.get("export") or ()]
    if opts.get("report"):
        named.append(("--report", Path(os.path.expanduser(opts["report"]))))
    seen: dict[Path, str] = {}
    for flag, path in named:
        key = path.resolve()
        if key in seen:
            hint = (" (an export is named after the output: give the output the "
                    "suffix .h5)" if seen[key] == "-o" and flag.startswith("--export")
                    else "")
            raise ValueError(f"{seen[key]} and {flag} name the same file {path}: give "
                             f"each output its own name{hint}")
        seen[key] = flag


def _export_path(out: Path, fmt: str) -> Path:
    return out.with_suffix(EXPORTS[fmt].suffix)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v) if math.isfinite(v) else ("nan" if v != v else
                                                 ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string: JSON's escapes are TOML's
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


def config_text(opts: dict) -> str:
    """The TOML configuration that replays a run: its inputs and every option."""
    lines = [f"# gridstrain {__version__} measure: replay with "
             "'gridstrain measure --config THIS_FILE -o OUT.h5'"]
    for key in _CONFIG_KEYS:
        if key in opts and key not in _RUN_ONLY and opts[key] is not None:
            lines.append(f"{key} = {_toml_value(opts[key])}")
    return "\n".join(lines) + "\n"


def _absolute(source):
    if isinstance(source, list):
        return [_absolute(s) for s in source]
    return str(Path(os.path.abspath(os.path.expanduser(source))))


def _refuse_empty(result: SeriesResult) -> None:
    """A state without a single valid pixel is a failure, never a written result."""
    for i in range(result.n_states):
        if not result.valid[i].any():
            raise ValueError(empty_state_message(
                result.names[i + 1], result.margin, result.sigma, result.guesses[i],
                result.guess_sources[i]))


def _noise_option(opts: dict):
    """The camera model of --noise or --noise-model, or None."""
    if opts.get("noise") and opts.get("noise-model"):
        raise ValueError("give --noise or --noise-model, not both")
    if opts.get("noise"):
        return read_noise_model(Path(os.path.expanduser(opts["noise"])))
    if opts.get("noise-model"):
        K, L = opts["noise-model"]
        if not (math.isfinite(K) and K > 0):
            raise ValueError(f"--noise-model K must be a positive gain in stored grey levels, "
                             f"got {K:g}")
        if not math.isfinite(L):
            raise ValueError(f"--noise-model L must be a finite variance, got {L:g}")
        return (K, L)
    return None


def _input_files(sources) -> set[Path]:
    files = set()
    for s in sources:
        for p in s.paths:
            files.add(Path(p).resolve())
    return files


# --------------------------------------------------------------------------- run


class _Bar:
    """The progress bar, remembering whether a line was left open on stderr."""

    def __init__(self, quiet: bool):
        self.open = False
        self.configure(quiet)

    def configure(self, quiet: bool) -> None:
        """Draw or not (``quiet`` may come from the configuration file)."""
        self._draw = bar(quiet=quiet)
        self._quiet = quiet

    def __call__(self, fraction: float, message: str) -> None:
        self._draw(fraction, message)
        if not self._quiet:
            self.open = fraction < 1.0

    def close(self) -> None:
        """End an open bar line, so that an error message gets a line of its own."""
        if hasattr(self._draw, "close"):
            self._draw.close()
            self.open = False
        if self.open:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self.open = False


def _size(text: str) -> int:
    try:
        return parse_size(text, name="--memory-budget")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run(args) -> int:
    progress = _Bar(quiet=bool(args.quiet))
    try:
        with memory_budget(args.memory_budget):
            return _run(args, progress)
    except BaseException:
        progress.close()
        raise


def _run(args, progress: _Bar) -> int:
    t0 = time.perf_counter()
    config = _read_config(args.config) if args.config else None
    opts, lattice, measured = _checked(_options(args, config))
    progress.configure(opts["quiet"])
    replay = {}
    if config is not None:
        replay["config_keys"] = config.taken(opts)
        replay["config_ignored"] = list(config.ignored)
        if config.from_result and not opts["quiet"]:
            print(_replay_line(config, opts), file=sys.stderr)
        if config.from_result and opts.get("loads") and args.loads is None:
            _check_replayed_loads(config.path, opts["loads"])
    reference, states, mask = _inputs(opts, args)
    ps, unit = _pixel_size(opts, lattice, reference, mask), opts.get("unit")
    stored = dict(opts)
    # the side outputs and the summary use the pixel size, however it was given
    opts["pixel-size"] = ps
    for key in ("reference", "states", "output", "mask", "loads"):
        if stored.get(key):
            stored[key] = _absolute(stored[key])
    extra = {"config": config_text(stored),
             "config_file": args.config or "", "mask_file": opts.get("mask") or "",
             **replay}
    # each state written as soon as it is measured, unless every state's phase maps
    # are to be stored with them
    spec = None if opts["phase-maps"] else ResultFile(
        opts["output"], pixel_size=ps, unit=unit, overwrite=opts["overwrite"], attrs=extra,
        dtype=opts.get("dtype"), lossless=opts["lossless"] or opts.get("dtype") is not None)
    options = dataclasses.replace(measured, mask=mask, output=spec, progress=progress)
    # with a cluster, its failures are one line (cli.main), not Dask's log records
    dask_logs = quiet_dask_logs() if opts.get("scheduler") else contextlib.nullcontext()
    with dask_logs:
        result = measure_series(
            None if opts.get("reference-frames") is not None else reference, states,
            options)
    if ps is not None:  # the result carries its file's pixel size (and the outputs use it)
        result = dataclasses.replace(result, pixel_size=ps, unit=unit)
    if spec is None:
        _refuse_empty(result)
        out = save_result(result, opts["output"], pixel_size=ps, unit=unit,
                          overwrite=opts["overwrite"], attrs=extra, phase_maps=True,
                          lossless=opts["lossless"] or opts.get("dtype") is not None)
    else:
        out = Path(os.path.expanduser(os.fspath(opts["output"])))
    outputs = _extra_outputs(result, out, opts, progress)
    _print(result, out, opts, outputs, time.perf_counter() - t0)
    return 0


def _check_replayed_loads(result: Path, loads) -> None:
    """Refuse to replay a run on a loads file other than the one it read: its SHA-256,
    recorded in the result, must match (a file given by --loads is taken as it is)."""
    import hashlib

    from ..results import load

    recorded = (load(result, in_memory=False).load_source or {}).get("sha256")
    path = Path(os.path.expanduser(loads))
    if recorded is None or not path.is_file():
        return  # loads given as numbers, or an older result: nothing to compare
    now = hashlib.sha256(path.read_bytes()).hexdigest()
    if now != recorded:
        raise ValueError(f"loads file {path} has changed since {result} was measured "
                         f"(SHA-256 {now[:12]}... now, {recorded[:12]}... then); pass "
                         "--loads to replay with it as it is")


def _label(name: str) -> str:
    """How an error names option ``name`` of measure_series: by its flag."""
    o = _MEASURED[name]
    return o.flag or (o.via[0] if o.via else name)


def _measure_options(opts: dict, lattice, noise_model) -> MeasureOptions:
    """measure_series's options from the command's, checked together (each was
    checked as it came in: _checked_value)."""
    values = {o.name: o.replay(opts[o.key]) for o in OPTIONS
              if o.flag is not None and opts.get(o.key) is not None}
    guesses = opts.get("guess")
    guess = "auto" if guesses is None else tuple(guesses[0]) if len(guesses) == 1 \
        else [tuple(g) for g in guesses]
    if values.get("loads") is not None:
        values["loads"] = os.path.expanduser(values["loads"])
    return check_together(MeasureOptions(
        **values, lattice=lattice, noise_model=noise_model, guess=guess,
        lagrangian=not opts["no-lagrangian"]), label=_label)


def _checked(opts: dict) -> tuple:
    """The options, refused with one line each where they cannot be right, with the
    lattice they give and measure_series's options (the noise model read once)."""
    noise_model = _noise_option(opts)
    if opts.get("pixel-size") is not None and opts.get("grid-pitch") is not None:
        raise ValueError("give --pixel-size or --grid-pitch, not both")
    scale = "--grid-pitch" if opts.get("grid-pitch") is not None else "--pixel-size"
    if (opts.get(scale[2:]) is None) != (opts.get("unit") is None):
        raise ValueError(f"{scale} and --unit go together (e.g. --pixel-size 0.04 --unit "
                         "mm, or --grid-pitch 0.2 --unit mm)")
    lattice = lattice_option(opts)
    guesses = opts.get("guess")
    n = len(opts.get("states") or ())
    frames = opts["each-frame"] or opts.get("reference-frames") is not None
    if guesses is not None and not frames and len(guesses) not in (1, n):
        raise ValueError(f"--guess given {len(guesses)} times: give it once (the first "
                         f"state, or every state with --order independent) or once per "
                         f"state ({n})")
    return opts, lattice, _measure_options(opts, lattice, noise_model)


def _pixel_size(opts: dict, lattice, reference, mask) -> float | None:
    """``--pixel-size``, or the grid's printed pitch over its pitch in px: that of
    the lattice given, else of the lattice detected as the measurement does."""
    grid_pitch = opts.get("grid-pitch")
    if grid_pitch is None:
        return opts.get("pixel-size")
    if lattice is None:
        lattice = reference_lattice(reference, mask=mask, margin=opts["margin"])
    try:
        return lattice.pixel_size(grid_pitch)
    except ValueError as exc:
        raise ValueError(f"--grid-pitch: {str(exc).removeprefix('grid_pitch: ')}") from None


def _inputs(opts: dict, args) -> tuple:
    """The series opened, the mask (with the regions of interest), and the outputs
    checked against the inputs (never written over an input)."""
    bits = opts.get("bit-depth")
    keep = opts["keep-order"]
    if opts.get("reference-frames") is not None:  # REF and any DEF: one record
        record = [opts["reference"], *(opts.get("states") or ())]
        given = state_inputs(record, reference_frames=opts["reference-frames"],
                             keep_order=keep, bit_depth=bits)
        reference = given.reference
    else:
        reference = open_series(opts["reference"], name="reference", bit_depth=bits)
        given = state_inputs(opts["states"], each_frame=opts["each-frame"], keep_order=keep,
                             bit_depth=bits)
    states = [s if isinstance(s, FrameSeries) else open_series(s, name=name, bit_depth=bits)
              for s, name in zip(given.states, state_names(given.states), strict=True)]
    given = dataclasses.replace(given, states=tuple(states))
    inputs = _input_files([reference, *states])
    mask = None
    if opts.get("mask"):
        mask_path = Path(os.path.expanduser(opts["mask"]))
        inputs.add(mask_path.resolve())
        mask = read_mask(mask_path, reference.shape)
    if opts.get("roi") is not None or opts.get("roi-polygon") is not None:
        roi = roi_mask(reference.shape, rectangle=opts.get("roi"),
                       polygon=opts.get("roi-polygon"))
        mask = roi if mask is None else mask & roi
        if not mask.any():
            raise ValueError("the region of interest and the mask have no pixel in common")
    if args.config:
        inputs.add(Path(os.path.expanduser(args.config)).resolve())
    if opts.get("loads"):
        inputs.add(Path(os.path.expanduser(opts["loads"])).resolve())
    _check_outputs(opts, len(states), inputs)
    return reference, given, mask


def _extra_outputs(result, out: Path, opts: dict, progress) -> dict:
    """The CSV, exports, report and figures asked for, by kind."""
    ps, unit, overwrite = opts.get("pixel-size"), opts.get("unit"), opts["overwrite"]
    outputs = {"hdf5": str(out)}
    if opts.get("csv"):
        outputs["csv"] = str(save_csv(result, opts["csv"], overwrite=overwrite,
                                      pixel_size=ps, unit=unit))
    if opts.get("export"):
        written = export(result, out.with_suffix(""), opts["export"], pixel_size=ps,
                         unit=unit, overwrite=overwrite)
        outputs["export"] = {k: str(v) for k, v in written.items()}
    if opts.get("report"):
        from ..post import write_report

        outputs["report"] = str(write_report(out, opts["report"], overwrite=overwrite))
    if opts.get("figures"):
        from ..post import save_figures  # matplotlib only when figures are asked

        figs = save_figures(result, opts["figures"], pixel_size=ps, unit=unit,
                            overwrite=overwrite, progress=progress)
        outputs["figures"] = [str(f) for f in figs]
    return outputs


def _print(result, out: Path, opts: dict, outputs: dict, seconds: float) -> None:
    """The report on stdout (or the JSON summary)."""
    ps, unit = opts.get("pixel-size"), opts.get("unit")
    if opts["json"]:
        json.dump(jsonable(summary(result, outputs=outputs, seconds=seconds, pixel_size=ps,
                                   unit=unit)), sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
        return
    if opts["quiet"]:
        return
    lines = report_lines(result, pixel_size=ps, unit=unit)
    H, W = result.shape
    lines.append(f"wrote {out} ({', '.join(MAP_FIELDS)}, valid: {result.n_states} x {H} "
                 f"x {W}) in {seconds:.1f} s")
    if "csv" in outputs:
        lines.append(f"wrote {outputs['csv']} (one row per valid pixel)")
    if "figures" in outputs:
        lines.append(f"wrote {len(outputs['figures'])} figures into {opts['figures']}")
    for path in (outputs.get("export") or {}).values():
        lines.append(f"wrote {path}")
    if "report" in outputs:
        lines.append(f"wrote {outputs['report']} (open it in a browser)")
    print("\n".join(lines))
