"""``gridstrain reproduce``: re-run the founding paper's synthetic experiments (§3.2)."""

from __future__ import annotations

import argparse
import sys
import time

from .._progress import bar
from ..models import PROFILES


def register(subparsers) -> None:
    """Add the ``reproduce`` sub-command to ``subparsers``."""
    p = subparsers.add_parser(
        "reproduce",
        help="re-run the paper's synthetic experiments (RMSE vs T, methods A and B)",
        description="Regenerate analogues of Figs. 5c, 12 and 13 of Sur & Grédiac (2015): "
                    "RMSE of phases, corrected phases, phase derivatives and averaged image "
                    "against the number T of vibrated, noisy images averaged, with the "
                    "small-noise theory. Writes PNG figures, results.json and summary.md.")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (must not exist unless --overwrite)")
    p.add_argument("--quick", action="store_true",
                   help="256x256 images, fewer T values, one repetition (about a minute)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--K", type=float, default=0.28,
                   help="noise gain: Var = K l + L, grey levels (default 0.28)")
    p.add_argument("--L", type=float, default=5.0,
                   help="read-noise variance, grey levels^2 (default 5)")
    p.add_argument("--amplitude", type=float, default=4096.0,
                   help="mean grey level A of eq. (1) (default 4096 = 2^12)")
    p.add_argument("--contrast", type=float, default=0.9,
                   help="contrast gamma of eq. (1) (default 0.9)")
    p.add_argument("--profile", default="sin3", choices=sorted(PROFILES),
                   help="line profile (default sin3)")
    p.add_argument("--size", type=int, nargs=2, metavar=("H", "W"),
                   help="image size in px (default 512 512; 256 256 with --quick)")
    p.add_argument("--T", type=int, nargs="+", metavar="T", dest="T",
                   help="stack sizes for method A (default 1 2 5 ... 1000)")
    p.add_argument("--T-b", type=int, nargs="+", metavar="T", dest="T_b",
                   help="stack sizes for method B, one WFT per frame (default up to 200)")
    p.add_argument("--repetitions", type=int,
                   help="independent repetitions (default 3; 1 with --quick)")
    p.add_argument("--cases", type=int, nargs="+", choices=(1, 2, 3, 4),
                   help="vibration cases (default 1 2 3 4)")
    p.add_argument("--workers", type=int,
                   help="worker processes (default: the CPUs available); results do not "
                        "depend on it")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``gridstrain reproduce`` with parsed ``args``; returns the exit code."""
    # heavy imports only when the command runs
    from ..paper import fixed_figure
    from ..paper.experiment import reproduce

    t0 = time.perf_counter()
    res = reproduce(args.out, quick=args.quick, overwrite=args.overwrite, seed=args.seed,
                    K=args.K, L=args.L, amplitude=args.amplitude, contrast=args.contrast,
                    profile=args.profile, size=args.size, T=args.T, T_b=args.T_b,
                    repetitions=args.repetitions, cases=args.cases, workers=args.workers,
                    progress=bar(quiet=args.quiet))
    if args.quiet:
        return 0
    wall = time.perf_counter() - t0
    ch = res["checks"]
    out = sys.stdout
    out.write(f"wrote {', '.join(res['files'])} to {res['out_dir']} in {wall:.0f} s\n")
    for m in ("A", "B", "C"):
        if m in ch:
            c = ch[m]
            out.write(f"method {m}: derivative slopes "
                      f"{fixed_figure(c['derivative_slopes_min'], 3)} .. "
                      f"{fixed_figure(c['derivative_slopes_max'], 3)}; RMSE/theory "
                      f"{fixed_figure(c['derivative_rmse_over_theory_min'], 3)} .. "
                      f"{fixed_figure(c['derivative_rmse_over_theory_max'], 3)}; spread across "
                      f"cases {100 * c['derivative_spread_across_cases_max']:.1f} %\n")
    if "B_over_A_derivatives_min" in ch:
        out.write(f"B/A derivative RMSE {fixed_figure(ch['B_over_A_derivatives_min'], 3)} .. "
                  f"{fixed_figure(ch['B_over_A_derivatives_max'], 3)}; cost ratio B/A "
                  f"{fixed_figure(ch['cost_ratio_B_over_A'], 1)}\n")
    if "C_over_B_derivatives_min" in ch:
        out.write(f"C/B derivative RMSE {fixed_figure(ch['C_over_B_derivatives_min'], 4)} .. "
                  f"{fixed_figure(ch['C_over_B_derivatives_max'], 4)}; cost ratio C/A "
                  f"{fixed_figure(ch['cost_ratio_C_over_A'], 1)}\n")
    for c, v in ch["image_level"].items():
        out.write(f"case {c}: averaged-image RMSE {v['rmse']:.3g} at T = {v['T']}, "
                  f"Prop. 2.1 level {v['prop21_level']:.3g} grey levels\n")
    return 0
