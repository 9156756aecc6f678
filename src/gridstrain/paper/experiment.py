"""Re-run the synthetic experiments of the founding paper (§3.2, Figs. 5c, 12, 13).

:func:`reproduce` generates the paper's vibrated, noisy stacks
(:mod:`gridstrain.paper.dataset`), averages them with methods A and B
(:mod:`gridstrain.stacks`) and with the vibration-compensated method C (not in the
paper; its shifts measured from the frames, as in the lab), measures the RMSE of
the phases, corrected phases,
phase derivatives and averaged image against the ground truth for a growing number
of images ``T``, and writes figures, a ``results.json`` and a ``summary.md`` that
sets the paper's statements beside our numbers.

Design of the experiment (choices the paper leaves open):

* **Ground truth.** The same windowed Fourier transform applied to the noise- and
  vibration-free image ``s`` (paper §3.2), so the window's own smoothing cancels.
* **Analysis region.** Pixels flagged valid by the transform of ``s`` (3.5 sigma
  from the border) and more than ``margin`` px from the border; the default
  ``ceil(4 sigma) + 1`` adds half a sigma, where the noise-free edge error of the
  transform is ~1e-6 rad (see :mod:`gridstrain.phase`), and one pixel for the edge of
  the phase maps, repeated beyond the image when a frame is shifted.
* **Nested stacks.** For each case one stream of ``max(T)`` frames is read once;
  the result for ``T`` uses its first ``T`` frames (running sums), and method B
  uses the first frames of the *same* stream, so A and B see the same data.
* **Common random numbers.** Within a repetition the four cases share the
  standard-normal draws behind the shifts (case ``c``'s shifts are
  ``(sigma_alpha, sigma_beta)`` times the same draws), so the phase offsets
  ``delta`` of eqs. (29)-(30) are, to first order, proportional to the vibration
  amplitude, and differences between cases come from the amplitude alone. The
  sensor noise is independent between cases and repetitions.
* **Repetitions.** Each reported RMSE is the root of the mean of the squared RMSE
  over independent repetitions, the estimator of ``sqrt(E[RMSE^2])`` that the
  theory predicts.
* **A fifth case**, ``(0.5, 0.5)`` px, beyond the paper's: vibrations large enough
  for method A's contrast loss (eq. 14, a factor 0.80) to show in every RMSE.
* **Method C's phase** is that of the grid at the stack's mean position (its
  shifts are measured from the frames, which cannot tell where ``s`` is): its
  uncorrected phase carries ``2 pi k . a_bar``, method B's offset, and its
  "corrected" phase removes that exactly-linear term with the known sample mean of
  the shifts (for A and B, eqs. 29-30). The phase modulation moves with the mean
  position as well, ``phi(x + a_bar)``: its theory adds ``a_bar . grad phi``, of
  variance ``(Var(alpha) <phi_x^2> + Var(beta) <phi_y^2>) / T`` over the region
  (1e-4 rad at 0.5 px and T = 100, a quarter of the noise there).
* **Theory** (the paper's small-noise model, from :mod:`gridstrain.theory`):
  phase and derivative noise of the WFT for a noise variance
  ``(K A + L + 1/12) / T`` (the mean grey level of ``s`` is ``A``; 1/12 is the
  rounding to integer grey levels), with the modulus of ``Psi`` attenuated by
  ``1 - (2 pi f sigma_j)^2 / 2`` for method A (eq. 14); plus, for uncorrected
  phases, the offset standard deviation of Proposition 2.4 with
  ``Var(alpha_bar) = Var(alpha) / T`` (method A) or ``2 pi f Std(alpha) / sqrt(T)``
  (method B, §2.3); for method C, :func:`gridstrain.theory.compensated_noise_std`
  (full contrast, offset of the mean position). For the averaged image: the RMS of
  Proposition 2.1's bias over
  the region, plus the ``O(1/T)`` terms of eq. (4) (noise, the random first-order
  term ``(alpha_bar, beta_bar) . grad s`` and the scatter of ``alpha^2_bar``).
"""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import numpy as np

from .._progress import Progress, null_progress
from .._validation import (
    as_int_tuple,
    check_choice,
    check_finite,
    check_int,
    check_positive,
    check_shape,
    check_workers,
)
from ..io import OutputDirectory, provenance
from ..models import PROFILES, line_profile
from ..phase import Lattice, PhaseMaps, Window, wft
from ..stacks import MeanImage, MethodC, PhaseMean, method_a, method_b, method_c, phase_offsets
from ._cases import _DERIVATIVES, QUANTITIES, _all_cases, _get
from ._summary import _at, _write
from .dataset import (
    MAX_DERIVATIVE,
    clean_frame,
    iter_frames,
    mean_image_bias,
    paper_phases,
    vibration_cases,
)

__all__ = ["FULL", "QUANTITIES", "QUICK", "reproduce"]


