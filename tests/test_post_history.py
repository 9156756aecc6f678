"""Histories over time (gridstrain.post.history): Savitzky-Golay smoothing and
derivatives of a gauge's readings, with their std."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import savgol_filter

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
    with pytest.raises(ValueError, match="no times"):
        history(_reading(x, x, s, None))
    with pytest.raises(ValueError, match="window must be odd"):
        history(_reading(x, x, s), window=4)
