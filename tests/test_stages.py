"""A state measured by declared stages, its findings typed, a long record's checks sampled.

The oracles: a finding's sentence is the text the measurement said before codes existed
(a ``str`` equal to it), its code one of the registry's; sampling a long record's
expensive checks changes no measured value (the maps of a record measured with and
without sampling are compared bit for bit), and every state sampled out says so in its
own records while every state in doubt (a step of the followed field over a tenth of a
period, written into the frames here) gets every check.
"""

from __future__ import annotations

import json
import pickle
import subprocess
import sys

import numpy as np
import pytest

import gridstrain.series._stages as stages
from gridstrain import FINDINGS, Finding, Lattice
from gridstrain._progress import SEVERITIES, tally
from gridstrain.models import synthetic
from gridstrain.results import load, save_result
from gridstrain.series import measure_series

SHAPE = (64, 96)
PITCH = 5.0
N = 25  # frames: the reference and 24 states, a long record (more than 20)


def _record(n: int = N, *, jump_at: int | None = None, jump: float = 1.0) -> np.ndarray:
    """(n, H, W) uint16 frames: a drift of 0.02 px a frame (0.004 period, a small step)
    and a strain of 1e-5 a frame; from frame ``jump_at`` on, ``jump`` px more along x
    (1 px = 0.2 period: followed, but more than a small step)."""
    rng = np.random.default_rng(3)
    lattice = Lattice.from_pitch(PITCH)
    out = np.empty((n, *SHAPE), dtype=np.uint16)
    for t in range(n):
        extra = jump if jump_at is not None and t >= jump_at else 0.0

        def disp(X, Y, t=t, extra=extra):
            return (0.02 * t + extra + 1e-5 * t * (X - SHAPE[1] / 2),
                    -0.01 * t + 0 * Y)

        clean = synthetic.grid_image(SHAPE, lattice, amplitude=1500.0,
                                     displacement=disp if t else None)
        out[t] = np.clip(synthetic.add_noise(clean + 200.0, rng=rng), 0, 4095)
    return out


@pytest.fixture(scope="module")
def sampled():
    return measure_series(None, _record(), reference_frames=1)


def test_a_finding_is_its_sentence_with_a_code():
    f = Finding("fringe_order.unconfirmed", "s2: fringe order not confirmed", state="s2",
                step=0.45)
    assert f == "s2: fringe order not confirmed"
    assert isinstance(f, str)
    assert (f.code, f.state, f.severity, f.figures["step"]) == (
        "fringe_order.unconfirmed", "s2", "doubt", 0.45)
    assert type(str(f)) is str
    assert str(f) == f
    with pytest.raises(AttributeError):
        f.code = "other"
    with pytest.raises(ValueError, match=r"finding codes.*'no\.such'"):
        Finding("no.such", "text")
    again = pickle.loads(pickle.dumps(f))
    assert (again, again.code, dict(again.figures)) == (f, f.code, {"step": 0.45})
    assert all(k.severity in SEVERITIES and k.advice for k in FINDINGS.values())
    assert tally([f, Finding("saturation", "x"), "plain"]) == (
        "1 doubt (fringe_order.unconfirmed), 2 warnings (saturation, other)")


def test_the_stages_are_declared_once():
    names = [s.name for s in stages.STAGES]
    assert len(set(names)) == len(names)
    assert all(s.rule in stages.RULES and s.cost >= 0 and callable(s.run)
               for s in stages.STAGES)
    assert {"kinematics", "image features", "pair check", "smoothing"} <= set(names)


def test_a_long_record_samples_its_checks_and_says_so(sampled):
    r = sampled
    n = r.n_states
    every = stages.SAMPLE_EVERY
    full = {0, n - 1, *range(0, n, every)}
    smooth = r.systematic["smoothing"]
    pairs = r.systematic["pair_match"]
    for i in range(n):
        said = "sampled every" in r.fringe_orders[i].detail
        assert said == (i not in full), (i, r.fringe_orders[i].detail)
        assert smooth[i]["computed"] == (i in full)
        assert (pairs[i]["verdict"] == "not checked") == (i not in full)
        # a state sampled out is followed by a small step from a confirmed state
        assert r.fringe_orders[i].confirmed
    (note,) = [w for w in r.warnings if w.code == "checks.sampled"]
    assert note.severity == "note"
    assert note.figures["states"] == n - len(full)
    assert "sampled" in note


