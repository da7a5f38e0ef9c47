"""Demonstrations recorded from the physics simulation itself.

The kinematic generator (:mod:`nonprehensile.demonstrations.synth`) moves the object by the
exact maneuver and the fingers with it, so its recordings agree with the model by
construction. Here the fingers *push a simulated object*: a mentor's planned hand motion (the
kinematic generator's fingertip paths, noise-free) drives compliant fingertips in MuJoCo, and
everything else is read from physics:

* the object's pose at every frame (written as markers fixed on the object, the dataset's
  ``object_markers``, so any reader can fit the rigid body's pose; in Motive CSV also as a
  rigid body);
* the contact events and their times (the debounced contacts, matched in order to the skill's
  events);
* whether the demonstration worked: only takes in which the object ends in the skill's final
  state, the skill's events all occur in order, and the object ends within ``max_slip`` of
  where the exact maneuver puts it (no sliding off the pivot) are kept; a mentor whose take
  fails tries again with another draw, as a person would.

The tip markers are the fingertips' centres as the hand drives them: the pad (a sphere of
``SimParams.finger_radius``) is compliant, and presses into the object by up to
``press_mm`` while in contact, like a fingertip pad. Knuckle markers, measurement noise and
dropouts follow the kinematic generator's mentor styles.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from nonprehensile.demonstrations.dataset import (
    DEFAULT_FINGERS,
    DEFAULT_GAP_LIMIT,
    DEFAULT_MARKERS,
    Dataset,
    Demonstration,
    EventTime,
    save_dataset,
)
from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory
from nonprehensile.demonstrations.synth import (
    DEFAULT_MENTORS,
    MentorStyle,
    event_progress,
    synthesize_demonstration,
)
from nonprehensile.errors import InputError, NonprehensileError, RecordError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.geometry.units import in_metres
from nonprehensile.io import read_skills
from nonprehensile.maneuvers import classify, move_pose
from nonprehensile.sim.compare import DEFAULT_ANGLE_TOL_DEG, Comparison, compare, events_text
from nonprehensile.sim.distribution import PhysicsDistribution
from nonprehensile.sim.execute import fingers_of, smooth_markers
from nonprehensile.sim.run import SimResult, Simulator, default_scale, pose_of_state
from nonprehensile.sim.scene import DEFAULT_PARAMS, RETUNABLE, SceneTuner, SimParams
from nonprehensile.skills.contacts import Edge, Face, Finger, Ground, Vertex
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State

__all__ = [
    "OBJECT_BODY",
    "TakeFailed",
    "TakeReason",
    "object_markers_of",
    "record_dataset",
    "record_demonstration",
    "what_to_change",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int], None]

#: Name of the object's rigid body in the recordings.
OBJECT_BODY = "object"


@dataclasses.dataclass(frozen=True)
class TakeReason:
    """Why one take failed, as physics showed it.

    Attributes
    ----------
    kind : str
        ``"stayed"`` (the object never left its initial face), ``"pushed"`` (it slid on it
        without tipping), ``"untouched"`` (no finger ever touched it), ``"turned"`` (it
        ended on the right face at another angle), ``"elsewhere"`` (on another face),
        ``"no-rest"`` (not at rest on a face), ``"events"`` (it moved as the skill says but
        some event never happened in order), ``"slid"`` (off its pivot), ``"fragile"`` (it
        worked, but not with another draw of tracker noise) or ``"unfit"`` (the synthetic
        mentor cannot make the skill's motion).
    key : str
        What takes failing alike share (counted together).
    text : str
        This take's detail, e.g. ``"ended in a:359.3"``.
    """

    kind: str
    key: str
    text: str
    events: tuple[str, ...] = ()


class TakeFailed(NonprehensileError):
    """A take in which the simulated object did not do what the skill says (``fragile``: it
    did, but not again with another draw of tracker noise); ``reason`` says what physics did.
    """

    def __init__(self, message: str, fragile: bool = False,
                 reason: TakeReason | None = None) -> None:
        super().__init__(message)
        self.fragile = fragile
        self.reason = reason or TakeReason("fragile" if fragile else "unfit", message, message)


def _reason(skill: Skill, cmp: Comparison, res: SimResult, slip: float,
            max_slip: float, moved: float) -> TakeReason:
    """What a failed attempt did, named so that attempts failing alike share a key
    (``moved``: how far the centre of mass went on the table, metres)."""
    got = res.final_state
    if not cmp.success:
        if got is None:
            return TakeReason("no-rest", "did not come to rest on a face",
                              "did not come to rest on a face")
        text = f"ended in {got}"
        if got.face == skill.initial.face and skill.maneuver != "rotating":
            if moved > max_slip:
                return TakeReason("pushed", f"slid on face {got.face} without tipping",
                                  f"{text}, {1000 * moved:.0f} mm away")
            first = next((e.id for e in skill.events
                          if any(isinstance(q.x, Finger) for q in e.pairs)), None)
            if first is not None and first in cmp.missing:
                return TakeReason("untouched", f"never left face {got.face}, never touched",
                                  f"{text}; event {first!r} never happened")
            return TakeReason("stayed", f"never left its initial face {got.face}", text)
        if got.face == skill.final.face:
            return TakeReason("turned", f"ended on face {got.face} at another angle",
                              f"{text} (skill: {skill.final})")
        return TakeReason("elsewhere", f"ended on face {got.face}", text)
    if not cmp.chain_ok:
        key = f"events {list(cmp.missing)} missing"
        chain = events_text(res.events)
        seen = chain if len(chain) <= 160 else chain[:157] + "..."
        return TakeReason("events", key, f"{key}; physics: {seen}", tuple(cmp.missing))
    return TakeReason("slid", "slid off its pivot",
                      f"slid {1000 * slip:.1f} mm (at most {1000 * max_slip:g} mm allowed)")


def what_to_change(skill: Skill, reason: TakeReason) -> str:
    """Advice for the commonest way a skill's takes fail (one sentence)."""
    see = f"`nonprehensile maneuvers MODEL --from {skill.initial}`"
    if reason.kind == "pushed" and skill.maneuver == "tumbling":
        return ("the pinch carried the object along the table instead of tipping it over its "
                "pivot vertex: pinch above the centre of mass so that it hangs from the "
                "pinch, or more table friction (--friction) keeps the vertex in place")
    if reason.kind == "pushed":
        return ("the push slid the object along the table instead of tipping it over its "
                "pivot: a push this low on a flat object slides it; push higher on the face "
                "(a hook on the far face, as roll-arc does), or more table friction "
                "(--friction) or less finger friction (--finger-friction) tips it")
    if reason.kind == "stayed":
        return ("the fingers touched the object but did not tip it (it barely moved): it is "
                "too heavy for the push (--mass, --stiffness, --force-limit), or the finger "
                "pushes too close to the pivot's height to turn it")
    if reason.kind == "untouched":
        return ("the fingertips never touched the object where the skill says: the face is "
                "too small or too far for a pad of --finger-radius, or the path misses it")
    if reason.kind == "turned":
        return (f"it reached face {skill.final.face} but turned on the way: more table "
                f"friction (--friction) holds it; if every take ends at the same angle, the "
                f"skill's final theta may be wrong ({see} lists the final states)")
    if reason.kind == "elsewhere" and skill.maneuver == "rotating":
        return ("the turn tipped the object over instead of turning it on its face: grip it "
                "lower on its sides (nearer the table), or on faces that hold it upright")
    if reason.kind == "elsewhere":
        return (f"it went on past {skill.final} (or fell another way): the push carries it "
                f"too far, or {skill.final.face} is not a stable face; {see} lists where each "
                "maneuver ends and whether it is stable")
    if reason.kind == "no-rest":
        return "the object was still moving or balanced on an edge when the take ended"
    if reason.kind == "events":
        named = [e for e in skill.events if e.id in reason.events]
        contacts = "; ".join(f"{e.id!r}: {e}" for e in named)
        final = skill.final.face
        landing = [e for e in named if any(isinstance(p.y, Face) and p.y.id == final
                                           for p in e.pairs if isinstance(p.x, Ground))
                   and any(isinstance(p.x, Finger) for p in e.pairs)]
        pivot = [e for e in named if any(isinstance(p.y, (Edge, Vertex)) for p in e.pairs
                                         if isinstance(p.x, Ground))]
        head = ("physics made the maneuver but not these events in order (" + contacts
                + "; what it made is in the reason): ")
        if landing:
            return head + ("the object falls ahead of the finger and lands without it: end "
                           "the moving arc on the landing with the ground alone (pivot, then "
                           f"(G,{final}): a topple)")
        if pivot:
            return head + ("the object never rested on that edge or vertex alone long enough "
                           "to be seen (it turned over another element, or passed it in a "
                           "few ms): name what physics shows, or leave the pivot event out")
        return head + "write them as physics makes them, or leave them out"

    if reason.kind == "slid":
        return ("the pivot slid along the table: more table friction (--friction), or a "
                "second finger holding the object down on its pivot")
    if reason.kind == "fragile":
        return ("takes work only for some draws of tracker noise: the skill is marginal in "
                "physics; a firmer grip or more friction makes it reliable")
    return "the synthetic mentor cannot make this skill's motion; see the reason"


def _summary(reasons: Counter[TakeReason], top: int = 3) -> str:
    """The commonest failure keys with counts, e.g. ``41 x events ['landed'] missing``."""
    by_key: Counter[str] = Counter()
    example: dict[str, str] = {}
    for r, n in reasons.items():
        by_key[r.key] += n
        example.setdefault(r.key, r.text)
    parts = []
    for key, n in by_key.most_common(top):
        detail = example[key]
        parts.append(f"{n} x {key}" + (f" (e.g. {detail})" if detail != key else ""))
    rest = sum(by_key.values()) - sum(n for _, n in by_key.most_common(top))
    return ", ".join(parts) + (f", {rest} other" if rest else "")


def object_markers_of(poly: Polyhedron) -> dict[str, tuple[float, float, float]]:
    """Three markers fixed on the object (model frame): at three vertices of its largest face
    that is not a bottom face in the usual states, pulled 10 % toward the face's centre."""
    # areas compared to 9 digits: equal faces stay equal whatever the units (a tie broken
    # by rounding noise would put the markers elsewhere in millimetres than in metres)
    big = max(poly.face_areas.values())
    top = max(poly.faces, key=lambda f: (round(poly.face_areas[f] / big, 9), f))
    loop = poly.faces[top]
    c = poly.face_centroids[top]
    picks = [loop[0], loop[len(loop) // 3], loop[(2 * len(loop)) // 3]]
    out: dict[str, tuple[float, float, float]] = {}
    for i, j in enumerate(picks):
        x, y, z = (float(v) for v in 0.9 * poly.vertices[j] + 0.1 * c)
        out[f"obj_{i + 1}"] = (x, y, z)
    return out


#: How a hand tumbles an object in a pinch (found in physics, docs/physics.md): it presses the
#: object down onto its pivot vertex (mm of the fingertips' targets below the plan, so the
#: vertex stays loaded and does not slide), and over the last share of the tumble it eases
#: the squeeze to a light touch (mm of press left) so that the object settles flat on its
#: new bottom face between the pads instead of being held on an edge.
PIVOT_PRESS_MM = 2.0
SET_DOWN_PRESS_MM = 0.5
SET_DOWN_SHARE = 0.3
#: A mentor whose take ends more than this many degrees off the skill's final theta corrects
#: the aim and does it again (at most ``corrections`` times; the take is kept if it ends
#: within the 5 degrees a replay is judged by): a careful demonstration leaves a margin for
#: the tracker noise a replay carries.
AIM_TOL_DEG = 2.5


def _ramp(times: FloatArray, start: float, end: float, width: float = 0.1) -> FloatArray:
    """0 -> 1 over ``width`` s from ``start``, back to 0 over ``width`` s before ``end``."""
    return np.asarray(np.minimum(np.clip((times - start) / width, 0.0, 1.0),
                                 np.clip((end - times) / width, 0.0, 1.0)))


def tumbling_hand(
    skill: Skill, targets: dict[int, FloatArray], event_times: Sequence[float], rate: float,
    press_mm: float,
) -> dict[int, FloatArray]:
    """A tumbling pinch's fingertip targets, with the pivot press and the setting down.

    Other skills' targets (and a tumble held by one finger) are returned unchanged.
    """
    if skill.maneuver != "tumbling" or len(targets) != 2:
        return targets
    lam = event_progress(skill)
    mv = next(i for i in range(len(lam) - 1) if lam[i] != lam[i + 1])
    first = min(i for i, e in enumerate(skill.events)
                if any(isinstance(p.x, Finger) for p in e.pairs))
    n = len(next(iter(targets.values())))
    times = np.arange(n) / rate
    t_move, t_land = event_times[mv], event_times[mv + 1]
    down = PIVOT_PRESS_MM / 1000.0 * _ramp(times, event_times[first], t_land)
    span = SET_DOWN_SHARE * (t_land - t_move)
    ease = np.clip((times - (t_land - span)) / max(span, 1e-9), 0.0, 1.0)
    ease *= max(0.0, press_mm - SET_DOWN_PRESS_MM) / 1000.0
    k1, k2 = sorted(targets)
    a, b = targets[k1].copy(), targets[k2].copy()
    apart = (a - b) / np.maximum(np.linalg.norm(a - b, axis=1, keepdims=True), 1e-9)
    out = {k1: a + ease[:, None] * apart, k2: b - ease[:, None] * apart}
    for k in out:
        out[k][:, 2] -= down
    return out


def _frames_at(trace: FloatArray, times: FloatArray) -> FloatArray:
    """Rows of the trace nearest the frame times (the trace is every physics step)."""
    idx = np.clip(np.searchsorted(trace[:, 0], times), 0, len(trace) - 1)
    return trace[idx]


def record_demonstration(
    sim: Simulator,
    skill: Skill,
    mentor: MentorStyle,
    rng: np.random.Generator,
    *,
    rate: float = 120.0,
    noise_mm: float = 0.5,
    dropouts: float = 0.5,
    gap_limit: int = DEFAULT_GAP_LIMIT,
    press_mm: float = 3.5,
    max_slip: float = 0.006,
    markers: dict[str, tuple[float, float, float]] | None = None,
    corrections: int = 3,
    aim_tol_deg: float = AIM_TOL_DEG,
    robust: bool = True,
    angle_tol: float = DEFAULT_ANGLE_TOL_DEG,
) -> tuple[MarkerTrajectory, tuple[EventTime, ...]]:
    """One take of ``skill`` by ``mentor`` pushed through physics.

    Returns
    -------
    trajectory : MarkerTrajectory
        Markers :data:`DEFAULT_MARKERS` then the object markers, mm, with the object's rigid
        body.
    events : tuple of EventTime
        The skill's events at the times physics made them.

    Raises
    ------
    TakeFailed
        If the object did not end as the skill says, an event is missing, or it slid; or
        (``robust``) the same hand motion with another draw of tracker noise, filtered as a
        replay filters it, ends elsewhere (``TakeFailed.fragile``).
    """
    poly, scale = sim.poly, sim.scale
    tip_mm = max(0.0, 1000.0 * sim.params.finger_radius - press_mm)
    plan_style = dataclasses.replace(mentor, tip_offset_mm=tip_mm)
    draw = int(rng.integers(2**32))
    start = pose_of_state(poly, skill.initial, (0.0, 0.0), scale)
    fingers = fingers_of(skill)
    aim = skill.final
    m = classify(poly, skill.initial, skill.final)
    r_end, t_end = move_pose(poly, m, start.rotation, start.translation, scale)
    exact = scale * (r_end @ poly.com) + t_end
    best: tuple[float, FloatArray, SimResult, Comparison] | None = None
    why: TakeReason | None = None
    for _ in range(corrections + 1):
        # the mentor aims the hand at ``aim`` and, seeing where the object ends, corrects the
        # aim by the error (the same take otherwise: same draw of the mentor's variations);
        # the best attempt that did what the skill says is kept
        intended = skill if aim == skill.final else dataclasses.replace(skill, final=aim)
        try:
            traj, planned = synthesize_demonstration(
                poly, intended, plan_style, np.random.default_rng(draw), rate=rate,
                scale=scale, noise_mm=0.0, dropouts=0.0, gap_limit=gap_limit)
        except InputError as exc:
            raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: {exc}",
                             reason=TakeReason("unfit", str(exc), str(exc))) from None
        pos = traj.positions / 1000.0  # metres
        names = list(traj.marker_names)
        targets = tumbling_hand(
            skill, {k: pos[:, names.index(DEFAULT_FINGERS[f"R{k}"])] for k in fingers},
            [e.time for e in planned], rate, press_mm)
        for k, tr in targets.items():  # the markers move with the hand that drives the tips
            j = names.index(DEFAULT_FINGERS[f"R{k}"])
            pos[:, j:j + 2] += (tr - pos[:, j])[:, None]  # the tip and its knuckle
        res = sim.run(start, targets, rate, keep_trace=1)
        cmp = compare(poly, skill, res, angle_tol=angle_tol)
        slip = float(np.hypot(*(np.asarray(res.final_pose.com[:2]) - exact[:2])))
        if cmp.success and cmp.chain_ok and slip <= max_slip:
            err = abs(cmp.theta_error or 0.0)
            if best is None or err < best[0]:
                best = (err, pos, res, cmp)
        elif why is None:
            moved = float(np.hypot(*(np.asarray(res.final_pose.com[:2])
                                     - np.asarray(start.com[:2]))))
            why = _reason(skill, cmp, res, slip, max_slip, moved)
        if cmp.theta_error is None or abs(cmp.theta_error) > 30.0 or (
                best is not None and best[0] <= aim_tol_deg):
            break
        aim = State(aim.face, aim.theta - cmp.theta_error)
    if best is None:
        assert why is not None
        raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: {why.text}", reason=why)
    _, pos, res, cmp = best
    if robust:
        # a take that works only by chance is not kept: the same hand motion, measured with
        # another draw of tracker noise and filtered as a replay filters it, must work too
        tips = {k: pos[:, names.index(DEFAULT_FINGERS[f"R{k}"])] for k in fingers}
        shaken = {k: smooth_markers(p + rng.normal(0.0, noise_mm / 1000.0, p.shape), 9)
                  for k, p in tips.items()}
        again = compare(poly, skill, sim.run(start, shaken, rate), angle_tol=angle_tol)
        if not again.success:
            text = f"with other tracker noise it ends in {again.simulated}"
            raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: not robust ({text})",
                             fragile=True,
                             reason=TakeReason("fragile", "fragile (not robust to tracker "
                                               "noise)", text))
    assert res.trace is not None
    # the recording lasts until the object is at rest, the fingers holding their last place
    n = max(len(pos), int(np.ceil(res.sim_time * rate)) + 1)
    times = np.arange(n) / rate
    rows = _frames_at(res.trace, times)
    if n > len(pos):
        pos = np.concatenate([pos, np.repeat(pos[-1:], n - len(pos), axis=0)])
    quat_wxyz = rows[:, 4:8]
    rot = Rotation.from_quat(np.column_stack([quat_wxyz[:, 1:], quat_wxyz[:, :1]]))
    body_pos = rows[:, 1:4]
    markers = markers if markers is not None else object_markers_of(poly)
    obj = [rot.apply(scale * np.asarray(x)) + body_pos for x in markers.values()]
    allpos = np.concatenate([pos, *(o[:, None] for o in obj)], axis=1) * 1000.0  # mm
    allpos += rng.normal(0.0, noise_mm, allpos.shape)
    longest = max(2, gap_limit // 2)
    for j in range(allpos.shape[1]):
        for _ in range(rng.poisson(dropouts)):
            length = int(rng.integers(2, longest + 1))
            s = int(rng.integers(0, max(1, n - length)))
            allpos[s:s + length, j] = np.nan
    body = PoseTrajectory(OBJECT_BODY, body_pos * 1000.0,
                          np.column_stack([quat_wxyz[:, 1:], quat_wxyz[:, :1]]), rate, "mm")
    out = MarkerTrajectory(allpos, (*names, *markers), rate, "mm", (body,))
    # annotated on frames, as an annotator marks them on the recording
    ev = []
    last = -1.0
    for eid, t, _ in cmp.matched:
        assert t is not None
        tf = max(round(t * rate) / rate, last + 1.0 / rate)
        ev.append(EventTime(eid, tf))
        last = tf
    return out, tuple(ev)


def record_dataset(
    skills_file: str | Path,
    *,
    seed: int = 20190520,
    n_per_skill: int = 30,
    mentors: Sequence[MentorStyle] = DEFAULT_MENTORS,
    scale: float | None = None,
    params: SimParams = DEFAULT_PARAMS,
    rate: float = 120.0,
    noise_mm: float = 0.5,
    dropouts: float = 0.5,
    gap_limit: int = DEFAULT_GAP_LIMIT,
    press_mm: float = 3.5,
    max_slip: float = 0.006,
    max_attempts: int = 60,
    only: Sequence[str] | None = None,
    keep_going: bool = False,
    angle_tol: float = DEFAULT_ANGLE_TOL_DEG,
    with_object_markers: bool = True,
    progress: Progress | None = None,
    distribution: PhysicsDistribution | None = None,
) -> tuple[Dataset, dict[str, dict[str, Any]]]:
    """Record ``n_per_skill`` physics takes of every skill of a skills file.

    The simulation runs in SI: the model is converted to metres once
    (:func:`~nonprehensile.geometry.units.in_metres`, from its ``units`` unless ``scale``
    overrides), and the mentors' paths scale with the object's size, so that the same object
    written in metres and in millimetres records the same takes.

    Parameters
    ----------
    scale : float, optional
        Metres per model unit; default from the model's ``units``.
    only : sequence of str, optional
        Record these skills only (the dataset keeps every skill); an unknown name is an
        error naming the skills.
    angle_tol : float
        A take ends in the skill's final state when its theta is within this many degrees.
    keep_going : bool
        When a skill cannot be recorded, go on with the others and return what succeeded
        (``stats[name]["failed"]`` says why) instead of raising.
    with_object_markers : bool
        ``False`` leaves the object markers out (smaller files).
    distribution : PhysicsDistribution, optional
        Record under it: every take (every attempt) runs in its own sample of the scene's
        parameters (friction, mass scaled to the object, fingertip, stiffness, force limit,
        contact softness), sample ``a`` of stream ``k`` of ``seed`` for the ``a``-th attempt
        at skill ``k``, instead of the one scene of ``params``. The mentor's hand and the
        tracker are the mentor's own: the distribution's start error and noise do not apply.
        ``stats[name]["physics"]`` lists each kept take's varied values.

    Returns
    -------
    dataset : Dataset
        In the model's own units, with ``scale`` metres per unit.
    stats : dict
        Per recorded skill: takes kept, takes tried (how hard the skill is in physics), takes
        that worked once but not again with other tracker noise (``fragile``, not kept),
        ``reasons`` (why takes failed: ``{reason: count}``, commonest first) and, for a skill
        that could not be recorded, ``failed`` (one line: the commonest reasons with counts
        and what to change).

    Raises
    ------
    RecordError
        A skill for which no take succeeds in ``max_attempts`` tries (unless ``keep_going``);
        its message gives, per such skill, the commonest reasons and what to change.
    """
    if isinstance(n_per_skill, bool) or not isinstance(n_per_skill, int) or n_per_skill < 1:
        raise InputError(f"n_per_skill must be a whole number >= 1, got {n_per_skill!r}")
    rng = np.random.default_rng(seed)
    poly, skills = read_skills(skills_file)
    names = [s.name for s in skills]
    unknown = [n for n in (only or ()) if n not in names]
    if unknown:
        raise InputError(f"{skills_file}: no skill named {unknown}; its skills are {names}")
    if scale is None:
        scale = default_scale(poly)
    si = in_metres(poly, scale)
    n_f = max(max(fingers_of(s), default=1) for s in skills)
    sim = Simulator(si, scale=1.0, n_fingers=max(n_f, 1), params=params)
    tuner = None
    if distribution is not None:
        distribution = distribution.for_object(si, 1.0)
        tuner = SceneTuner(sim.model, sim.data, sim.params)
    markers = object_markers_of(poly) if with_object_markers else {}
    markers_si = object_markers_of(si) if with_object_markers else {}
    demos: list[Demonstration] = []
    stats: dict[str, dict[str, Any]] = {}
    failures: dict[str, str] = {}
    chosen = [s for s in skills if only is None or s.name in only]
    total = n_per_skill * len(chosen)
    for k_skill, skill in enumerate(chosen):
        tried = fragile = kept = 0
        reasons: Counter[TakeReason] = Counter()
        physics: list[dict[str, float]] = []
        for j in range(n_per_skill):
            mentor = mentors[j % len(mentors)]
            for _ in range(max_attempts):
                tried += 1
                if tuner is not None and distribution is not None:
                    sample = distribution.sample(seed, index=tried - 1, stream=k_skill)
                    tuner.tune(sample.params)
                    sim.params = sim.judge.params = sample.params
                try:
                    traj, events = record_demonstration(
                        sim, skill, mentor, rng, rate=rate, noise_mm=noise_mm,
                        dropouts=dropouts, gap_limit=gap_limit, press_mm=press_mm,
                        max_slip=max_slip, markers=markers_si, angle_tol=angle_tol)
                    break
                except TakeFailed as exc:
                    fragile += exc.fragile
                    reasons[exc.reason] += 1
                    continue
            else:
                commonest = max(reasons, key=lambda r: (
                    sum(n for q, n in reasons.items() if q.key == r.key), reasons[r]))
                failures[skill.name] = (
                    f"{skill.name}: no take by {mentor.name} succeeded in {max_attempts} tries "
                    f"({_summary(reasons)}); what to change: "
                    f"{what_to_change(skill, commonest)}")
                break
            if tuner is not None:
                physics.append({k: round(v, 6) for k, v in sample.values().items()
                                if k in RETUNABLE})
            name = f"{skill.name}_{mentor.name}_{j // len(mentors):02d}.c3d"
            demos.append(Demonstration(name, skill, mentor.name, skill.initial, skill.final,
                                       events, traj))
            kept += 1
            if progress is not None:
                progress(len(demos), total)
        by_key: Counter[str] = Counter()
        for r, n in reasons.items():
            by_key[r.key] += n
        stats[skill.name] = {"kept": kept, "tried": tried, "fragile": fragile,
                             "reasons": dict(by_key.most_common())}
        if tuner is not None:
            stats[skill.name]["physics"] = physics
        if skill.name in failures:
            stats[skill.name]["failed"] = failures[skill.name]
            if not keep_going:
                raise RecordError(failures[skill.name], dict(failures))
    ds = Dataset(poly, tuple(skills), tuple(demos), float(scale), gap_limit,
                 dict(DEFAULT_FINGERS), None, markers)
    return ds, stats


def write_recorded(ds: Dataset, out_dir: str | Path, trajectory_format: str = "c3d") -> Path:
    """Write a recorded dataset folder (the annotations name the object markers)."""
    return save_dataset(ds, out_dir, trajectory_format=trajectory_format,
                        markers=DEFAULT_MARKERS)
