"""The skill graph as an event-driven controller: the decisions of closed-loop execution.

A plan step is a chain of contact events joined by arcs of finger motion (paper Section IV);
a controller can watch exactly that chain. For each step (:class:`StepMonitor`):

1. **Anchor.** The arc's reference motion is placed on the object where it is *observed*:
   at the step's start and at every contact event, the planar transform (a turn about the
   vertical and a horizontal shift) that carries the event's ground element (the face, edge
   or vertex on the table) from where the plan predicted it to where it is observed moves
   the next arc's reference (:func:`anchor_transform`). The fingertip blends from where it
   is into the moved reference (minimum jerk), so it never jumps.
2. **Run until the arc's end event is observed**, read from the observations by geometry
   (:func:`~nonprehensile.observation.observed_contacts`, confirmed over
   ``ControlConfig.confirm``): the next arc starts then, early or late, never on time
   alone. An arc whose reference ends before its event is seen *seeks* it (an approach goes
   on slowly along its last direction for at most ``reach``), then waits ``grace``; past
   that the step is aborted with the reason.
3. **Watch for what the skill does not expect**: the object sliding on its face while the
   arc should tip it (``slide_tol``), falling back onto its start face after it pivoted,
   or resting on an element no event of the skill names (tipped too far): the step is
   aborted at once, with the reason.
4. **Read the state** from the observed pose once the object is still (``still_time``).

What to do after a step (:func:`after_step`): the next step when the object rests in the
predicted state; otherwise a re-plan from the observed state and position, bounded
(``max_replans``), a skill that made the object slide instead of tip being avoided in the
new plan (it needs more table friction than there is; a different skill for the same
maneuver, or another route). At the end of the plan, an object resting in the goal state but
off the goal position is slid there by short pushes low on a side face
(:func:`correction_pushes`). A step or plan that fails is reported as failed, never
continued silently.

Pure core: no simulator; :mod:`nonprehensile.sim.closed_loop` runs this in MuJoCo.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from nonprehensile.errors import ContactError, GeometryError, InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.inference import Expansion
from nonprehensile.observation import (
    Observation,
    PairCache,
    hull_distance,
    observed_contacts,
)
from nonprehensile.planning import MotionLibrary, ObjectPose, Plan, PlanStep, plan
from nonprehensile.skills.contacts import (
    ContactEvent,
    ContactPair,
    Edge,
    Face,
    Finger,
    Ground,
    ObjectElement,
    Vertex,
    normalize_event,
)
from nonprehensile.states import State, angle_diff, state_of_pose
from nonprehensile.step_paths import (
    ease,
    fingers_of,
    resample,
    step_directions,
    step_targets,
    with_stop,
)

__all__ = [
    "GO_ON",
    "ArcSpec",
    "ControlConfig",
    "Decision",
    "NextAction",
    "PlanarTransform",
    "Replanner",
    "StepMonitor",
    "StepSpec",
    "after_step",
    "anchor_transform",
    "angular_step",
    "correction_pushes",
    "one_finger_push",
    "push_finger",
    "raised",
    "replanner",
    "snap_state",
    "step_spec",
    "top_roll",
    "turn_push",
]

FloatArray = NDArray[np.float64]
Pairs = frozenset[ContactPair]


@dataclass(frozen=True)
class ControlConfig:
    """Settings of the closed-loop controller (SI units; every one can be overridden).

    Attributes
    ----------
    confirm : float
        An observed contact set must hold this long (s) to be an event.
    contact_tol : float
        A fingertip within its radius plus this (m) of the object touches it.
    ground_tol : float
        Vertices within this (m) of the lowest one, and of the table, rest on it.
    slide_tol : float
        The object may slide this far (m) on its face during an arc that should tip it.
    anomaly_time : float
        An unexpected contact (resting on an element no later event names, falling back)
        must last this long (s) to abort the step: a landing face's edges touch first for a
        few milliseconds as it lands.
    grace : float
        Time (s) an arc may run past its reference before its end event is missing.
    reach : float
        How far (m) an approach goes on past its reference seeking the contact ...
    reach_speed : float
        ... at this speed (m/s).
    still_time : float
        The observed object must keep still this long (s) for its state to be read ...
    still_tol : float
        ... its centre of mass within this (m, plus the observation noise) of its mean.
    max_settle : float
        Longest wait (s) for the object to come to rest after a step.
    max_replans : int
        Retries and re-plans allowed in one execution.
    max_tries : int
        Tries of one step while the object stays in its start state ...
    slow_retry : float
        ... each retry this many times slower than the last.
    clearance : float
        Margin (m) between fingertip and object during transits.
    max_speed : float
        Fingertip speed bound (m/s) of every commanded motion.
    max_accel : float
        Fingertip acceleration bound (m/s^2): the demonstrations' own references reach
        about 16 m/s^2 after filtering, at the physics step; transits use half, unless ...
    transit_accel : float or None
        ... this (m/s^2) is given: the bound of the transits' legs (one arm's transits run at
        its motions' bound, :func:`~nonprehensile.sim.robot_run.robot_control`).
    angle_tol, position_tol : float
        A state within ``angle_tol`` degrees (and, at the goal, ``position_tol`` m) is
        reached.
    correct_position : bool
        Slide the object onto the goal position at the end of the plan.
    correction_tol : float
        Position error (m) left alone at the end; larger errors are slid away.
    max_corrections : int
        Correction pushes allowed.
    align_tol : float or None
        A step that ends on its predicted face (or the goal's) within this many degrees of
        the predicted ``theta`` (but past ``angle_tol``) is turned onto it by pushes off
        the centre line (:func:`turn_push`) and the plan goes on, instead of a re-plan:
        the same face, turned, is a turn away, whatever skill made it. It must be below
        half the model's angular step (the nearest state must be the predicted one):
        :meth:`for_step` checks it; None (the default) derives it there as a third of the
        step, at most 30 degrees (30 at the usual 90-degree step).
    follow_deg : float
        A tipping arc whose reference ends with the object still on a pivot of its landing
        face follows through: the fingers turn on about the pivot by at most this (degrees;
        0: never) ...
    follow_speed : float
        ... at this rate (degrees/s) ...
    follow_depth : float or None
        ... but no further than where the fingertip sphere would lie more than this (m)
        inside the object as observed when the follow-through begins: an object that does
        not turn (heavy, balanced on its edge under the pad) is not driven into. None (the
        default, the free fingertips'): no bound; robots:
        :func:`~nonprehensile.sim.robot_run.robot_control`.
    push_approach : float or None
        A correction push (a slide or a turn at the end of a plan) crosses the clearance
        between its start and the face as a guarded move: after the cross-fade into the
        push, at its own speed, it speeds up to at most this (m/s) and is back at its own
        speed 3 mm before the face as observed (:func:`~nonprehensile.transit.guarded_push`).
        None (the default, the free fingertips') or 0: at its own speed throughout; a
        compliant pad lags and overshoots its command in proportion to its speed, and
        measured with 0.1 m/s the free fingertips' slides turned the cube on landing (the
        main plan across the distribution 194/200 against 197/200). Robots (a
        position-controlled arm follows its command within 0.2 mm at 0.1 m/s in free
        motion): 0.1 m/s, :func:`~nonprehensile.sim.robot_run.robot_control`.
    """

    confirm: float = 0.015
    contact_tol: float = 0.0015
    ground_tol: float = 0.0015
    slide_tol: float = 0.012
    anomaly_time: float = 0.08
    grace: float = 0.4
    reach: float = 0.008
    reach_speed: float = 0.03
    still_time: float = 0.08
    still_tol: float = 0.0005
    max_settle: float = 2.0
    max_replans: int = 12
    max_tries: int = 2
    slow_retry: float = 1.25
    clearance: float = 0.015
    max_speed: float = 0.45
    max_accel: float = 20.0
    transit_accel: float | None = None
    angle_tol: float = 5.0
    position_tol: float = 0.010
    correct_position: bool = True
    correction_tol: float = 0.003
    max_corrections: int = 4
    align_tol: float | None = None
    follow_deg: float = 30.0
    follow_speed: float = 60.0
    follow_depth: float | None = None
    push_approach: float | None = None

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if name == "correct_position":  # the one switch
                if not isinstance(value, bool):
                    raise InputError(f"control setting correct_position must be True or "
                                     f"False, got {value!r}")
                continue
            if name in ("align_tol", "transit_accel", "follow_depth",
                        "push_approach") and value is None:
                continue  # (left to its default)
            # (a bool is a number to Python: True would read as 1)
            ok = (isinstance(value, (int, float)) and not isinstance(value, bool)
                  and math.isfinite(value) and value >= 0)
            positive = name in ("max_speed", "max_accel", "transit_accel", "reach_speed",
                                "still_time", "slow_retry", "follow_speed")
            if positive and ok:
                ok = value > 0
            if name in ("max_speed", "push_approach") and ok:
                ok = value <= 0.5  # the bound on every fingertip
            if name in ("max_replans", "max_tries", "max_corrections") and ok:
                ok = isinstance(value, int) and value <= 100  # bounded work
            if not ok:
                extra = {"max_speed": " and <= 0.5 m/s", "push_approach": " and <= 0.5 m/s",
                         "max_replans": ", whole, <= 100",
                         "max_tries": ", whole, <= 100",
                         "max_corrections": ", whole, <= 100"}.get(name, "")
                lower = "> 0" if positive else ">= 0"
                raise InputError(f"control setting {name} must be a finite number {lower}"
                                 f"{extra}, got {value!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return asdict(self)

    @property
    def transit_bound(self) -> float:
        """The transits' acceleration bound, m/s^2 (``transit_accel``, else half of
        ``max_accel``)."""
        return self.max_accel / 2.0 if self.transit_accel is None else self.transit_accel

    def for_step(self, step_deg: float | None) -> ControlConfig:
        """This configuration for a model whose states on one face lie ``step_deg`` degrees
        apart (:func:`angular_step`; None: at most one state per face): ``align_tol``
        derived (a third of the step, at most 30 degrees) when None, else checked to lie
        below half the step (:class:`~nonprehensile.errors.InputError` if not)."""
        if self.align_tol is None:
            derived = 30.0 if step_deg is None else min(30.0, step_deg / 3.0)
            return replace(self, align_tol=derived)
        if step_deg is not None and self.align_tol >= step_deg / 2.0:
            raise InputError(
                f"control setting align_tol must be below half the model's angular step "
                f"({step_deg:g} degrees between states on a face, so below {step_deg / 2:g}),"
                f" got {self.align_tol:g}: a turned object would be nearer another state; "
                f"pass a smaller one, or none to derive it ({min(30.0, step_deg / 3):g})")
        return self


def angular_step(states: Sequence[State]) -> float | None:
    """The model's angular step (degrees): the smallest turn between two of ``states`` on
    one face (90 for states every 90 degrees); None when no face has two."""
    by_face: dict[str, list[float]] = {}
    for s in states:
        by_face.setdefault(s.face, []).append(s.theta % 360.0)
    best: float | None = None
    for thetas in by_face.values():
        t = np.unique(np.round(thetas, 6) % 360.0)
        gaps = np.diff(np.concatenate([t, [t[0] + 360.0]]))
        gaps = gaps[gaps > 1e-3]  # the same state twice (0 and 359.9999999)
        if len(gaps) < 2:  # one state on this face
            continue
        gap = float(gaps.min())
        best = gap if best is None else min(best, gap)
    return best


# ------------------------------------------------------------------------ planar anchor
@dataclass(frozen=True)
class PlanarTransform:
    """A turn by ``yaw`` (radians, counterclockwise seen from above) about the vertical
    through ``center`` (x, y), then a horizontal ``shift``; heights are kept."""

    yaw: float = 0.0
    center: tuple[float, float] = (0.0, 0.0)
    shift: tuple[float, float] = (0.0, 0.0)

    def apply(self, points: FloatArray) -> FloatArray:
        """The transform of points of shape (..., 3)."""
        p = np.array(points, dtype=np.float64)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x = p[..., 0] - self.center[0]
        y = p[..., 1] - self.center[1]
        p[..., 0] = c * x - s * y + self.center[0] + self.shift[0]
        p[..., 1] = s * x + c * y + self.center[1] + self.shift[1]
        return p

    def turn(self, vectors: FloatArray) -> FloatArray:
        """Directions of shape (..., 3) turned by ``yaw`` about the vertical (no shift)."""
        v = np.array(vectors, dtype=np.float64)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x, y = v[..., 0].copy(), v[..., 1].copy()
        v[..., 0] = c * x - s * y
        v[..., 1] = s * x + c * y
        return v

    def to_dict(self) -> dict[str, Any]:
        """JSON form (degrees, metres)."""
        return {"yaw_deg": round(math.degrees(self.yaw), 4),
                "shift_m": [round(v, 6) for v in self.shift]}


def _turned_about(axis: FloatArray, angle: float, s: FloatArray, points: FloatArray
                 ) -> FloatArray:
    """``points`` (shape (3,) or (k, 3)) turned by ``angle * si`` (radians) about the unit
    ``axis`` through the origin, for each ``si`` of ``s``: shape ``(len(s), *points.shape)``.

    The numbers of ``np.stack([Rotation.from_rotvec(axis * angle * si).apply(points) for
    si in s])``, built at once: ``from_rotvec`` and ``as_matrix`` of a stack run scipy's
    loop of the single rotation row by row, and ``apply`` of a single rotation is one
    ``np.matmul`` of its matrix (a stack of one), which a stack of matrices repeats matrix
    by matrix (numpy's matmul chooses its kernel by the shapes and strides of one matrix).
    A list of a few hundred single rotations costs scipy's checks each time.
    """
    mats = Rotation.from_rotvec((axis * angle)[None, :] * s[:, None]).as_matrix()
    if points.ndim == 1:
        return np.asarray(np.matmul(mats, points))
    if len(points) == 1:
        return np.asarray(np.matmul(mats, points[0]))[:, None, :]
    return np.asarray(np.matmul(mats, points, axes=[(-2, -1), (-1, -2), (-1, -2)]))


def _element_vertices(poly: Polyhedron, element: ObjectElement) -> list[int]:
    if isinstance(element, Face):
        return list(poly.faces[element.id])
    if isinstance(element, Edge):
        return list(poly.edges[element.faces])
    if isinstance(element, Vertex):
        return poly.shared_vertices(element.faces)[:1]
    raise InputError(f"no vertices for {element}")  # pragma: no cover - elements only


def anchor_transform(poly: Polyhedron, element: ObjectElement | None,
                     predicted: ObjectPose, observed: ObjectPose, *,
                     yaw: float | None = None) -> PlanarTransform:
    """The planar transform that carries ``element`` (on the table) from the predicted pose
    to the observed one: a 2-D least-squares fit of its vertices (a face's, an edge's two);
    a single vertex (or no element) matches the point (the centre of mass without an
    element) and turns by ``yaw`` (radians) when given, else by the best vertical-axis fit
    of the two rotations.

    A vertex pivot is given the turn of the anchor before it: an object tipped onto a
    corner is tilted, and the vertical-axis part of its rotation against the (untilted)
    predicted pose is the skill's own twist as much as any error (a tumble that twists
    while it tips), which re-anchoring would add to the reference a second time."""
    idx = _element_vertices(poly, element) if element is not None else []
    a = predicted.to_world(poly.vertices[idx])[:, :2] if idx else predicted.com[None, :2]
    b = observed.to_world(poly.vertices[idx])[:, :2] if idx else observed.com[None, :2]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    if len(a) >= 2:
        h = (a - ca).T @ (b - cb)
        yaw = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    elif yaw is not None:
        pass
    else:
        rel = observed.rotation @ predicted.rotation.T
        yaw = math.atan2(rel[1, 0] - rel[0, 1], rel[0, 0] + rel[1, 1])
    return PlanarTransform(yaw, (float(ca[0]), float(ca[1])),
                           (float(cb[0] - ca[0]), float(cb[1] - ca[1])))


# --------------------------------------------------------------------------- step specs
@dataclass(frozen=True)
class ArcSpec:
    """One arc of a step as the controller runs it.

    Attributes
    ----------
    source, target : str
        Event ids.
    positions : array, shape (n_frames, n_used, 3)
        The arc's reference (world, at the plan's predicted poses), fingers ``used`` of the
        step, sampled at the step's rate.
    anchor : ObjectElement or None
        The ground element of the source event (what the arc is anchored on).
    anchor_end : bool
        Whether that element is predicted at the step's end pose (else its start pose).
    seeks : bool
        The target event adds a finger contact: an approach, which seeks it past its end.
    tips : bool
        The target event has the object on another ground element: the arc should tip it.
    releases : bool
        The target event has fewer finger contacts: past its end the arc lets go by
        moving the fingertips straight up.
    min_progress : float
        Share of the arc's reference that must have run before its end event counts. A
        skill run backwards (``NAME:reverse``) makes each contact at the start of the arc
        that, forwards, ended with it (a reversed twist grips first and then turns): its
        events count near the end of their arcs only (0.9); forwards, whenever seen (0).
    directions : array, shape (n_frames, n_used, 3), or None
        The recorded finger directions along the reference (unit, knuckle to tip, world at
        the plan's predicted poses: :func:`~nonprehensile.step_paths.step_directions`),
        frame by frame with ``positions``; zero rows for a used finger whose knuckle marker
        is not in the references; None when no used finger's is (or the arc's positions are
        not the reference's: :func:`top_roll`).
    """

    source: str
    target: str
    positions: FloatArray
    anchor: ObjectElement | None
    anchor_end: bool
    seeks: bool
    tips: bool
    releases: bool = False
    min_progress: float = 0.0
    directions: FloatArray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.directions is not None and np.shape(self.directions) != np.shape(
                self.positions):
            raise InputError(f"arc {self.source}->{self.target}: its directions (shape "
                             f"{np.shape(self.directions)}) must be frame by frame with its "
                             f"positions (shape {np.shape(self.positions)}); pass "
                             f"directions=None with positions that are not the reference's")


@dataclass(frozen=True)
class StepSpec:
    """A plan step prepared for the controller (:func:`step_spec`)."""

    step: PlanStep
    used: tuple[int, ...]
    rate: float
    arcs: tuple[ArcSpec, ...]
    events: tuple[Pairs, ...]
    event_ids: tuple[str, ...]
    grounds: tuple[ObjectElement | None, ...]
    start_pose: ObjectPose
    end_pose: ObjectPose
    targets: Mapping[int, FloatArray] = field(repr=False)
    event_times: tuple[float, ...] = ()

    @property
    def end_state(self) -> State:
        """The predicted final state (world)."""
        return self.step.end_world

    @property
    def skill(self) -> str:
        """The step's skill name."""
        return self.step.transition.skill.name

    @property
    def source_skill(self) -> str:
        """The demonstrated skill behind the step (a reverse shares its name)."""
        return self.step.transition.source.name.removesuffix(":reverse")


def _norm_pairs(event: ContactEvent, poly: Polyhedron) -> Pairs:
    try:
        return normalize_event(event, poly).pairs
    except ContactError:
        return event.pairs


def _ground_of(pairs: Pairs) -> ObjectElement | None:
    for p in pairs:
        if isinstance(p.x, Ground) and not isinstance(p.y, (Ground, Finger)):
            return p.y
        if isinstance(p.y, Ground) and not isinstance(p.x, (Ground, Finger)):
            return p.x
    return None


def _pair_names(pairs: Pairs | None) -> list[str]:
    """The observed pairs in canonical order as text; none when the object is seen touching
    nothing (airborne after a push, or tracked above the table): an event needs a pair, a
    log line does not."""
    return [str(p) for p in ContactEvent("", pairs).ordered_pairs] if pairs else []


def _fingers_in(pairs: Pairs) -> set[int]:
    return {el.index for p in pairs for el in (p.x, p.y) if isinstance(el, Finger)}


def step_spec(poly: Polyhedron, step: PlanStep, fingers: Mapping[str, str],
              smooth: int = 9) -> StepSpec:
    """Prepare a plan step: its filtered reference split back into arcs, each arc's anchor
    element, and what each arc should do (seek a contact, tip the object).

    Raises
    ------
    InputError
        A step without poses or reference motions.
    """
    if step.start_pose is None or step.end_pose is None:
        raise InputError("the step carries no object pose: make it with plan() or step_for()")
    skill = step.transition.skill
    targets, rate, times = step_targets(step, fingers, smooth)
    used = tuple(fingers_of(skill))
    stacked = np.stack([targets[k] for k in used], axis=1)
    dirs = step_directions(step, fingers, smooth)
    # a finger without a knuckle marker gets zero rows: no direction, the IK's rule
    stacked_dirs = (np.stack([dirs.get(k, np.zeros((len(stacked), 3))) for k in used],
                             axis=1) if any(k in dirs for k in used) else None)
    events = tuple(_norm_pairs(e, poly) for e in skill.events)
    grounds = tuple(_ground_of(e) for e in events)
    start_face, end_face = Face(step.transition.start.face), Face(step.transition.end.face)
    # which predicted pose each event's ground element is read at: the start pose until the
    # object has left its start face (an edge or vertex pivot stays where it was), the end
    # pose once it rests on its end face (or, for a turn on one face, at the last event)
    at_end = []
    moved = False
    for i, g in enumerate(grounds):
        if isinstance(g, (Edge, Vertex)):
            moved = True
            at_end.append(False)
        elif g == end_face and (moved or g != start_face or i == len(grounds) - 1):
            at_end.append(True)
        else:
            at_end.append(False)
    frames = [round(t * rate) for t in times]
    n_ref = len(stacked)
    stacked = with_stop(stacked, rate)  # the last arc comes to rest
    targets = {k: stacked[:, j] for j, k in enumerate(used)}
    arcs = []
    for i, (source, target, _, _) in enumerate(step.motions):
        a = frames[i]
        b = min(frames[i + 1], n_ref - 1) if i < len(step.motions) - 1 else len(stacked) - 1
        src, tgt = events[i], events[i + 1]
        # an arc cut at its event is still moving: should the event come late, the
        # fingertip comes to rest along its way rather than stopping dead
        piece = np.asarray(stacked[a:b + 1])
        if i < len(step.motions) - 1:
            piece = with_stop(piece, rate)
        piece_dirs = None
        if stacked_dirs is not None:  # the direction held while the arc comes to rest
            piece_dirs = stacked_dirs[a:min(b, len(stacked_dirs) - 1) + 1]
            piece_dirs = np.concatenate([piece_dirs, np.repeat(
                piece_dirs[-1:], len(piece) - len(piece_dirs), axis=0)])
        arcs.append(ArcSpec(
            source, target, piece, grounds[i], at_end[i],
            seeks=bool(_fingers_in(tgt) - _fingers_in(src)),
            tips=grounds[i + 1] is not None and grounds[i + 1] != grounds[i],
            releases=bool(_fingers_in(src) - _fingers_in(tgt)),
            min_progress=0.9 if step.transition.source.name.endswith(":reverse") else 0.0,
            directions=piece_dirs,
        ))
    return StepSpec(step, used, rate, tuple(arcs), events, tuple(e.id for e in skill.events),
                    grounds, step.start_pose, step.end_pose, targets, tuple(times))


def _touched_face(spec: StepSpec) -> str | None:
    """The face the step's single finger touches first (None if none)."""
    return next((el.id for ev in spec.events for q in ev for el in (q.x, q.y)
                 if isinstance(el, Face) and any(isinstance(o, Finger) for o in (q.x, q.y))),
                None)


def raised(spec: StepSpec, poly: Polyhedron, finger_radius: float) -> StepSpec:
    """The step with a single finger's contact moved up its face (another contact point on
    the same face). Pushed higher, a tipping push needs less table friction: with a push at
    height ``h`` on a cube of width ``w`` whose pad lifts the face by friction ``mu_f``, it
    tips before sliding when the table's friction exceeds ``(w / 2) / (h + mu_f w / 2)``.

    * A vertical face: every arc's reference raised so that the fingertip touches
      ``finger_radius + 2 mm`` below the object's top.
    * A face that leans back (its normal points up, as a hexagonal prism's upper side
      faces do): a round pad pushing it horizontally touches it ``finger_radius`` times the
      normal's height below its own centre, low on the face, and presses along the normal,
      partly down. The reference is moved up the face (along its steepest ascent, so also
      toward the object) until the contact is 4 mm below the face's top edge. For a
      hexagonal prism of side ``r`` rolled about a bottom edge by a push along the normal
      of the opposite upper face, the table friction needed falls from ``1 / sqrt(3)``
      (0.58) at the face's middle to ``(sqrt(3) / 2) / (5 / 2)`` (0.35) at its top edge.

    Skills of several fingers (a pinch) are left as they are.
    """
    if len(spec.used) != 1 or not spec.arcs:
        return spec
    touched = _touched_face(spec)
    if touched is None:
        return spec
    z_centre = float(spec.arcs[0].positions[-1, 0, 2])
    normal = spec.start_pose.rotation @ poly.normals[touched]
    if 0.05 < normal[2] < 0.95:  # leans back (not a top face): up the face
        up = np.array([0.0, 0.0, 1.0]) - normal[2] * normal
        up /= float(np.linalg.norm(up))
        edge_top = float(spec.start_pose.to_world(poly.vertices[list(poly.faces[touched])])[:, 2]
                         .max())
        z_contact = z_centre - finger_radius * float(normal[2])
        length = (edge_top - 0.004 * float(up[2]) - z_contact) / float(up[2])
        if length <= 0.0:
            return spec
        lift = length * up
    else:
        top = float(spec.start_pose.to_world(poly.vertices)[:, 2].max())
        dz = top - finger_radius - 0.002 - z_centre
        if dz <= 0.0:
            return spec
        lift = np.array([0.0, 0.0, dz])
    arcs = tuple(replace(a, positions=a.positions + lift) for a in spec.arcs)
    return replace(spec, arcs=arcs, targets={k: v + lift for k, v in spec.targets.items()})


def top_roll(spec: StepSpec, poly: Polyhedron, finger_radius: float, *,
             inset: float = 0.005, press: float = 0.006, standoff: float = 0.006,
             approach_speed: float = 0.03, drag: float = 0.03, drag_speed: float = 0.03,
             roll_deg: float = 40.0, roll_speed: float = 60.0, lift: float = 0.02
             ) -> StepSpec:
    """A one-finger roll about a bottom edge done from the top face (a hexagonal prism's
    push-roll): the pad presses the top face down near the edge above the pivot and drags
    it toward the pivot side, then turns with it about the pivot edge and lets go.

    Why not the recorded push on the face that leans back: its approach comes in at about
    0.2 m/s and kicks a light prism away; a round pad pressing a face that leans back 30
    degrees rides up it and pulls it down by friction; and with the pad's set-point noise
    (about 1 mm, as stiff as the finger: 0.6-3 N) against the 0.1-0.8 N that tips a
    0.03-0.26 kg prism, the force's direction is mostly noise; the object slides on any
    table below about 0.5 (measured). Pressed down near the edge above the pivot (``inset`` from
    it) with a normal force ``N`` and dragged by the pad's friction ``F <= mu_f N``, a
    prism of side ``r`` (centre of mass ``r / 2`` from the pivot, top ``sqrt(3) r`` high)
    tips when ``F sqrt(3) r >= m g r / 2 + N inset`` while the table holds
    ``F <= mu_t (m g + N)``: the press adds to the table's grip instead of taking from it,
    so it tips for ``mu_t`` down to about 0.2 with ``mu_f >= 0.5`` (see docs/physics.md),
    and a press of several millimetres (``press``, several newtons) is far above the
    noise.

    1. **approach**: straight down onto the top face from ``standoff`` above, at
       ``approach_speed``, at ``inset`` from the top face's edge on the pivot side;
    2. **push**: ``press`` down into the face, then ``drag`` horizontally toward the pivot
       side at ``drag_speed``, until the object is seen pivoting;
    3. **roll**: the touching point turned about the predicted pivot edge (a rigid roll
       carries it on a circle) by ``roll_deg`` (past the balance point: 30 degrees for a
       hexagonal prism) at ``roll_speed`` degrees/s, pressed by ``press`` down and toward
       the pivot side in the world (along the face's turned normal the press would push
       the object back, and its pivot slides); the object falls onto its landing face;
    4. **retreat**: straight up by ``lift``.

    The step's events name the top face instead of the pushed one. Several fingers, faces
    that do not lean back, objects without a horizontal top face or a pivot edge: returned
    as they are.
    """
    if len(spec.used) != 1 or len(spec.arcs) != 4 or not spec.arcs[1].tips:
        return spec
    touched = _touched_face(spec)
    pivot = spec.grounds[2] if len(spec.grounds) > 2 else None
    if touched is None or not isinstance(pivot, Edge):
        return spec
    pose = spec.start_pose
    n = pose.rotation @ poly.normals[touched]
    top = next((f for f in poly.face_ids if (pose.rotation @ poly.normals[f])[2] > 0.99),
               None)
    if not 0.05 < n[2] < 0.95 or top is None:
        return spec
    rate = spec.rate
    ends = pose.to_world(poly.vertices[_element_vertices(poly, pivot)])
    mid = ends.mean(axis=0)
    axis = ends[1] - ends[0]
    axis /= float(np.linalg.norm(axis))
    toward = mid - pose.com  # horizontal, across the pivot edge
    toward[2] = 0.0
    toward -= float(toward @ axis) * axis
    toward /= float(np.linalg.norm(toward))
    face_w = pose.to_world(poly.vertices[list(poly.faces[top])])
    centre = face_w.mean(axis=0)
    reach = float((face_w[:, :2] @ toward[:2]).max() - centre[:2] @ toward[:2])
    c = centre + (reach - inset) * toward
    c[2] = float(face_w[:, 2].max()) + finger_radius
    down = np.array([0.0, 0.0, -1.0])

    def line(p0: FloatArray, p1: FloatArray, speed: float) -> FloatArray:
        k = max(2, math.ceil(float(np.linalg.norm(p1 - p0)) / speed * rate) + 1)
        s = np.linspace(0.0, 1.0, k)[:, None]
        return np.asarray(p0[None] + s * (p1 - p0)[None])[:, None, :]

    pressed = c + press * down
    approach = with_stop(line(c - standoff * down, c, approach_speed), rate)
    push = with_stop(np.concatenate([line(c, pressed, approach_speed),
                                     line(pressed, pressed + drag * toward,
                                          drag_speed)[1:]]), rate)
    landing = pose.rotation @ poly.normals[spec.step.transition.end.face]
    if np.cross(axis, landing)[2] > 0.0:  # turn so that the landing face goes down
        axis = -axis
    angle = math.radians(roll_deg)
    k = max(2, math.ceil(roll_deg / roll_speed * rate) + 1)
    s = ease(np.linspace(0.0, 1.0, k))
    # the contact point turned about the pivot, pressed down and toward the pivot side in
    # the world: pressed along the face's turned normal instead, the pad would push the
    # object back (the turned press points away from the pivot) and the pivot slides
    rel = c - mid
    lead = press * (down + toward) / math.sqrt(2.0)
    roll = with_stop((_turned_about(axis, angle, s, rel) + mid + lead)[:, None, :], rate)
    end = roll[-1, 0]
    retreat = with_stop(line(end, end - lift * down, 2.0 * approach_speed), rate)
    # (made-up motions: the recorded fingers' directions belong to the push they replace)
    arcs = (replace(spec.arcs[0], positions=approach, directions=None),
            replace(spec.arcs[1], positions=push, directions=None),
            replace(spec.arcs[2], positions=roll, directions=None),
            replace(spec.arcs[3], positions=retreat, directions=None))

    def on_top(event: Pairs) -> Pairs:
        out = set()
        for q in event:
            if Face(touched) in (q.x, q.y) and (isinstance(q.x, Finger)
                                                or isinstance(q.y, Finger)):
                finger = q.x if isinstance(q.x, Finger) else q.y
                out.add(ContactPair(finger, Face(top)))
            else:
                out.add(q)
        return frozenset(out)

    (k1,) = spec.used
    return replace(spec, arcs=arcs, events=tuple(on_top(e) for e in spec.events),
                   targets={k1: np.concatenate([a.positions[:, 0] for a in arcs])})


def one_finger_push(spec: StepSpec, poly: Polyhedron, finger_radius: float, *,
                    higher: bool = False) -> StepSpec:
    """The step as the closed loop runs it: a roll whose pushed face leans back done from
    the top (:func:`top_roll`; a retry presses 2 mm deeper); otherwise, on a retry, the
    contact raised on its face (:func:`raised`)."""
    rolled = top_roll(spec, poly, finger_radius, press=0.008 if higher else 0.006)
    if rolled is not spec:
        return rolled
    return raised(spec, poly, finger_radius) if higher else spec


# ----------------------------------------------------------------------- the step monitor
@dataclass(frozen=True)
class Decision:
    """What the controller asks after an observation.

    Attributes
    ----------
    segment : array, shape (n, n_fingers, 3) or None
        New fingertip targets from now, one per physics step (the last is held); None keeps
        the current ones.
    done : bool
        The step is over (``outcome`` says how).
    outcome : {"", "finished", "aborted"}
    reason : str
    fade : float, optional
        How long (s) to fade from the running targets into the new ones (default the
        executor's); a release fades fast, so that the turn stops.
    """

    segment: FloatArray | None = None
    done: bool = False
    outcome: Literal["", "finished", "aborted"] = ""
    reason: str = ""
    fade: float | None = None


#: "Go on" (no new targets, not done): one frozen value serves every observation that
#: changes nothing, instead of building an equal one each time (``Decision()``).
GO_ON = Decision()


class StepMonitor:
    """The event-driven execution of one plan step.

    Call :meth:`begin` with the first observation, then :meth:`update` with every new
    one; each returns a :class:`Decision`. :attr:`log` keeps every observed event, anchor
    and anomaly (JSON-ready).

    Parameters
    ----------
    poly : Polyhedron
    spec : StepSpec
    config : ControlConfig
    dt : float
        Period of the targets the monitor returns (the physics step), s.
    finger_radius : float
        m, for reading finger contacts.
    rest : array, shape (n_fingers, 3)
        Where every finger of the scene waits when the step does not use it.
    noise : float
        The observations' position noise (m): widens the stillness test.
    """

    def __init__(self, poly: Polyhedron, spec: StepSpec, config: ControlConfig, *,
                 dt: float, finger_radius: float, rest: FloatArray,
                 noise: float = 0.0) -> None:
        self.poly = poly
        self.spec = spec
        self.cfg = config
        self.dt = dt
        self.radius = finger_radius
        self.rest = np.asarray(rest, dtype=np.float64)
        self.noise = noise
        self.log: list[dict[str, Any]] = []
        self.arc = 0
        self.phase: Literal["run", "seek", "settle", "over"] = "run"
        self._t0 = 0.0  # the step's start (controller time)
        self._arc_t0 = 0.0
        self._arc_com = np.zeros(2)
        self._candidate: Pairs | None = None
        self._since = 0.0
        self.current: Pairs | None = None
        self._pivoted = False
        self._odd: tuple[str, float] | None = None  # an unexpected contact, and since when
        self._released = False  # a turn in place let go once its angle was reached
        self._settle_t0 = 0.0
        self._window: list[tuple[float, FloatArray, FloatArray]] = []
        self.final_pose: ObjectPose | None = None
        self.final_state: State | None = None
        self._planes = (np.array([poly.normals[f] for f in poly.face_ids]),
                        np.array([poly.normals[f] @ poly.vertices[poly.faces[f][0]]
                                  for f in poly.face_ids]))
        self._pair_cache: PairCache = {}  # contact pairs seen by this step (observation.py)
        self._seek_dir = np.zeros((len(spec.used), 3))
        self._yaw: float | None = None  # the last anchor's turn (radians)
        self._followed = 0.0  # how long (s) the current arc's follow-through runs
        # the running arc's recorded finger directions, anchored as its reference, and the
        # controller time of its first frame (:meth:`pointing`)
        self._dirs: FloatArray | None = None
        self._dirs_t0 = 0.0

    # ---------------------------------------------------------------------------- helpers
    def _full(self, used_path: FloatArray) -> FloatArray:
        """Targets of every finger: the used ones along ``used_path``, the others at rest."""
        n = len(used_path)
        out = np.repeat(self.rest[None], n, axis=0)
        for j, k in enumerate(self.spec.used):
            out[:, k - 1] = used_path[:, j]
        return out

    def _arc_segment(self, obs: Observation, command: FloatArray) -> FloatArray:
        """The current arc's reference anchored on the observed pose, blended from the
        commanded point, at the physics step."""
        arc = self.spec.arcs[self.arc]
        predicted = self.spec.end_pose if arc.anchor_end else self.spec.start_pose
        # a corner pivot keeps the turn of the last anchor (see anchor_transform)
        keep = self._yaw if isinstance(arc.anchor, Vertex) else None
        tf = anchor_transform(self.poly, arc.anchor, predicted, obs.pose, yaw=keep)
        self._yaw = tf.yaw
        ref = tf.apply(arc.positions)
        now = np.asarray(command, dtype=np.float64)[[k - 1 for k in self.spec.used]]
        gap = now - ref[0]
        n = len(ref)
        # the blend must respect the speed bound: stretched over enough frames
        need = 2.0 * float(np.linalg.norm(gap, axis=1).max()) / self.cfg.max_speed
        m = max(n, math.ceil(need * self.spec.rate) + 1)
        if m > n:  # a long gap: hold the first reference frame longer while blending in
            ref = np.concatenate([np.repeat(ref[:1], m - n, axis=0), ref])
        w = 1.0 - ease(np.linspace(0.0, 1.0, len(ref)))
        path = ref + w[:, None, None] * gap[None]
        if arc.directions is not None:  # turned as the reference is (about the vertical)
            dirs = tf.turn(arc.directions)
            if m > n:
                dirs = np.concatenate([np.repeat(dirs[:1], m - n, axis=0), dirs])
            self._dirs, self._dirs_t0 = dirs, obs.time
        else:
            self._dirs = None
        if len(path) >= 2:
            self._seek_dir = path[-1] - path[-2]
        self.log.append({"time": round(obs.time - self._t0, 4), "anchor": arc.source,
                         "arc": f"{arc.source}->{arc.target}", **tf.to_dict()})
        return self._full(resample(path, self.spec.rate, self.dt))

    def pointing(self, time: float) -> FloatArray | None:
        """The recorded finger directions where the running arc's reference is.

        A robot's IK points its finger tools along them
        (:class:`~nonprehensile.sim.robot_run.RobotSimulator`'s ``finger_direction``). The
        frame is the reference's at ``time`` by the clock of the arc's start, as the
        segment runs at its own rate: a segment that the runner slows down to its speed
        bound (``limit_speed``; the bundled references stay under it) runs behind them.

        Parameters
        ----------
        time : float
            Controller time, s (an observation's ``time``).

        Returns
        -------
        ndarray, shape (n_fingers, 3), or None
            Unit vectors (world; zero rows for fingers the step does not use or that have
            no knuckle marker), the arc's last past its end; None when the arc carries no
            directions, and from a let-go or follow-through on (the IK's own rule).
        """
        dirs = self._dirs
        if dirs is None:
            return None
        i = min(max(round((time - self._dirs_t0) * self.spec.rate), 0), len(dirs) - 1)
        out = np.zeros((len(self.rest), 3))
        for j, k in enumerate(self.spec.used):
            out[k - 1] = dirs[i, j]
        return out

    def _abort(self, obs: Observation, reason: str) -> Decision:
        self.phase = "over"
        self.log.append({"time": round(obs.time - self._t0, 4), "anomaly": reason})
        return Decision(done=True, outcome="aborted", reason=reason)

    @property
    def expected_duration(self) -> float:
        """The reference's length (s)."""
        return sum((len(a.positions) - 1) / self.spec.rate for a in self.spec.arcs)

    # ------------------------------------------------------------------------------- api
    def begin(self, obs: Observation, command: FloatArray) -> Decision:
        """Start the step's first arc from the observation ``obs``; ``command`` is where the
        fingertips are being held (shape (n_fingers, 3))."""
        self._t0 = self._arc_t0 = obs.time
        self._arc_com = obs.pose.com[:2].copy()
        # what the object shows now is the step's first event (at rest): a later event with
        # the same contacts (a turn in place ends as it began, (G,a)) must be seen anew
        self.current = self._candidate = observed_contacts(
            self.poly, obs, finger_radius=self.radius, tol=self.cfg.contact_tol,
            ground_tol=self.cfg.ground_tol, planes=self._planes, cache=self._pair_cache)
        self._since = obs.time
        self.log.append({"time": 0.0, "contacts": _pair_names(self.current),
            **({"event": self.spec.event_ids[0]} if self.current == self.spec.events[0]
               else {})})
        return Decision(segment=self._arc_segment(obs, command))

    def update(self, obs: Observation, command: FloatArray) -> Decision:
        """React to a new observation (``command``: the fingertips' current targets)."""
        if self.phase == "over":
            return Decision(done=True)
        pairs = observed_contacts(self.poly, obs, finger_radius=self.radius,
                                  tol=self.cfg.contact_tol, ground_tol=self.cfg.ground_tol,
                                  planes=self._planes, cache=self._pair_cache)
        if pairs != self._candidate:
            self._candidate, self._since = pairs, obs.time
        if self.phase == "settle":
            return self._settle(obs)
        turned = self._turned_enough(obs, command)
        if turned is not None:
            return turned
        new = (self._candidate != self.current
               and obs.time - self._since >= self.cfg.confirm - 1e-9)
        if new:
            assert self._candidate is not None
            self.current = self._candidate
            got = self._on_event(obs, self.current, command)
            if got is not None:
                return got
        if self._odd is not None and self.phase in ("run", "seek") \
                and obs.time - self._odd[1] >= self.cfg.anomaly_time:
            return self._abort(obs, self._odd[0])
        ground = _ground_of(self.current) if self.current is not None else None
        arc = self.spec.arcs[self.arc]
        if arc.tips and ground is not None and ground == self.spec.grounds[self.arc] \
                and isinstance(ground, Face) and not self._pivoted \
                and _slid_beyond(obs.pose.com, self._arc_com, self.cfg.slide_tol):
            slid = float(np.hypot(*(obs.pose.com[:2] - self._arc_com)))
            return self._abort(obs, f"slides instead of tipping: moved "
                                    f"{1000 * slid:.1f} mm on face {ground} during "
                                    f"{arc.source}->{arc.target}")
        elapsed = obs.time - self._arc_t0
        length = (len(arc.positions) - 1) / self.spec.rate
        if self.phase == "run" and elapsed > length and arc.tips:
            follow = self._follow_through(obs, command)
            if follow is not None:
                return follow
        # a single finger's push that has not tipped the object yet pushes on, slowly
        pushes = arc.tips and len(self.spec.used) == 1 and not self._pivoted \
            and isinstance(ground, Face)
        if self.phase == "run" and elapsed > length and (arc.seeks or arc.releases or pushes):
            self.phase = "seek"
            step = self._seek_dir
            if arc.releases:  # let go: straight up, away from the object
                step = np.tile([0.0, 0.0, 1.0], (len(self.spec.used), 1))
                self._dirs = None  # (a let-go: the IK's own rule)
            norm = float(np.linalg.norm(step, axis=1).max())
            if norm > 1e-9:
                direction = step / norm
                t_seek = self.cfg.reach / self.cfg.reach_speed
                s = np.arange(round(t_seek / self.dt) + 1) * self.dt * self.cfg.reach_speed
                start = np.asarray(command, dtype=np.float64)[[k - 1 for k in self.spec.used]]
                path = start[None] + s[:, None, None] * direction[None]
                return Decision(segment=self._full(path))
        limit = length + self.cfg.grace + (
            self.cfg.reach / self.cfg.reach_speed if arc.seeks or arc.releases or pushes
            else 0.0) + (
            self._followed if arc.tips else 0.0)
        if elapsed > limit:
            seen = " ∧ ".join(_pair_names(self.current)) or "nothing"
            return self._abort(obs, f"event {arc.target!r} not observed within "
                                    f"{limit:.2f} s of {arc.source!r} (observed {seen})")
        return GO_ON

    def _follow_through(self, obs: Observation, command: FloatArray) -> Decision | None:
        """A tipping arc whose reference is over while the object still pivots on an edge
        or corner of its landing face (a compliant or slipping pinch lags the recorded
        turn, a light push leaves the object short of its balance point): the fingers go
        on turning about the observed pivot, toward the landing face, by at most
        ``config.follow_deg`` at ``config.follow_speed``, so that the object goes over
        instead of falling back. Once per arc; None when it does not apply."""
        if self._followed > 0.0 or self.cfg.follow_deg <= 0.0:
            return None
        landing = self.spec.grounds[self.arc + 1] if self.arc + 1 < len(self.spec.grounds) \
            else None
        ground = _ground_of(self.current) if self.current is not None else None
        if not isinstance(landing, Face) or not isinstance(ground, (Edge, Vertex)) \
                or landing.id not in ground.faces:
            return None
        pts = obs.pose.to_world(self.poly.vertices[_element_vertices(self.poly, ground)])
        pivot = pts.mean(axis=0)
        normal = obs.pose.rotation @ self.poly.normals[landing.id]
        if isinstance(ground, Edge):
            axis = pts[1] - pts[0]
        else:  # about the horizontal across the landing face's fall line
            axis = np.cross([0.0, 0.0, 1.0], [normal[0], normal[1], 0.0])
        norm = float(np.linalg.norm(axis))
        if norm < 1e-9:
            return None
        axis = axis / norm
        if np.cross(axis, normal)[2] > 0.0:  # turn so that the landing face goes down
            axis = -axis
        angle = math.radians(self.cfg.follow_deg)
        duration = angle / math.radians(self.cfg.follow_speed)
        n = max(2, round(duration / self.dt))
        used = [k - 1 for k in self.spec.used]
        start = np.asarray(command, dtype=np.float64)[used] - pivot
        s = ease(np.linspace(0.0, 1.0, n))
        path = _turned_about(axis, angle, s, start) + pivot
        deg = self.cfg.follow_deg
        bound = self.cfg.follow_depth
        if bound is not None:
            # a stiff finger follows its command: turned on into an object that does not
            # turn, it presses the object onto its pivot with the arm's whole servo force
            # (measured: a 0.4 kg cube balanced on an edge, the tip on its top face, the
            # command 33 mm inside it)
            # (the pads' depth: the radius less the centres' signed distance, the
            # deepest finger's at each frame)
            depth = (self.radius - hull_distance(self.poly, obs.pose, path)).max(axis=-1)
            deep = depth > bound + 1e-12
            if deep.any():
                keep = max(int(np.argmax(deep)), 2)  # the path up to its first deep frame
                deg = self.cfg.follow_deg * float(s[keep - 1])
                path = path[:keep]
        self._followed = duration
        self._dirs = None  # a turn the recording does not have: the IK's own rule
        self.log.append({"time": round(obs.time - self._t0, 4), "follow_through": str(ground),
                         "deg": round(deg, 3)})
        return Decision(segment=self._full(path))

    def _turned_enough(self, obs: Observation, command: FloatArray) -> Decision | None:
        """A turn in place (start and end on the same face) watched by its angle: once the
        observed ``theta`` reaches the predicted one (within 0.5 degrees, or past it), the
        fingers let go (away from the object, then up) instead of turning it further; the
        step then ends on its last event, as it would have."""
        spec = self.spec
        start, end = spec.step.transition.start, spec.step.transition.end
        if start.face != end.face or self.phase != "run" or self.arc == 0 \
                or self._released:
            return None
        st = observed_state(self.poly, obs.pose.rotation)
        if st is None or st.face != spec.end_state.face:
            return None
        want = angle_diff(spec.end_state.theta, spec.step.start_world.theta)
        left = angle_diff(spec.end_state.theta, st.theta)
        if abs(left) > 0.5 and left * want > 0:
            return None
        self._released = True
        self._dirs = None  # a let-go: the IK's own rule
        self.log.append({"time": round(obs.time - self._t0, 4),
                         "turned": round(float(angle_diff(st.theta,
                                                          spec.step.start_world.theta)), 3),
                         "release": "theta reached"})
        # from where the pads are, not where they are commanded: a compliant pinch lags its
        # targets, and going back to them would turn the object on
        now = np.asarray(obs.tips, dtype=np.float64)[[k - 1 for k in spec.used]]
        off = now.copy()
        for j in range(len(off)):
            away = off[j, :2] - obs.pose.com[:2]
            norm = float(np.hypot(*away))
            if norm > 1e-9:
                off[j, :2] += away / norm * (self.radius + 0.01)
        up = off.copy()
        up[:, 2] += self.radius + self.cfg.clearance
        n1 = max(2, round(0.15 / self.dt))
        s1 = ease(np.linspace(0.0, 1.0, n1))[:, None, None]
        path = np.concatenate([now[None] + s1 * (off - now)[None],
                               off[None] + s1 * (up - off)[None]])
        # the last arc's end event (no finger on the object) is what is waited for now
        self.arc = len(spec.arcs) - 1
        self._arc_t0 = obs.time
        return Decision(segment=self._full(path), fade=0.04)

    def _on_event(self, obs: Observation, pairs: Pairs, command: FloatArray
                  ) -> Decision | None:
        spec = self.spec
        t = round(self._since - self._t0, 4)
        ahead = range(self.arc + 1, len(spec.events))
        j = next((j for j in ahead if spec.events[j] == pairs), None)

        arc = spec.arcs[self.arc]
        if j is not None and arc.min_progress > 0 and self.phase == "run":
            ran = (obs.time - self._arc_t0) * spec.rate / max(len(arc.positions) - 1, 1)
            if ran < arc.min_progress:
                # too early to count; looked at again at the next observation
                self.current = None
                return None
        entry: dict[str, Any] = {
            "time": t, "contacts": _pair_names(pairs)}
        if j is not None:
            entry["event"] = spec.event_ids[j]
        entry["moved_mm"] = round(1000 * float(np.hypot(*(obs.pose.com[:2]
                                                          - self._arc_com))), 2)
        self.log.append(entry)
        ground = _ground_of(pairs)
        if isinstance(ground, (Edge, Vertex)):
            self._pivoted = True
        if j is not None:
            self._odd = None
            if j == len(spec.events) - 1:  # the last event: the motion is over
                self.phase = "settle"
                self._settle_t0 = obs.time
                self._window = []
                return None
            self.arc = j
            self.phase = "run"
            self._followed = 0.0
            self._arc_t0 = obs.time
            self._arc_com = obs.pose.com[:2].copy()
            # blend from the commanded points, not the observed tips: a compliant pad in
            # contact is commanded inside the object, and that press must not be let go
            return Decision(segment=self._arc_segment(obs, command))
        # not an event ahead: is it something the skill does not expect? (it must last
        # ``anomaly_time`` to abort the step)
        odd = None
        if ground is None:
            pass
        elif self._pivoted and ground == spec.grounds[0] and isinstance(
                spec.grounds[self.arc], (Edge, Vertex)):
            odd = f"fell back onto {ground} after pivoting"
        elif ground not in set(spec.grounds[self.arc:]):
            faces = {g.id for g in spec.grounds[self.arc:] if isinstance(g, Face)}
            # an edge or vertex of a face still to come is a wobble (a landing face's edge
            # touching first, a pad pressing a corner down): the state read at the end
            # catches a real roll-over; a face no event names is an anomaly
            if not (isinstance(ground, (Edge, Vertex)) and faces & set(ground.faces)):
                odd = (f"the object rests on {ground}, which no later event of "
                       f"{spec.skill!r} names (tipped too far or over)")
        if odd is None:
            self._odd = None
        elif self._odd is None or self._odd[0] != odd:
            self._odd = (odd, self._since)
        return None

    def watch_rest(self, now: float) -> None:
        """After an abort: watch the object come to rest and read its state (the next
        :meth:`update` calls finish the step once it is still)."""
        self.phase = "settle"
        self._settle_t0 = now
        self._window = []

    def _settle(self, obs: Observation) -> Decision:
        self._window.append((obs.time, obs.pose.com.copy(), obs.pose.rotation.copy()))
        horizon = obs.time - self.cfg.still_time
        while len(self._window) > 2 and self._window[1][0] <= horizon:
            self._window.pop(0)
        times = [w[0] for w in self._window]
        if times[-1] - times[0] >= self.cfg.still_time - 1e-9:
            coms = np.array([w[1] for w in self._window])
            spread = float(np.linalg.norm(coms - coms.mean(axis=0), axis=1).max())
            if spread <= self.cfg.still_tol + 3.0 * self.noise:
                return self._finish(obs, coms.mean(axis=0),
                                    [w[2] for w in self._window], settled=True)
        if obs.time - self._settle_t0 > self.cfg.max_settle:
            coms = np.array([w[1] for w in self._window])
            return self._finish(obs, coms.mean(axis=0), [w[2] for w in self._window],
                                settled=False)
        return GO_ON

    def _finish(self, obs: Observation, com: FloatArray, rots: Sequence[FloatArray],
                settled: bool) -> Decision:
        rot = Rotation.from_matrix(np.array(rots)).mean().as_matrix()
        s = obs.pose.scale
        trans = com - s * (rot @ self.poly.com)
        self.final_pose = ObjectPose(rot, trans, com, s)
        self.final_state = observed_state(self.poly, rot)
        self.phase = "over"
        self.log.append({"time": round(obs.time - self._t0, 4),
                         "observed_state": (self.final_state.to_dict()
                                            if self.final_state else None),
                         "observed_position": [round(float(v), 6) for v in com[:2]],
                         "settled": settled})
        return Decision(done=True, outcome="finished",
                        reason="" if settled else "the object did not come to rest")


def _slid_beyond(com: FloatArray, origin: FloatArray, tol: float) -> bool:
    """Whether ``np.hypot(*(com[:2] - origin))`` exceeds ``tol`` (m): in floats (the
    monitor asks at every observation, and numpy's call on two scalars costs more than the
    sum), by numpy when the distance is within 1e-9 of ``tol`` (``math.hypot`` and the C
    library's ``hypot`` may round the last place differently; the differences are exact
    in both)."""
    x0, x1 = com[:2].tolist()
    o0, o1 = origin[:2].tolist()
    d = math.hypot(x0 - o0, x1 - o1)
    if abs(d - tol) > 1e-9:  # (a NaN falls through to numpy)
        return d > tol
    return bool(float(np.hypot(*(com[:2] - origin))) > tol)


def observed_state(poly: Polyhedron, rotation: FloatArray, tilt_deg: float = 3.0
                   ) -> State | None:
    """The state an observed orientation rests in, or None (on an edge, or tilted)."""
    try:
        return state_of_pose(poly, rotation, tol=tilt_deg)
    except GeometryError:
        return None


# ------------------------------------------------------------------ after a step / a plan
@dataclass(frozen=True)
class NextAction:
    """What the executor does after a step.

    Attributes
    ----------
    action : {"next", "retry", "replan", "align", "done", "fail"}
        ``"align"``: turn the object onto ``target`` (same face), then go on as if the
        step had ended there (``done`` when ``target`` is the goal); a re-plan if the turn
        falls short.
    reason : str
    avoid : frozenset of str
        Skills (demonstrated names) the re-plan must avoid.
    slow : float
        A retry runs the step's reference this many times slower ...
    higher : bool
        ... and a single finger's contact higher on its face (:func:`raised`).
    target : State, optional
        The state an ``"align"`` turns the object onto.
    """

    action: Literal["next", "retry", "replan", "align", "done", "fail"]
    reason: str = ""
    avoid: frozenset[str] = frozenset()
    slow: float = 1.0
    higher: bool = False
    target: State | None = None


def snap_state(observed: State, candidates: Sequence[State], angle_tol: float) -> State:
    """The candidate on the observed face nearest in ``theta``, if within ``angle_tol``
    degrees (the plan's own states, so a re-plan keeps the plan's frame); else ``observed``.
    """
    near = [c for c in candidates if c.face == observed.face
            and abs(angle_diff(c.theta, observed.theta)) <= angle_tol]
    return min(near, key=lambda c: abs(angle_diff(c.theta, observed.theta))) \
        if near else observed


def same_state(a: State | None, b: State, angle_tol: float) -> bool:
    """Same bottom face, theta within ``angle_tol`` degrees."""
    return a is not None and a.face == b.face and abs(angle_diff(a.theta, b.theta)) <= angle_tol


def after_step(spec: StepSpec, monitor_reason: str, observed: State | None, goal: State,
               *, replans: int, avoid: frozenset[str], last: bool,
               config: ControlConfig, tries: int = 0) -> NextAction:
    """Decide what follows a step from the state the object was observed to rest in.

    * the predicted state: the next step (or, after the last, done);
    * the goal itself (reached early): done;
    * no resting state: fail;
    * the predicted face (or the goal's), turned by more than ``config.angle_tol`` but at
      most ``config.align_tol`` degrees: align (turn it onto the predicted state, or the
      goal, by pushes; then on);
    * still the step's start state (it slid, was kicked away, never tipped): the same step
      again, anchored anew, its single finger's contact higher on the face (:func:`raised`)
      and its reference ``config.slow_retry`` times slower (a higher, slower push), at most
      ``config.max_tries`` times in all; then a re-plan avoiding the skill;
    * another state: re-plan from it. Retries and re-plans together are at most
      ``config.max_replans``.
    """
    if config.align_tol is None:
        raise InputError("after_step needs a resolved align_tol, got None: pass "
                         "config.for_step(angular_step(states)) (execute_plan does)")
    if same_state(observed, goal, config.angle_tol):
        return NextAction("done")
    if same_state(observed, spec.end_state, config.angle_tol):
        return NextAction("done" if last else "next")
    if observed is None:
        return NextAction("fail", "the object came to rest on no face of the model")
    for target in (goal, spec.end_state):
        off = angle_diff(observed.theta, target.theta)
        if observed.face == target.face and abs(off) <= config.align_tol:
            return NextAction("align", f"ended in {observed}, {off:+.1f} deg off {target}",
                              avoid, target=target)
    if replans >= config.max_replans:
        return NextAction("fail", f"ended in {observed} instead of {spec.end_state} with "
                                  f"{replans} re-plans spent ({monitor_reason or 'no anomaly'})")
    start = spec.step.start_world
    # the object did not do what the skill is for: still on its start face (a turn in
    # place: still at its start theta); a small turn of it is put right before a re-plan
    stayed = observed.face == start.face and (
        start.face != spec.end_state.face
        or abs(angle_diff(observed.theta, start.theta)) <= config.angle_tol)
    why = f": {monitor_reason}" if monitor_reason else ""
    if stayed and tries + 1 < config.max_tries:
        return NextAction("retry", f"still in {observed}{why}",
                          avoid, config.slow_retry ** (tries + 1), higher=True)
    # a skill that left the object where it was (it slid, or never tipped), slower too, will
    # not do better on this table: the re-plan avoids it (another skill, or another route)
    name = spec.source_skill
    more = frozenset({name}) if stayed else frozenset()
    return NextAction("replan", f"ended in {observed} instead of {spec.end_state}"
                                + (f": {monitor_reason}" if monitor_reason else ""),
                      avoid | more)


@dataclass(frozen=True)
class Push:
    """One correction push: the fingertip moves from ``start`` along ``direction``
    (unit, horizontal) pressing the face ``face`` at height ``start[2]`` until the object
    has moved ``distance`` (m) that way."""

    face: str
    start: FloatArray
    direction: FloatArray
    distance: float

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"face": self.face, "start": [round(float(v), 6) for v in self.start],
                "direction": [round(float(v), 4) for v in self.direction],
                "distance_m": round(self.distance, 6)}


