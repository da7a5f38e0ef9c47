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
from collections.abc import Callable, Sequence
from pathlib import Path

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
from nonprehensile.errors import InputError, NonprehensileError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.io import read_skills
from nonprehensile.maneuvers import classify, move_pose
from nonprehensile.sim.compare import Comparison, compare
from nonprehensile.sim.execute import fingers_of, smooth_markers
from nonprehensile.sim.run import SimResult, Simulator, pose_of_state
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams
from nonprehensile.skills.contacts import Finger
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State

__all__ = ["OBJECT_BODY", "object_markers_of", "record_dataset", "record_demonstration"]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int], None]

#: Name of the object's rigid body in the recordings.
OBJECT_BODY = "object"


class TakeFailed(NonprehensileError):
    """A take in which the simulated object did not do what the skill says (``fragile``: it
    did, but not again with another draw of tracker noise)."""

    def __init__(self, message: str, fragile: bool = False) -> None:
        super().__init__(message)
        self.fragile = fragile


def object_markers_of(poly: Polyhedron) -> dict[str, tuple[float, float, float]]:
    """Three markers fixed on the object (model frame): at three vertices of its largest face
    that is not a bottom face in the usual states, pulled 10 % toward the face's centre."""
    top = max(poly.faces, key=lambda f: (poly.face_areas[f], f))
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
    why = ""
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
            raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: {exc}") from None
        pos = traj.positions / 1000.0  # metres
        names = list(traj.marker_names)
        targets = tumbling_hand(
            skill, {k: pos[:, names.index(DEFAULT_FINGERS[f"R{k}"])] for k in fingers},
            [e.time for e in planned], rate, press_mm)
        for k, tr in targets.items():  # the markers move with the hand that drives the tips
            j = names.index(DEFAULT_FINGERS[f"R{k}"])
            pos[:, j:j + 2] += (tr - pos[:, j])[:, None]  # the tip and its knuckle
        res = sim.run(start, targets, rate, keep_trace=1)
        cmp = compare(poly, skill, res)
        slip = float(np.hypot(*(np.asarray(res.final_pose.com[:2]) - exact[:2])))
        if cmp.success and cmp.chain_ok and slip <= max_slip:
            err = abs(cmp.theta_error or 0.0)
            if best is None or err < best[0]:
                best = (err, pos, res, cmp)
        elif not why:
            why = ("ended in " + str(res.final_state) if not cmp.success else
                   f"events {list(cmp.missing)} missing" if not cmp.chain_ok else
                   f"slid {1000 * slip:.1f} mm")
        if cmp.theta_error is None or abs(cmp.theta_error) > 30.0 or (
                best is not None and best[0] <= aim_tol_deg):
            break
        aim = State(aim.face, aim.theta - cmp.theta_error)
    if best is None:
        raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: {why}")
    _, pos, res, cmp = best
    if robust:
        # a take that works only by chance is not kept: the same hand motion, measured with
        # another draw of tracker noise and filtered as a replay filters it, must work too
        tips = {k: pos[:, names.index(DEFAULT_FINGERS[f"R{k}"])] for k in fingers}
        shaken = {k: smooth_markers(p + rng.normal(0.0, noise_mm / 1000.0, p.shape), 9)
                  for k, p in tips.items()}
        again = compare(poly, skill, sim.run(start, shaken, rate))
        if not again.success:
            raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: not robust (with "
                             f"other tracker noise it ends in {again.simulated})", fragile=True)
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
    scale: float = 0.05,
    params: SimParams = DEFAULT_PARAMS,
    rate: float = 120.0,
    noise_mm: float = 0.5,
    dropouts: float = 0.5,
    gap_limit: int = DEFAULT_GAP_LIMIT,
    press_mm: float = 3.5,
    max_slip: float = 0.006,
    max_attempts: int = 60,
    only: Sequence[str] | None = None,
    with_object_markers: bool = True,
    progress: Progress | None = None,
) -> tuple[Dataset, dict[str, dict[str, int]]]:
    """Record ``n_per_skill`` physics takes of every skill of a skills file.

    ``only`` restricts the takes to those skills (the dataset keeps every skill);
    ``with_object_markers=False`` leaves the object markers out (smaller files).

    Returns
    -------
    dataset : Dataset
    attempts : dict
        Per skill: takes kept, takes tried (how hard the skill is in physics) and takes that
        worked once but not again with other tracker noise (``fragile``, not kept).

    Raises
    ------
    InputError
        A skill for which no take succeeds in ``max_attempts`` tries.
    """
    if isinstance(n_per_skill, bool) or not isinstance(n_per_skill, int) or n_per_skill < 1:
        raise InputError(f"n_per_skill must be a whole number >= 1, got {n_per_skill!r}")
    rng = np.random.default_rng(seed)
    poly, skills = read_skills(skills_file)
    n_f = max(max(fingers_of(s), default=1) for s in skills)
    sim = Simulator(poly, scale=scale, n_fingers=max(n_f, 1), params=params)
    markers = object_markers_of(poly) if with_object_markers else {}
    demos: list[Demonstration] = []
    stats: dict[str, dict[str, int]] = {}
    chosen = [s for s in skills if only is None or s.name in only]
    total = n_per_skill * len(chosen)
    for skill in chosen:
        tried = fragile = 0
        for j in range(n_per_skill):
            mentor = mentors[j % len(mentors)]
            for _ in range(max_attempts):
                tried += 1
                try:
                    traj, events = record_demonstration(
                        sim, skill, mentor, rng, rate=rate, noise_mm=noise_mm,
                        dropouts=dropouts, gap_limit=gap_limit, press_mm=press_mm,
                        max_slip=max_slip, markers=markers)
                    break
                except TakeFailed as exc:
                    fragile += exc.fragile
                    continue
            else:
                raise InputError(f"no physics take of skill {skill.name!r} by {mentor.name} "
                                 f"succeeded in {max_attempts} tries; the skill may be "
                                 "impossible as written (check which faces the fingers touch)")
            name = f"{skill.name}_{mentor.name}_{j // len(mentors):02d}.c3d"
            demos.append(Demonstration(name, skill, mentor.name, skill.initial, skill.final,
                                       events, traj))
            if progress is not None:
                progress(len(demos), total)
        stats[skill.name] = {"kept": n_per_skill, "tried": tried, "fragile": fragile}
    ds = Dataset(poly, tuple(skills), tuple(demos), float(scale), gap_limit,
                 dict(DEFAULT_FINGERS), None, markers)
    return ds, stats


def write_recorded(ds: Dataset, out_dir: str | Path, trajectory_format: str = "c3d") -> Path:
    """Write a recorded dataset folder (the annotations name the object markers)."""
    return save_dataset(ds, out_dir, trajectory_format=trajectory_format,
                        markers=DEFAULT_MARKERS)
