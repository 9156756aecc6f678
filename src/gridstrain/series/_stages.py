"""The measurement of one state as a declared list of stages.

Each :class:`Stage` has a name (what the progress messages and the benchmarks call
it), a cost (its weight in the progress, in frames read: a transform is about 4) and
a rule for when it runs, and it is one function of the run (:class:`_Run`) and the
state (:class:`_State`, the owner of the state's arrays, which drops each once its
last stage has used it). :data:`STAGES` is the whole measurement; the loop of
:func:`gridstrain.series.measure_series` runs it for every state. A new per-state
check is one function and one line of :data:`STAGES`.

When a stage runs (:data:`RULES`)
    ``"every"``: every state. ``"full"``: the expensive checks (image features,
    the pair check, the contrast and smoothing bounds), run on every state except in a long record
    of single frames followed in series order (:class:`_Policy`), where they run on
    the first and the last state, every :data:`SAMPLE_EVERY`-th, and every state in
    doubt (its own or its predecessor's: a fringe order not confirmed or corrected, a
    step of the followed field over a tenth of a period, a jump, a screening flag, a
    carrier that moved by more than such a step, a finding of the kinematics); what a
    sampled-out state did not get is written in its fringe order's record, its
    smoothing record and its pair check's verdict, and one ``checks.sampled``
    finding names those states.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._progress import Finding, findings_of
from ..kinematics import (
    CoarseEstimate,
    Measurement,
    check_parted,
    check_parts,
    find_discontinuities,
    without_discontinuities,
)
from ..kinematics.tracking import SMALL_STEP, check_after_warp, state_runs
from ..uncertainty import (
    contrast_step_bound,
    contrast_step_findings,
    nearest_filled,
    nearest_index,
)
from ._passes import _WFT_COST, _pair_check
from ._sinks import empty_state_message

#: When a stage runs (see the module).
RULES = ("every", "full")

#: In a long record, the expensive checks run on every this-many-th state (and on
#: every state in doubt).
SAMPLE_EVERY = 10

# A record of more states than this, each a single frame, followed in series order,
# is long: below it every state gets every check (the cost of a short series is its
# frames' reading and transforms, not its checks).
_LONG_RECORD = 2 * SAMPLE_EVERY


@dataclass(frozen=True)
class Stage:
    """One stage of a state's measurement: ``run(run, state)`` when ``rule`` says
    so (:data:`RULES`), ``cost`` its weight in the progress (frames read)."""

    name: str
    cost: float
    rule: str
    run: Callable


class _State:
    """One state while it is measured: its series' maps and statistics (``c``), its
    measurement, fringe order, jumps, pair check, uncertainty and findings; each
    array dropped once its last stage has used it (the ``release`` and ``store``
    stages)."""

    def __init__(self, index: int, c, guess, *, carrier_doubt: bool = False):
        self.index, self.c, self.guess = index, c, guess
        self.carrier_doubt = carrier_doubt  # its carrier moved more than a small step
        self.prev = None  # the previous state's field, as the tracker kept it
        self.name = c.name
        self.est = None  # the image features' estimate of its displacement
        self.res = self.rec = None
        self.found: tuple = ()
        self.match: dict | None = None
        self.unc = self.floors = self.smooth = None
        self.contrast = None  # the contrast step's bound map, until the uncertainty's
        self.summary = None
        self.notes: list[Finding] = []
        self.full = True  # whether the expensive checks run on it
        self.doubt = False  # whether a stage found a reason to check it in full

    def say(self, texts, code: str) -> None:
        """Keep ``texts`` as findings of this state (``code`` for plain sentences)."""
        self.notes.extend(findings_of(texts, code, self.name))


class _Policy:
    """Which states get the ``"full"`` stages (see the module)."""

    def __init__(self, n_states: int, order: str, singles: bool):
        self.n = n_states
        self.sampling = order == "series" and singles and n_states > _LONG_RECORD
        self.doubt_before = False  # the previous state was in doubt
        self.sampled: list[tuple[int, str]] = []

    def full(self, st: _State) -> bool:
        i = st.index
        if not self.sampling or not isinstance(st.guess, str):
            return True
        return (i in (0, self.n - 1) or i % SAMPLE_EVERY == 0 or self.doubt_before
                or bool(st.c.warnings) or st.carrier_doubt)

    def after(self, st: _State) -> None:
        self.doubt_before = st.doubt or (st.rec is not None and not st.rec.confirmed)
        if not st.full:
            self.sampled.append((st.index, st.name))

    def finding(self) -> list[Finding]:
        if not self.sampled:
            return []
        return [Finding("checks.sampled",
                        f"{state_runs(self.sampled)}: followed from the state before, each by "
                        f"a step under {SMALL_STEP} period with nothing in doubt; their "
                        f"image features, pair check, contrast and smoothing bounds were sampled "
                        f"(every {SAMPLE_EVERY}th state, the first, the last and every "
                        "state in doubt got them): their records say so",
                        states=len(self.sampled), every=SAMPLE_EVERY)]


def _sampled_detail(what: str = "image features") -> str:
    """What a state sampled out did not get, for its records."""
    return f"{what} sampled every {SAMPLE_EVERY} states, not run on this one"


# --------------------------------------------------------------------------- the stages


def _noise(run, st: _State) -> None:
    st.c = run.noise.complete(st.c)


def _features(run, st: _State) -> None:
    st.est = run.tracker.features(st.c.maps, st.c.stats.mean, st.guess)


def _kinematics(run, st: _State) -> None:
    """The state's displacement and strain with the tracker's guess, its fringe order
    checked once its image is warped back. A state whose features were sampled out is
    measured again with them when its followed step is not small or its order not
    confirmed."""
    st.prev = run.tracker.prev  # a jump's parts are followed from it (_jumps)
    if not st.full:
        saved = run.tracker.snapshot()
        est = _no_features()
        res, rec, notes = run.tracker.measure(st.c.maps, est, st.guess, st.name)
        if rec.confirmed and rec.source == "previous state" and rec.step <= SMALL_STEP \
                and not notes:
            st.res = res
            st.rec = dataclasses.replace(rec, detail=f"{rec.detail}; {_sampled_detail()}")
            st.res = dataclasses.replace(res, fringe_order=st.rec)
            return
        run.tracker.restore(saved)  # in doubt: measured again with every check
        del res, rec, notes
        st.full, st.doubt = True, True
        _features(run, st)
    res, rec, notes = run.tracker.measure(st.c.maps, st.est, st.guess, st.name)
    st.est = None
    if isinstance(st.guess, str):
        res, checked, said = check_after_warp(res, rec, run.tracker.coarse, st.c.stats.mean,
                                              run.lattice, st.name)
        if checked is not rec:  # confirmed now: the doubt said before is void
            notes = [n for n in notes if n.code != "fringe_order.unconfirmed"]
        rec = checked
        notes = [*notes, *said]
    st.res, st.rec = res, rec
    st.doubt = st.doubt or bool(notes)
    st.say(notes, "other")


def _jumps(run, st: _State) -> None:
    prev, st.prev = st.prev, None
    follow = prev[0] if prev is not None and st.rec.source == "previous state" else None
    images = (run.tracker.mean_ref, st.c.stats.mean, run.tracker.mask) \
        if isinstance(st.guess, str) else None
    confirmed = st.rec.confirmed
    st.res, st.rec, st.found, said = _discontinuities(st.res, st.rec, st.name, images,
                                                      follow)
    if st.rec.confirmed and not confirmed:  # each part by its own features now
        st.notes = [n for n in st.notes if n.code != "fringe_order.unconfirmed"]
    st.doubt = st.doubt or bool(st.found)
    st.notes.extend(said)


def _pair(run, st: _State) -> None:
    st.match, told = _pair_check(st.res, run.tracker.mean_ref, run.tracker.mask,
                                 run.done[0], st.c, run.lattice, run.o.outliers)
    st.say(told, "pair.mismatch")


def _contrast(run, st: _State) -> None:
    """The per-pixel bound of the bias next to a change of the grid's contrast, made
    while the state's transforms are at hand; stated against the noise once the
    uncertainty maps are made. About one transform's time (1024 x 1024 px: 0.95-1.02 times
    a wft, 0.09-0.15 times the pair's measure), hence one of the sampled checks."""
    r = st.res
    if r.reference is None or r.deformed is None:
        return
    st.contrast = contrast_step_bound(r.reference.psi, r.deformed.psi, r.u, r.valid,
                                      sigma=r.sigma)