def test_sampling_changes_no_measured_value(sampled, monkeypatch):
    monkeypatch.setattr(stages, "_LONG_RECORD", 10**6)
    every = measure_series(None, _record(), reference_frames=1)
    assert not [w for w in every.warnings if w.code == "checks.sampled"]
    assert all(s["computed"] for s in every.systematic["smoothing"])
    # the displacement and strain are the kinematics' own, whatever the checks
    np.testing.assert_array_equal(sampled.u, every.u)
    np.testing.assert_array_equal(sampled.strain, every.strain)
    np.testing.assert_array_equal(sampled.valid, every.valid)


def test_a_state_in_doubt_gets_every_check():
    jump_at = 13  # state 12 (frame 13) steps by 0.2 period: more than a small step
    r = measure_series(None, _record(jump_at=jump_at), reference_frames=1)
    i = jump_at - 1
    for k in (i, i + 1):  # the state in doubt and the one after it
        assert "sampled every" not in r.fringe_orders[k].detail, r.fringe_orders[k].detail
        assert r.systematic["smoothing"][k]["computed"]
    assert r.fringe_orders[i].step > 0.1  # periods: the doubt was real
    # the jump is measured, not lost: 1 px more than the state before, in u_x
    v = r.valid[i] & r.valid[i - 1]
    assert abs(np.median(r.u[i, 0][v] - r.u[i - 1, 0][v]) - 1.02) < 0.05  # px: noise


def test_findings_keep_their_codes_in_the_file_and_old_files_load(sampled, tmp_path):
    save_result(sampled, tmp_path / "r.h5")
    back = load(tmp_path / "r.h5")
    assert [(w, w.code, w.state) for w in back.warnings] == [
        (w, w.code, w.state) for w in sampled.warnings]
    # a file of before the codes: sentences alone, each read as code "other"
    import dataclasses

    old = dataclasses.replace(sampled, warnings=tuple(str(w) for w in sampled.warnings),
                              findings=())
    assert {w.code for w in old.warnings} == {"other"}
    assert list(old.warnings) == list(sampled.warnings)


def test_the_json_summary_gives_each_finding_its_code(tmp_path):
    import tifffile

    path = tmp_path / "rec.tif"
    tifffile.imwrite(path, _record(6))
    out = subprocess.run([sys.executable, "-m", "gridstrain.cli", "measure", str(path),
                          "--reference-frames", "1", "-o", str(tmp_path / "r.h5"), "--json",
                          "--quiet"], capture_output=True, text=True, check=True).stdout
    summary = json.loads(out)
    assert len(summary["findings"]) == len(summary["warnings"]) > 0
    assert all(f["code"] in FINDINGS and f["severity"] == FINDINGS[f["code"]].severity
               for f in summary["findings"])


@pytest.mark.parametrize(("shape", "workers"), [((100, 160), 1), ((512, 512), None)])
def test_small_states_are_transformed_on_the_calling_thread(monkeypatch, shape, workers):
    # a state's phase maps (method A): one thread below _THREADED_PIXELS, the usable
    # cores from it on; the same maps either way (the transform's two wave vectors are
    # independent)
    from gridstrain.phase import Window
    from gridstrain.series import _passes

    lat = Lattice.from_pitch(5.0)
    img = synthetic.grid_image(shape, lat, amplitude=1000.0)
    seen = []
    real = _passes.transform

    def spy(*args, **kwargs):
        seen.append(kwargs["workers"])
        return real(*args, **kwargs)

    monkeypatch.setattr(_passes, "transform", spy)
    window = Window(sigma=5.0)
    pm, _ = _passes._phase_maps_a(img, lat, window, None)
    assert seen == [workers]
    monkeypatch.setattr(_passes, "_THREADED_PIXELS", 0 if workers == 1 else 2**40)
    other, _ = _passes._phase_maps_a(img, lat, window, None)
    assert seen[1] == (None if workers == 1 else 1)
    np.testing.assert_array_equal(pm.psi, other.psi)
    np.testing.assert_array_equal(pm.dphi, other.dphi)