def correction_pushes(poly: Polyhedron, pose: ObjectPose, target: Sequence[float], *,
                      finger_radius: float, clearance: float, tol: float) -> list[Push]:
    """Pushes that slide the object's centre of mass onto ``target`` (x, y).

    Each side face whose outward normal is horizontal can be pushed low (at the fingertip's
    radius plus 2 mm, or a quarter of the object's height if higher), which slides the object
    along minus that normal without tipping it as long as ``friction * height < half width``
    (a 5 cm cube pushed 10 mm up tips only above friction 2.5). A face that leans back
    (its normal 0.1-0.7 up: a hexagonal prism lying on a side face shows no vertical face
    but its end caps) is pushed horizontally 2 mm above its lowest edge: the prism's upper
    side faces start at half its height, so pushed there (``z = sqrt(3) r / 2 + 2 mm``) it
    slides across before it tips while ``friction < (r / 2) / z`` (about 0.53 for the
    5 cm prism); the executor stops a push that tilts the object. The displacement is split
    over the one or two faces whose inward normals best span it (non-negative weights).
    """
    d = np.array([float(target[0]), float(target[1])]) - pose.com[:2]
    dist = float(np.hypot(*d))
    if dist <= tol:
        return []
    world = pose.to_world(poly.vertices)
    height = float(world[:, 2].max() - world[:, 2].min())
    side = []
    for f in poly.face_ids:
        n = pose.rotation @ poly.normals[f]
        if abs(n[2]) < 0.1 or 0.1 <= n[2] <= 0.7:
            side.append((f, n[:2] / float(np.hypot(*n[:2]))))
    best: tuple[float, list[tuple[str, FloatArray, float]]] | None = None
    for i, (fa, na) in enumerate(side):
        for fb, nb in [*side[i + 1:], (fa, na)]:
            m = np.column_stack([-na, -nb]) if fb != fa else -na[:, None]
            w, *_ = np.linalg.lstsq(m, d, rcond=None)
            if (w < -1e-9).any():
                continue
            resid = float(np.linalg.norm(m @ w - d))
            total = float(w.sum())
            key = resid + 1e-3 * total
            if best is None or key < best[0]:
                pushes = [(fa, na, float(w[0]))] + ([(fb, nb, float(w[1]))]
                                                     if fb != fa else [])
                best = (key, [p for p in pushes if p[2] > 1e-4])
    if best is None:
        return []
    out = []
    z = max(finger_radius + 0.002, 0.25 * height)
    for f, n, amount in best[1]:
        c = pose.to_world(poly.face_centroids[f][None])[0]
        n3 = pose.rotation @ poly.normals[f]
        if n3[2] >= 0.1:  # leans back: the pad on the face 2 mm above its lowest edge
            up = np.array([0.0, 0.0, 1.0]) - n3[2] * n3
            up /= float(np.linalg.norm(up))
            low = float(pose.to_world(poly.vertices[list(poly.faces[f])])[:, 2].min())
            q = c + (low + 0.002 - float(c[2])) / float(up[2]) * up
            centre = q + finger_radius * n3
            start = np.array([*(centre[:2] + clearance * n), centre[2]])
        else:
            face_dist = float(n @ (c[:2] - pose.com[:2]))
            xy = pose.com[:2] + n * (face_dist + finger_radius + clearance)
            start = np.array([xy[0], xy[1], z])
        out.append(Push(f, start, np.array([-n[0], -n[1], 0.0]), amount))
    return out


