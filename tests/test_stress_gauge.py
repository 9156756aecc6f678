"""The stress gauge of an impact record (gridstrain.identify.stress_gauge and
``gridstrain stress-gauge``) against an exact elastic wave in a bar.

The oracle is d'Alembert's solution written below with numpy alone; the stress it
knows, ``E eps(x, t)``, is what the gauge must find from the accelerations alone.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from scipy.special import erf

from gridstrain.cli import main
from gridstrain.identify import stress_gauge, stress_gauge_of

E, RHO = 70e3, 2700.0  # MPa, kg/m3: aluminium, c = 5.09 mm/us
C = math.sqrt(E * 1e6 / RHO) * 1e3  # mm/s
PS, RATE = 0.25, 5e6  # mm per px; a 5 MHz camera


def bar_wave(n=120, W=200, *, eps0=2e-3, w=10.0, lead=4.0, ps=PS, rate=RATE, x=None):
    """An exact elastic wave in a bar free at x = 0, struck at x = L = W ps.

    Assumptions: a one-dimensional bar (plane sections stay plane, uniaxial
    stress, no lateral inertia: the long-wavelength limit, pulse 40 times the
    pixel), linear elastic, wave speed ``C = sqrt(E / rho)``. A compressive pulse,
    Gaussian of std ``w`` (mm) in space and peak strain ``-eps0``, enters at
    ``x = L`` (its centre ``lead w`` beyond it at t = 0, so that the bar is still at
    rest then) and travels towards the free end, where it reflects as tension:
    ``u = F(C t + x) + F(C t - x)`` with ``F'(s) = -eps0 exp(-(s - s0)^2 / 2w^2)``,
    whose derivative in x vanishes at x = 0 (a free end) at every time.

    Returns ``t`` (s), ``u`` (mm), ``eps``, ``acc`` (mm/s2) and ``acc_xx``
    (``d2 acc / dx2``, 1/s2 mm), each ``(n, W)`` at the pixel centres ``x = (j +
    1/2) ps`` (or ``(n, len(x))`` at the given ``x``, mm): the free end lies on the
    image's left border.
    """
    L = W * ps
    s0 = L + lead * w
    t = np.arange(n) / rate
    x = (np.arange(W) + 0.5) * ps if x is None else np.asarray(x, dtype=float)

    def z(s):
        return (s - s0) / w

    def F(s):
        return -eps0 * w * math.sqrt(math.pi / 2) * (1 + erf(z(s) / math.sqrt(2)))

    def F1(s):
        return -eps0 * np.exp(-z(s) ** 2 / 2)

    def F2(s):
        return eps0 * z(s) * np.exp(-z(s) ** 2 / 2) / w

    def F4(s):
        return -eps0 * (3 * z(s) - z(s) ** 3) * np.exp(-z(s) ** 2 / 2) / w**3

    a, b = C * t[:, None] + x[None, :], C * t[:, None] - x[None, :]
    return (t, F(a) + F(b), F1(a) - F1(b), C**2 * (F2(a) + F2(b)),
            C**2 * (F4(a) + F4(b)))


def _maps(field, H=8):
    """``(n, W)`` profiles as ``(n, H, W)`` maps, uniform down the columns."""
    return np.repeat(field[:, None, :], H, axis=1)


@pytest.fixture(scope="module")
def wave():
    t, u, eps, acc, acc_xx = bar_wave()
    return t, _maps(u / PS), _maps(eps), acc, acc_xx


def test_stress_is_e_times_strain_without_noise(wave):
    t, U, EPS, _, _ = wave
    g = stress_gauge(U, EPS, t, density=RHO, free_edge="left", pixel_size=PS, unit="mm")
    h = g.window // 2
    err = (g.stress - E * g.strain)[h:-h]
    # 0.2 MPa of a 140 MPa peak: the filter (order 4) misses the sixth time derivative
    # of a pulse 9.8 frames in std (measured 0.04 MPa), the midpoint rule a'' h^2 / 24
    # (2.6e-5 of the stress at 0.25 mm over a 10 mm pulse)
    assert np.abs(err).max() < 0.2
    assert np.abs(E * g.strain).max() > 130.0  # the pulse and its reflection were seen
    assert g.strip_width == pytest.approx(0.0)
    assert np.all(g.strip_stress == 0.0)
    # E from the slope: the same small bias, 0.1 % (measured 0.03 %)
    assert pytest.approx(E, rel=1e-3) == g.E
    # without std maps no std is made up: the interval is the residuals' scatter.
    # The filter's bias (-0.03 %) lies along the strain, so no residual shows it and
    # no interval holds it (measured: +-0.0004 %): bias_coefficient states it instead
    assert np.isnan(g.stress_std).all()
    assert g.interval_basis == "residual scatter"
    assert 0 < g.E_std < 1e-4 * E
    np.testing.assert_allclose(g.distance, (np.arange(200) + 0.5) * PS)
    # the strain rate: the filter's derivative of the strain, against C d eps / ds
    _, _, eps_x, _, _ = bar_wave(x=g.distance)
    rate = np.gradient(eps_x, t, axis=0)
    # 30 1/s of a peak 1000 1/s: the central difference's own error, (dt^2 / 6)
    # eps''' ~ 1 % of the peak for a 2 us pulse
    assert np.abs(g.strain_rate - rate)[h:-h, :].max() < 30.0
    assert g.strain_rate_range[1] > 500.0


def test_acceleration_bias_is_the_stated_coefficient():
    # a rigid body accelerated as u = alpha t^4 (the same at every section): the
    # filter of order 3 (window 7) returns 12 alpha t^2 + 24 alpha b exactly, b the
    # stated coefficient; order 4 returns 12 alpha t^2. A strain that varies along
    # the bar is given only so that E can be fitted.
    n, W = 40, 30
    t = np.arange(n) / RATE
    alpha = 1e20  # px/s^4: 24 alpha b is about 1 % of the acceleration
    U = _maps(np.repeat((alpha * t**4)[:, None], W, axis=1))
    EPS = _maps(np.outer(np.linspace(1, 2, n), np.linspace(0, 1e-3, W)))
    truth = 12 * alpha * t**2 * PS * 1e-3  # m/s^2
    for window, order in ((7, 3), (9, 4)):
        g = stress_gauge(U, EPS, t, density=RHO, free_edge="left", pixel_size=PS,
                         window=window, order=order)
        b = g.bias_coefficient
        h = window // 2
        expected = truth + 24 * alpha * b * PS * 1e-3
        # rounding only: 1e-9 of the acceleration
        np.testing.assert_allclose(g.acceleration[h:-h], np.repeat(expected[h:-h, None],
                                   W, axis=1), rtol=1e-8, atol=1e-9 * truth.max())
        # sigma = rho d a: the slab's momentum balance
        np.testing.assert_allclose(g.stress, RHO * g.distance * 1e-3 * g.acceleration
                                   * 1e-6, rtol=1e-12)
        # the 7-point second-derivative weights of a cubic, by hand, times dt^2
        b3 = np.sum(np.array([5, 0, -3, -4, -3, 0, 5]) / 42 * np.arange(-3, 4) ** 4) \
            / 24 / RATE**2
        if order == 3:
            assert b == pytest.approx(b3, rel=1e-12)
        else:  # zero but for rounding
            assert abs(b) < 1e-9 * b3


@pytest.mark.parametrize("edge", ["right", "top", "bottom"])
def test_every_free_edge_gives_the_same_stress(wave, edge):
    # the same bar mirrored or turned: its displacement changes sign with the
    # axis, the stress (tension positive) and the strain do not
    t, U, EPS, _, _ = wave
    ref = stress_gauge(U, EPS, t, density=RHO, free_edge="left", pixel_size=PS)
    if edge == "right":
        U2, E2 = -U[..., ::-1], EPS[..., ::-1]
    elif edge == "top":
        U2, E2 = np.swapaxes(U, 1, 2), np.swapaxes(EPS, 1, 2)
    else:
        U2, E2 = -np.swapaxes(U, 1, 2)[:, ::-1], np.swapaxes(EPS, 1, 2)[:, ::-1]
    g = stress_gauge(U2, E2, t, density=RHO, free_edge=edge, pixel_size=PS)
    np.testing.assert_allclose(g.stress, ref.stress, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(g.distance, ref.distance)
    assert pytest.approx(ref.E, rel=1e-12) == g.E
    if edge in ("right", "bottom"):  # the sections counted from the free edge
        assert g.index[0] == 199
        assert g.index[-1] == 0


def test_strip_without_data_is_extrapolated_with_its_stated_bias(wave):
    # no data over the first 10 columns (the margin of a measurement): everything but
    # the strip stays exact, the strip's part carries the bias the Notes state, and
    # E, whose fit takes one intercept per state, owes nothing to it
    t, U, EPS, _, _ = wave
    valid = np.ones(U.shape[1:], dtype=bool)
    valid[:, :10] = False
    g = stress_gauge(U, EPS, t, density=RHO, free_edge="left", pixel_size=PS,
                     valid=valid)
    gw = 10 * PS  # the strip, mm
    assert g.strip_width == pytest.approx(gw)
    # the slab's true stress from the strip is the stress at its inner side: rho
    # int_0^g a dx = E eps(g, t)
    _, _, eps_g, _, _ = bar_wave(x=[gw])
    strip_true = E * eps_g[:, 0]
    h = g.window // 2
    inner = g.stress - g.strip_stress + strip_true[:, None]
    assert np.abs(inner - E * g.strain)[h:-h].max() < 0.2  # MPa, as without a strip
    # the extrapolation's error against the stated bias, a'' (g^3/3 + l g^2/2 +
    # l^2 g/6) / 2, with the largest |a''| over the strip and the fit of l = 20 px
    # (twice the strip): within 1.5 times (a'' varies over the 7.5 mm it spans)
    l_fit = 20 * PS
    x = np.linspace(0, gw + l_fit, 61)
    _, _, _, _, axx = bar_wave(x=x)
    bound = RHO * np.abs(axx).max(axis=1) * 1e-9 * 1e-6 / 2 * (
        gw**3 / 3 + l_fit * gw**2 / 2 + l_fit**2 * gw / 6) * 1e3
    strip_err = np.abs(g.strip_stress[:, 0] - strip_true)
    assert np.all(strip_err[h:-h] <= 1.5 * bound[h:-h] + 0.2)
    assert strip_err.max() > 1.0  # MPa: the bias is real (measured 4.3) and stated
    assert pytest.approx(E, rel=1e-3) == g.E


def _noisy_draws(wave, n_draws, *, su, se, share, sigma, seed):
    """The wave with noise: each state's own (a (1 - share) part of the variance) and
    the reference's, one field common to every state (the share); white or, with
    ``sigma``, smoothed by a Gaussian of std sigma in x and y (as the window smooths
    the sensor noise), so that two pixels d apart correlate as exp(-d^2 / 4 sigma^2),
    the autocorrelation of that Gaussian."""
    _, U, EPS = wave
    rng = np.random.default_rng(seed)
    if sigma is not None:
        s = sigma
        pad = math.ceil(4 * s)  # drawn larger and cut: no wrap, no border effect
        delta = np.zeros((2 * pad + 1, 2 * pad + 1))
        delta[pad, pad] = 1.0
        gain = math.sqrt(np.sum(gaussian_filter(delta, s, mode="constant") ** 2))

    def field(shape):
        if sigma is None:
            return rng.normal(0.0, 1.0, shape)
        n, H, W = shape
        z = rng.normal(0.0, 1.0, (n, H + 2 * pad, W + 2 * pad))
        z = gaussian_filter(z, (0, s, s), mode="constant")[:, pad:-pad, pad:-pad]
        return z / gain  # unit std
    for _ in range(n_draws):
        common_u, common_e = field((1, *U.shape[1:])), field((1, *U.shape[1:]))
        yield (U + su * (math.sqrt(1 - share) * field(U.shape) + math.sqrt(share)
                         * common_u),
               EPS + se * (math.sqrt(1 - share) * field(U.shape) + math.sqrt(share)
                           * common_e))


@pytest.mark.parametrize("sigma", [None, 3.0])
def test_stds_and_interval_coverage_over_noise_draws(wave, sigma):
    # displacement and strain noise a pixel, half of each variance from the
    # reference (common to all states): 0.01 px and 1e-4 on white pixels, 0.002 px
    # and 2e-5 on pixels correlated as a window of sigma 3 px correlates them (their
    # sections' means average less noise away: E's std stays within 2 % of E, where
    # the first-order propagation holds)
    if sigma is None:
        t, U, EPS = wave[:3]
        n_draws, su, se = 100, 0.01, 1e-4
    else:  # a shorter record, the propagation through correlated sections costing more
        t, u, eps, _, _ = bar_wave(n=80, W=100, ps=0.5, lead=3.0)
        U, EPS = _maps(u / 0.5), _maps(eps)
        n_draws, su, se = 60, 0.002, 2e-5
    share = 0.5
    std_u, std_e = np.full(U.shape, su), np.full(U.shape, se)
    f = np.full(t.size, share)
    stresses, Es, covered = [], [], 0
    for Un, En in _noisy_draws((t, U, EPS), n_draws, su=su, se=se, share=share,
                               sigma=sigma, seed=3):
        g = stress_gauge(Un, En, t, density=RHO, free_edge="left",
                         pixel_size=PS if sigma is None else 0.5,
                         displacement_std=std_u, strain_std=std_e, reference_share=f,
                         sigma=sigma)
        stresses.append(g.stress)
        Es.append(g.E)
        covered += g.E_interval[0] <= E <= g.E_interval[1]
    stresses = np.array(stresses)
    h = g.window // 2
    ratio = (stresses.std(axis=0, ddof=1) / g.stress_std)[h:-h]
    # the std of 60 to 100 draws scatters by 7 to 9 %: the median ratio within 5 % of
    # 1 (its own sampling error, over correlated points, about 2 %; measured 0.999
    # with 200 correlated draws), every point within 40 % (4 sampling std)
    assert abs(np.median(ratio) - 1) < 0.05, np.median(ratio)
    assert np.all(np.abs(ratio - 1) < 0.4)
    # E's std against the draws' (measured 425 / 412 MPa with 400 white draws, 0.97
    # with 200 correlated ones): within 30 % (3 sampling std of 60 draws)
    assert abs(np.std(Es, ddof=1) / g.E_std - 1) < 0.3
    # coverage of the 95 % interval, 3 binomial std below (88 of 100, 50 of 60)
    assert covered >= math.floor(n_draws * (0.95 - 3 * math.sqrt(0.95 * 0.05 / n_draws))), \
        covered
    assert g.interval_basis == "stated std"


def test_errors_name_the_parameter(wave):
    t, U, EPS, _, _ = wave
    kw = {"density": RHO, "free_edge": "left", "pixel_size": PS}
    with pytest.raises(ValueError, match="free_edge"):
        stress_gauge(U, EPS, t, **{**kw, "free_edge": "front"})
    with pytest.raises(ValueError, match="unit must be one of"):
        stress_gauge(U, EPS, t, **kw, unit="furlong")
    uneven = t.copy()
    uneven[10] += 0.5 / RATE
    with pytest.raises(ValueError, match="evenly"):
        stress_gauge(U, EPS, uneven, **kw)
    with pytest.raises(ValueError, match="strain must be a"):
        stress_gauge(U, EPS[:, :, :5], t, **kw)
    with pytest.raises(ValueError, match="go together"):
        stress_gauge(U, EPS, t, **kw, displacement_std=np.ones(U.shape))
    with pytest.raises(ValueError, match="window must be odd"):
        stress_gauge(U, EPS, t, **kw, window=8)
    with pytest.raises(ValueError, match="density"):
        stress_gauge(U, EPS, t, **{**kw, "density": -1.0})
    with pytest.raises(ValueError, match=r"strain does not vary|nothing to fit"):
        stress_gauge(U, 0 * EPS, t, **kw)


# --- a result file and the command line -----------------------------------------


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """The bar's wave filmed and measured: 50 frames of 48 x 128 px at 5 MHz and 0.3
    mm a pixel (a 38 mm bar), a 6 mm pulse of peak strain 5e-3, after 2 frames at
    rest (the reference), drawn as grid images (pitch 5 px) by the numpy-only
    generator of ``tests/independent_grid.py`` through a Poisson-Gaussian camera,
    then measured one frame per state with the frame rate (about 10 s)."""
    sys.path.insert(0, str(Path(__file__).parent))
    from gridstrain import measure_series
    from independent_grid import camera, scene

    n, H, W, ps = 50, 48, 128, 0.3
    _, u, _, _, _ = bar_wave(n=n, W=W, ps=ps, eps0=5e-3, w=6.0, lead=3.0)
    rng = np.random.default_rng(1)
    frames = np.empty((n + 2, H, W), dtype=np.uint16)
    for k in range(n + 2):
        uk = u[max(k - 2, 0)] / ps

        def moved(X, Y, uk=uk):
            return np.interp(X, np.arange(W), uk), 0.0 * Y

        level, _ = scene((H, W), pitch=5.0, angle=0.0, hole=False, light=False,
                         displacement=moved)
        frames[k] = camera(level, 0.5, 5.0, rng)
    res = measure_series(None, frames, reference_frames=2, frame_rate=RATE)
    d = tmp_path_factory.mktemp("impact")
    # lossless: the command must read back the very maps measured here
    return {"good": res.save(d / "impact.h5", pixel_size=ps, unit="mm", lossless=True),
            "nopix": res.save(d / "nopix.h5"),
            "notime": dataclasses.replace(res, time=None).save(d / "notime.h5",
                                                               pixel_size=ps, unit="mm"),
            "result": res, "ps": ps}


def test_result_times_pixel_size_and_edge(record):
    res = record["result"]
    g = stress_gauge_of(res, density=RHO, free_edge="left", pixel_size=record["ps"],
                        unit="mm")
    assert g.time[1] - g.time[0] == pytest.approx(1 / RATE)
    # the sections start where the measurement does (4 sigma from the border, the
    # mask's edge and the bar's free end): the strip is that margin
    first = int(np.flatnonzero(np.asarray(res.valid).any(axis=1).all(axis=0))[0])
    assert g.strip_width == pytest.approx(first * record["ps"])
    # E from images through the grid method, within its 95 % interval (measured 69.1
    # GPa, [62.0, 76.3]); the noise of 0.005 px at 5 MHz dominates
    assert g.E_interval[0] <= E <= g.E_interval[1]
    assert g.E_interval[1] - g.E_interval[0] < 0.3 * E  # an interval that says something
    with pytest.raises(ValueError, match="pixel size"):
        stress_gauge_of(res, density=RHO, free_edge="left", pixel_size=None, unit=None)


def test_command_prints_E_and_writes_the_curves(record, tmp_path, capsys):
    curves, plot = tmp_path / "curves.csv", tmp_path / "ss.png"
    rc = main(["stress-gauge", str(record["good"]), "--density", str(RHO),
               "--free-edge", "left", "--json", "--curves", str(curves),
               "--plot", str(plot)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    g = stress_gauge_of(record["result"], density=RHO, free_edge="left",
                        pixel_size=record["ps"], unit="mm")
    # the command is the function on the file's maps, read back exactly
    assert out["E"] == pytest.approx(g.E, rel=1e-9)
    assert out["E_interval"] == pytest.approx(list(g.E_interval), rel=1e-9)
    assert out["E_unit"] == "MPa"
    assert out["strain_rate_range"] == pytest.approx(
        list(g.strain_rate_range), rel=1e-9)
    rows = curves.read_text().splitlines()
    assert rows[0].startswith("time [s],distance [mm],stress [MPa]")
    assert len(rows) == 1 + g.stress.size  # a row per state and section
    assert plot.stat().st_size > 0
    assert main(["stress-gauge", str(record["good"]), "--density", "2700",
                 "--free-edge", "left"]) == 0
    text = capsys.readouterr().out
    # --edge-at: the free edge 1.5 mm outside the image, in the file's unit
    assert main(["stress-gauge", str(record["good"]), "--density", "2700",
                 "--free-edge", "left", "--edge-at", "-1.5", "--json"]) == 0
    moved = json.loads(capsys.readouterr().out)
    assert moved["strip_width"] == pytest.approx(out["strip_width"] + 1.5 - 0.5 * 0.3)
    assert "E = " in text
    assert "strip without data" in text


@pytest.mark.parametrize(("which", "args", "message"), [
    ("notime", [], "has no times: measure the record with --each-frame --frame-rate"),
    ("nopix", [], "has no pixel size"),
    ("good", ["--free-edge", "front"], "invalid choice: 'front'"),
    ("good", ["--density", "-5"], "density"),
    # the filter's window longer than the record: named by the option that sets it
    ("good", ["--smoothing", "99", "4"], "--smoothing WINDOW ORDER: window must be odd"),
])
def test_command_errors_are_one_line(record, capsys, which, args, message):
    argv = ["stress-gauge", str(record[which]), "--density", "2700", "--free-edge",
            "left", *args]
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2
    assert message in err, err
    assert len(err.strip().splitlines()) == 1, err


def test_the_result_s_own_pixel_size_is_used_and_another_refused(record):
    bare = record["result"]  # measured here: no pixel size of its own
    res = dataclasses.replace(bare, pixel_size=record["ps"], unit="mm")
    given = stress_gauge_of(bare, density=RHO, free_edge="left", pixel_size=record["ps"],
                            unit="mm")
    own = stress_gauge_of(res, density=RHO, free_edge="left")
    assert own.E == given.E
    assert own.unit == "mm"
    np.testing.assert_array_equal(own.distance, given.distance)
    # its own given again, as typed from 6 printed digits: the same, to the last digit
    again = stress_gauge_of(res, density=RHO, free_edge="left",
                            pixel_size=record["ps"] * (1 + 2e-6), unit="mm")
    assert again.E == own.E
    # another: refused in one line naming both, before any work
    for ps, unit in ((0.25, "mm"), (3e-4, "m")):
        with pytest.raises(ValueError, match=rf"pixel_size={ps:g} {unit} disagrees with "
                                             r"this result's own \(0.3 mm\)") as info:
            stress_gauge_of(res, density=RHO, free_edge="left", pixel_size=ps, unit=unit)
        assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="length unit 'mm'"):
        stress_gauge_of(res, density=RHO, free_edge="left", unit="m")


def test_command_edge_at_in_px(record, capsys):
    """``--px``: ``--edge-at`` in px (the stress keeps mm): -5 px is -1.5 mm."""
    args = ["stress-gauge", str(record["good"]), "--density", "2700", "--free-edge",
            "left", "--json", "--edge-at"]
    assert main([*args, "-1.5"]) == 0
    mm = json.loads(capsys.readouterr().out)
    assert main([*args, "-5", "--px"]) == 0
    px = json.loads(capsys.readouterr().out)
    assert px["strip_width"] == pytest.approx(mm["strip_width"], rel=1e-12)
    assert px["E"] == pytest.approx(mm["E"], rel=1e-12)
