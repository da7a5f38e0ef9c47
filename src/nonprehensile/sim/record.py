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
    synthesize_demonstration,
)
from nonprehensile.errors import InputError, NonprehensileError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.io import read_skills
from nonprehensile.maneuvers import classify, move_pose
from nonprehensile.sim.compare import compare
from nonprehensile.sim.execute import fingers_of
from nonprehensile.sim.run import Simulator, pose_of_state
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State

__all__ = ["OBJECT_BODY", "object_markers_of", "record_dataset", "record_demonstration"]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int], None]

#: Name of the object's rigid body in the recordings.
OBJECT_BODY = "object"


class TakeFailed(NonprehensileError):
    """A take in which the simulated object did not do what the skill says."""


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
        If the object did not end as the skill says, an event is missing, or it slid.
    """
    poly, scale = sim.poly, sim.scale
    tip_mm = max(0.0, 1000.0 * sim.params.finger_radius - press_mm)
    plan_style = dataclasses.replace(mentor, tip_offset_mm=tip_mm)
    draw = int(rng.integers(2**32))
    start = pose_of_state(poly, skill.initial, (0.0, 0.0), scale)
    fingers = fingers_of(skill)
    aim = skill.final
    for _ in range(corrections + 1):
        # the mentor aims the hand at ``aim`` and, seeing where the object ends, corrects the
        # aim by the error (the same take otherwise: same draw of the mentor's variations)
        intended = skill if aim == skill.final else dataclasses.replace(skill, final=aim)
        try:
            traj, _ = synthesize_demonstration(
                poly, intended, plan_style, np.random.default_rng(draw), rate=rate,
                scale=scale, noise_mm=0.0, dropouts=0.0, gap_limit=gap_limit)
        except InputError as exc:
            raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: {exc}") from None
        pos = traj.positions / 1000.0  # metres
        names = list(traj.marker_names)
        targets = {k: pos[:, names.index(DEFAULT_FINGERS[f"R{k}"])] for k in fingers}
        res = sim.run(start, targets, rate, keep_trace=1)
        cmp = compare(poly, skill, res)
        if cmp.success or cmp.theta_error is None or abs(cmp.theta_error) > 30.0:
            break
        aim = State(aim.face, aim.theta - cmp.theta_error)
    m = classify(poly, skill.initial, skill.final)
    r_end, t_end = move_pose(poly, m, start.rotation, start.translation, scale)
    exact = scale * (r_end @ poly.com) + t_end
    slip = float(np.hypot(*(np.asarray(res.final_pose.com[:2]) - exact[:2])))
    if not cmp.success or not cmp.chain_ok or slip > max_slip:
        why = ("ended in " + str(res.final_state) if not cmp.success else
               f"events {list(cmp.missing)} missing" if not cmp.chain_ok else
               f"slid {1000 * slip:.1f} mm")
        raise TakeFailed(f"take of {skill.name!r} by {mentor.name}: {why}")
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
        Per skill: takes kept and takes tried (how hard the skill is in physics).

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
        tried = 0
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
                except TakeFailed:
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
        stats[skill.name] = {"kept": n_per_skill, "tried": tried}
    ds = Dataset(poly, tuple(skills), tuple(demos), float(scale), gap_limit,
                 dict(DEFAULT_FINGERS), None, markers)
    return ds, stats


def write_recorded(ds: Dataset, out_dir: str | Path, trajectory_format: str = "c3d") -> Path:
    """Write a recorded dataset folder (the annotations name the object markers)."""
    return save_dataset(ds, out_dir, trajectory_format=trajectory_format,
                        markers=DEFAULT_MARKERS)
