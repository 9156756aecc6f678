"""A map of every state as an animation (GIF, MP4) on fixed colour limits."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import as_path, check_choice, check_positive, check_type
from ..io import atomic_path
from ..results import SeriesResult, state_loads
from ._places import drawn_in

FORMATS = (".gif", ".mp4")
_VIDEO_EXTRA = "MP4 needs PyAV: pip install 'gridstrain[video]'"


def _frame_text(name, i, load, load_unit, time) -> str:
    parts = [name]
    if time is not None:
        parts.append(f"t = {time[i]:.6g} s")
    if load is not None:
        parts.append(f"load = {load[i]:.6g} {load_unit or ''}".rstrip())
    return ", ".join(parts)


def animate(result: SeriesResult, name: str, path, *, fps: float = 5.0,
            limits="robust", cmap: str | None = None, pixel_size: float | None = None,
            unit: str | None = None, px: bool = False, load=None,
            load_unit: str | None = None, time=None,
            dpi: float = 100, strain_units: str = "microstrain", overwrite: bool = False,
            progress=None) -> Path:
    """Write an animation of one quantity over the states, on fixed colour limits.

    Parameters
    ----------
    result : SeriesResult
    name : str
        A quantity of :data:`gridstrain.post.QUANTITIES` (``"exx"``,
        ``"ux"``, ``"e1"``...).
    path : str or os.PathLike
        ``.gif`` (Pillow) or ``.mp4`` (PyAV, the ``video`` extra; MPEG-4 part 2,
        FFmpeg's own encoder). Written atomically.
    fps : float
        Frames (states) per second.
    limits : {"robust", "common"} or (float, float)
        The colour limits, over every state (:func:`gridstrain.post.map_norm`): the
        0.5th to 99.5th percentiles of the valid values (default), their full
        range, or the two ends given in the unit drawn.
    cmap : str, optional
        A matplotlib colormap; default :func:`gridstrain.post.map_norm`'s choice.
    pixel_size, unit : float, str, optional
        Displacements and the axes in ``unit``; default the result's own
        (:attr:`SeriesResult.pixel_size`), px for a result without one.
    px : bool
        In px, even for a result with a pixel size.
    load, load_unit, time : optional
        Shown in each frame's title (default: the result's own).
    dpi : float
        Resolution of the frames (6.4 in wide).
    strain_units : {"microstrain", "%", "1"}
        Strains in µε (default), percent or dimensionless
        (:data:`gridstrain.post.STRAIN_UNITS`).
    overwrite : bool
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    pathlib.Path
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ._plotting import (
        QUANTITIES,
        check_cmap,
        check_limits,
        colormap,
        map_extent,
        state_quantity,
        states_norm,
    )

    check_type(result, "result", SeriesResult)
    check_choice(name, "name", tuple(QUANTITIES))
    limits = check_limits(limits)
    cmap = check_cmap(cmap)
    fps = check_positive(fps, "fps")
    dpi = check_positive(dpi, "dpi")
    dest = as_path(path, "path")
    ext = dest.suffix.lower()
    if ext not in FORMATS:
        raise ValueError(f"path must end in {' or '.join(FORMATS)}, got {dest.name!r}")
    if ext == ".mp4":
        try:
            import av  # noqa: F401
        except ImportError:
            raise ImportError(_VIDEO_EXTRA) from None
    ps, unit = drawn_in(result, pixel_size=pixel_size, unit=unit, px=px)
    load, load_unit, time = state_loads(result, load=load, load_unit=load_unit, time=time)
    def values_of(i):
        # in the unit the figures draw (µε, mrad, degrees, the length unit)
        v = state_quantity(result, name, i, pixel_size=ps, unit=unit,
                           microstrain=strain_units)[0]
        return np.where(np.asarray(result.valid[i]), v, np.nan)

    drawn = state_quantity(result, name, 0, pixel_size=ps, unit=unit,
                           microstrain=strain_units)[1]

    n = result.n_states
    def valued(i):  # NaN where not valid
        v = values_of(i)
        return v, np.isfinite(v)

    # exactly those of the valid values of every state, read state by state
    norm = states_norm(valued, n, limits=limits)
    cmap = colormap(norm, cmap)
    H, W = result.shape
    bg = result.reference_image
    lo_g, hi_g = np.percentile(bg, (1.0, 99.0))
    fig = Figure(figsize=(6.4, max(2.5, 5.0 * H / W + 0.9)), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    # the axes in the unit places are named in (px without a pixel size)
    s, axis_unit = (1.0, "px") if ps is None else (ps, unit)
    extent = map_extent((H, W), s)
    ax.imshow(bg, cmap="gray", vmin=lo_g, vmax=hi_g if hi_g > lo_g else lo_g + 1,
              interpolation="nearest", extent=extent)
    im = ax.imshow(np.full((H, W), np.nan), cmap=cmap, norm=norm, interpolation="nearest",
                   extent=extent)
    ax.set_xlabel(f"x ({axis_unit})")
    ax.set_ylabel(f"y ({axis_unit})")
    symbol = QUANTITIES[name][0]
    cbar = fig.colorbar(im, ax=ax, shrink=0.9)
    cbar.set_label(f"{symbol} ({drawn})")
    title = ax.set_title("", fontsize=10)
    fig.tight_layout()

    def frames():
        for i in range(n):
            im.set_data(np.ma.masked_invalid(values_of(i)))
            title.set_text(f"{symbol}: " + _frame_text(result.names[i + 1], i, load,
                                                       load_unit, time))
            canvas.draw()
            rgb = np.asarray(canvas.buffer_rgba())[..., :3]
            if progress is not None:
                progress((i + 1) / n, f"frame {i + 1}/{n}")
            yield rgb

    with atomic_path(dest, overwrite=overwrite) as tmp:
        if ext == ".gif":
            _write_gif(tmp, frames(), fps)
        else:
            _write_mp4(tmp, frames(), fps)
    return dest


def _write_gif(path, frames, fps: float) -> None:
    from PIL import Image

    images = [Image.fromarray(f).quantize(colors=255) for f in frames]
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                   duration=round(1000 / fps), loop=0)


def _write_mp4(path, frames, fps: float) -> None:
    from fractions import Fraction

    import av

    # MPEG-4 part 2 (FFmpeg's own encoder, in every FFmpeg build), 4 Mbit/s: sharp
    # colour maps; yuv420p needs even sizes, so the frame gets a white edge if odd
    with av.open(str(path), "w", format="mp4") as container:
        stream = None
        for f in frames:
            h, w = f.shape[:2]
            f = np.pad(f, ((0, h % 2), (0, w % 2), (0, 0)), constant_values=255)
            if stream is None:
                stream = container.add_stream(
                    "mpeg4", rate=Fraction(fps).limit_denominator(1000))
                stream.width, stream.height = f.shape[1], f.shape[0]
                stream.pix_fmt = "yuv420p"
                stream.bit_rate = 4_000_000
            for packet in stream.encode(av.VideoFrame.from_ndarray(
                    np.ascontiguousarray(f), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