def _release(run, st: _State) -> None:
    """The images and phase derivatives dropped once their uses are over; the
    state's summary made."""
    if st.match is None:  # sampled out: recorded as such
        st.match = {"state": st.name, **_NOT_CHECKED}
    st.c = st.c.dropping("mean")  # the image features and the pair check were its uses
    run.pager.page_out()  # the uncertainty maps read back the moduli only
    if run.o.output is not None:
        # the file keeps no phase maps, and the state's derivatives serve its
        # kinematics only: freed before its uncertainty maps are made
        st.res = dataclasses.replace(st.res, reference=None, deformed=None)
        st.c = st.c.without_derivatives()
        if not st.res.valid.any():  # never a file
            raise ValueError(empty_state_message(st.name, run.o.margin, run.o.window.sigma,
                                                 st.rec.guess, st.rec.source))
    st.summary = st.c.summary()


def _uncertainty(run, st: _State) -> None:
    said = []
    st.unc, st.floors = run.floor.state(st.c, st.summary, st.res, run.alias, said)
    st.say(said, "aliasing.bound")
    bound, st.contrast = st.contrast, None
    if bound is not None:
        # the noise: the uncertainty maps, else the state's floors
        noise = st.unc if st.unc is not None else (st.floors["ux"], st.floors["uy"])
        st.notes.extend(contrast_step_findings(bound, st.res.valid, noise=noise,
                                               name=st.name))


