"""Planning: from a task to an executable plan (paper Section VII).

Given an initial state and a goal state of the object:

1. if the initial state is not a state of the model (any orientation, any position on the
   table), find the offset (a rotation of the agent about the vertical, and a translation) that
   maps it onto a model state;
2. plan the transitions with Dijkstra's algorithm over the expanded state-transition graph
   (cost: one per transition, or a cost per skill such as duration; with measured success
   rates, :class:`RobustnessCosts`, each arc's cost grows with its failures and transitions
   below a threshold are avoided);
3. for each transition, the adapted skill: its contact events with mapped faces, edges and
   vertices;
4. for each motion arc, the reference finger trajectory (from a :class:`MotionLibrary`),
   expressed in the world frame after the offset.

The plan tracks the object's full pose (orientation and position on the table) through every
step with the exact maneuvers (:func:`nonprehensile.maneuvers.move_pose`): rolling and tumbling
move the object across the table, so each step's reference motion is placed where the object
is at the start of that step, not where it was at the start of the plan.

The plan is a value; :meth:`Plan.steps` can be run one at a time (the seam a simulator or a
robot controller uses).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import networkx as nx
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from nonprehensile.checks import DRIFT_DEG, suggest_angle_tol
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.inference import Expansion, InferredTransition
from nonprehensile.maneuvers import Maneuver, classify, move_pose, tumble
from nonprehensile.skills.skill import events_to_dicts
from nonprehensile.states import DEFAULT_ANGLE_TOL, State, StateIndex, angle_diff, state_pose
from nonprehensile.success_rates import LOOPS, Rate, SuccessRates, TransitionKey

__all__ = [
    "DEFAULT_RELOCATION_COST",
    "DEFAULT_ROBUSTNESS_THRESHOLD",
    "AvoidedTransition",
    "MotionLibrary",
    "NoPlanError",
    "ObjectPose",
    "Offset",
    "Plan",
    "PlanStep",
    "ReferenceMotion",
    "RobustnessCosts",
    "SearchLimitError",
    "find_offset",
    "landing_drift",
    "plan",
    "step_for",
]

FloatArray = NDArray[np.float64]

#: Default cost of relocating the agent between steps (a transition costs 1 by default).
DEFAULT_RELOCATION_COST = 0.5
#: Most search nodes the planner expands before giving up (a very fine --states set).
MAX_SEARCH_NODES = 2_000_000
#: Transitions measured below this success rate are avoided (:class:`RobustnessCosts`).
DEFAULT_ROBUSTNESS_THRESHOLD = 0.8


@dataclass(frozen=True)
class AvoidedTransition:
    """A transition the planner did not use because physics says it fails too often."""

    key: TransitionKey
    rate: Rate | None
    loop: str
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"skill": self.key.skill, "from": self.key.start.to_dict(),
                "to": self.key.end.to_dict(), "loop": self.loop,
                "success": None if self.rate is None else self.rate.to_dict(),
                "reason": self.reason}


@dataclass(frozen=True)
class RobustnessCosts:
    """Measured success rates as arc costs (``plan --robustness FILE``).

    An arc measured at ``k`` successes of ``n`` executions under ``loop`` costs its skill's
    cost plus ``weight * -ln((k + 1) / (n + 2))``: with independent steps, the sum of ``-ln p``
    over a plan is ``-ln`` of the probability that every step succeeds, so the planner trades
    steps against the chance of getting there; Laplace's ``(k + 1) / (n + 2)`` keeps a perfect
    count from being free and a failed one from being infinite. An arc whose rate ``k / n`` is
    below ``threshold`` is avoided. An arc that was not measured counts as ``0 / 0``: the
    rule gives it 1/2 (``ln 2`` more than its plain cost: a measured 18/20 beats it, a
    measured 8/20 does not), or it is avoided when ``avoid_unmeasured``.

    Parameters
    ----------
    rates : SuccessRates
    loop : {"closed", "open"}
        Whose rates to use (the rates file may hold both).
    threshold : float
        In [0, 1].
    weight : float
        Cost per unit of ``-ln p`` (>= 0).
    avoid_unmeasured : bool
    """

    rates: SuccessRates
    loop: str = "closed"
    threshold: float = DEFAULT_ROBUSTNESS_THRESHOLD
    weight: float = 1.0
    avoid_unmeasured: bool = False

    def __post_init__(self) -> None:
        if self.loop not in LOOPS:
            raise InputError(f"the robustness loop must be one of {list(LOOPS)}, got "
                             f"{self.loop!r}")
        if self.loop not in self.rates.loops():
            raise InputError(f"the success rates hold no {self.loop}-loop measurement (they "
                             f"hold {self.rates.loops() or 'none'}); choose one they hold")
        for name, v, hi in (("threshold", self.threshold, 1.0), ("weight", self.weight, 1e6)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not \
                    (math.isfinite(v) and 0.0 <= v <= hi):
                raise InputError(f"the robustness {name} must be a number in [0, {hi:g}], "
                                 f"got {v!r}")

    def judge(self, start: State, end: State, skill: str) -> tuple[float | None, Rate | None]:
        """The extra cost of an arc (None: avoid it) and its measured rate."""
        r = self.rates.get(TransitionKey.of(skill, start, end), self.loop)
        if r is None or r.n == 0:
            # nothing measured: Laplace's rule with no count, 1/2
            return (None if self.avoid_unmeasured else self.weight * math.log(2.0)), None
        if r.rate < self.threshold:
            return None, r
        return -self.weight * math.log(r.smoothed), r

    def avoided(self, graph: nx.MultiDiGraph) -> list[AvoidedTransition]:
        """Every arc of ``graph`` this avoids, and why."""
        out = []
        for u, v, skill in sorted(graph.edges(keys=True), key=lambda e: (e[2], e[0], e[1])):
            extra, r = self.judge(u, v, skill)
            if extra is not None:
                continue
            why = (f"not measured ({self.loop} loop) and unmeasured transitions are avoided"
                   if r is None else
                   f"succeeded {r} {self.loop} loop, below the threshold "
                   f"{100 * self.threshold:g} %")
            out.append(AvoidedTransition(TransitionKey.of(skill, u, v), r, self.loop, why))
        return out


class NoPlanError(InputError):
    """The goal cannot be reached from the start with the known skills.

    Attributes
    ----------
    reachable : list of State
        The states that can be reached (in the frame after the offset).
    drift : float or None
        As :class:`SearchLimitError`'s.
    """

    def __init__(self, message: str, reachable: Sequence[State]) -> None:
        super().__init__(message)
        self.reachable = list(reachable)
        self.drift: float | None = None  # (see SearchLimitError)


class SearchLimitError(InputError):
    """The plan search expanded :data:`MAX_SEARCH_NODES` states without reaching the goal
    (an object whose transitions turn it by angles that never repeat has no end of world
    states: a goal out of reach is then not proven so, only not found).

    Attributes
    ----------
    drift : float or None
        How far (degrees) the expansion's transitions land from its state set, where that is
        past the angle tolerance but below :data:`DRIFT_DEG` (:func:`landing_drift`: the
        model's rounding); None otherwise.
    """

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.drift: float | None = None  # (set where the states drift: _with_drift)


@dataclass(frozen=True)
class Offset:
    """How the agent must be relocated so that the start becomes a model state.

    A point ``p`` of the model's (agent's) frame is at ``R(rotate_deg) p + translate`` in
    the world, where ``R`` turns about the vertical, counterclockwise seen from above.
    """

    rotate_deg: float = 0.0
    translate: tuple[float, float] = (0.0, 0.0)

    def to_world(self, points: FloatArray) -> FloatArray:
        """Map points (shape (..., 3)) from the agent's frame to the world frame."""
        c, s = math.cos(math.radians(self.rotate_deg)), math.sin(math.radians(self.rotate_deg))
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return np.asarray(points @ rot.T + np.array([*self.translate, 0.0]))

    def state_to_model(self, state: State) -> State:
        """The world state as the relocated agent sees it."""
        return State(state.face, state.theta - self.rotate_deg)

    def state_to_world(self, state: State) -> State:
        """A model state as it lies in the world."""
        return State(state.face, state.theta + self.rotate_deg)

    def to_dict(self) -> dict[str, Any]:
        """The spec's JSON form."""
        return {"rotate_deg": self.rotate_deg, "translate": list(self.translate)}