#: Settings of the full run (about 15 min on two cores).
FULL = {"size": (512, 512), "T": (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000),
        "T_b": (1, 2, 5, 10, 20, 50, 100, 200), "repetitions": 3}
#: Settings of ``--quick`` (about a minute on two cores).
QUICK = {"size": (256, 256), "T": (1, 3, 10, 30, 100, 300, 1000),
         "T_b": (1, 3, 10, 30, 100), "repetitions": 1}

_FILES = ("results.json", "summary.md", "fig4_phase_maps.png", "fig5c_image_rmse.png",
         "fig12_method_A_rmse.png", "fig13_method_B_rmse.png", "fig13c_method_C_rmse.png")

# ---------------------------------------------------------------------------- theory

def _profile_derivative(ell, t, order):
    h = 1e-3
    if order == 1:
        return (ell(t + h) - ell(t - h)) / (2 * h)
    return (ell(t + h) - 2 * ell(t) + ell(t - h)) / h**2


def _image_terms(phases, region, stds, *, amplitude, contrast, pitch, profile):
    """Mean squares, over the region, of the terms of eq. (4) (grey levels^2).

    Returns ``(bias2, var_bias_over_T, grad_over_T)``: the squared RMS of
    Proposition 2.1's bias; ``T`` times the extra mean square from the scatter of
    ``alpha^2_bar`` (``Var(alpha^2_bar) = 2 sigma^4 / T`` for a Gaussian); ``T``
    times the mean square of ``(alpha_bar, beta_bar) . grad s`` with the gradient
    of eqs. (8)-(9).
    """
    sa, sb = stds
    kw = {"amplitude": amplitude, "contrast": contrast, "pitch": pitch, "profile": profile}
    bx = mean_image_bias(phases, (sa**2, 0.0), **kw)[region]
    by = mean_image_bias(phases, (0.0, sb**2), **kw)[region]
    bias2 = float(np.mean((bx + by) ** 2))
    scatter = 2 * float(np.mean(bx**2) + np.mean(by**2))
    ell = line_profile(profile)
    H, W = phases.shape[1:]
    w = 2 * math.pi / pitch
    t1 = w * np.arange(W, dtype=float)[None, :] + phases[0]
    t2 = w * np.arange(H, dtype=float)[:, None] + phases[1]
    c = contrast * amplitude / 2 * w
    sx = c * _profile_derivative(ell, t1, 1)[region]
    sy = c * _profile_derivative(ell, t2, 1)[region]
    grad = sa**2 * float(np.mean(sx**2)) + sb**2 * float(np.mean(sy**2))
    return bias2, scatter, grad


# ----------------------------------------------------------------------- measurement

def _rmse_all(maps: PhaseMaps, gt: PhaseMaps, region: np.ndarray, delta) -> dict:
    """RMSEs against the ground truth; ``delta`` (2,) rad is removed from the
    phases for the corrected ones."""
    sel = region & maps.valid
    out = {}
    for j in range(2):
        d = np.angle(maps.psi[j][sel] * np.conj(gt.psi[j][sel]))
        out[f"phi{j + 1}"] = float(np.sqrt(np.mean(d**2)))
        d = np.angle(np.exp(1j * (d - delta[j])))
        out[f"phi{j + 1}_corrected"] = float(np.sqrt(np.mean(d**2)))
        for a, axis in enumerate("xy"):
            e = maps.dphi[j, a][sel].astype(np.float64) - gt.dphi[j, a][sel]
            out[f"dphi{j + 1}_d{axis}"] = float(np.sqrt(np.mean(e**2)))
    return out


def _slope(T, y) -> float | None:
    T = np.asarray(T, float)
    y = np.asarray(y, float)
    ok = (y > 0) & np.isfinite(y)
    if ok.sum() < 2:
        return None
    return float(np.polyfit(np.log(T[ok]), np.log(y[ok]), 1)[0])


def _stack_sizes(values, name):
    """The stack sizes ``values`` (positive integers), sorted, each once; None stays."""
    if values is None:
        return None
    return tuple(sorted(set(as_int_tuple(values, name, minimum=1))))


# ----------------------------------------------------------------------- the jobs

def _setup_maps(setup):
    """Phase maps, reference image, its WFT and the analysis region (deterministic)."""
    H, W = setup["size"]
    phases, exact_der = paper_phases((H, W))
    s = clean_frame(phases, **setup["gen"])
    lattice = Lattice.from_pitch(setup["gen"]["pitch"])
    gt = wft(s, lattice, sigma=setup["sigma"])
    yy, xx = np.mgrid[0:H, 0:W]
    m = setup["margin"]
    inner = np.minimum(np.minimum(yy, H - 1 - yy), np.minimum(xx, W - 1 - xx)) >= m
    return phases, exact_der, s, lattice, gt, gt.valid & inner


