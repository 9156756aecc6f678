"""Histories over time (gridstrain.post.history): Savitzky-Golay smoothing and
derivatives of a gauge's readings, with their std."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.signal import savgol_coeffs, savgol_filter

from gridstrain.post import GaugeReading, history

N = 25
T = 0.002 * np.arange(N) + 1.0  # a high-speed record: 500 frames per second


def _reading(exx, ux, std, time=T, share=None):
    n = exx.size
    z = np.zeros(n)
    return GaugeReading(
        states=tuple(f"s{i}" for i in range(n)), where="test", n_pixels=np.ones(n, int),
        exx=exx, exx_std=std, eyy=-0.3 * exx, eyy_std=std, exy=z, exy_std=std,
        ux=ux, ux_std=std * 100, uy=z, uy_std=std * 100, time=time, reference_share=share)


def test_derivatives_of_a_cubic_are_exact():
    # a degree-3 polynomial is reproduced exactly by an order-3 filter: the strain
    # rate and the acceleration equal the analytic derivatives (to rounding)
    t = T - T[0]
    exx = 1e-3 + 0.5 * t - 40.0 * t**2 + 2000.0 * t**3
    ux = 0.2 + 30.0 * t + 900.0 * t**2 - 1e4 * t**3
    h = history(_reading(exx, ux, np.full(N, 1e-5)), window=7, order=3, pixel_size=0.05,
                unit="mm")
    np.testing.assert_allclose(h.exx_rate, 0.5 - 80.0 * t + 6000.0 * t**2, rtol=1e-9,
                               atol=1e-9)
    np.testing.assert_allclose(h.vx, 0.05 * (30.0 + 1800.0 * t - 3e4 * t**2), rtol=1e-9)
    # atol: the rounding of the second derivative's weights, 1e-11 of 90 mm/s2
    np.testing.assert_allclose(h.ax, 0.05 * (1800.0 - 6e4 * t), rtol=1e-8, atol=1e-6)
    assert h.columns()["vx [mm/s]"] is h.vx


def test_std_matches_repeated_draws():
    # 4000 noise draws: each state's own noise plus, in half of its variance, a noise
    # common to every state (the reference's). The empirical std of each output
    # within 5 % of the propagated one (the sampling error of a std from 4000 draws
    # is 1.1 %): the common part cancels in the rate and stays in the smoothed strain
    rng = np.random.default_rng(2)
    s = rng.uniform(5e-6, 2e-5, N)  # each state its own std
    f = np.full(N, 0.5)
    draws = rng.normal(0.0, 1.0, (4000, N)) * s * np.sqrt(1 - f) \
        + rng.normal(0.0, 1.0, (4000, 1)) * s * np.sqrt(f)
    out = np.array([history(_reading(d, d * 100, s, share=f), window=9, order=2).exx_rate
                    for d in draws[:200]])
    h = history(_reading(draws[0], draws[0] * 100, s, share=f), window=9, order=2)
    # scipy's own filter on all the draws at once, for the empirical side
    rates = savgol_filter(draws, 9, 2, deriv=1, delta=0.002, axis=1, mode="interp")
    np.testing.assert_allclose(out, rates[:200], rtol=1e-9, atol=1e-12)
    for emp, pred in ((rates, h.exx_rate_std),
                      (savgol_filter(draws * 100, 9, 2, deriv=2, delta=0.002, axis=1,
                                     mode="interp"), h.ax_std),
                      (savgol_filter(draws, 9, 2, axis=1, mode="interp"), h.exx_std)):
        ratio = emp.std(axis=0, ddof=1) / pred
        assert np.all(np.abs(ratio - 1) < 0.05), ratio
    # without the share the states are taken as independent: the rate's std is then
    # overstated, by up to sqrt(2), where the common part cancels (interior points;
    # measured 1.27 to 1.41, the states' std differing)
    h0 = history(_reading(draws[0], draws[0] * 100, s), window=9, order=2)
    assert np.all(h0.exx_rate_std[4:-4] > 1.2 * h.exx_rate_std[4:-4])


def test_uneven_or_missing_times_are_refused():
    x = np.zeros(N)
    s = np.full(N, 1e-5)
    uneven = T.copy()
    uneven[5] += 0.0005
    with pytest.raises(ValueError, match="evenly spaced"):
        history(_reading(x, x, s, uneven))
    with pytest.raises(ValueError, match=r"no times.*--frame-rate"):
        history(_reading(x, x, s, None))
    with pytest.raises(ValueError, match="window must be odd"):
        history(_reading(x, x, s), window=4)


def _stretch_reading(t, lx, ly, s):
    """A gauge under the uniform stretch ``(lx(t), ly(t))`` without rotation: the
    Lagrangian gradient is ``diag(lx - 1, ly - 1)``, each of its four components with
    the std ``s``."""
    n = t.size
    z = np.zeros(n)
    std = np.full(n, s)
    return GaugeReading(
        states=tuple(f"s{i}" for i in range(n)), where="test", n_pixels=np.ones(n, int),
        exx=lx - 1, exx_std=std, eyy=ly - 1, eyy_std=std, exy=z, exy_std=std,
        ux=z, ux_std=std, uy=z, uy_std=std, time=t, rotation=z, rotation_std=std,
        gradient_std=np.tile(std[:, None], (1, 4)), pixel_size=0.05, unit="mm")


def test_finite_strain_history_of_a_uniform_stretch_is_exact():
    # a 30 % stretch ramped along x, an exponential one along y: the Green-Lagrange
    # xx strain (lx^2 - 1) / 2 = a t + a^2 t^2 / 2 is quadratic in time and the
    # logarithmic yy strain ln ly = b t linear, so the order-2 filter reproduces both
    # and their rates exactly (to rounding, 1e-9 of the strains)
    t = T - T[0]
    a, b = 0.3 / t[-1], -0.1 / t[-1]
    lx, ly = 1 + a * t, np.exp(b * t)
    s = 1e-5
    h = history(_stretch_reading(t + 1.0, lx, ly, s), window=7, order=2, unit="mm",
                finite=True)
    assert_allclose = np.testing.assert_allclose
    assert_allclose(h.gl_xx, a * t + a**2 * t**2 / 2, rtol=0, atol=1e-12)
    assert_allclose(h.gl_xx_rate, a + a**2 * t, rtol=1e-9)
    assert_allclose(h.log_yy, b * t, rtol=0, atol=1e-12)
    assert_allclose(h.log_yy_rate, b, rtol=1e-9)
    assert_allclose(h.gl_xy, 0.0, atol=1e-15)
    # at 30 % the small strain misses the Green-Lagrange one by a^2 t^2 / 2 = 4.5 %
    assert h.exx[-1] < 0.96 * h.gl_xx[-1]
    # the std: the Green-Lagrange xx strain moves by lx per unit du_x/dx (first
    # order), so its rate's std is that of scipy's derivative weights on lx * s
    w = savgol_coeffs(7, 2, deriv=1, delta=0.002, use="dot")
    i = N // 2
    assert_allclose(h.gl_xx_rate_std[i], s * np.sqrt(np.sum((w * lx[i - 3:i + 4]) ** 2)),
                    rtol=1e-9)
    cols = h.columns()
    assert cols["gl_xx_rate [1/s]"] is h.gl_xx_rate
    assert cols["log_yy_std [-]"] is h.log_yy_std
    # without finite, no finite column
    plain = history(_stretch_reading(t + 1.0, lx, ly, s), window=7, unit="mm")
    assert plain.gl_xx is None
    assert "gl_xx [-]" not in plain.columns()


def test_velocities_say_their_unit_by_the_rule_of_places():
    t = T - T[0]
    ux = 3.0 + 20.0 * t  # px
    z = np.zeros(N)
    r = dataclasses.replace(_reading(z, ux, np.full(N, 1e-5)), pixel_size=0.05,
                            unit="mm")
    mm = history(r, unit="mm")
    assert mm.unit == "mm"
    np.testing.assert_allclose(mm.vx, 20.0 * 0.05, rtol=1e-9)
    px = history(r, px=True)
    assert px.unit == "px"
    np.testing.assert_allclose(px.vx, 20.0, rtol=1e-9)
    # the result's own pixel size given again is accepted
    np.testing.assert_array_equal(history(r, pixel_size=0.05, unit="mm").vx, mm.vx)
    # without either: refused, since the call once gave px/s
    with pytest.raises(ValueError, match=r"do not say their unit.*unit='mm'.*px=True"):
        history(r)
    with pytest.raises(ValueError, match=r"pixel_size=0.04 mm disagrees .* \(0.05 mm\)"):
        history(r, pixel_size=0.04, unit="mm")
    with pytest.raises(ValueError, match="length unit 'mm'"):
        history(r, unit="um")
    with pytest.raises(ValueError, match="px=True gives the velocities in px/s"):
        history(r, px=True, unit="mm")
    # a reading of a result without a pixel size: px, as before
    assert history(_reading(z, ux, np.full(N, 1e-5))).unit == "px"
    # a place needs the result, not a reading
    with pytest.raises(TypeError, match="region name a place on a result"):
        history(r, unit="mm", region=(0, 0, 1, 1))
    # finite strains need the gauge's rotation
    with pytest.raises(ValueError, match=r"gauge\(\.\.\., finite=True\)"):
        history(r, unit="mm", finite=True)


def test_a_dropped_frame_is_named_where_the_times_break():
    """A record with a frame dropped (states numbered by their files: 3 then 5) has
    one step twice the others: the refusal names the two states around it."""
    x = np.zeros(N)
    s = np.full(N, 1e-5)
    dropped = np.delete(0.002 * np.arange(N + 1) + 1.0, 4)  # frame 4 missing
    with pytest.raises(ValueError, match=r"evenly spaced.*0\.004 s from s3 to s4"):
        history(_reading(x, x, s, dropped))