@dataclass(frozen=True)
class ObjectPose:
    """Where the object is: a point ``x`` of the model (model units) is at
    ``scale * rotation @ x + translation`` in the world.

    Attributes
    ----------
    rotation : array, shape (3, 3)
        Object-to-world rotation.
    translation : array, shape (3,)
        World translation (world units: metres with a dataset).
    com : array, shape (3,)
        The centre of mass in the world.
    scale : float
        World units per model unit.
    """

    rotation: FloatArray
    translation: FloatArray
    com: FloatArray
    scale: float = 1.0

    def __init__(self, rotation: FloatArray, translation: FloatArray, com: FloatArray,
                 scale: float = 1.0) -> None:
        # written by hand (a dataclass keeps a class's own ``__init__``): the generated one
        # of a frozen dataclass sets each field by ``object.__setattr__``, twice the cost of
        # the whole construction here, and the executor builds poses at every observation;
        # the fields land in the instance's dict as there
        v = self.__dict__
        v["rotation"] = rotation
        v["translation"] = translation
        v["com"] = com
        v["scale"] = scale

    @property
    def position(self) -> tuple[float, float]:
        """The centre of mass on the table (world ``x``, ``y``)."""
        return float(self.com[0]), float(self.com[1])

    def to_world(self, points: FloatArray) -> FloatArray:
        """Model points (shape (..., 3), model units) in the world."""
        return np.asarray(self.scale * (np.asarray(points) @ self.rotation.T) + self.translation)

    def to_dict(self) -> dict[str, Any]:
        """JSON form: centre of mass, translation, and the rotation as a unit quaternion
        ``[w, x, y, z]`` (MuJoCo's order) and as a matrix."""
        x, y, z, w = Rotation.from_matrix(self.rotation).as_quat()
        return {
            "position": [round(v, 9) for v in self.position],
            "com": [round(float(v), 9) for v in self.com],
            "translation": [round(float(v), 9) for v in self.translation],
            "quaternion_wxyz": [round(float(v), 12) for v in (w, x, y, z)],
            "rotation": np.round(self.rotation, 12).tolist(),
            "scale": self.scale,
        }