def _shifts(setup, rep, case, n):
    """Shifts of a repetition: standard normals shared by the cases, then scaled."""
    z = np.random.default_rng(np.random.SeedSequence([setup["seed"], rep])).standard_normal(
        (n, 2))
    return z * np.array(_all_cases()[case])


def _job(setup, rep, case, report=None) -> dict:
    """Squared RMSEs of one repetition of one case: ``{(method, case, q, T): rmse^2}``."""
    phases, _, s, lattice, gt, region = _setup_maps(setup)
    Ts, Tbs, sigma = setup["Ts"], setup["Tbs"], setup["sigma"]
    tmax = Ts[-1]
    shifts = _shifts(setup, rep, case, tmax)
    # the noise stream depends on (seed, repetition, case) only
    noise = np.random.default_rng(np.random.SeedSequence([setup["seed"], rep, 1000 + case]))
    frames = iter_frames(phases, shifts, rng=noise, K=setup["K"], L=setup["L"],
                         bits=setup["bits"], **setup["gen"])
    window = Window.for_lattice(lattice, sigma=sigma)
    acc_a, acc_b, acc_c = MeanImage(), PhaseMean(), MethodC(lattice)
    set_a, set_b = set(Ts), set(Tbs)
    out = {}
    for t, frame in enumerate(frames, start=1):
        acc_a.add(frame)
        acc_c.add(frame)  # shifts measured from the frames, as in the lab
        if t <= Tbs[-1]:
            acc_b.add_frame(frame, lattice, window)
        delta = phase_offsets(shifts[:t], lattice, exact=False)  # eqs. (29)-(30)
        if t in set_a:
            avg = acc_a.mean()
            vals = _rmse_all(wft(avg, lattice, sigma=sigma), gt, region, delta)
            vals["image"] = float(np.sqrt(np.mean((avg - s)[region] ** 2)))
            out.update({("A", case, q, t): v * v for q, v in vals.items()})
            # method C: the mean position, exactly linear in the shifts
            mean_pos = 2 * math.pi * lattice.K @ shifts[:t].mean(axis=0)
            vals = _rmse_all(acc_c.result(window).maps, gt, region, mean_pos)
            out.update({("C", case, q, t): v * v for q, v in vals.items()})
        if t in set_b:
            vals = _rmse_all(acc_b.result().maps, gt, region, delta)
            out.update({("B", case, q, t): v * v for q, v in vals.items()})
        if report is not None and (t % 10 == 0 or t == tmax):
            report(rep, case, t)
    return out


def _job_in_worker(setup, rep, case, queue):
    def report(r, c, t):
        queue.put((r, c, t))

    return _job(setup, rep, case, report)


def _run_jobs(setup, jobs, workers, progress, work_total) -> dict:
    """Run the (repetition, case) jobs, in worker processes if ``workers > 1``."""
    done = {}
    tmax = setup["Ts"][-1]

    def report(rep, case, t):
        done[rep, case] = t
        progress(sum(done.values()) / work_total,
                 f"repetition {rep + 1}, case {case}: frame {t}/{tmax}")

    results: dict = {}
    if workers <= 1 or len(jobs) == 1:
        for job in jobs:
            results[job] = _job(setup, *job, report)
    else:
        import multiprocessing as mp
        import queue as _queue
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

        with mp.Manager() as manager, ProcessPoolExecutor(max_workers=workers) as pool:
            q = manager.Queue()
            futures = {pool.submit(_job_in_worker, setup, *job, q): job for job in jobs}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                for fut in finished:
                    results[futures[fut]] = fut.result()
                while True:
                    try:
                        report(*q.get_nowait())
                    except _queue.Empty:
                        break
    sq: dict = {}
    for job in jobs:  # summed in a fixed order: the result does not depend on workers
        for k, v in results[job].items():
            sq[k] = sq.get(k, 0.0) + v
    return sq


# ------------------------------------------------------------------------ the driver

