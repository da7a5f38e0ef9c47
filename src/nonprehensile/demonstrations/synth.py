"""A seeded generator of demonstration datasets whose finger paths agree with the object's motion.

The paper's data (Section VI) come from people manipulating a cube while an OptiTrack V120:Duo
tracks four markers on the index finger and thumb at 120 Hz. This module makes such data from
a skills file, so that the whole pipeline (loading, segmentation, registration, clustering)
can be run and tested without a motion-capture lab.

Model of a demonstration
------------------------
* The object moves by the exact maneuver of the skill (:func:`~nonprehensile.maneuvers.classify`):
  a rotation by ``angle`` about ``axis`` through the pivot (a point of the pivot edge for
  rolling, the pivot vertex for tumbling, the centre of mass for rotating), with a
  minimum-jerk profile, during the one arc that carries it (see :func:`event_progress`).
* Finger ``R1`` is the index finger, ``R2`` the thumb. The landing event may leave out a
  finger that held the object as it started to move (a topple that falls ahead of it): the
  finger rides with the object to the landing and lets go there. While a finger is in contact
  (from the event that first names it to the first event that no longer does) its contact
  point is a point of the named element, in the object's frame; the tip marker is that point
  moved outward along the element's normal by the mentor's marker offset (a marker sits on the
  nail side of the pad, 0.5 to 2 mm proud). So at each event time every named finger's tip
  lies on the named face, edge or vertex of the object in its pose at that time, on the
  outside: what ``tests/test_synth.py`` checks.
* How the contact point moves during a motion arc depends on the motion's label:
  ``straight-pull`` (rolling only) slides it so that the finger moves on a straight line (the
  line where the face's start plane meets its current plane); any other label keeps it
  fixed on the object, so the finger rides with it (the quarter circle of the paper's Fig. 5
  skill 2). Arcs in which the object does not move let the contact creep a little.
* Tumbling skills pinch two opposite faces (a pinch on adjacent faces pushes the object off
  its pivot vertex, docs/physics.md) at points that put the pinch line above and behind the
  centre of mass: high for a ``lift-over`` (:data:`TUMBLE_GRIPS`), low at the back with the
  hand turned sideways for a ``twist-over``, whose wrist then turns by 160 degrees about the
  pinch as the object tumbles (the knuckle markers sweep round; the pads stay put, as they
  must to hold the object).
* Before its first contact a finger approaches from a hover point along a bowed path that
  stays outside the object (it is always on the outer side of the plane of the element it
  will touch); after its last contact it retreats the same way. A finger the skill never
  names follows the other one at a fixed offset, away from the object.
* Knuckle markers sit behind and above the tips, shifted by the mentor's placement offset.
* Measurement: Gaussian noise (0.5 mm by default) and occasional dropouts (runs of NaN of
  2 to ``gap_limit // 2`` frames), as an optical tracker occludes markers.

Mentors differ in speed (durations), amplitude (approach heights and distances), timing (the
share of time spent approaching, holding, and moving the object), marker placement, and where
on a face they put their fingers; see :data:`DEFAULT_MENTORS`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from nonprehensile.bounds import check_path
from nonprehensile.demonstrations.dataset import (
    ANNOTATION_FILES,
    DEFAULT_FINGERS,
    DEFAULT_GAP_LIMIT,
    DEFAULT_MARKERS,
    SCALE_RANGE,
    Dataset,
    Demonstration,
    EventTime,
    save_dataset,
)
from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory, kabsch_poses
from nonprehensile.errors import InputError, ManeuverError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.io import read_skills
from nonprehensile.maneuvers import classify
from nonprehensile.skills.contacts import (
    ContactPair,
    Edge,
    Face,
    Finger,
    Ground,
    ObjectElement,
    Vertex,
    element_vertices,
)
from nonprehensile.skills.skill import Skill
from nonprehensile.states import state_pose

__all__ = [
    "DEFAULT_MENTORS",
    "DEFAULT_SEED",
    "MentorStyle",
    "ObjectMotion",
    "default_object_markers",
    "event_progress",
    "object_motion",
    "object_size",
    "synthesize",
    "synthesize_dataset",
    "synthesize_demonstration",
]

FloatArray = NDArray[np.float64]
#: Most dropouts per marker and demonstration the generator accepts.
MAX_DROPOUTS = 20.0
#: Lowest sample rate the generator accepts, in Hz.
MIN_RATE = 30.0
#: Highest sample rate the generator accepts, in Hz (fast optical trackers run at 2 kHz).
MAX_RATE = 2000.0
#: Most demonstrations per skill.
MAX_N_PER_SKILL = 1000
#: Most mentors.
MAX_MENTORS = 100
#: Most demonstrations times the rate (frames per second of demonstration, summed): a
#: demonstration lasts a few seconds, so this bounds the frames held in memory (about 400 MB).
MAX_DEMOS_X_RATE = 1_000_000.0
#: Largest measurement noise, mm.
MAX_NOISE_MM = 100.0
#: Largest longest-dropout, frames.
MAX_GAP_LIMIT = 100_000
#: Largest seed (numpy seeds are non-negative integers; 64 bits is plenty).
MAX_SEED = 2**64 - 1
Progress = Callable[[int, int], None]

#: The seed of the bundled dataset (``data/cube_demos``).
DEFAULT_SEED = 20190520

_UP = np.array([0.0, 0.0, 1.0])
# base durations (s) of an arc by kind, before a mentor's speed and timing are applied
_BASE = {"free": 0.6, "hold": 0.3, "move": 0.9}
_LEAD, _TAIL = 0.1, 0.25  # hover before the first event, retreat after the last (s)
_FACE_MARGIN = 0.08  # keep chosen contact points this far (object sizes) inside a face
#: A hook for a straight pull sits this share of the mentor's grip offset from the face's
#: middle: hooked far from the middle, the drag to the rolling edge loses the cube before its
#: tipping point (physics: ben's grip, 14 mm off, tipped it in 2 takes of 20; halved, 20 of 20)
_PULL_GRIP = 0.5
_TWIST_DEG = 160.0  # how far the wrist turns about the pinch during a twist-over
#: Where a tumbling skill's pinch holds each face, object sizes from the face's centre (up the
#: slope, across: the mirror image on the opposite face), by its moving arc's label: the pinch
#: line lies above and behind the centre of mass, so that the object hangs from it the way
#: the tumble turns it and keeps its pivot vertex on the table (found in physics; a pinch
#: through the centre of mass carries the object without turning it about the pinch). A
#: mentor's own grip shifts it by a third of the mentor's offset from (0.2, 0).
TUMBLE_GRIPS = {"lift-over": (0.3, -0.3), "twist-over": (0.0, -0.2)}


@dataclass(frozen=True)
class MentorStyle:
    """How one (simulated) mentor demonstrates.

    Attributes
    ----------
    name : str
        The mentor's name in the annotations.
    speed : float
        Speed factor: arc durations are divided by it.
    amplitude : float
        Scale of approach and retreat distances and of the bow of free paths, in object
        sizes (:func:`object_size`).
    timing : tuple of float, length 3
        Duration weights of free arcs (approach), holding arcs (contact, object still) and
        moving arcs (the object turns): the share of time spent in each.
    tip_offset_mm : float
        How far the tip marker sits outward from the contact point, mm.
    knuckle_offset_mm : tuple of float, length 3
        Placement offset of the knuckle markers, mm (world x, y, z).
    grip : tuple of float, length 2
        Where on a face the mentor puts a finger, in object sizes (:func:`object_size`) from
        the face's centre along (its up-slope direction, the horizontal across it).
    """

    name: str
    speed: float
    amplitude: float
    timing: tuple[float, float, float]
    tip_offset_mm: float
    knuckle_offset_mm: tuple[float, float, float]
    grip: tuple[float, float]


#: Three mentors with distinct styles: a quick, tight one; a slow, sweeping one with
#: long holds of the contact; and one who moves the object briskly after a careful approach.
DEFAULT_MENTORS: tuple[MentorStyle, ...] = (
    MentorStyle("ana", speed=1.35, amplitude=0.7, timing=(0.75, 0.8, 1.0),
                tip_offset_mm=0.8, knuckle_offset_mm=(2.0, -3.0, 3.0), grip=(0.2, 0.08)),
    MentorStyle("ben", speed=0.8, amplitude=1.45, timing=(1.2, 1.5, 1.15),
                tip_offset_mm=1.8, knuckle_offset_mm=(-4.0, 2.0, 7.0), grip=(0.28, -0.1)),
    MentorStyle("chen", speed=1.0, amplitude=1.05, timing=(1.5, 0.9, 0.75),
                tip_offset_mm=1.2, knuckle_offset_mm=(1.0, 5.0, -2.0), grip=(0.12, 0.0)),
)


# ---------------------------------------------------------------------------- object motion


@dataclass(frozen=True)
class ObjectMotion:
    """The exact world motion of a skill's maneuver, in model units.

    The pose at progress ``lam`` in [0, 1] maps an object point ``x`` to
    ``Q(lam) @ (R0 @ x + t0 - pivot) + pivot`` with ``Q(lam)`` the rotation by
    ``lam * angle`` about ``axis``.

    Attributes
    ----------
    rotation0 : array, shape (3, 3)
        ``R0`` of the initial state (:func:`~nonprehensile.states.state_pose`).
    translation0 : array, shape (3,)
        ``t0`` of the initial state.
    pivot : array, shape (3,)
        A world point on the rotation axis that stays fixed.
    axis : array, shape (3,)
        World unit axis.
    angle : float
        Total rotation, radians.
    """

    rotation0: FloatArray
    translation0: FloatArray
    pivot: FloatArray
    axis: FloatArray
    angle: float

    def pose(self, lam: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Poses at progress ``lam``.

        Parameters
        ----------
        lam : array, shape (n,)

        Returns
        -------
        R : array, shape (n, 3, 3)
            Object-to-world rotations.
        t : array, shape (n, 3)
            Translations: world = ``R @ x + t``.
        """
        lam = np.asarray(lam, dtype=np.float64).reshape(-1)
        q = Rotation.from_rotvec(np.outer(lam * self.angle, self.axis)).as_matrix()
        r = q @ self.rotation0
        t = np.einsum("nij,j->ni", q, self.translation0 - self.pivot) + self.pivot
        return np.asarray(r), np.asarray(t)