def _smoothing(run, st: _State) -> None:
    st.smooth, said = run.floor.smoothing(st.name, st.res, st.floors)
    st.say(said, "smoothing.bias")


def _store(run, st: _State) -> None:
    if st.smooth is None:  # sampled out: recorded as such
        st.smooth = run.floor.smoothing_not_computed(_sampled_detail("smoothing bound"))
    st.c = None
    run.sink.add(st.index, st.res, st.rec, st.unc, st.floors, st.smooth)
    st.unc = None
    i, o = st.index, run.o
    if o.order == "series" and i + 1 < run.n_states:
        # a small field is kept as measured (the bits the file holds); a large one is
        # read back from the file when the next state needs it
        small = st.res.u.nbytes <= run.follow_in_memory
        run.tracker.follow(st.res, st.name, None if small else run.sink.reader(i))
    st.res = None


#: A state's measurement, stage by stage, once its series' pass has given its maps.
STAGES = (
    # every stage has a weight, however small, so that its time is reported by name
    # (a stage of none would have its time counted in the next one's)
    Stage("noise", 0.1 * _WFT_COST, "every", _noise),
    Stage("image features", _WFT_COST, "full", _features),
    Stage("kinematics", 3 * _WFT_COST, "every", _kinematics),
    Stage("jumps", 0.5 * _WFT_COST, "every", _jumps),
    Stage("pair check", 0.5 * _WFT_COST, "full", _pair),
    Stage("contrast", _WFT_COST, "full", _contrast),
    Stage("release", 0.1 * _WFT_COST, "every", _release),
    Stage("uncertainty", 0.5 * _WFT_COST, "every", _uncertainty),
    Stage("smoothing", _WFT_COST, "full", _smoothing),
    Stage("store", _WFT_COST, "every", _store),
)


def stages_cost() -> float:
    """The progress weight of one state's stages."""
    return sum(s.cost for s in STAGES)


def measure_state(run, st: _State) -> _State:
    """Run :data:`STAGES` on ``st``, each reported by name to the progress."""
    st.full = run.policy.full(st)
    for stage in STAGES:
        if stage.rule == "every" or st.full:
            stage.run(run, st)
        if stage.cost:
            run.steps.step(stage.cost, f"{st.name}: {stage.name}")
    run.policy.after(st)
    run.warnings.extend(st.notes)
    return st


def _no_features() -> CoarseEstimate:
    """The image features' estimate of a state they were not compared on."""
    nan = math.nan
    return CoarseEstimate((nan, nan), (nan, nan), nan, nan, nan, nan, False,
                          _sampled_detail())


# the pair check's record of a state it did not run on
_NOT_CHECKED = {"match": math.nan, "rho": math.nan, "rho_match": math.nan,
                "rho_sd": math.nan, "snr": [math.nan, math.nan], "conclusive": False,
                "verdict": "not checked", "warped": False}