def reproduce(out_dir, *, quick: bool = False, overwrite: bool = False, seed: int = 0,
              K: float = 0.28, L: float = 5.0, amplitude: float = 4096.0,
              contrast: float = 0.9, profile: str = "sin3", pitch: float = 5.0,
              size=None, T=None, T_b=None, repetitions: int | None = None, cases=None,
              sigma: float | None = None, margin: int | None = None,
              bits: int | None = 12, timing_frames: int = 100,
              workers: int | None = None, progress: Progress | None = None) -> dict:
    """Reproduce the paper's synthetic experiments (§3.2) and write their report.

    Parameters
    ----------
    out_dir : str or Path
        Output folder, created if missing (parents included). Each file is written
        atomically and listed in the folder's marker file
        (:class:`gridstrain.io.OutputDirectory`); files of other names are left
        alone, and a file of the same name that gridstrain did not write is
        refused.
    quick : bool
        Use :data:`QUICK` defaults (256 x 256, 7 values of T up to 1000, method B up
        to 100, one repetition; about a minute) instead of :data:`FULL` (512 x 512,
        10 values up to 1000, B up to 200, three repetitions; about 15 minutes).
    overwrite : bool
        Replace the files an earlier run wrote in ``out_dir`` (only those).
    seed : int
        Seed of every random draw; the same seed gives the same results.
    K, L : float
        Sensor noise ``Var = K l + L`` (grey levels).
    amplitude, contrast : float
        ``A`` and ``gamma`` of eq. (1) (paper: 2**12 and 0.9; see
        :mod:`gridstrain.paper.dataset` on the 12-bit range).
    profile : str
        Line profile, a key of :data:`gridstrain.models.synthetic.PROFILES`.
    pitch : float
        Grid pitch ``1/f``, px (paper: 5).
    size : (int, int), optional
        Image shape ``(H, W)``.
    T : list of int, optional
        Stack sizes for method A (the largest sets the frames per case).
    T_b : list of int, optional
        Stack sizes for method B (one WFT per frame: keep it smaller); each must
        not exceed ``max(T)``.
    repetitions : int, optional
        Independent repetitions averaged (root mean square of the RMSEs).
    cases : list of int, optional
        Vibration cases (default all five: the four of
        :func:`gridstrain.paper.dataset.vibration_cases` and case 5,
        :data:`LARGE_VIBRATION`).
    sigma : float, optional
        WFT window, px (default: the pitch, the paper's choice).
    margin : int, optional
        Border band excluded from the RMSEs, px (default ``ceil(4 sigma) + 1``).
    bits : int or None
        Quantisation to integer grey levels (None: none).
    timing_frames : int
        Frames used to time methods A, B and C (reported per 100 images).
    workers : int, optional
        Processes running the (repetition, case) streams in parallel (default: the
        CPUs available, at most the number of streams; 1 runs in this process).
        The results do not depend on it: every stream has its own seed.
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    dict
        The content of ``results.json``: ``records`` (list of
        ``{"method", "case", "quantity", "T", "rmse", "theory"}``), ``parameters``,
        ``slopes`` (``slopes[method][case][quantity]``, fitted log-log slope of the
        RMSE against T), ``timing``, ``checks`` (the acceptance figures), plus
        ``out_dir`` and ``files``.
    """
    progress = progress or null_progress
    out = Path(out_dir)
    # refused now, not after the run: a folder holding files gridstrain did not write
    directory = OutputDirectory(out, _FILES, overwrite=overwrite, parents=True,
                                adopt=False, what="out_dir")
    setup = _settings(quick=quick, seed=seed, K=K, L=L, amplitude=amplitude,
                      contrast=contrast, profile=profile, pitch=pitch, size=size, T=T,
                      T_b=T_b, repetitions=repetitions, cases=cases, sigma=sigma,
                      margin=margin, bits=bits, timing_frames=timing_frames)
    jobs = [(rep, c) for rep in range(setup["repetitions"]) for c in setup["cases"]]
    # default: the CPUs available, at most one process per (repetition, case) stream
    workers = min(check_workers(None), len(jobs)) if workers is None else check_workers(
        workers)

    t_start = time.perf_counter()
    phases, exact_der, _s, lattice, gt, region = _setup_maps(setup)
    if region.sum() < 100:
        raise ValueError(f"size {setup['size']} leaves only {int(region.sum())} pixels once "
                         f"the {setup['margin']}-px border is excluded; use a larger image")
    theory, levels = _theory_curves(setup, phases, exact_der, region, lattice)
    work_total = len(jobs) * setup["Ts"][-1] + setup["timing_frames"]
    sq = _run_jobs(setup, jobs, workers, progress, work_total)
    timing = _time_methods(setup, phases, lattice)
    progress(1.0, "writing the report")

    records = _records(sq, theory, setup["repetitions"])
    slopes = _slopes(records, setup["cases"])
    checks = _checks(records, slopes, setup["cases"], levels, timing)
    parameters = _parameters(setup, phases, exact_der, region, workers)
    timing["total_run_seconds"] = time.perf_counter() - t_start
    result = {"parameters": parameters, "records": records, "slopes": slopes,
              "timing": timing, "checks": checks}
    _write(directory, result, phases, gt, region, levels)
    result = dict(result, out_dir=str(out), files=list(_FILES))
    return result