def object_motion(poly: Polyhedron, skill: Skill) -> ObjectMotion:
    """The exact motion that carries out ``skill``'s maneuver (paper Section II).

    Raises
    ------
    InputError
        If no single maneuver takes the initial state to the final one.
    """
    try:
        m = classify(poly, skill.initial, skill.final)
    except ManeuverError as exc:
        raise InputError(f"cannot synthesize skill {skill.name!r}: {exc}") from None
    r0, t0 = state_pose(poly, skill.initial)
    if m.kind == "rolling":
        x = poly.vertices[poly.edges[frozenset(m.pivot)][0]]
    elif m.kind == "tumbling":
        x = poly.vertices[poly.shared_vertices(m.pivot)[0]]
    else:  # rotating: about the vertical through the centre of mass
        x = poly.com
    pivot = r0 @ x + t0
    return ObjectMotion(r0, t0, pivot, np.asarray(m.axis, dtype=np.float64),
                        math.radians(m.angle))


def _ground_faces(event_pairs: Sequence[tuple[object, object]]) -> set[str]:
    return {y.id for x, y in event_pairs if isinstance(x, Ground) and isinstance(y, Face)}


def event_progress(skill: Skill) -> list[float]:
    """How far the object has moved at each event: 0 (initial pose) or 1 (final pose).

    Rule: for rolling and tumbling, an event whose ground contact is the final bottom face is
    at 1, others at 0 (the pivot event is the instant the object leaves its bottom face). For
    rotating, where the bottom face never changes, the object turns during the arc that leaves
    the first event with a finger contact.

    Raises
    ------
    InputError
        If the rule does not give one moving arc held by the same fingers at both ends.
    """
    lam: list[float] = []
    if skill.maneuver == "rotating":
        first = next((i for i, e in enumerate(skill.events)
                      if any(isinstance(p.x, Finger) for p in e.pairs)), None)
        if first is None or first + 1 >= len(skill.events):
            raise InputError(
                f"cannot synthesize skill {skill.name!r}: a rotation needs an event with a "
                "finger contact followed by another event"
            )
        lam = [0.0 if i <= first else 1.0 for i in range(len(skill.events))]
    else:
        for e in skill.events:
            faces = _ground_faces([(p.x, p.y) for p in e.pairs])
            lam.append(1.0 if skill.final.face in faces else 0.0)
    moves = [i for i in range(len(lam) - 1) if lam[i + 1] != lam[i]]
    if lam[0] != 0.0 or lam[-1] != 1.0 or len(moves) != 1 or lam != sorted(lam):
        raise InputError(
            f"cannot synthesize skill {skill.name!r}: its events should rest on the initial "
            f"bottom face, then on the final one ({skill.final.face!r}) from some event on; "
            f"got progress {lam}"
        )
    i = moves[0]
    a, b = _finger_elements(skill.events[i].pairs), _finger_elements(skill.events[i + 1].pairs)
    if not a and skill.maneuver != "rotating":
        raise InputError(
            f"cannot synthesize skill {skill.name!r}: no finger touches the object when it "
            f"starts to move (event {skill.events[i].id!r})"
        )
    # fingers may let go as the object lands (a topple: it falls ahead of the finger), so
    # the landing event may name fewer of them, never others
    if skill.maneuver != "rotating" and any(b.get(k, a.get(k)) != a.get(k) for k in {*a, *b}):
        raise InputError(
            f"cannot synthesize skill {skill.name!r}: the fingers holding the object change "
            f"while it moves ({skill.events[i].id!r} -> {skill.events[i + 1].id!r}); the "
            "landing event may leave a finger out (it lets go), not add or move one"
        )
    return lam


