"""Reading a high-speed record frame by frame: Photron MRAW (12-bit packed, 16-bit) and
Phantom cine (16-bit, packed 12-bit) through ``open_series().frames()``, against the
same frames in a multi-page TIFF read page by page with tifffile (the reference), and
against numpy reading the raw 16-bit MRAW bytes straight off the disk (the floor).

    PYTHONPATH=src python benchmarks/bench_camera.py [--frames 200] [--size 1024x1024]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import tifffile

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import interleaved, machine
from camera_files import write_cine, write_mraw
from gridstrain.io import open_series


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--size", default="1024x1024")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tmp", default=None)
    args = ap.parse_args()
    H, W = (int(v) for v in args.size.split("x"))
    n = args.frames
    tmp = Path(tempfile.mkdtemp(dir=args.tmp))
    try:
        rng = np.random.default_rng(0)
        frames = rng.integers(0, 4096, (n, H, W), dtype=np.uint16)
        tifffile.imwrite(tmp / "rec.tif", frames, photometric="minisblack")
        files = {
            "MRAW 12-bit packed": write_mraw(tmp / "p.mraw", frames, color_bit=12),
            "MRAW 16-bit": write_mraw(tmp / "w.mraw", frames, color_bit=16,
                                      effective_bit=12),
            "cine 16-bit": write_cine(tmp / "w.cine", frames, real_bpp=12,
                                      times=np.arange(n) / 1e4),
            "cine packed 12-bit": write_cine(tmp / "p.cine", frames, real_bpp=12,
                                             packed=True, times=np.arange(n) / 1e4),
        }

        def tiff():
            with tifffile.TiffFile(tmp / "rec.tif") as t:
                for page in t.pages:
                    page.asarray()

        def floor():
            with open(tmp / "w.mraw", "rb") as fh:
                for _ in range(n):
                    np.frombuffer(fh.read(2 * H * W), "<u2").reshape(H, W)

        def ours(path):
            def run():
                for _ in open_series(path).frames(dtype=None):
                    pass
            return run

        funcs = {"multi-page TIFF (tifffile)": tiff, "raw 16-bit bytes (numpy)": floor}
        funcs.update({k: ours(p) for k, p in files.items()})
        times = interleaved(funcs, args.repeat)
        print(machine())
        print(f"{n} frames of {H} x {W} px, best of {args.repeat}, wall s; ratio to the "
              "TIFF reference")
        ref = times["multi-page TIFF (tifffile)"][0]
        for name, (best, _, _) in times.items():
            print(f"  {name:28s} {best:7.3f} s  ({n / best:7.0f} frames/s)  "
                  f"x{best / ref:5.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