def _settings(*, quick, seed, K, L, amplitude, contrast, profile, pitch, size, T, T_b,
              repetitions, cases, sigma, margin, bits, timing_frames) -> dict:
    """The run's settings, checked and completed with the preset's defaults: the
    ``setup`` every job receives (:func:`_setup_maps`, :func:`_job`)."""
    preset = QUICK if quick else FULL
    H, W = check_shape(size if size is not None else preset["size"], "size", minimum=64)
    Ts = _stack_sizes(T, "T") or preset["T"]
    Tbs = _stack_sizes(T_b, "T_b")
    if Tbs is None:
        Tbs = tuple(t for t in preset["T_b"] if t <= Ts[-1]) or (Ts[-1],)
    if Tbs[-1] > Ts[-1]:
        raise ValueError(f"T_b must not exceed the largest T ({Ts[-1]}), got {Tbs[-1]}")
    R = check_int(repetitions if repetitions is not None else preset["repetitions"],
                  "repetitions", minimum=1)
    all_cases = _all_cases()
    case_list = list(all_cases) if cases is None else [
        check_choice(c, "cases", tuple(all_cases)) for c in as_int_tuple(cases, "cases")]
    seed = check_int(seed, "seed", minimum=0)
    K = check_positive(K, "K")
    if check_finite(L, "L") < 0:
        raise ValueError(f"L must be a finite variance >= 0, got {L!r}")
    amplitude = check_positive(amplitude, "amplitude")
    if check_positive(contrast, "contrast") > 1:
        raise ValueError(f"contrast must be in (0, 1], got {contrast!r}")
    check_choice(profile, "profile", tuple(sorted(PROFILES)))
    pitch = check_positive(pitch, "pitch")
    sigma = check_positive(sigma, "sigma", allow_none=True) or pitch
    margin = (math.ceil(4 * sigma) + 1) if margin is None else check_int(margin, "margin",
                                                                         minimum=0)
    timing_frames = check_int(timing_frames, "timing_frames", minimum=1)
    if bits is not None:
        bits = check_int(bits, "bits", minimum=1)
    gen = {"amplitude": amplitude, "contrast": float(contrast), "pitch": pitch,
           "profile": profile}
    return {"size": (H, W), "gen": gen, "K": K, "L": float(L), "bits": bits,
            "sigma": sigma, "margin": margin, "Ts": Ts, "Tbs": Tbs, "seed": seed,
            "quick": bool(quick), "repetitions": R, "cases": sorted(set(case_list)),
            "timing_frames": timing_frames}


def _theory_curves(setup, phases, exact_der, region, lattice) -> tuple[dict, dict]:
    """The small-noise theory of every (method, case, T): ``theory[method, case, T]``
    is a row of RMSEs by quantity; ``levels[case]`` the averaged image's bias levels
    (Prop. 2.1, its closed form, and the exact Gaussian average)."""
    from .. import theory as th  # imported when needed: the closed forms of the paper

    gen, sigma = setup["gen"], setup["sigma"]
    amplitude, contrast, profile = gen["amplitude"], gen["contrast"], gen["profile"]
    noise_var = _noise_variance(setup)
    modulus = th.grid_modulus(amplitude, contrast, profile=profile)
    f = 1.0 / gen["pitch"]
    theory, levels = {}, {}
    # mean squares of the phase maps' derivatives over the region, (rad/px)^2
    grad2 = np.array([[np.mean(exact_der[j, a][region] ** 2) for a in range(2)]
                      for j in range(2)])
    for c in setup["cases"]:
        stds = _all_cases()[c]
        cov = np.diag(np.square(stds))
        b2, scat, grad = _image_terms(phases, region, stds, **gen)
        levels[c] = {"prop21": math.sqrt(b2),
                     "prop21_closed_form": th.mean_image_bias_rms(
                         lattice, cov, amplitude=amplitude, contrast=contrast,
                         profile=profile),
                     "exact_gaussian": th.mean_image_bias_rms(
                         lattice, cov, amplitude=amplitude, contrast=contrast,
                         profile=profile, exact=True)}
        for method, counts in (("A", setup["Ts"]), ("B", setup["Tbs"]), ("C", setup["Ts"])):
            for t in counts:
                row = {}
                for j in range(2):
                    row.update(_theory_phase(method, j, t, stds, grad2, noise_var, modulus,
                                             sigma, f))
                if method == "A":
                    row["image"] = math.sqrt(b2 + (scat + grad + noise_var) / t)
                theory[method, c, t] = row
    return theory, levels


def _noise_variance(setup) -> float:
    """Sensor noise variance of a frame at the mean grey level ``A``, plus the 1/12 of
    the rounding to integers when the frames are quantised (grey levels^2)."""
    from .. import theory as th

    return th.effective_noise_variance(setup["K"], setup["L"], setup["gen"]["amplitude"]) + (
        1.0 / 12.0 if setup["bits"] is not None else 0.0)


