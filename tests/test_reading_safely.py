"""Every command that reads a result file, and ``gridstrain.load``, on a file that is not
what it was: replaced while it is read, damaged, or holding a configuration nested far
deeper than any gridstrain writes. Each gives one line naming the file and a non-zero
exit, never numbers from two files or a traceback.

The result files are measured from a record of the numpy-only generator of
``tests/sequence_record.py`` (64 x 80 px, three one-frame states): what a file holds
does not matter here, only that it is a real one.
"""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

import gridstrain
from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.series import measure_series
from sequence_record import record

LAT = Lattice.from_pitch(5.0)
DEEP = 600  # levels: Python's recursion limit is 1000 frames, a parser needs 1-3 a level


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("safe")
    out = {}
    for name, strain in (("a", 2e-3), ("b", -3e-3)):  # two files of the same layout
        frames = record(4, (64, 80), strain=strain, seed=1 if strain > 0 else 2)
        measure_series(frames[0][None], [f[None] for f in frames[1:]], lattice=LAT,
                       guess=None, output=d / f"{name}.h5", loads=[1.0, 2.0, 3.0])
        out[name] = d / f"{name}.h5"
    return out


def _commands(path, tmp):
    """The argv of every command that reads the result at ``path``."""
    return {
        "gauge": ["gauge", path, "-o", tmp / "g.csv"],
        "history": ["history", path, "-o", tmp / "h.csv"],
        "modulus": ["modulus", path, "--area", "2"],
        "plot": ["plot", path, "-o", tmp / "figs"],
        "animate": ["animate", path, "exx", "-o", tmp / "a.gif"],
        "report": ["report", path, "-o", tmp / "r.html"],
        "measure --config": ["measure", "--config", path, "-o", tmp / "again.h5"],
    }


def _one_line_error(argv, capsys, *, naming) -> str:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert rc == 2, (argv[0], err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, (argv[0], err[-2000:])
    assert str(naming) in lines[0], (argv[0], lines[0])
    assert "Traceback" not in out + err
    return lines[0]


@pytest.fixture
def damaged(files, tmp_path):
    """A copy of a result with 256 bytes flipped in its first 64 KiB (past the 512 of
    the HDF5 signature and superblock, so that it still opens as HDF5)."""
    path = tmp_path / "damaged.h5"
    data = bytearray(files["a"].read_bytes())
    assert len(data) > 65536
    for i in np.random.default_rng(0).integers(512, 65536, 256):
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))
    return path


COMMANDS = ("gauge", "history", "modulus", "plot", "animate", "report", "measure --config")


@pytest.mark.parametrize("command", COMMANDS)
def test_a_damaged_file_is_one_line_from_every_command(damaged, tmp_path, capsys, command):
    argv = _commands(damaged, tmp_path)[command]
    line = _one_line_error(argv, capsys, naming=damaged)
    assert "damaged" in line or "not a gridstrain result" in line or "cannot be read" in line


def test_a_damaged_file_is_one_error_from_load(damaged):
    with pytest.raises(ValueError, match=rf"^{damaged}: "):
        gridstrain.load(damaged)
    with pytest.raises(ValueError, match=rf"^{damaged}: "):
        gridstrain.load(damaged, in_memory=False)


@pytest.mark.parametrize("command", ["gauge", "history", "modulus", "plot", "animate",
                                     "report"])
def test_a_file_replaced_while_a_command_reads_it_is_refused(files, tmp_path, capsys,
                                                             monkeypatch, command):
    """The file is replaced (as ``mv`` or ``measure --overwrite`` do: another file
    renamed onto its path) once the command has read its first maps: the command stops
    with one line, rather than go on with the other file's states."""
    import gridstrain.results._file as rf

    path = tmp_path / "r.h5"
    shutil.copy(files["a"], path)
    other = tmp_path / "other.h5"
    shutil.copy(files["b"], other)
    real = rf.StoredMaps._read
    reads = []

    def replacing(self, states):
        out = real(self, states)
        reads.append(states)
        if len(reads) == 1:
            other.replace(path)
        return out

    monkeypatch.setattr(rf.StoredMaps, "_read", replacing)
    line = _one_line_error(_commands(path, tmp_path)[command], capsys, naming=path)
    assert "replaced" in line
    assert len(reads) == 1  # nothing read from the other file


def test_load_refuses_maps_of_a_file_replaced_since(files, tmp_path):
    path = tmp_path / "r.h5"
    shutil.copy(files["a"], path)
    lazy = gridstrain.load(path, in_memory=False)
    first = np.asarray(lazy.ux[0])
    shutil.copy(files["b"], tmp_path / "other.h5")
    (tmp_path / "other.h5").replace(path)
    with pytest.raises(ValueError, match=r"r\.h5: the result file was replaced"):
        lazy.ux[1]
    assert first.shape == (64, 80)


def _deep_toml() -> str:
    return "method = " + "[" * DEEP + "]" * DEEP + "\n"


def test_a_config_file_nested_600_deep_is_one_line(tmp_path, capsys):
    cfg = tmp_path / "deep.toml"
    cfg.write_text(_deep_toml())
    line = _one_line_error(["measure", "--config", cfg, "-o", tmp_path / "o.h5"], capsys,
                           naming=cfg)
    assert "nested too deep" in line


@pytest.mark.parametrize("command", COMMANDS)
def test_a_stored_configuration_nested_600_deep_never_crashes_a_command(
        files, tmp_path, capsys, command):
    """The result's ``config`` attribute replaced by a TOML text nested 600 deep: the
    commands that read only the maps run as on the file before; ``measure --config``,
    which parses it, refuses it in one line."""
    path = tmp_path / "r.h5"
    shutil.copy(files["a"], path)
    with h5py.File(path, "a") as h5:
        h5.attrs["config"] = _deep_toml()
    argv = [str(a) for a in _commands(path, tmp_path)[command]]
    if command == "measure --config":
        line = _one_line_error(argv, capsys, naming=path)
        assert "nested too deep" in line
        return
    rc = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    assert "RecursionError" not in out + err
    assert rc == 0 or len(err.strip().splitlines()) == 1, err[-2000:]