@dataclass(frozen=True)
class ReferenceMotion:
    """A reference finger trajectory for one motion arc.

    Attributes
    ----------
    positions : array, shape (n_frames, n_markers, 3)
        Marker positions in the world frame (after the offset).
    marker_names : tuple of str
    rate : float
        Sample rate in Hz.
    cluster : int
        Cluster of the demonstrations it represents (its medoid).
    n_demonstrations : int
        How many demonstrations that cluster holds.
    """

    positions: FloatArray
    marker_names: tuple[str, ...]
    rate: float
    cluster: int
    n_demonstrations: int

    def to_dict(self) -> dict[str, Any]:
        """JSON form (positions as nested lists)."""
        return {
            "marker_names": list(self.marker_names),
            "rate": self.rate,
            "cluster": self.cluster,
            "n_demonstrations": self.n_demonstrations,
            "n_frames": int(self.positions.shape[0]),
            "positions": np.round(self.positions, 6).tolist(),
        }


class MotionLibrary(Protocol):
    """Where reference finger motions come from (clustered demonstrations)."""

    def reference(self, skill: str, source: str, target: str) -> ReferenceMotion | None:
        """The reference motion of a demonstrated skill's arc ``source -> target``, in the
        frame of the skill's demonstrated initial state (``state_pose``: the centre of mass
        above the origin), or None if there is none."""
        ...


@dataclass(frozen=True)
class PlanStep:
    """One transition of a plan, with its adapted skill and reference motions.

    ``start_pose`` and ``end_pose`` are the object's world poses before and after the step,
    tracked through the plan's exact maneuvers; the step's reference motions are placed on
    the object where ``start_pose`` puts it.

    ``agent`` is where the agent stands for this step (its rotation about the vertical and the
    origin of its frame, world units); ``relocated`` says that it moved there just before the
    step (always for the first step: the paper's Section VII, step 1), at
    ``relocation_cost`` (zero for the first placement).
    """

    transition: InferredTransition
    start_world: State
    end_world: State
    motions: tuple[tuple[str, str, str, ReferenceMotion | None], ...]
    cost: float
    start_pose: ObjectPose | None = None
    end_pose: ObjectPose | None = None
    agent: Offset | None = None
    relocated: bool = False
    relocation_cost: float = 0.0
    success_rate: Rate | None = None

    def to_dict(self, *, with_positions: bool = False) -> dict[str, Any]:
        """The spec's JSON form of a step (with ``success_rate`` when the plan used measured
        rates)."""
        t = self.transition
        motions = []
        for source, target, label, ref in self.motions:
            m: dict[str, Any] = {"from": source, "to": target, "label": label}
            if ref is not None:
                r = ref.to_dict()
                if not with_positions:
                    r.pop("positions")
                m["reference"] = r
            else:
                m["reference"] = None
            motions.append(m)
        return {
            "from": self.start_world.to_dict(),
            "to": self.end_world.to_dict(),
            "skill": t.skill.name,
            "maneuver": t.skill.maneuver,
            "demonstrated": t.demonstrated,
            "mapping": dict(sorted(t.mapping.items())),
            "events": events_to_dicts(t.skill.events),
            "motions": motions,
            "cost": self.cost,
            "agent": self.agent.to_dict() if self.agent is not None else None,
            "relocated": self.relocated,
            "relocation_cost": self.relocation_cost,
            "pose": {
                "from": self.start_pose.to_dict() if self.start_pose is not None else None,
                "to": self.end_pose.to_dict() if self.end_pose is not None else None,
            },
            **({"success_rate": self.success_rate.to_dict()}
               if self.success_rate is not None else {}),
        }