def _theory_phase(method, j, t, stds, grad2, noise_var, modulus, sigma, f) -> dict:
    """Theoretical RMSEs of phase ``j`` (0 or 1) of method ``method`` for ``t`` frames:
    uncorrected and corrected phase, and both derivatives."""
    from .. import theory as th

    n = j + 1
    if method == "C":  # full contrast; the offset of the mean position
        p_std, d_std, off = th.compensated_noise_std(
            noise_var, modulus, sigma, t, frequency=f, vibration_variance=stds[j] ** 2)
        # the modulation moves with the mean position too, phi(x + a_bar): a_bar .
        # grad phi is left by the uniform correction
        moved = math.sqrt(float(stds[0] ** 2 * grad2[j, 0] + stds[1] ** 2 * grad2[j, 1]) / t)
        return {f"phi{n}": math.hypot(p_std, off, moved),
                f"phi{n}_corrected": math.hypot(p_std, moved),
                f"dphi{n}_dx": d_std, f"dphi{n}_dy": d_std}
    if method == "A":  # eq. (14): the averaged grid's d_1 is attenuated
        mod = modulus * th.contrast_factor(f, stds[j] ** 2)
        p_std, d_std = th.wft_noise_std(noise_var / t, mod, sigma)
    else:  # independent frames of full contrast, averaged
        p_std, d_std = th.wft_noise_std(noise_var, modulus, sigma)
        p_std, d_std = p_std / math.sqrt(t), d_std / math.sqrt(t)
    # Prop. 2.4 (A) and §2.3 (B); Var(alpha_bar) = Var(alpha) / T
    off = th.phase_offset_std(f, stds[j] ** 2, t, method=method)
    return {f"phi{n}": math.hypot(p_std, off), f"phi{n}_corrected": p_std,
            f"dphi{n}_dx": d_std, f"dphi{n}_dy": d_std}


def _time_methods(setup, phases, lattice) -> dict:
    """Wall-clock and CPU time of methods A, B and C on one stack of the first case,
    per 100 images (``total_run_seconds`` is filled in by the caller)."""
    H, W = setup["size"]
    n = setup["timing_frames"]
    # a separate stream (seed word 2**32 - 1 is never a repetition index)
    t_rng = np.random.default_rng([setup["seed"], 2**32 - 1])
    t_shifts = t_rng.standard_normal((n, 2)) * np.array(_all_cases()[setup["cases"][0]])
    timing_stack = list(iter_frames(phases, t_shifts, rng=t_rng, K=setup["K"], L=setup["L"],
                                    bits=setup["bits"], **setup["gen"]))
    wall, cpu = {}, {}
    for name, fn in (("A", method_a), ("B", method_b), ("C", method_c)):
        # wall-clock time, and the CPU time of every thread of this process (the
        # figure to compare on a machine shared with other work)
        t0, c0 = time.perf_counter(), time.process_time()
        fn(timing_stack, lattice, sigma=setup["sigma"])
        wall[name], cpu[name] = time.perf_counter() - t0, time.process_time() - c0
    ta, tb, tc = wall["A"], wall["B"], wall["C"]
    scale = 100.0 / n
    return {"method_A_seconds_per_100_images": ta * scale,
            "method_B_seconds_per_100_images": tb * scale,
            "method_C_seconds_per_100_images": tc * scale,
            "ratio_B_over_A": tb / ta if ta > 0 else None,
            "ratio_C_over_A": tc / ta if ta > 0 else None,
            "cpu_seconds_per_100_images": {m: v * scale for m, v in cpu.items()},
            "cpu_ratio_C_over_A": cpu["C"] / cpu["A"] if cpu["A"] > 0 else None,
            "cpu_ratio_C_over_B": cpu["C"] / cpu["B"] if cpu["B"] > 0 else None,
            "image_shape": [H, W], "frames_timed": n,
            "total_run_seconds": None}


def _records(sq, theory, R) -> list[dict]:
    """One record per (method, case, quantity, T): the RMSE over the ``R`` repetitions
    (root mean square) beside its theory, in a fixed order."""
    records = []
    for (method, c, q, t), v in sorted(sq.items(), key=lambda kv: (
            kv[0][0], kv[0][1], list(QUANTITIES).index(kv[0][2]), kv[0][3])):
        th_v = theory.get((method, c, t), {}).get(q)
        records.append({"method": method, "case": c, "quantity": q, "T": t,
                        "rmse": math.sqrt(v / R),
                        "theory": None if th_v is None else float(th_v)})
    return records


def _slopes(records, cases) -> dict:
    """Fitted log-log slope of the RMSE against T: ``slopes[method][case][quantity]``."""
    slopes: dict = {}
    for method in ("A", "B", "C"):
        for c in cases:
            for q in QUANTITIES:
                rs = [r for r in records if r["method"] == method and r["case"] == c
                      and r["quantity"] == q]
                if rs:
                    slopes.setdefault(method, {}).setdefault(str(c), {})[q] = _slope(
                        [r["T"] for r in rs], [r["rmse"] for r in rs])
    return slopes


