"""The vibration offset of methods A and B about the frames' mean position: its size
(:func:`gridstrain.stacks.circular_offset_std`), its removal with the measured shifts
(``correct_phases(..., about="mean")``) and the measurement that removes it.

Stacks come from ``independent_grid`` (numpy only): each frame is the specimen moved
rigidly by a known shift ``a_t``, ``v_t(x) = s(x + a_t)``, through a Poisson-Gaussian
12-bit sensor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gridstrain import Lattice, measure_series, wft
from gridstrain.stacks import circular_offset_std, correct_phases, method_a, method_b
from gridstrain.stacks._methods import phase_offsets
from independent_grid import camera, scene

H, W, PITCH = 96, 128, 5.0
LAT = Lattice.from_pitch(PITCH)
K, L = 0.28, 5.0  # sensor gain and read-noise variance, 12-bit grey levels
T = 24


def _moved(a):
    # the generator's displacement is Lagrangian (the point X seen at X + u): a frame
    # s(x + a) is the specimen moved by u = -a
    return lambda X, Y: (0 * X - a[0], 0 * Y - a[1])


def _stack(std, rng):
    shifts = rng.normal(0.0, std, (T, 2))
    frames = [camera(scene((H, W), pitch=PITCH, angle=0.0, hole=False,
                           displacement=_moved(a))[0], K, L, rng) for a in shifts]
    return np.stack(frames), shifts


@pytest.fixture(scope="module")
def still():
    """The transform of the specimen unmoved and noise-free: the phases' truth."""
    return wft(scene((H, W), pitch=PITCH, angle=0.0, hole=False)[0], LAT)


def _offset_about_mean(maps, still, shifts):
    """The stack's phase less the truth at its mean position, averaged over the valid
    pixels (a circular mean), and the pixels' spread (the phase noise), rad."""
    sel = maps.valid & still.valid
    e = np.angle(maps.psi * np.conj(still.psi))[:, sel]
    e = e - (2 * np.pi * LAT.K @ shifts.mean(axis=0))[:, None]
    e = np.angle(np.exp(1j * e))
    return np.angle(np.mean(np.exp(1j * e), axis=1)), e.std(axis=1)


def test_the_offset_spread_follows_its_law():
    # 4000 stacks of 64 frames per amplitude: the std of the offset about the mean
    # position against the formula (the mean of its value over the draws, each with
    # its sample std of the shifts). A std from 4000 draws is within 1.1 % (1 sigma);
    # the formula's remainder is fifth order (the 0.5-px case: 2 %): 6 %.
    rng = np.random.default_rng(0)
    for std in (0.1, 0.25, 0.5):
        draws = [rng.normal(0.0, std, (64, 2)) for _ in range(4000)]
        got = np.std([phase_offsets(d, LAT, exact=True, about_mean=True) for d in draws],
                     axis=0)
        want = np.mean([circular_offset_std(d, LAT) for d in draws], axis=0)
        np.testing.assert_allclose(got, want, rtol=0.06)
    # third order: s^3 / sqrt(6 T) when the spread s of the phase advances is small
    s = 2 * math.pi * 0.01 / PITCH
    tiny = rng.normal(0.0, 1.0, (10_000, 2))
    tiny = 0.01 * (tiny - tiny.mean(0)) / tiny.std(0)
    np.testing.assert_allclose(circular_offset_std(tiny, LAT), s**3 / math.sqrt(6e4),
                               rtol=1e-3)


@pytest.mark.parametrize("method", [method_b, method_a])
@pytest.mark.parametrize("std", [0.1, 0.25, 0.5])
def test_measured_shifts_remove_the_offset_down_to_the_noise(still, method, std):
    rng = np.random.default_rng(int(std * 100))
    frames, shifts = _stack(std, rng)
    res = method(frames, LAT)
    before, noise = _offset_about_mean(res.maps, still, shifts)
    measured = res.screening.shifts()  # centred, from the frames alone
    stated = phase_offsets(measured, LAT, exact=True, about_mean=True)
    after, _ = _offset_about_mean(correct_phases(res.maps, measured, about="mean"), still,
                                  shifts)
    # The offset's average over the pixels keeps the phase noise's average over
    # about (96 - 30) x (128 - 30) / (4 pi sigma^2) ~ 20 independent windows: noise /
    # 4.5. The stated offset (from the measured shifts) is the measured one within
    # twice that; the corrected offset is within it: at the noise level.
    tol = 2 * noise / math.sqrt(20)
    for j in range(2):
        assert abs(before[j] - stated[j]) <= tol[j], (before, stated, tol)
        assert abs(after[j]) <= tol[j], (after, tol)
    if std == 0.5:
        # what was removed is tens of times the phase noise of a pixel (here ~20x at
        # T = 24 frames)
        assert np.max(np.abs(before)) > 5 * np.max(noise), (before, noise)


def test_the_measurement_removes_the_offset_and_states_it():
    # method B on a vibrated pair (0.5 px std) whose specimen moved rigidly by (0.4,
    # -0.3) px: the displacement is that move plus the difference of the two stacks'
    # mean positions, uniform, within the noise of its average.
    rng = np.random.default_rng(11)
    ref, a_ref = _stack(0.5, rng)
    move = np.array([0.4, -0.3])
    cur_shifts = rng.normal(0.0, 0.5, (T, 2))
    cur = np.stack([camera(scene((H, W), pitch=PITCH, angle=0.0, hole=False,
                                 displacement=_moved(a - move))[0], K, L, rng)
                    for a in cur_shifts])
    res = measure_series(ref, [cur], lattice=LAT, method="B")
    v = res.valid[0]
    # frame t of the state is s(x + a_t - move): the specimen at x + u, u = move
    # minus the state's mean shift, plus the reference's mean shift
    want = move - cur_shifts.mean(0) + a_ref.mean(0)
    u = np.array([np.mean(np.asarray(res.u[0, k])[v]) for k in range(2)])
    # the map's mean keeps the phase noise's mean over ~20 windows, p / 2 pi x 3e-4
    # rad / 4.5 ~ 5e-5 px, and the measured shifts' error, 1e-3 px / sqrt(T): 1e-3 px
    # (the offset removed is p / 2 pi x 0.0125 rad ~ 0.01 px)
    np.testing.assert_allclose(u, want, atol=1e-3)
    recs = res.systematic["vibration_offset"]
    assert [r["series"] for r in recs] == list(res.names)
    for r, a in zip(recs, (a_ref, cur_shifts), strict=True):
        assert r["method"] == "B"
        # what was removed and its stated spread, from the measured shifts, are those
        # of the true shifts: the shifts are measured within ~1e-3 px of 0.5 px, which
        # moves the offset by ~1e-4 rad and its spread (cubic in the amplitude) by 1 %
        np.testing.assert_allclose(r["removed_rad"],
                                   phase_offsets(a, LAT, exact=True, about_mean=True),
                                   atol=2e-4)
        np.testing.assert_allclose(r["predicted_std_rad"], circular_offset_std(a, LAT),
                                   rtol=0.03)