@dataclass(frozen=True)
class Plan:
    """A plan from ``start`` to ``goal`` (world frame)."""

    start: State
    goal: State
    offset: Offset
    steps: tuple[PlanStep, ...] = field(default_factory=tuple)
    robustness: dict[str, Any] | None = None

    @property
    def cost(self) -> float:
        """Total cost: the transitions' and the agent's relocations'."""
        return float(sum(s.cost + s.relocation_cost for s in self.steps))

    @property
    def relocations(self) -> int:
        """How many times the agent moves after its first placement."""
        return sum(s.relocated for s in self.steps[1:])

    def to_dict(self, *, with_positions: bool = False) -> dict[str, Any]:
        """The spec's ``nonprehensile plan --json`` document."""
        return {
            "start": self.start.to_dict(),
            "goal": self.goal.to_dict(),
            "offset": self.offset.to_dict(),
            "cost": self.cost,
            "relocations": self.relocations,
            "steps": [s.to_dict(with_positions=with_positions) for s in self.steps],
            **({"robustness": self.robustness} if self.robustness is not None else {}),
        }


def find_offset(
    poly: Polyhedron,
    states: Sequence[State],
    start: State,
    *,
    position: tuple[float, float] = (0.0, 0.0),
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> tuple[State, Offset]:
    """The model state the start maps onto, and the agent's offset that does it.

    Parameters
    ----------
    poly : Polyhedron
    states : sequence of State
        The model's state set.
    start : State
        The start as it lies in the world (any orientation).
    position : (float, float)
        Where the object's centre of mass is on the table (world ``x``, ``y``).
    angle_tol : float
        Below this many degrees no rotation is needed.

    Returns
    -------
    (State, Offset)
        The model state with the same bottom face and the nearest orientation, and the
        smallest rotation of the agent that maps the start onto it.

    Raises
    ------
    InputError
        If no state of the model rests on the start's bottom face.
    """
    poly.loop(start.face)
    x, y = (float(v) for v in position)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InputError(f"the object's position must be two finite numbers, got {position!r}")
    position = (x, y)
    hit = StateIndex(states).find(start, angle_tol)
    if hit is not None:
        return states[hit], Offset(0.0, position)
    same_face = [s for s in states if s.face == start.face]
    if not same_face:
        raise InputError(
            f"the start {start} rests on face {start.face!r}, on which the model has no state; "
            f"its states rest on {sorted({s.face for s in states})}"
        )
    best = min(same_face, key=lambda s: abs(angle_diff(start.theta, s.theta)))
    return best, Offset(angle_diff(start.theta, best.theta), position)


def _arc_cost(
    data: Mapping[str, Any], costs: Mapping[str, float] | None, default: float,
    robustness: RobustnessCosts | None = None, ends: tuple[State, State] | None = None,
) -> tuple[float, str] | None:
    """Cheapest parallel arc: (cost, skill); demonstrated arcs win ties, then names. None
    when ``robustness`` avoids every one of them."""
    best = None
    for skill, d in data.items():
        t = d["transition"]
        c = float(costs.get(_demonstrated_name(t.skill), default)) if costs else default
        if robustness is not None and ends is not None:
            extra, _ = robustness.judge(ends[0], ends[1], skill)
            if extra is None:
                continue
            c += extra
        key = (c, not t.demonstrated, skill)
        if best is None or key < best:
            best = key
    if best is None:
        return None
    return best[0], best[2]


def _demonstrated_name(skill: str) -> str:
    """The demonstrated skill behind an arc (``NAME:reverse`` is NAME run backwards)."""
    return skill.removesuffix(":reverse")


def _check_costs(
    costs: Mapping[str, float] | None, default: float, skills: set[str]
) -> dict[str, float] | None:
    """Costs must be finite, not negative (Dijkstra's condition), and name known skills."""
    for name, value in [("default_cost", default), *((costs or {}).items())]:
        v = float(value)
        if not math.isfinite(v) or v < 0:
            raise InputError(f"the cost of {name!r} must be a finite number >= 0, got {value!r}")
    if costs is None:
        return None
    unknown = sorted(set(costs) - skills)
    if unknown:
        raise InputError(f"costs name unknown skill(s) {unknown}; the skills are "
                         f"{sorted(skills)}")
    return {k: float(v) for k, v in costs.items()}


def plan(
    poly: Polyhedron,
    expansion: Expansion,
    start: State,
    goal: State,
    *,
    position: tuple[float, float] = (0.0, 0.0),
    costs: Mapping[str, float] | None = None,
    default_cost: float = 1.0,
    motions: MotionLibrary | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
    scale: float = 1.0,
    relocation_cost: float = DEFAULT_RELOCATION_COST,
    robustness: RobustnessCosts | None = None,
    max_nodes: int | None = None,
) -> Plan:
    """Plan the transitions, contact events and finger motions from ``start`` to ``goal``.

    Parameters
    ----------
    poly : Polyhedron
    expansion : Expansion
        The expanded state-transition graph (:func:`nonprehensile.inference.expand`).
    start, goal : State
        In the world frame; the start may be any orientation (see :func:`find_offset`).
    position : (float, float)
        The object's position on the table.
    costs : mapping of str to float, optional
        Cost per skill (a demonstrated skill's name; reverses share it); default one per
        transition.
    default_cost : float
        Cost of a skill missing from ``costs``.
    motions : MotionLibrary, optional
        Source of reference finger motions; without it, motions carry no reference.
    angle_tol : float
    scale : float
        World units per model unit (a dataset's ``scale``: metres per model unit), so that
        the object's tracked positions are in the units of ``position`` and of the
        reference motions.
    relocation_cost : float
        Cost of relocating the agent between two steps (turning about the vertical and
        moving to the object). Its first placement, before the first step, is free.
    robustness : RobustnessCosts, optional
        Measured success rates: each arc's cost grows with its failures and arcs below the
        threshold are avoided. The plan's ``robustness`` then lists the avoided transitions
        with their rates, each step carries its own rate, and, when the rates changed the
        route, ``without_rates`` names the steps the plan would have taken without them.
    max_nodes : int, optional
        The most search nodes expanded before giving up (default :data:`MAX_SEARCH_NODES`).

    Returns
    -------
    Plan

    Raises
    ------
    NoPlanError
        If the goal cannot be reached; it lists the reachable states (and, with
        ``robustness``, the avoided transitions a route would need).
    SearchLimitError
        If the search expanded ``max_nodes`` states (default :data:`MAX_SEARCH_NODES`)
        without reaching the goal.
    """
    scale = float(scale)
    if not (math.isfinite(scale) and scale > 0):
        raise InputError(f"the scale (world units per model unit) must be a finite positive "
                         f"number, got {scale!r}")
    graph = expansion.graph.graph
    model_states = expansion.graph.states
    costs = _check_costs(costs, default_cost,
                         {_demonstrated_name(t.skill.name) for t in expansion.transitions})
    relocation_cost = float(relocation_cost)
    if not (math.isfinite(relocation_cost) and relocation_cost >= 0):
        raise InputError(f"the relocation cost must be a finite number >= 0, got "
                         f"{relocation_cost!r}")
    # validates the start (a face the model rests on) and the position
    _, offset = find_offset(poly, model_states, start, position=position,
                            angle_tol=angle_tol)
    poly.loop(goal.face)
    if start.isclose(goal, angle_tol):
        return Plan(start, goal, offset, (), _robustness_doc(robustness, graph, [], None))
    try:
        moves = _search(graph, start, goal, costs, default_cost, relocation_cost, angle_tol,
                        robustness, max_nodes=max_nodes)
    except NoPlanError as exc:
        err = exc
        if robustness is not None:
            try:
                _explain_avoided(exc, graph, start, goal, costs, default_cost,
                                 relocation_cost, angle_tol, robustness)
            except NoPlanError as avoided:
                err = avoided
            except SearchLimitError:
                pass  # (the search without the rates gave up: nothing more to say of them)
        raise _with_drift(err, expansion, angle_tol) from None
    except SearchLimitError as exc:
        raise _with_drift(exc, expansion, angle_tol) from None
    steps: list[PlanStep] = []
    agent = offset
    here = offset.translate  # where the object's centre of mass is on the table
    rot = trans = com = np.zeros(3)
    for k, (u, v, skill, cost, phi, relocated) in enumerate(moves):
        if relocated:
            # the agent turns to `phi` and stands at the object: in its new frame the object
            # lies in the model state u with its centre of mass above the origin
            agent = Offset(angle_diff(phi, 0.0) + 0.0, here)
            rot, trans = state_pose(poly, u)
            trans = scale * trans
            com = np.zeros(3)
        t = expansion.adapted(u, v, skill)
        step, rot, trans, com = _make_step(poly, t, agent, rot, trans, com, scale, motions,
                                           cost, angle_tol)
        rate = robustness.judge(u, v, skill)[1] if robustness is not None else None
        steps.append(replace(step, agent=agent, relocated=relocated,
                             relocation_cost=relocation_cost if relocated and k > 0 else 0.0,
                             success_rate=rate))
        assert step.end_pose is not None
        here = step.end_pose.position
    blind = None
    if robustness is not None:
        blind = _search(graph, start, goal, costs, default_cost, relocation_cost, angle_tol,
                        None)
    return Plan(start, goal, steps[0].agent or offset, tuple(steps),
                _robustness_doc(robustness, graph, moves, blind))


def _move_doc(move: tuple[State, State, str, float, float, bool],
              robustness: RobustnessCosts) -> dict[str, Any]:
    u, v, skill = move[0], move[1], move[2]
    rate = robustness.judge(u, v, skill)[1]
    return {"skill": skill, "from": u.to_dict(), "to": v.to_dict(),
            "success": None if rate is None else rate.to_dict()}


def _robustness_doc(
    robustness: RobustnessCosts | None, graph: nx.MultiDiGraph,
    moves: Sequence[tuple[State, State, str, float, float, bool]],
    blind: Sequence[tuple[State, State, str, float, float, bool]] | None,
) -> dict[str, Any] | None:
    """What the measured rates did to the plan (model-frame transitions)."""
    if robustness is None:
        return None
    avoided = robustness.avoided(graph)
    rates = [robustness.judge(u, v, sk)[1] for u, v, sk, *_ in moves]
    doc: dict[str, Any] = {
        "loop": robustness.loop, "threshold": robustness.threshold,
        "weight": robustness.weight, "avoid_unmeasured": robustness.avoid_unmeasured,
        "measured": {k: v for k, v in robustness.rates.meta.items()
                     if k in ("seed", "samples", "dataset", "step", "distribution_name")},
        "avoided": [a.to_dict() for a in avoided],
        "unmeasured_steps": sum(r is None for r in rates),
        # the chance that every step succeeds, if steps fail independently (measured steps)
        "estimated_success": (math.prod(r.rate for r in rates if r is not None)
                              if any(r is not None for r in rates) else None),
    }
    if blind is not None and [m[:3] for m in blind] != [m[:3] for m in moves]:
        doc["without_rates"] = [_move_doc(m, robustness) for m in blind]
    return doc


def _explain_avoided(
    exc: NoPlanError, graph: nx.MultiDiGraph, start: State, goal: State,
    costs: Mapping[str, float] | None, default_cost: float, relocation_cost: float,
    angle_tol: float, robustness: RobustnessCosts,
) -> None:
    """When only avoided transitions lead to the goal, raise saying which."""
    try:
        blind = _search(graph, start, goal, costs, default_cost, relocation_cost, angle_tol,
                        None)
    except NoPlanError:
        return
    needed = [m for m in blind if robustness.judge(m[0], m[1], m[2])[0] is None]
    names = "; ".join(f"{m[2]} {m[0]} -> {m[1]} ({robustness.judge(m[0], m[1], m[2])[1]})"
                      for m in needed)
    raise NoPlanError(
        f"{exc}; without the success rates a plan exists, through transitions below the "
        f"robustness threshold {100 * robustness.threshold:g} % ({robustness.loop} loop): "
        f"{names}; lower --robustness-threshold to allow them", exc.reachable) from None


def landing_drift(expansion: Expansion, angle_tol: float) -> float | None:
    """How far (degrees) the transitions of an expansion land from its state set, where
    that is more than ``angle_tol`` and less than :data:`DRIFT_DEG`: the smallest such miss,
    or None (none such, or no state set recorded).

    A transition that lands that near a state of the set, but not within the tolerance, is
    one the model's rounding split from it (a model from a mesh carries its file's: a
    float32 STL's rolls land 1e-5 degrees off the 90-degree states, the tolerance being
    1e-6): no skill goes on from where it lands, and a goal there is never matched. An
    exact model's transitions land on the states of its set, however fine; a transition of
    a set that lands near one of its states by chance is taken for drift (1 in 1,000 of a
    1-degree set's).
    """
    sets: dict[str, list[float]] = {}
    for s in expansion.state_set:
        sets.setdefault(s.face, []).append(s.theta % 360.0)
    ends: dict[str, list[float]] = {}
    for t in expansion.transitions:
        v = t.end
        ends.setdefault(v.face, []).append(v.theta % 360.0)
    worst = math.inf
    for face, landed in ends.items():
        if face not in sets:
            continue
        table = np.unique(np.asarray(sets[face], dtype=np.float64))
        e = np.asarray(landed, dtype=np.float64)
        # the set's nearest state round the circle: one of the two the end falls between
        i = np.searchsorted(table, e)
        near = np.stack([table[i % len(table)], table[(i - 1) % len(table)]])
        miss = np.abs((near - e + 180.0) % 360.0 - 180.0).min(axis=0)
        miss = miss[(miss > angle_tol) & (miss < DRIFT_DEG)]
        if len(miss):
            worst = min(worst, float(miss.min()))
    return None if worst == math.inf else worst


def _with_drift(exc: NoPlanError | SearchLimitError, expansion: Expansion,
                angle_tol: float) -> NoPlanError | SearchLimitError:
    """``exc``, saying so when the model's states drift (:func:`landing_drift`), with a
    tolerance that would join them; ``exc`` itself when they do not."""
    drift = landing_drift(expansion, angle_tol)
    if drift is None:
        return exc
    hint = (f"; the transitions land {drift:.2g} degrees off the state set, "
            f"more than the angle tolerance {angle_tol:g} degrees (a model from a mesh "
            f"carries its file's rounding): raise it (--angle-tol, e.g. "
            f"{suggest_angle_tol(drift):g})")
    if isinstance(exc, NoPlanError):
        out: NoPlanError | SearchLimitError = NoPlanError(f"{exc}{hint}", exc.reachable)
    else:
        out = SearchLimitError(f"{exc}{hint}")
    out.drift = drift
    return out


def _norm(theta: float) -> float:
    """An angle in [0, 360), rounded so that equal angles are equal keys."""
    a = round(theta % 360.0, 6)
    return 0.0 if a >= 360.0 else a + 0.0


def _search(
    graph: nx.MultiDiGraph,
    start: State,
    goal: State,
    costs: Mapping[str, float] | None,
    default_cost: float,
    relocation_cost: float,
    angle_tol: float,
    robustness: RobustnessCosts | None = None,
    *,
    max_nodes: int | None = None,
) -> list[tuple[State, State, str, float, float, bool]]:
    """Dijkstra over (world state, agent rotation): a transition of the expanded graph is a
    move from any world state that the agent, turned by ``phi``, sees as its start; turning
    the agent between steps is a move of its own cost; at most ``max_nodes`` nodes (default
    :data:`MAX_SEARCH_NODES`, read at the call).

    Returns, per step: the model arc ``(u, v)``, its skill and cost, the agent's rotation and
    whether it relocated before the step. Ties are broken by the agent's total turning.
    """
    limit = MAX_SEARCH_NODES if max_nodes is None else int(max_nodes)
    by_face: dict[str, list[tuple[State, State, str, float]]] = {}
    for u, v in set(graph.edges()):
        if u == v:
            continue
        got = _arc_cost(graph.get_edge_data(u, v), costs, default_cost, robustness, (u, v))
        if got is None:
            continue
        c, skill = got
        by_face.setdefault(u.face, []).append((u, v, skill, c))
    for arcs in by_face.values():
        arcs.sort(key=lambda a: (a[0], a[1], a[2]))
    Node = tuple[str, float, float | None]  # world face, world theta, agent rotation
    start_node: Node = (start.face, _norm(start.theta), None)
    dist: dict[Node, tuple[float, float]] = {start_node: (0.0, 0.0)}
    parent: dict[Node, tuple[Node, tuple[State, State, str, float, float, bool]]] = {}
    heap: list[tuple[float, float, int, Node]] = [(0.0, 0.0, 0, start_node)]
    done: set[Node] = set()
    seen_world: set[tuple[str, float]] = {(start.face, _norm(start.theta))}
    counter = 0
    end: Node | None = None
    while heap:
        c, r, _, node = heapq.heappop(heap)
        if node in done:
            continue
        done.add(node)
        face, theta, phi = node
        if face == goal.face and abs(angle_diff(theta, goal.theta)) <= angle_tol:
            end = node
            break
        if len(done) > limit:
            raise SearchLimitError(f"the plan search passed {limit} states without "
                                   f"reaching {goal}; use a coarser state set (--step or "
                                   f"--states)")
        for u, v, skill, ec in by_face.get(face, ()):
            phi_e = _norm(theta - u.theta)
            if phi is None:  # the first placement: free, but the least turning wins ties
                dc, dr, moved = 0.0, abs(angle_diff(phi_e, 0.0)), True
            elif abs(angle_diff(phi_e, phi)) <= 1e-6:
                dc, dr, moved = 0.0, 0.0, False
            else:
                dc, dr, moved = relocation_cost, abs(angle_diff(phi_e, phi)), True
            nxt: Node = (v.face, _norm(v.theta + phi_e), phi_e)
            key = (c + ec + dc, r + dr)
            if nxt not in dist or key < dist[nxt]:
                dist[nxt] = key
                parent[nxt] = (node, (u, v, skill, ec, phi_e, moved))
                counter += 1
                heapq.heappush(heap, (key[0], key[1], counter, nxt))
                seen_world.add((nxt[0], nxt[1]))
    if end is None:
        reachable = sorted(State(f, t) for f, t in seen_world)
        # (in full: a rounded model's d:30.000005 is not the goal d:30, which six digits
        # would print it as)
        shown = ", ".join(s.exact() for s in reachable[:40]) + (
            f", ... ({len(reachable) - 40} more)" if len(reachable) > 40 else "")
        raise NoPlanError(
            f"no sequence of known skills takes {start} to {goal}, even relocating the agent "
            f"between steps; reachable states ({len(reachable)}): {shown}",
            reachable,
        )
    path = []
    node = end
    while node != start_node:
        node, move = parent[node]
        path.append(move)
    return path[::-1]


def _make_step(
    poly: Polyhedron, t: InferredTransition, offset: Offset, rot: FloatArray,
    trans: FloatArray, com: FloatArray, scale: float, motions: MotionLibrary | None,
    cost: float, angle_tol: float,
) -> tuple[PlanStep, FloatArray, FloatArray, FloatArray]:
    """One step from the object's pose (agent's frame), and the pose it ends in."""
    m = step_maneuver(poly, t, angle_tol=angle_tol)
    rot_end, trans_end = move_pose(poly, m, rot, trans, scale)
    start_pose = _world_pose(poly, offset, rot, trans, scale)
    end_pose = _world_pose(poly, offset, rot_end, trans_end, scale)
    # the reference motion was recorded with the demonstrated initial state's centre of
    # mass above the origin; a reversed skill runs it from the demonstrated final state,
    # which is where this step ends
    # (a rotation about the vertical leaves the centre of mass exactly where it was)
    com_end = com if m.kind == "rotating" else _com_agent(poly, rot_end, trans_end, scale)
    shift = com_end if _demonstrated_name(t.source.name) != t.source.name else com
    step = PlanStep(
        t, offset.state_to_world(t.start), offset.state_to_world(t.end),
        _step_motions(t, offset, motions, shift), cost, start_pose, end_pose,
    )
    return step, rot_end, trans_end, com_end


def step_for(
    poly: Polyhedron,
    transition: InferredTransition,
    *,
    position: tuple[float, float] = (0.0, 0.0),
    motions: MotionLibrary | None = None,
    scale: float = 1.0,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> PlanStep:
    """One transition as a plan step, with the object's centre of mass at ``position``.

    The step's reference motions are placed on the object there (see :func:`plan`); this is
    how a single demonstrated or inferred transition is executed (e.g. simulated).
    """
    rot, trans = state_pose(poly, transition.start)
    com = np.array([float(position[0]), float(position[1]), 0.0])
    trans = scale * trans + com
    return _make_step(poly, transition, Offset(), rot, trans, com, scale, motions, 1.0,
                      angle_tol)[0]


def step_maneuver(
    poly: Polyhedron, t: InferredTransition, *, angle_tol: float = DEFAULT_ANGLE_TOL
) -> Maneuver:
    """The exact maneuver of a transition (model frame).

    For tumbling, where more than one vertex could serve as the pivot, the pivot is the
    vertex equivalent to the demonstrated one (through the transition's face mapping).
    """
    m = classify(poly, t.start, t.end, angle_tol=angle_tol)
    if m.kind != "tumbling":
        return m
    try:
        demo = classify(poly, t.source.initial, t.source.final, angle_tol=angle_tol)
        faces = [t.mapping[f] for f in demo.pivot]
        (vertex,) = poly.shared_vertices(faces)
        return tumble(poly, t.start, vertex, t.end.face, theta=t.end.theta,
                      angle_tol=angle_tol)
    except (KeyError, ValueError, InputError):
        return m


def _com_agent(poly: Polyhedron, rot: FloatArray, trans: FloatArray, scale: float
               ) -> FloatArray:
    """Horizontal centre of mass (agent's frame, world units), as a 3-vector with z = 0."""
    c = scale * (rot @ poly.com) + trans
    return np.array([c[0], c[1], 0.0])


def _world_pose(poly: Polyhedron, offset: Offset, rot: FloatArray, trans: FloatArray,
                scale: float) -> ObjectPose:
    a = math.radians(offset.rotate_deg)
    rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0],
                   [0.0, 0.0, 1.0]])
    r = rz @ rot
    tw = offset.to_world(trans[None, :])[0]
    return ObjectPose(r, tw, scale * (r @ poly.com) + tw, scale)


def _step_motions(
    t: InferredTransition, offset: Offset, library: MotionLibrary | None,
    shift: FloatArray,
) -> tuple[tuple[str, str, str, ReferenceMotion | None], ...]:
    out = []
    demo_name = _demonstrated_name(t.source.name)
    reverse = demo_name != t.source.name
    for step in t.skill.steps():
        ref = None
        if library is not None:
            a, b = step.motion.source, step.motion.target
            # a reversed skill replays its demonstrated arc backwards in time
            got = library.reference(demo_name, b, a) if reverse else library.reference(
                demo_name, a, b)
            if got is not None:
                pos = got.positions[::-1] if reverse else got.positions
                # an equivalent start state occupies the same space as the demonstrated one
                # up to a horizontal shift (both poses put the centre of mass above the
                # origin), so the finger motion is the same in the agent's frame once shifted
                # to where the object is; the offset carries it to the world
                ref = ReferenceMotion(
                    offset.to_world(pos + shift), got.marker_names, got.rate, got.cluster,
                    got.n_demonstrations,
                )
        out.append((step.motion.source, step.motion.target, step.motion.label, ref))
    return tuple(out)