def _parameters(setup, phases, exact_der, region, workers) -> dict:
    """The ``parameters`` record of ``results.json``: every setting of the run."""
    from .. import theory as th

    gen = setup["gen"]
    H, W = setup["size"]
    amplitude = gen["amplitude"]
    return {
        **provenance(),
        "quick": setup["quick"], "seed": setup["seed"], "repetitions": setup["repetitions"],
        "size": [H, W], "pitch_px": gen["pitch"], "frequency_cycles_per_px": 1.0 / gen["pitch"],
        "amplitude_A": amplitude, "contrast_gamma": gen["contrast"],
        "profile": gen["profile"],
        "K": setup["K"], "L": setup["L"], "quantisation_bits": setup["bits"], "clip": False,
        "noise_variance_per_frame": _noise_variance(setup),
        "mean_grey_level": amplitude,
        "cases_px": {str(c): list(_all_cases()[c]) for c in setup["cases"]},
        "T_method_A": list(setup["Ts"]), "T_method_B": list(setup["Tbs"]),
        "wft_sigma_px": setup["sigma"], "border_margin_px": setup["margin"],
        "analysis_pixels": int(region.sum()),
        "phase_maps": {"max_derivative_rad_per_px": MAX_DERIVATIVE,
                       "measured_max_derivative": float(np.abs(exact_der).max()),
                       "phi1_max_rad": float(phases[0].max()),
                       "phi2_max_rad": float(phases[1].max()),
                       "interpolation": "bilinear (map_coordinates order=1, mode='nearest')"},
        "grid_modulus": th.grid_modulus(amplitude, gen["contrast"], profile=gen["profile"]),
        "noise_variance_includes": "K A + L + 1/12 (rounding)",
        "workers": workers,
        "common_random_numbers": "cases share the standard-normal draws of the shifts",
        "rmse_over_repetitions": "root mean square",
        "phase_correction": "eqs. (29)-(30) with the sample moments of the shifts "
                            "(methods A, B); the sample mean position 2 pi k . a_bar "
                            "(method C)",
        "method_C_shifts": "measured from the frames (carrier phases of 2 x 2 "
                           "quadrants), centred",
    }


# -------------------------------------------------------------------------- checks


def _checks(records, slopes, cases, levels, timing) -> dict:
    """The figures that the paper's statements are judged on.

    The per-method figures are over the paper's four cases (those run): case 5 is
    judged by :func:`_checks_c`. Method A's theory uses eq. (14)'s large-T contrast
    factor, which a stack of a few frames at 0.5 px beats by chance (one frame keeps
    all its contrast).
    """
    out: dict = {}
    methods = sorted({r["method"] for r in records})
    all_cases = cases
    cases = [c for c in cases if c in vibration_cases()] or all_cases
    for m in methods:
        ds = [slopes[m][str(c)][q] for c in cases for q in _DERIVATIVES
              if slopes[m][str(c)].get(q) is not None]
        ratios = [r["rmse"] / r["theory"] for r in records if r["method"] == m
                  and r["case"] in cases and r["quantity"] in _DERIVATIVES and r["theory"]]
        # spread of the RMSE across cases at each T: raw, and divided by the theory
        # (for method A the theory itself differs by the contrast factor of eq. 14,
        # up to 1.8 % in case 1)
        spread = spread_th = 0.0
        for q in _DERIVATIVES:
            curves = [_get(records, m, c, q) for c in cases]
            for i in range(len(curves[0][0])):
                vals = [cv[1][i] for cv in curves]
                rel = [cv[1][i] / cv[2][i] for cv in curves]
                spread = max(spread, (max(vals) - min(vals)) / float(np.mean(vals)))
                spread_th = max(spread_th, (max(rel) - min(rel)) / float(np.mean(rel)))
        corr = {str(c): {q: slopes[m][str(c)][q] for q in ("phi1_corrected", "phi2_corrected")}
                for c in all_cases}
        order = {}
        for j, q in enumerate(("phi1", "phi2")):
            by_amp = sorted(all_cases, key=lambda c: -_all_cases()[c][j])
            curves = [_get(records, m, c, q)[1] for c in by_amp]
            n_ok = sum(all(a >= b for a, b in itertools.pairwise(col))
                       for col in zip(*curves, strict=True))
            logs = [float(np.mean(np.log(y))) for y in curves]
            order[q] = {"cases_by_amplitude": by_amp,
                        "fraction_of_T_ordered": n_ok / len(curves[0]),
                        "geometric_mean_ordered": all(
                            a >= b for a, b in itertools.pairwise(logs))}
        out[m] = {
            "derivative_slopes_min": _least(ds), "derivative_slopes_max": _most(ds),
            "derivative_rmse_over_theory_min": _least(ratios),
            "derivative_rmse_over_theory_max": _most(ratios),
            "derivative_rmse_over_theory_mean": float(np.mean(ratios)) if ratios else None,
            "derivative_spread_across_cases_max": spread,
            "derivative_spread_across_cases_over_theory_max": spread_th,
            "corrected_phase_slopes": corr,
            "uncorrected_phase_order": order,
        }
    if "A" in out and "B" in out:
        rb = []
        for c in cases:
            for q in _DERIVATIVES:
                Ta, ya, _ = _get(records, "A", c, q)
                Tb, yb, _ = _get(records, "B", c, q)
                a = dict(zip(Ta, ya, strict=True))
                rb += [v / a[t] for t, v in zip(Tb, yb, strict=True) if t in a]
        out["B_over_A_derivatives_min"] = _least(rb)
        out["B_over_A_derivatives_max"] = _most(rb)
    if "C" in out:
        out.update(_checks_c(records, all_cases))
    img = {}
    for c in all_cases:
        Ts, ys, _ = _get(records, "A", c, "image")
        img[str(c)] = {"T": Ts[-1], "rmse": ys[-1], "prop21_level": levels[c]["prop21"],
                       "exact_gaussian_level": levels[c]["exact_gaussian"],
                       "prop21_closed_form_level": levels[c]["prop21_closed_form"],
                       "rmse_over_prop21": ys[-1] / levels[c]["prop21"]}
    out["image_level"] = img
    out["cost_ratio_B_over_A"] = timing["ratio_B_over_A"]
    out["cost_ratio_C_over_A"] = timing.get("ratio_C_over_A")
    return out