def _finger_elements(pairs: Iterable[ContactPair]) -> dict[int, ObjectElement]:
    """Finger number -> the object element it touches, in one event."""
    out: dict[int, ObjectElement] = {}
    for p in pairs:
        if isinstance(p.x, Finger) and isinstance(p.y, (Face, Edge, Vertex)):
            out[p.x.index] = p.y
    return out


# ------------------------------------------------------------------------------ geometry


def _smooth(s: FloatArray) -> FloatArray:
    """Minimum-jerk profile 10 s^3 - 15 s^4 + 6 s^5 (zero speed and acceleration at ends)."""
    s = np.clip(s, 0.0, 1.0)
    return np.asarray(s**3 * (10.0 - 15.0 * s + 6.0 * s**2))


def object_size(poly: Polyhedron) -> float:
    """The object's size: the edge of the cube of its volume (1 for the unit cube), in model
    units.

    Every distance of a mentor's path that is not a physical constant of the hand (marker
    offsets and pad, in mm) is a multiple of it, so that the same object written in metres
    and in millimetres gets the same path in SI, and a small object a tight one. Rounded to
    12 significant digits, so that the unit cube's is exactly 1.
    """
    return float(f"{float(np.cbrt(poly.volume)):.12g}")


def _element_frame(poly: Polyhedron, el: ObjectElement) -> tuple[FloatArray, FloatArray]:
    """A point and outward unit normal of an element, object frame."""
    idx = list(element_vertices(el, poly))
    if isinstance(el, Face):
        return np.asarray(poly.face_centroids[el.id]), np.asarray(poly.normals[el.id])
    faces = el.faces if isinstance(el, Edge) else poly.vertex_faces[idx[0]]
    n = np.sum([poly.normals[f] for f in faces], axis=0)
    return np.asarray(poly.vertices[idx].mean(axis=0)), np.asarray(n / np.linalg.norm(n))


def _planes(poly: Polyhedron) -> tuple[FloatArray, FloatArray]:
    n = np.array([poly.normals[f] for f in poly.faces])
    h = np.array([poly.normals[f] @ poly.vertices[poly.faces[f][0]] for f in poly.faces])
    return n, h


def _inside(poly: Polyhedron, x: FloatArray, margin: float) -> bool:
    """Whether ``x`` is inside the object, at least ``margin`` from every face plane."""
    n, h = _planes(poly)
    return bool(np.all(n @ x - h <= -margin + 1e-9 * poly.diameter))


def _place_on_face(poly: Polyhedron, face: str, target: FloatArray) -> FloatArray:
    """``target`` (in the face's plane) pulled toward the centre until it is well inside."""
    c = np.asarray(poly.face_centroids[face])
    n = poly.normals[face]
    size = object_size(poly)
    n_all, h_all = _planes(poly)
    others = [i for i, f in enumerate(poly.faces) if f != face]
    d = target - c
    d = d - (d @ n) * n
    for s in np.linspace(1.0, 0.0, 41):
        x = c + s * d
        if np.all(n_all[others] @ x - h_all[others] <= -_FACE_MARGIN * size):
            return np.asarray(x)
    return c