#: Cost given to a skill a re-plan must avoid (one transition costs 1): any route without it
#: wins, and the skill is used again only where nothing else reaches the goal.
AVOID_COST = 1000.0


class Replanner:
    """A re-planner for :func:`nonprehensile.sim.closed_loop.execute_plan`: from an
    observed state and position to ``goal`` (call it as ``replanner(observed, position,
    avoid)``).

    The states a plan can reach from a start are the model's states turned by the start's
    offset from them (a turn of the whole scene about the vertical changes no transition):
    a re-plan from an object that turned off that frame can never reach the goal's
    ``theta``. :attr:`frame` is the model's states turned into the goal's frame; the
    executor turns a turned object back onto the nearest of them on its face before it
    re-plans (:func:`snap_state`). The observed ``theta`` is snapped to the nearest state
    of :attr:`frame` on the same face when within ``angle_tol`` degrees (the step's
    reference is anchored on the observed pose anyway); skills to avoid cost
    :data:`AVOID_COST`.

    Attributes
    ----------
    frame : tuple of State
        The model's states in the goal's frame.
    """

    def __init__(self, poly: Polyhedron, expansion: Expansion, goal: State, *,
                 motions: MotionLibrary | None, scale: float,
                 costs: Mapping[str, float] | None = None,
                 angle_tol: float = 5.0) -> None:
        self.poly, self.expansion, self.goal = poly, expansion, goal
        self.motions, self.scale, self.costs = motions, scale, costs
        self.angle_tol = angle_tol
        states = list(expansion.graph.states)
        on_goal = [s for s in states if s.face == goal.face]
        offset = (angle_diff(goal.theta, min(
            on_goal, key=lambda s: abs(angle_diff(goal.theta, s.theta))).theta)
            if on_goal else 0.0)
        self.frame: tuple[State, ...] = tuple(
            State(s.face, (s.theta + offset) % 360.0) for s in states)

    def __call__(self, observed: State, position: tuple[float, float],
                 avoid: frozenset[str]) -> Plan:
        """A plan from ``observed`` at ``position`` (x, y) to the goal avoiding ``avoid``."""
        start = snap_state(observed, self.frame, self.angle_tol)
        c = dict(self.costs or {})
        c.update(dict.fromkeys(avoid, AVOID_COST))
        # (states matched as the expansion matched them: a model from a mesh needs its
        # wider tolerance in every re-plan too)
        return plan(self.poly, self.expansion, start, self.goal, position=position,
                    motions=self.motions, scale=self.scale, costs=c or None,
                    angle_tol=self.expansion.angle_tol)