def _least(values):
    """Smallest value, or None when a run's T values leave nothing to compare."""
    return min(values) if values else None


def _most(values):
    """Largest value, or None when a run's T values leave nothing to compare."""
    return max(values) if values else None


def _ratios(records, num, den, cases, quantities, *, theory=False):
    """``rmse(num) / rmse(den)`` (or ``num``'s ``rmse / theory``) at the shared T."""
    out = []
    for c in cases:
        for q in quantities:
            Tn, yn, thn = _get(records, num, c, q)
            if theory:
                out += [y / t for y, t in zip(yn, thn, strict=True) if t]
                continue
            Td, yd, _ = _get(records, den, c, q)
            d = dict(zip(Td, yd, strict=True))
            out += [y / d[t] for t, y in zip(Tn, yn, strict=True) if t in d]
    return out


def _checks_c(records, cases) -> dict:
    """Method C against B, A and its theory (derivatives, corrected phases).

    Against the theory over the paper's cases, as for A and B. In case 5 every
    method also carries a deterministic error that no averaging removes: the
    generator interpolates the phase maps bilinearly at the shifted points (paper
    §3.2), which at 0.5 px blurs the kinks of ``phi2``; measured noise-free at 256 x
    256, T = 200: 1.4e-5 rad/px RMS on ``d phi2 / dy`` (1.3e-5 for method A), as
    large as the noise from T ~ 300 on. Case 5 is judged against method A, on the
    RMS over the four derivatives, where the noise dominates (30 <= T <= 100).
    """
    phases = ("phi1_corrected", "phi2_corrected")
    cb = _ratios(records, "C", "B", cases, _DERIVATIVES)
    out = {"C_over_B_derivatives_min": _least(cb), "C_over_B_derivatives_max": _most(cb)}
    cases = [c for c in cases if c in vibration_cases()] or cases
    ct = _ratios(records, "C", None, cases, _DERIVATIVES, theory=True)
    out["C_derivative_rmse_over_theory_min"] = _least(ct)
    out["C_derivative_rmse_over_theory_max"] = _most(ct)
    cp = _ratios(records, "C", None, cases, phases, theory=True)
    out["C_corrected_phase_rmse_over_theory_min"] = _least(cp)
    out["C_corrected_phase_rmse_over_theory_max"] = _most(cp)
    for m in ("A", "B"):
        r = _ratios(records, m, None, cases, phases, theory=True)
        if r:
            out[f"{m}_corrected_phase_rmse_over_theory_max"] = _most(r)
    if 5 in cases or 5 in {r["case"] for r in records}:
        # from T = 30 on: a stack of a few frames keeps more of its contrast by
        # chance (one frame keeps all of it, and methods A and C then coincide; ten
        # keep 0.84 on average, against 0.82 for a long stack)
        ca = []
        Ta = _get(records, "A", 5, _DERIVATIVES[0])[0]
        for t in Ta:
            if not 30 <= t <= 100:
                continue
            sq = {m: [_at(records, m, 5, q, t) for q in _DERIVATIVES] for m in "AC"}
            if all(v is not None for m in sq for v in sq[m]):
                ca.append(math.sqrt(sum(v * v for v in sq["C"]) / sum(v * v for v in sq["A"])))
        if ca:
            out["C_over_A_derivatives_case5_max"] = _most(ca)
        cp5 = [y / th for q in phases for t, y, th in zip(*_get(records, "C", 5, q),
                                                            strict=True) if t <= 100 and th]
        if cp5:
            out["C_corrected_phase_case5_over_theory_max"] = _most(cp5)
            out["C_corrected_phase_case5_over_theory_min"] = _least(cp5)
    return out


# ------------------------------------------------------------------------ writing

