"""The states of a result as a ParaView time series: a ``.pvd`` collection of ``.vti`` files.

Written with the standard library (XML, zlib, base64): pyevtk's ``imageToVTK``
writes uncompressed appended data only, which would make a long record several
times larger, and sets no time values.

The frame (ParaView's y axis points up, the image's rows go down): a point of
column ``x`` and row ``y`` sits at ``X = x s``, ``Y = -y s`` (``s`` the pixel size,
1 without one), a rotation of the image plane by 180 degrees about its x axis,
so that ParaView shows the specimen as the camera saw it. The ``.vti`` files
hold the rows bottom first with origin ``(0, -(H - 1) s, 0)`` and a positive
spacing, which every VTK reader understands (no direction matrix needed).
Vectors and tensor components are given in that frame: the displacement vector is
``(u_x, -u_y, 0)``, and ``exy`` and ``rotation`` change sign (Y = -y); ``exx``,
``eyy`` and every std are unchanged. The frame is stated in a comment of each file.
"""

from __future__ import annotations

import base64
import re
import struct
import zlib

import numpy as np

from .._validation import check_pixel_size, check_type
from ..io import OutputDirectory, write_atomic
from ._loads import state_loads
from ._result import SeriesResult

FRAME = ("X = x * pixel size, Y = -y * pixel size (image rows downwards, ParaView's Y "
         "upwards): displacement = (ux, -uy, 0); exy and rotation change sign")


# characters XML 1.0 cannot hold (control characters, lone surrogates): a state's name
# or a unit from someone else's file may have them, and would make the file unreadable
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def quoteattr(text: str) -> str:
    """:func:`xml.sax.saxutils.quoteattr`, imported when a file is written: it brings
    ``urllib.request`` and ``http.client`` with it, 15 ms and more of every command's
    start-up otherwise."""
    from xml.sax.saxutils import quoteattr

    return quoteattr(text)


def _xml_text(text: str) -> str:
    return _NOT_XML.sub("\ufffd", str(text))


def _array(name: str, arr: np.ndarray, components: int = 1) -> str:
    a = np.ascontiguousarray(arr).reshape(-1)
    raw = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
    comp = zlib.compress(raw, 6)
    # zlib-compressed binary: one block, header (count, block size, last size, sizes)
    header = struct.pack("<4Q", 1, len(raw), len(raw), len(comp))
    kind = {"f4": "Float32", "f8": "Float64", "u1": "UInt8"}[a.dtype.str[1:]]
    return (f"        <DataArray type={quoteattr(kind)} Name={quoteattr(_xml_text(name))} "
            f'NumberOfComponents="{components}" format="binary">'
            f"{base64.b64encode(header).decode()}{base64.b64encode(comp).decode()}"
            "</DataArray>\n")


def _field_data(values: dict) -> str:
    """One-value arrays of the whole image (a state's time and load), in ParaView's
    Information panel."""
    if not values:
        return ""
    rows = "".join(f"      <DataArray type=\"Float64\" Name={quoteattr(_xml_text(name))} "
                   f'NumberOfTuples="1" format="ascii">{float(v)!r}</DataArray>\n'
                   for name, v in values.items())
    return f"    <FieldData>\n{rows}    </FieldData>\n"


def _vti(fields: dict, H: int, W: int, s: float, notes: dict,
         field_data: dict | None = None) -> bytes:
    extent = f"0 {W - 1} 0 {H - 1} 0 0"
    # notes as a comment: every reader skips it, and a person reading the file sees it
    comment = _xml_text("; ".join(f"{k}: {v}" for k, v in notes.items())
                        .replace("--", "- -"))
    vector = next(k for k in fields if k.startswith("displacement"))
    arrays = "".join(_array(name, arr, comps) for name, (arr, comps) in fields.items())
    text = ('<?xml version="1.0"?>\n'
            '<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian" '
            'header_type="UInt64" compressor="vtkZLibDataCompressor">\n'
            f'  <ImageData WholeExtent="{extent}" Origin="0 {-(H - 1) * s!r} 0" '
            f'Spacing="{s!r} {s!r} 1">\n'
            f"    <!-- {comment} -->\n" + _field_data(field_data or {}) +
            f'    <Piece Extent="{extent}">\n      <PointData Vectors={quoteattr(vector)}>\n'
            + arrays + "      </PointData>\n    </Piece>\n  </ImageData>\n</VTKFile>\n")
    return text.encode("utf-8")


def _up(a) -> np.ndarray:
    """A map ``[y, x]`` in the order of the points: the bottom row first, float32."""
    return np.asarray(a)[::-1].astype(np.float32)