def replanner(poly: Polyhedron, expansion: Expansion, goal: State, *,
              motions: MotionLibrary | None, scale: float,
              costs: Mapping[str, float] | None = None,
              angle_tol: float = 5.0) -> Replanner:
    """A :class:`Replanner` to ``goal`` (the same arguments)."""
    return Replanner(poly, expansion, goal, motions=motions, scale=scale, costs=costs,
                     angle_tol=angle_tol)


@dataclass(frozen=True)
class TurnPush:
    """A push off the centre-of-mass line that turns the object about the vertical: the
    fingertip presses face ``face`` at ``start`` (beside the face, ``offset`` m along it from
    the line through the centre of mass) moving along ``direction``; a push at an offset
    ``e`` along the face's tangent ``t = z x n`` turns the object by the torque ``F e``
    (counterclockwise seen from above for ``e > 0``)."""

    face: str
    start: FloatArray
    direction: FloatArray
    offset: float

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"face": self.face, "start": [round(float(v), 6) for v in self.start],
                "direction": [round(float(v), 4) for v in self.direction],
                "offset_m": round(self.offset, 5)}


def turn_push(poly: Polyhedron, pose: ObjectPose, turn_deg: float, toward: Sequence[float],
              *, finger_radius: float, clearance: float) -> TurnPush | None:
    """A push that turns the object by ``turn_deg`` (its sign: counterclockwise positive),
    on the side face whose push also moves the centre of mass most toward ``toward`` (x, y);
    None if the object shows no side face. The contact sits at half the face's half-width
    from the centre line, low on the face (as :func:`correction_pushes`)."""
    world = pose.to_world(poly.vertices)
    height = float(world[:, 2].max() - world[:, 2].min())
    goal = np.array([float(toward[0]), float(toward[1])]) - pose.com[:2]
    best: tuple[float, str, FloatArray] | None = None
    for f in poly.face_ids:
        n3 = pose.rotation @ poly.normals[f]
        if abs(n3[2]) >= 0.1:
            continue
        n = n3[:2] / float(np.hypot(*n3[:2]))
        score = float(-n @ goal)
        if best is None or score > best[0]:
            best = (score, f, n)
    if best is None:
        return None
    _, f, n = best
    t = np.array([-n[1], n[0]])
    pts = world[list(poly.faces[f])][:, :2] - pose.com[:2]
    along = pts @ t
    half = float(min(along.max(), -along.min()))
    e = math.copysign(max(0.0, 0.5 * half), turn_deg)
    face_dist = float(n @ (pts.mean(axis=0)))
    xy = pose.com[:2] + n * (face_dist + finger_radius + clearance) + t * e
    z = max(finger_radius + 0.002, 0.25 * height)
    return TurnPush(f, np.array([xy[0], xy[1], z]), np.array([-n[0], -n[1], 0.0]), e)