__all__ = ["RULES", "SAMPLE_EVERY", "STAGES", "Stage", "measure_state", "stages_cost"]


def _discontinuities(res: Measurement, rec, name: str, images, follow) -> tuple:
    """``(res, rec, regions, warnings)``: ``res`` measured again without the pixels
    whose window straddles a jump of its displacement
    (:mod:`gridstrain.kinematics`), each part the jump cuts the field into
    followed from the previous state's field pixel by pixel when ``follow`` (a
    callable giving back its ``(u, valid)``) is given and checked on its own
    content when ``images`` (reference, deformed, mask) are, the fringe order's
    record, the jumps' regions, and the warnings naming them."""
    disc = find_discontinuities(res)
    if not disc:
        return _parted(res, rec, name, images)
    before = res.valid
    guess = None
    if follow is not None:
        u, valid = follow()
        nearest = nearest_index(valid)
        guess = np.stack([nearest_filled(np.asarray(c, dtype=np.float64), valid, nearest)
                          for c in u])
        del u, valid, nearest
    res = without_discontinuities(dataclasses.replace(res, fringe_order=rec), disc,
                                  guess=guess)
    del guess
    said = [Finding("jump.found",
                    f"{name}: the displacement jumps (a crack, an edge or a torn grid?) at "
                    f"{disc.describe()}: the {int(disc.band.sum())} pixels whose window "
                    "straddles it are left out", state=name,
                    pixels_left_out=int(disc.band.sum()))]
    if images is not None:
        res, parts = check_parts(res, before, images[0], images[1], mask=images[2])
        said.extend(_parts_notes(parts, name, res.lattice))
        return res, res.fringe_order, tuple(disc.regions), said
    after = ndimage.label(res.valid)[1]
    if after > ndimage.label(before)[1]:
        said.append(Finding(
            "jump.part", f"{name}: the jump cuts the field into {after} parts whose whole "
            "numbers of periods were fixed each on its own (closest to the guess): across "
            "an opening of more than half a pitch one of them may be whole periods off; "
            "pass a guess or an intermediate state", state=name, parts=after))
    return res, rec, tuple(disc.regions), said


def _parted(res: Measurement, rec, name: str, images) -> tuple:
    """``(res, rec, (), warnings)`` of a state with no jump: where invalid bands part
    its field (a gradient too steep for the window dims the grid along it) and its order
    is not confirmed, each part's whole periods from its own content, as across a crack
    (:func:`check_parts`), taken when one part is confirmed so."""
    if images is None:
        return res, rec, (), []
    checked, parts = check_parted(dataclasses.replace(res, fringe_order=rec), images[0],
                                  images[1], mask=images[2])
    if not parts:
        return res, rec, (), []
    said = [Finding("jump.part",
                    f"{name}: the part of the field at {p.describe()}, parted from the rest "
                    f"by invalid bands, {p.detail}" + (": left out" if p.left_out else ""),
                    state=name) for p in parts if p.left_out or any(p.shift_px)]
    return checked, checked.fringe_order, (), said


def _parts_notes(parts: tuple, name: str, lattice) -> list[Finding]:
    """The warnings that say how each part a crack cut off was fixed."""
    if not parts:
        return []
    out = []
    for p in parts:
        if p.left_out:
            out.append(Finding("jump.part",
                               f"{name}: the part of the field at {p.describe()}, cut off "
                               f"by the jump, has no image features of its own to fix its "
                               f"whole periods ({p.detail}): left out", state=name))
        elif p.confirmed and any(p.shift_px):
            out.append(Finding("jump.part",
                               f"{name}: the part of the field at {p.describe()}, cut off "
                               f"by the jump, was whole periods off: {p.detail}",
                               state=name))
    if not any(p.confirmed for p in parts):
        p1, p2 = lattice.pitches
        out.append(Finding(
            "fringe_order.unconfirmed",
            f"{name}: the jump cuts the field into {len(parts)} parts and none has image "
            "features of its own: their whole periods assume an opening below half a pitch "
            f"(periods {p1:.3g}/{p2:.3g} px) across it: fringe order not confirmed; pass "
            "--guess UX UY per part (guess= a field in Python), an intermediate state, or "
            "image a grid with printed features", state=name, parts=len(parts)))
    return out