def export_pvd(result: SeriesResult, path, *, pixel_size: float | None = None,
               unit: str | None = None, overwrite: bool = False, load=None,
               load_unit: str | None = None, time=None):
    """Write the states as a ParaView time series, atomically file by file.

    Parameters
    ----------
    result : SeriesResult
    path : str or os.PathLike
        The ``.pvd`` collection; the ``.vti`` files, one per state, go into the
        folder ``<stem>_vti`` beside it (listed in its marker, so that
        ``overwrite`` replaces only files gridstrain wrote).
    pixel_size, unit : float, str, optional
        Coordinates and displacements in ``unit``; px without them.
    load, load_unit, time : optional
        Per state: the time values are the times (s), else the loads, else the
        state's index (default: the result's own).

    Returns
    -------
    pathlib.Path
        The ``.pvd`` file.

    Notes
    -----
    Point data of each state (float32: 7 significant digits, for viewing):
    ``displacement [UNIT]`` (a 3-component vector, see the module's frame),
    ``exx [-]``, ``eyy [-]``, ``exy [-]``, ``rotation [rad]``, the derived strains
    ``e1 [-]``, ``e2 [-]``, ``principal_angle [rad]`` (from X towards Y: the sign of
    the image frame's angle changes), ``equivalent [-]``, ``max_shear [-]``, the
    finite strains ``gl_xx [-]``... ``log_xy [-]`` (Lagrangian results; the shears'
    sign changes with Y), the std maps (``exx_std [-]``, ``e1_std [-]``...,
    ``rotation_std [rad]``) and ``valid`` (0/1); NaN where not
    valid. Field data of each state (one value): ``time [s]`` and ``load [UNIT]``
    when known.
    """
    from pathlib import Path

    check_type(result, "result", SeriesResult)
    ps, unit = check_pixel_size(pixel_size, unit)
    s, u = (1.0, "px") if ps is None else (ps, unit)
    load, load_unit, time = state_loads(result, load=load, load_unit=load_unit, time=time)
    steps, what = (time, "time [s]") if time is not None else \
        (load, f"load [{load_unit or '-'}]") if load is not None else \
        (np.arange(result.n_states, dtype=float), "state index")
    dest = Path(path)
    folder = dest.with_name(dest.stem + "_vti")
    names = [f"state_{i:05d}.vti" for i in range(result.n_states)]
    out = OutputDirectory(folder, names, overwrite=overwrite, what="ParaView folder")
    out.prepare()
    H, W = result.shape
    unc = result.uncertainty or {}
    for i, name in enumerate(names):
        ux, uy = _up(result.ux[i]) * s, _up(result.uy[i]) * s
        fields = {f"displacement [{u}]": (np.stack([ux, -uy, np.zeros_like(ux)], axis=-1),
                                          3),
                  "exx [-]": (_up(result.exx[i]), 1), "eyy [-]": (_up(result.eyy[i]), 1),
                  "exy [-]": (-_up(result.exy[i]), 1),
                  "rotation [rad]": (-_up(result.measurements[i].rotation), 1)}
        derived = result.derived_maps(i)
        for key, arr in derived.items():
            if key.endswith("_std"):
                continue
            # Y = -y: an angle and a shear change sign
            sign = -1.0 if key == "principal_angle" or key.endswith("_xy") else 1.0
            fields[f"{key} [{'rad' if key == 'principal_angle' else '-'}]"] = (
                sign * _up(arr), 1)
        for key, arr in unc.items():
            scale = s if key in ("ux_std", "uy_std") else 1.0
            label = u if key in ("ux_std", "uy_std") else "-"
            fields[f"{key} [{label}]"] = (_up(np.asarray(arr)[i]) * scale, 1)
        for key, arr in derived.items():
            if key.endswith("_std"):
                label = "rad" if key.startswith(("principal_angle", "rotation")) else "-"
                fields[f"{key} [{label}]"] = (_up(arr), 1)
        fields["valid"] = (np.asarray(result.valid[i])[::-1].astype(np.uint8), 1)
        notes = {"state": result.names[i + 1], "frame": FRAME, "time value": what}
        values = {}
        if time is not None:
            values["time [s]"] = time[i]
        if load is not None:
            values[f"load [{load_unit or '-'}]"] = load[i]
        out.write(name, _vti(fields, H, W, s, notes, values))
    rows = "".join(f'    <DataSet timestep="{float(t)!r}" part="0" '
                   f"file={quoteattr(folder.name + '/' + n)}/>\n"
                   for t, n in zip(steps, names, strict=True))
    text = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" '
            'byte_order="LittleEndian">\n'
            f"  <!-- time values: {what}; {FRAME} -->\n  <Collection>\n"
            + rows + "  </Collection>\n</VTKFile>\n")
    return write_atomic(dest, text.encode("utf-8"), overwrite=overwrite)