def _in_face_axes(poly: Polyhedron, face: str, r0: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two in-face unit directions (object frame): up the slope in the pose ``r0``, across."""
    n = poly.normals[face]
    up_obj = r0.T @ _UP
    u = up_obj - (up_obj @ n) * n
    if np.linalg.norm(u) < 1e-6:  # a face facing up or down: use its first edge
        u = poly.edge_direction(face, 1)
    u = u / np.linalg.norm(u)
    return u, np.cross(n, u)


def _straight_pull(
    motion: ObjectMotion, n_obj: FloatArray, q_obj: FloatArray, start_world: FloatArray,
    lam: FloatArray,
) -> FloatArray:
    """World points of a finger that keeps touching a face while moving on a straight line.

    The line is where the face's plane at the start meets the plane through the start point
    perpendicular to the axis; at progress ``lam`` the finger is where that line meets the
    face's current plane. Returns array, shape (n, 3).
    """
    r, t = motion.pose(lam)
    n0 = motion.rotation0 @ n_obj
    h0 = n0 @ start_world
    out = np.empty((len(lam), 3))
    for k in range(len(lam)):
        nk = r[k] @ n_obj
        if np.linalg.norm(np.cross(n0, nk)) < 1e-9:
            out[k] = start_world
            continue
        a = np.array([n0, nk, motion.axis])
        b = np.array([h0, nk @ (r[k] @ q_obj + t[k]), motion.axis @ start_world])
        out[k] = np.linalg.solve(a, b)
    return out


# ----------------------------------------------------------------------- one demonstration


@dataclass
class _Contact:
    """A finger's contact: element, and its contact point (object frame) at each event."""

    element: ObjectElement
    normal: FloatArray  # outward normal, object frame
    points: dict[int, FloatArray]  # event index -> contact point
    first: int  # first event naming it
    last: int  # last event that still has it (the break event, or the chain's last)


def _arc_kinds(skill: Skill, lam: list[float]) -> list[str]:
    kinds = []
    for i in range(len(skill.events) - 1):
        a = _finger_elements(skill.events[i].pairs)
        b = _finger_elements(skill.events[i + 1].pairs)
        if lam[i] != lam[i + 1]:
            kinds.append("move")
        elif set(b) - set(a):
            kinds.append("free")
        else:
            kinds.append("hold")
    return kinds


def _contacts(
    poly: Polyhedron, skill: Skill, lam: list[float], motion: ObjectMotion,
    mentor: MentorStyle, rng: np.random.Generator,
) -> dict[int, _Contact]:
    """Each finger's contact element and contact points at the events."""
    events = skill.events
    per_event = [_finger_elements(e.pairs) for e in events]
    fingers = sorted({k for d in per_event for k in d})
    out: dict[int, _Contact] = {}
    for k in fingers:
        named = [i for i, d in enumerate(per_event) if k in d]
        first, last_named = named[0], named[-1]
        if named != list(range(first, last_named + 1)):
            raise InputError(
                f"cannot synthesize skill {skill.name!r}: finger R{k} touches, lets go and "
                "touches again; the generator makes one contact per finger"
            )
        el = per_event[first][k]
        if any(per_event[i][k] != el for i in named):
            raise InputError(
                f"cannot synthesize skill {skill.name!r}: finger R{k} moves from "
                f"{el} to another element without letting go"
            )
        last = min(last_named + 1, len(events) - 1)
        _, normal = _element_frame(poly, el)
        pts: dict[int, FloatArray] = {}
        labels = [m.label for m in skill.motions]
        grip = _tumble_grip(skill, lam)
        for i in range(first, last + 1):
            if i == first:
                pts[i] = _first_point(poly, el, motion, mentor, rng, grip, k)
                if "straight-pull" in labels[first:last] and isinstance(el, Face):
                    centre = poly.face_centroids[el.id]
                    pts[i] = centre + _PULL_GRIP * (pts[i] - centre)
            else:
                prev, label = pts[i - 1], labels[i - 1]
                moved = lam[i - 1] != lam[i]
                if moved and label == "straight-pull":
                    pts[i] = _pull_end(poly, el, motion, prev, skill)
                elif moved or not isinstance(el, Face):
                    pts[i] = prev  # the finger rides with the object (or holds an edge/vertex)
                else:  # holding a still object: the pad creeps a little
                    creep = rng.normal(0.0, 0.04 * object_size(poly), 3)
                    pts[i] = _place_on_face(poly, el.id, prev + creep)
            if i < last and lam[i] != lam[i + 1] and labels[i] == "straight-pull":
                # the pull must start where the face is nearest the rolling edge
                pts[i] = _pull_start(poly, el, motion, pts[i], skill)
        out[k] = _Contact(el, normal, pts, first, last)
    return out


def _tumble_grip(skill: Skill, lam: Sequence[float]) -> tuple[float, float] | None:
    """The base grip of a tumbling skill's pinch (:data:`TUMBLE_GRIPS`), else None."""
    if skill.maneuver != "tumbling":
        return None
    mv = next(i for i in range(len(lam) - 1) if lam[i] != lam[i + 1])
    return TUMBLE_GRIPS.get(skill.motions[mv].label, TUMBLE_GRIPS["lift-over"])


def _first_point(
    poly: Polyhedron, el: ObjectElement, motion: ObjectMotion, mentor: MentorStyle,
    rng: np.random.Generator, grip: tuple[float, float] | None, finger: int,
) -> FloatArray:
    if not isinstance(el, Face):
        return _element_frame(poly, el)[0]
    u, v = _in_face_axes(poly, el.id, motion.rotation0)
    up, across = mentor.grip
    if grip is not None:  # a tumbling pinch: the skill's grip, shifted by the mentor's
        up, across = grip[0] + (up - 0.2) / 3.0, grip[1] + across / 3.0
    size = object_size(poly)
    off = (size * (up * u + across * (1 if finger == 1 else -1) * v)
           + rng.normal(0.0, 0.03 * size, 3))
    return _place_on_face(poly, el.id, poly.face_centroids[el.id] + off)


def _wrist_twist(back: FloatArray, normal: FloatArray, angle: FloatArray) -> FloatArray:
    """``back`` (n, 3) turned about ``normal`` (n, 3) by ``angle`` (n,) radians (Rodrigues)."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    dot = np.sum(normal * back, axis=1, keepdims=True)
    return np.asarray(back * c + np.cross(normal, back) * s + normal * dot * (1.0 - c))


def _pull_start(
    poly: Polyhedron, el: ObjectElement, motion: ObjectMotion, hook: FloatArray, skill: Skill
) -> FloatArray:
    """Where a straight pull starts: the face's point nearest the axis, beside the hook."""
    r0, t0 = motion.rotation0, motion.translation0
    if not isinstance(el, Face) or skill.maneuver != "rolling":
        raise InputError(
            f"cannot synthesize skill {skill.name!r}: a straight-pull motion needs a finger on "
            "a face and a rolling maneuver"
        )
    n_w = r0 @ poly.normals[el.id]
    if abs(n_w @ motion.axis) > 1e-6:
        raise InputError(
            f"cannot synthesize skill {skill.name!r}: face {el.id!r} is not parallel to the "
            "rolling edge, so no straight pull keeps the finger on it"
        )
    hook_w = r0 @ hook + t0
    lateral = motion.pivot + ((hook_w - motion.pivot) @ motion.axis) * motion.axis
    h = n_w @ (r0 @ poly.face_centroids[el.id] + t0)
    foot_w = lateral + (h - n_w @ lateral) * n_w
    foot = r0.T @ (foot_w - t0)
    if not _inside(poly, foot, 0.0):
        raise InputError(
            f"cannot synthesize skill {skill.name!r}: the straight pull would start off face "
            f"{el.id!r}"
        )
    return np.asarray(foot)


def _pull_end(
    poly: Polyhedron, el: ObjectElement, motion: ObjectMotion, start: FloatArray, skill: Skill
) -> FloatArray:
    assert isinstance(el, Face)  # _pull_start has checked it
    q = poly.face_centroids[el.id]
    start_w = motion.rotation0 @ start + motion.translation0
    end_w = _straight_pull(motion, poly.normals[el.id], q, start_w, np.array([1.0]))[0]
    r, t = motion.pose(np.array([1.0]))
    end = r[0].T @ (end_w - t[0])
    if not _inside(poly, end, 0.0):
        raise InputError(
            f"cannot synthesize skill {skill.name!r}: the straight pull would leave face "
            f"{el.id!r} before the object lands; start it nearer the rolling edge"
        )
    return np.asarray(end)


def _free_dir(n_w: FloatArray) -> FloatArray:
    """Direction to hover away from a contact with world normal ``n_w``: out and up."""
    w = n_w + 0.8 * _UP if n_w @ _UP > -0.5 else n_w
    return np.asarray(w / np.linalg.norm(w))


#: Radius of a retro-reflective marker (its centre stands this far off the surface it is
#: stuck on), mm.
OBJECT_MARKER_RADIUS_MM = 4.0


def default_object_markers(
    poly: Polyhedron, skills: Sequence[Skill], scale: float = 0.05, n: int = 4
) -> dict[str, FloatArray]:
    """Where the generator sticks markers on the object: a layout in the model frame.

    One marker on each of ``n`` faces that no skill rests the object on and no finger
    touches (falling back to touched faces when too few are left), off-centre so that no
    symmetry of the object maps the layout onto itself, and standing
    :data:`OBJECT_MARKER_RADIUS_MM` off the face.

    Returns
    -------
    dict of str to array, shape (3,)
        Marker name (``"<object>:1"``, ...) -> position in model units.
    """
    busy: set[str] = set()
    for sk in skills:
        busy |= {sk.initial.face, sk.final.face}
        for e in sk.events:
            for p in e.pairs:
                if isinstance(p.y, Face):
                    busy.add(p.y.id)
    free = [f for f in poly.faces if f not in busy]
    faces = (free + [f for f in poly.faces if f in busy and f not in
                     {sk.initial.face for sk in skills} | {sk.final.face for sk in skills}])
    faces = (faces + [f for f in poly.faces if f not in faces])[:n]
    out: dict[str, FloatArray] = {}
    lift = OBJECT_MARKER_RADIUS_MM / (scale * 1000.0)
    for k, f in enumerate(faces):
        c = np.asarray(poly.face_centroids[f])
        v = poly.vertices[poly.faces[f][k % len(poly.faces[f])]]
        # a share of the way to a different corner on each face breaks the symmetry
        x = c + (0.2 + 0.1 * k) * (v - c) + lift * np.asarray(poly.normals[f])
        out[f"{poly.name}:{k + 1}"] = np.asarray(x)
    return out


def synthesize_demonstration(
    poly: Polyhedron,
    skill: Skill,
    mentor: MentorStyle,
    rng: np.random.Generator | int | None = None,
    *,
    rate: float = 120.0,
    scale: float = 0.05,
    noise_mm: float = 0.5,
    dropouts: float = 0.5,
    gap_limit: int = DEFAULT_GAP_LIMIT,
    object_markers: Mapping[str, FloatArray] | None = None,
) -> tuple[MarkerTrajectory, tuple[EventTime, ...]]:
    """One demonstration of ``skill`` by ``mentor``: marker trajectories and event times.

    Parameters
    ----------
    poly : Polyhedron
        The object model (model units).
    skill : Skill
        The skill to demonstrate.
    mentor : MentorStyle
        The mentor's style.
    rng : numpy Generator, int or None
        Randomness (a seed makes the result reproducible).
    rate : float
        Sampling rate, Hz.
    scale : float
        Metres per model unit (0.05: a 5 cm cube from the unit cube model).
    noise_mm : float
        Standard deviation of the measurement noise, mm.
    dropouts : float
        Mean number of dropouts per marker per demonstration.
    gap_limit : int
        Dropouts last 2 to ``max(2, gap_limit // 2)`` frames, so that they can be filled.
    object_markers : mapping of str to array, shape (3,), optional
        Markers stuck on the object (a layout in model units, e.g.
        :func:`default_object_markers`): when given, the trajectory also holds them (same
        noise and dropouts, drawn after the fingers', so that the finger markers are those
        made without them) and one rigid body named after the object, its pose solved from
        the noisy markers by Kabsch as Motive solves a rigid body (untracked where fewer than
        three are seen). The rigid body's frame is the model frame, in mm.

    Returns
    -------
    trajectory : MarkerTrajectory
        Markers :data:`~nonprehensile.demonstrations.dataset.DEFAULT_MARKERS` (then the
        object markers), in mm, shape (n_frames, 4 [+ m], 3).
    events : tuple of EventTime
        The skill's events with their times (on frame times), seconds.

    Raises
    ------
    InputError
        If the skill's events do not fit the generator's model (see :func:`event_progress`).
    """
    gen = np.random.default_rng(rng)
    motion = object_motion(poly, skill)
    lam_ev = event_progress(skill)
    kinds = _arc_kinds(skill, lam_ev)
    contacts = _contacts(poly, skill, lam_ev, motion, mentor, gen)
    weight = dict(zip(("free", "hold", "move"), mentor.timing, strict=True))
    durs = [_BASE[k] * weight[k] / mentor.speed * float(np.exp(gen.normal(0.0, 0.08)))
            for k in kinds]
    lead = _LEAD * float(np.exp(gen.normal(0.0, 0.2)))
    tail = _TAIL / mentor.speed * float(np.exp(gen.normal(0.0, 0.1)))
    # event times sit on frames, as an annotator marks them on the recording
    t_ev = np.round((lead + np.concatenate(([0.0], np.cumsum(durs)))) * rate) / rate
    for i in range(1, len(t_ev)):  # keep every arc at least two frames long
        t_ev[i] = max(t_ev[i], t_ev[i - 1] + 2.0 / rate)
    n_frames = round((t_ev[-1] + tail) * rate) + 1
    times = np.arange(n_frames) / rate

    # object progress per frame: the minimum-jerk turn during the moving arc
    mv = next(i for i, k in enumerate(kinds) if k == "move")
    lam = _smooth((times - t_ev[mv]) / (t_ev[mv + 1] - t_ev[mv]))
    r, t = motion.pose(lam)

    tips: dict[int, FloatArray] = {}
    normals: dict[int, FloatArray] = {}
    size = object_size(poly)
    tip_off = mentor.tip_offset_mm / (scale * 1000.0)
    for k, c in contacts.items():
        tips[k], normals[k] = _finger_path(
            poly, skill, c, motion, times, t_ev, lam, r, t, mentor, gen, tip_off
        )
    # a finger the skill never names follows the other one, out and up from the object
    fingers_named = sorted(tips)
    for k in (1, 2):
        if k not in tips:
            ref = fingers_named[0]
            off = 0.5 * normals[ref] + _UP
            off /= np.linalg.norm(off, axis=1, keepdims=True)
            tips[k] = tips[ref] + size * (
                0.6 * off + 0.1 * np.array([0.0, 1.0 if k == 2 else -1.0, 0.0]))
            normals[k] = normals[ref]
    pos = np.empty((n_frames, 4, 3))
    place = np.asarray(mentor.knuckle_offset_mm) / (scale * 1000.0)
    twist = skill.maneuver == "tumbling" and skill.motions[mv].label == "twist-over"
    for j, k in enumerate((1, 2)):
        back = 0.6 * normals[k] + 0.8 * _UP
        if twist:  # the hand turned sideways, its wrist turning about the pinch meanwhile
            wrist = math.radians(90.0) - lam * math.radians(_TWIST_DEG)
            back = _wrist_twist(back, normals[k], wrist)
        back /= np.linalg.norm(back, axis=1, keepdims=True)
        pos[:, 2 * j] = tips[k]
        pos[:, 2 * j + 1] = tips[k] + 0.45 * size * back + place
    pos *= scale * 1000.0  # model units -> mm
    pos += gen.normal(0.0, noise_mm, pos.shape)
    longest = max(2, gap_limit // 2)
    for m in range(pos.shape[1]):
        for _ in range(gen.poisson(dropouts)):
            length = int(gen.integers(2, longest + 1))
            start = int(gen.integers(0, max(1, n_frames - length)))
            pos[start:start + length, m] = np.nan
    names: tuple[str, ...] = DEFAULT_MARKERS
    bodies: tuple[PoseTrajectory, ...] = ()
    if object_markers:
        lay_mm = np.array([np.asarray(v, dtype=np.float64) for v in object_markers.values()])
        lay_mm = lay_mm * (scale * 1000.0)
        obj = np.einsum("nij,mj->nmi", r, lay_mm) + t[:, None] * (scale * 1000.0)
        obj += gen.normal(0.0, noise_mm, obj.shape)
        for m in range(obj.shape[1]):
            for _ in range(gen.poisson(dropouts)):
                length = int(gen.integers(2, longest + 1))
                start = int(gen.integers(0, max(1, n_frames - length)))
                obj[start:start + length, m] = np.nan
        pos = np.concatenate([pos, obj], axis=1)
        names = (*DEFAULT_MARKERS, *object_markers)
        bp, bq, _ = kabsch_poses(obj, lay_mm)
        bodies = (PoseTrajectory(poly.name, bp, bq, rate, "mm"),)
    traj = MarkerTrajectory(pos, names, rate, "mm", bodies)
    events = tuple(EventTime(e.id, float(tt))
                   for e, tt in zip(skill.events, t_ev, strict=True))
    return traj, events


def _finger_path(
    poly: Polyhedron, skill: Skill, c: _Contact, motion: ObjectMotion, times: FloatArray,
    t_ev: FloatArray, lam: FloatArray, r: FloatArray, t: FloatArray, mentor: MentorStyle,
    rng: np.random.Generator, tip_off: float,
) -> tuple[FloatArray, FloatArray]:
    """World tip positions and outward normals of one finger, shape (n_frames, 3) each."""
    n = len(times)
    obj = np.full((n, 3), np.nan)  # contact point in the object frame while in contact
    world = np.full((n, 3), np.nan)
    for i in range(c.first, c.last):
        sel = (times >= t_ev[i]) & (times <= t_ev[i + 1])
        s = (times[sel] - t_ev[i]) / (t_ev[i + 1] - t_ev[i])
        a, b = c.points[i], c.points[i + 1]
        if skill.motions[i].label == "straight-pull" and np.ptp(lam[sel]) > 0:
            start_w = motion.rotation0 @ a + motion.translation0
            q = poly.face_centroids[c.element.id] if isinstance(c.element, Face) else a
            xw = _straight_pull(motion, c.normal, q, start_w, lam[sel])
            obj[sel] = np.einsum("nji,nj->ni", r[sel], xw - t[sel])
        else:
            obj[sel] = a + np.outer(_smooth(s), b - a)
    held = ~np.isnan(obj[:, 0])
    nrm = np.einsum("nij,j->ni", r, c.normal)
    world[held] = np.einsum("nij,nj->ni", r[held], obj[held]) + t[held] + tip_off * nrm[held]

    # approach: hover, then a bowed path onto the first contact point
    i_make, i_break = c.first, c.last
    w_make = _free_dir(nrm[np.searchsorted(times, t_ev[i_make])])
    w_break = _free_dir(nrm[min(n - 1, np.searchsorted(times, t_ev[i_break]))])
    amp = mentor.amplitude * object_size(poly)
    for w, t_contact, t_far, towards in (
        (w_make, t_ev[i_make], t_ev[max(i_make - 1, 0)], True),
        (w_break, t_ev[i_break], min(times[-1], t_ev[i_break] + _TAIL / mentor.speed), False),
    ):
        k_contact = int(np.argmin(np.abs(times - t_contact)))
        p = world[k_contact]
        across = np.cross(_UP, w)
        across = across / np.linalg.norm(across) if np.linalg.norm(across) > 1e-6 else across
        far = p + 0.9 * amp * w + rng.uniform(-0.3, 0.3) * amp * across
        bow = 0.35 * amp * rng.uniform(0.8, 1.2)
        if towards:
            span = (times >= t_far) & (times < t_contact)
            s = _smooth((times[span] - t_far) / max(t_contact - t_far, 1e-9))
            before = times < t_far
        else:
            span = (times > t_contact) & (times <= t_far)
            s = _smooth((t_far - times[span]) / max(t_far - t_contact, 1e-9))
            before = times > t_far
        # p + (1 - s)(far - p) + bow sin(pi s) w: always on the outer side of the contact plane
        world[span] = (p + np.outer(1.0 - s, far - p)
                       + bow * np.outer(np.sin(np.pi * s), w))
        drift = np.outer(np.sin(times[before] * 2.1), rng.normal(0.0, 0.01 * object_size(poly), 3))
        world[before] = far + drift
    # before contact and after release, the normal is the one at making / breaking contact
    nrm[times < t_ev[i_make]] = nrm[np.searchsorted(times, t_ev[i_make])]
    nrm[times > t_ev[i_break]] = nrm[min(n - 1, np.searchsorted(times, t_ev[i_break]))]
    return world, nrm


# --------------------------------------------------------------------------------- dataset


def _check_int(name: str, value: object, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
            low <= value <= high):
        raise InputError(f"{name} must be a whole number in {low}..{high}, got {value!r}")
    return int(value)


def _check_float(name: str, value: object, low: float, high: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a number of {unit} in {low:g}..{high:g}, got {value!r}")
    v = float(value) + 0.0  # -0.0 becomes 0.0 (numpy refuses a noise scale of -0.0)
    if not (math.isfinite(v) and low <= v <= high):
        raise InputError(f"{name} must be a number of {unit} in {low:g}..{high:g}, got {value!r}")
    return v


def _bundled_skills() -> Path:
    return Path(str(resources.files("nonprehensile").joinpath("data", "cube_skills.json")))


def _mentor_list(mentors: Sequence[MentorStyle] | int, rng: np.random.Generator
                 ) -> list[MentorStyle]:
    if isinstance(mentors, bool):
        raise InputError(f"mentors must be a number or a list of MentorStyle, got {mentors!r}")
    if isinstance(mentors, int):
        if mentors < 1:
            raise InputError(f"mentors must be at least 1, got {mentors}")
        out = list(DEFAULT_MENTORS[:mentors])
        for j in range(len(out), mentors):  # more mentors than the named ones: draw styles
            w = [float(x) for x in rng.uniform(0.7, 1.5, 3)]
            knuckle = [float(x) for x in rng.uniform(-5.0, 5.0, 3)]
            out.append(MentorStyle(
                f"mentor{j + 1}", float(rng.uniform(0.75, 1.4)), float(rng.uniform(0.7, 1.5)),
                (w[0], w[1], w[2]), float(rng.uniform(0.5, 2.0)),
                (knuckle[0], knuckle[1], knuckle[2]),
                (float(rng.uniform(0.1, 0.3)), float(rng.uniform(-0.1, 0.1))),
            ))
        return out
    out = list(mentors)
    if not out or not all(isinstance(m, MentorStyle) for m in out):
        raise InputError(
            f"mentors must be a number of mentors or a list of MentorStyle, got {mentors!r}"
        )
    names = [m.name for m in out]
    if len(set(names)) != len(names):
        raise InputError(f"mentor names must differ, got {names}")
    return out


def synthesize_dataset(
    *,
    seed: int | np.random.Generator | None = DEFAULT_SEED,
    skills_file: str | Path | None = None,
    n_per_skill: int = 30,
    mentors: Sequence[MentorStyle] | int = DEFAULT_MENTORS,
    rate: float = 120.0,
    scale: float = 0.05,
    noise_mm: float = 0.5,
    dropouts: float = 0.5,
    gap_limit: int = DEFAULT_GAP_LIMIT,
    track_object: bool = False,
    progress: Progress | None = None,
) -> Dataset:
    """A synthetic dataset in memory: ``n_per_skill`` demonstrations of every skill.

    Demonstrations of a skill are shared round-robin among the mentors. Same arguments, same
    dataset, to the bit.

    Parameters
    ----------
    seed : int, numpy Generator or None
        Randomness.
    skills_file : str or Path, optional
        A skills file; by default the bundled cube skills (``data/cube_skills.json``).
    n_per_skill : int
        Demonstrations per skill (at least 1).
    mentors : int or sequence of MentorStyle
        The mentors, or how many (the first of :data:`DEFAULT_MENTORS`, then drawn styles).
    rate, scale, noise_mm, dropouts, gap_limit
        See :func:`synthesize_demonstration`.
    track_object : bool
        Also track the object: markers stuck on it (:func:`default_object_markers`) and its
        rigid body, and the dataset's ``object_markers`` naming the marker layout (so that
        ``dataset annotate`` can find the contact events without the annotated times).
    progress : callable (done, total) -> None, optional
        Called after each demonstration.

    Raises
    ------
    InputError
        Bad arguments, or a skill the generator cannot demonstrate (naming it).
    """
    _check_int("n_per_skill", n_per_skill, 1, MAX_N_PER_SKILL)
    if not isinstance(mentors, int) or isinstance(mentors, bool):
        pass  # a list of styles: checked by _mentor_list
    else:
        _check_int("mentors", mentors, 1, MAX_MENTORS)
    rate = _check_float("rate", rate, MIN_RATE, MAX_RATE, "Hz (a tracker's)")
    scale = _check_float("scale", scale, *SCALE_RANGE, "metres per model unit")
    noise_mm = _check_float("noise_mm", noise_mm, 0.0, MAX_NOISE_MM, "mm")
    dropouts = _check_float("dropouts", dropouts, 0.0, MAX_DROPOUTS,
                            "per marker and demonstration")
    _check_int("gap_limit", gap_limit, 0, MAX_GAP_LIMIT)
    # dropouts last 2 to gap_limit // 2 frames, so that every one can be filled
    if dropouts > 0 and gap_limit < 4:
        raise InputError(
            f"gap_limit must be >= 4 frames with dropouts (they last 2 to gap_limit // 2 "
            f"frames), got {gap_limit!r}"
        )
    if not (seed is None or isinstance(seed, np.random.Generator)):
        _check_int("seed", seed, 0, MAX_SEED)
    rng = np.random.default_rng(seed)
    path = Path(skills_file) if skills_file is not None else _bundled_skills()
    poly, skills = read_skills(path)
    total = n_per_skill * len(skills)
    if total * rate > MAX_DEMOS_X_RATE:
        raise InputError(
            f"{total} demonstrations ({n_per_skill} per skill x {len(skills)} skills) at "
            f"{rate:g} Hz is more than the generator makes at once (demonstrations x rate <= "
            f"{MAX_DEMOS_X_RATE:g}); lower n_per_skill or rate"
        )
    styles = _mentor_list(mentors, rng)
    layout = default_object_markers(poly, skills, scale) if track_object else None
    demos: list[Demonstration] = []
    for skill in skills:
        for j in range(n_per_skill):
            mentor = styles[j % len(styles)]
            traj, events = synthesize_demonstration(
                poly, skill, mentor, rng, rate=rate, scale=scale, noise_mm=noise_mm,
                dropouts=dropouts, gap_limit=gap_limit, object_markers=layout,
            )
            name = f"{skill.name}_{mentor.name}_{j // len(styles):02d}.c3d"
            demos.append(Demonstration(name, skill, mentor.name, skill.initial, skill.final,
                                       events, traj))
            if progress is not None:
                progress(len(demos), total)
    object_markers = {} if layout is None else {
        k: (float(v[0]), float(v[1]), float(v[2])) for k, v in layout.items()}
    return Dataset(poly, tuple(skills), tuple(demos), float(scale), gap_limit,
                   dict(DEFAULT_FINGERS), object_markers=object_markers)


def synthesize(
    out_dir: str | Path,
    *,
    seed: int | None = DEFAULT_SEED,
    skills_file: str | Path | None = None,
    n_per_skill: int = 30,
    mentors: Sequence[MentorStyle] | int = DEFAULT_MENTORS,
    rate: float = 120.0,
    scale: float = 0.05,
    noise_mm: float = 0.5,
    dropouts: float = 0.5,
    gap_limit: int = DEFAULT_GAP_LIMIT,
    trajectory_format: str = "c3d",
    track_object: bool = False,
    progress: Progress | None = None,
    overwrite: bool = False,
) -> Dataset:
    """Generate a dataset and write it to ``out_dir`` (``nonprehensile dataset synth``).

    See :func:`synthesize_dataset` for the arguments; ``trajectory_format`` is ``"c3d"``
    (needs the ``mocap`` extra) or ``"csv"`` (Motive CSV). With ``track_object``, the
    annotations give the ``object_markers``, and a CSV dataset also names its
    ``rigid_body`` (written in each file; C3D has no rigid bodies). A folder that already
    holds a dataset (an annotations file) is refused before any work unless ``overwrite``:
    its annotations may be a person's work.

    Raises
    ------
    InputError
        Bad arguments, ``out_dir`` a file, or a dataset there already (without ``overwrite``).

    Returns
    -------
    Dataset
        What was written, with ``root`` set to ``out_dir``.
    """
    root = check_path(out_dir, "dataset folder")
    if root.exists() and not root.is_dir():
        raise InputError(f"{root}: is a file, not a folder; give a folder for the dataset")
    present = [name for name in ANNOTATION_FILES if (root / name).exists()]
    if present and not overwrite:
        raise InputError(
            f"{root}: already holds a dataset ({present[0]}); give another folder, or "
            "--force (overwrite=True) to replace its annotations and recordings"
        )
    ds = synthesize_dataset(
        seed=seed, skills_file=skills_file, n_per_skill=n_per_skill, mentors=mentors,
        rate=rate, scale=scale, noise_mm=noise_mm, dropouts=dropouts, gap_limit=gap_limit,
        track_object=track_object, progress=progress,
    )
    rigid_body = ds.poly.name if track_object and trajectory_format == "csv" else None
    ds = Dataset(ds.poly, ds.skills, ds.demonstrations, ds.scale, ds.gap_limit, ds.fingers,
                 Path(out_dir), ds.object_markers, rigid_body=rigid_body)
    save_dataset(ds, out_dir, trajectory_format=trajectory_format, markers=DEFAULT_MARKERS)
    return ds