def push_finger(start: FloatArray | Sequence[float], direction: FloatArray | Sequence[float],
                origins: Sequence[Sequence[float]] | None) -> int:
    """The finger (1-based) that runs a correction push (:func:`correction_pushes`,
    :func:`turn_push`) from ``start`` along ``direction`` (horizontal): the one whose
    ``origins`` row (x, y: where the finger comes from, a robot arm's base) lies most behind
    the push, so that it reaches the face from its own side; finger 1 without origins (free
    fingertips) or with one.

    An arm behind the object reaches its far face over the object's top: with two arms
    whose bases stand on opposite sides of the cube, finger 1 ran every correction, and
    pushing the far side low it leaned its rod onto the cube's top edge (the two-arm
    tumble-twists, ``docs/benchmarks.md``).

    Parameters
    ----------
    start : array_like, shape (2,) or (3,)
        The push's start (the fingertip centre), m.
    direction : array_like, shape (2,) or (3,)
        The push's direction (its horizontal part is used).
    origins : sequence of (x, y) or (x, y, z), or None
        Each finger's origin, m, in finger order.

    Returns
    -------
    int
        The finger's number; ties go to the lower number, and a direction of no length (or
        NaN) gives finger 1.
    """
    if origins is None or len(origins) <= 1:
        return 1
    dx, dy = float(direction[0]), float(direction[1])
    n = math.hypot(dx, dy)
    if not n > 0.0:
        return 1
    dx, dy = dx / n, dy / n
    best, best_k = -math.inf, 1
    for k, o in enumerate(origins, start=1):
        # the cosine between the push and the way from the origin to the start: 1 for an
        # origin straight behind the push, -1 for one on the far side of the object (an
        # origin's height, if given, is not used)
        vx, vy = float(start[0]) - float(o[0]), float(start[1]) - float(o[1])
        m = math.hypot(vx, vy)
        score = (vx * dx + vy * dy) / m if m > 0.0 else -math.inf
        if score > best:  # (ties: the lower finger number)
            best, best_k = score, k
    return best_k
