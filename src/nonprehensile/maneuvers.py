"""Exact maneuvers in the world (agent's) frame: rolling, rotating, tumbling (paper Section II).

Each maneuver is a rotation of the object about something that stays on the ground: an edge
(rolling), the vertical through the bottom face (rotating), or a vertex (tumbling). The motion
from the start pose to the end pose is the shortest rotation (a geodesic) about an axis through
the pivot; it is refused if any point of the object would go below the ground on the way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from nonprehensile.checks import Range, check_number
from nonprehensile.errors import ManeuverError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.states import (
    DEFAULT_ANGLE_TOL,
    State,
    angle_diff,
    is_stable,
    state_of_pose,
    state_pose,
)

__all__ = [
    "MANEUVER_TYPES",
    "Maneuver",
    "ManeuverOption",
    "ManeuverType",
    "classify",
    "final_states",
    "ground_clearance",
    "maneuvers_from",
    "move_pose",
    "pivot_point",
    "roll",
    "roll_directions",
    "rotate",
    "tumble",
]

FloatArray = NDArray[np.float64]
ManeuverType = Literal["rolling", "rotating", "tumbling"]
#: The paper's three maneuver types, by what stays on the ground: an edge, a face, a vertex.
MANEUVER_TYPES: tuple[ManeuverType, ...] = ("rolling", "rotating", "tumbling")


@dataclass(frozen=True)
class Maneuver:
    """One exact state transition.

    Attributes
    ----------
    kind : {"rolling", "rotating", "tumbling"}
        What stays on the ground: an edge, the bottom face, a vertex.
    start, end : State
        Initial and final states.
    pivot : tuple of str
        The faces naming what stays on the ground: two faces for the edge ``E(f,g)``, the
        bottom face for rotating, the faces meeting at the vertex ``V(...)`` for tumbling.
    angle : float
        Rotation angle of the object in degrees (positive about ``axis``).
    axis : tuple of float
        World-frame unit rotation axis (x, y, z).
    """

    kind: ManeuverType
    start: State
    end: State
    pivot: tuple[str, ...]
    angle: float
    axis: tuple[float, float, float]

    def to_dict(self) -> dict[str, object]:
        """JSON-friendly form."""
        return {
            "kind": self.kind,
            "from": self.start.to_dict(),
            "to": self.end.to_dict(),
            "pivot": list(self.pivot),
            "angle": self.angle,
            "axis": list(self.axis),
        }


def _rotation(axis: FloatArray, angle_rad: float) -> FloatArray:
    return np.asarray(Rotation.from_rotvec(axis * angle_rad).as_matrix())


def ground_clearance(
    poly: Polyhedron, start: State, rotation: FloatArray, pivot: FloatArray
) -> float:
    """Lowest height any vertex reaches along the geodesic rotation about a pivot point.

    The object starts in the pose of ``start``; it turns by the world rotation ``rotation``
    along the shortest path (a constant axis ``a`` and angle ``phi``), about an axis through
    ``pivot``. Each vertex height is ``C + A cos(psi) + B sin(psi)`` for ``psi`` in
    ``[0, phi]``, so its minimum is found in closed form, not by sampling.

    Parameters
    ----------
    poly : Polyhedron
    start : State
    rotation : array, shape (3, 3)
        World-frame rotation from the start pose to the end pose.
    pivot : array, shape (3,)
        World point the axis passes through (it stays fixed).

    Returns
    -------
    float
        Minimum ``z`` over all vertices and the whole motion (0 when the pivot stays lowest).
    """
    r0, t0 = state_pose(poly, start)
    x = poly.vertices @ r0.T + t0 - pivot  # (V, 3) relative to the pivot
    rotvec = Rotation.from_matrix(rotation).as_rotvec()
    phi = float(np.linalg.norm(rotvec))
    z = x[:, 2] + pivot[2]
    if phi < 1e-12:
        return float(z.min())
    a = rotvec / phi
    along = x @ a
    c = pivot[2] + along * a[2]
    amp_cos = x[:, 2] - along * a[2]
    amp_sin = np.cross(a, x)[:, 2]
    lowest = np.minimum(z, c + amp_cos * math.cos(phi) + amp_sin * math.sin(phi))
    # interior minimum at psi* = atan2(B, A) + pi, value C - sqrt(A^2 + B^2)
    psi = (np.arctan2(amp_sin, amp_cos) + math.pi) % (2 * math.pi)
    inside = psi <= phi
    interior = c - np.hypot(amp_cos, amp_sin)
    lowest = np.where(inside, np.minimum(lowest, interior), lowest)
    return float(lowest.min())


def roll_directions(poly: Polyhedron, state: State) -> dict[int, float]:
    """World direction (degrees, from ``+x`` counterclockwise) toward which each bottom edge
    tips the object.

    Edge ``k`` of the bottom face points along ``theta + Delta[k]`` seen from above, with the
    face's interior on its left; rolling over it moves the object toward the edge's outward
    side, ``theta + Delta[k] - 90``.
    """
    f = state.face
    return {
        k: (state.theta + d - 90.0) % 360.0 for k, d in enumerate(poly.delta[f], start=1)
    }


def _landing_tol(poly: Polyhedron, f: str, g: str, angle_tol: float) -> float:
    """Degrees within which the landing face points down after an exact roll or tumble.

    The faces of a model are planar within its length tolerance ``atol``, so a face's normal
    is known to about ``2 atol / size`` radians (size: the square root of its area); a mesh's
    merged hull faces land that far off straight down (1e-5 degrees on a real STL).
    """
    slack = sum(2.0 * poly.atol / math.sqrt(poly.face_areas[h]) for h in (f, g))
    return max(angle_tol, 1e-6, math.degrees(slack))


def roll(
    poly: Polyhedron,
    state: State,
    *,
    edge: int | None = None,
    direction: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> Maneuver:
    """Roll the object over one of its bottom edges onto the neighbouring face.

    Parameters
    ----------
    poly : Polyhedron
    state : State
        Initial state ``{F_b, theta}``.
    edge : int, optional
        Edge number (on ``F_b``) to roll over.
    direction : float, optional
        Or: the world direction in degrees toward which to roll; it must match one edge's
        outward direction within ``angle_tol``.
    angle_tol : float
        Angle tolerance in degrees.

    Returns
    -------
    Maneuver
        Of kind ``"rolling"``; ``end`` is exact (not snapped to any state set).

    Raises
    ------
    ManeuverError
        Neither or both of ``edge`` and ``direction``, no such edge, no edge facing
        ``direction``.
    """
    f = state.face
    n = poly.n_edges(f)
    if (edge is None) == (direction is None):
        raise ManeuverError("roll needs exactly one of edge= (an edge number) or direction=")
    if direction is not None:
        dirs = roll_directions(poly, state)
        best = min(dirs, key=lambda k: abs(angle_diff(dirs[k], direction)))
        if abs(angle_diff(dirs[best], direction)) > angle_tol:
            listed = ", ".join(f"edge {k}: {d:g}" for k, d in dirs.items())
            raise ManeuverError(
                f"in state {state}, no bottom edge faces direction {direction:g} degrees; "
                f"the edges roll toward {listed}"
            )
        edge = best
    assert edge is not None
    if isinstance(edge, bool) or not isinstance(edge, (int, np.integer)) or not 1 <= edge <= n:
        raise ManeuverError(f"face {f!r} has edges 1..{n}, got edge {edge!r}")
    g = poly.neighbor(f, int(edge))
    rot, t = state_pose(poly, state)
    i, _ = poly.edge_vertices(f, int(edge))
    p_i = rot @ poly.vertices[i] + t
    axis = rot @ poly.edge_direction(f, int(edge))
    # the exterior dihedral angle: the angle between the two faces' outward normals
    nf, ng = poly.normals[f], poly.normals[g]
    ang = math.atan2(float(np.linalg.norm(np.cross(nf, ng))), float(nf @ ng))
    q = _rotation(axis, ang)
    end = state_of_pose(poly, q @ rot, tol=_landing_tol(poly, f, g, angle_tol))
    # the edge stays put and the body turns away from its own interior: never through the
    # ground for a convex solid; checked anyway, since it is cheap
    _require_clear(poly, state, end, q, p_i, "rolling")
    return Maneuver("rolling", state, end, (f, g), *_axis_angle(q))


def rotate(poly: Polyhedron, state: State, angle: float) -> Maneuver:
    """Rotate the object about the vertical by ``angle`` degrees (counterclockwise from above).

    The bottom face stays on the ground: a rotating maneuver.
    """
    angle = float(check_number(angle, "rotation angle", Range(), ManeuverError))
    if abs(angle_diff(angle, 0.0)) < 1e-12:
        raise ManeuverError(f"a rotation needs a non-zero finite angle, got {angle!r}")
    end = State(state.face, state.theta + angle)
    return Maneuver("rotating", state, end, (state.face,), float(angle), (0.0, 0.0, 1.0))


def tumble(
    poly: Polyhedron,
    state: State,
    vertex: int,
    to_face: str,
    *,
    theta: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> Maneuver:
    """Tumble the object over a vertex of its bottom face onto another face at that vertex.

    Parameters
    ----------
    poly : Polyhedron
    state : State
    vertex : int
        Index of a vertex of the bottom face; it stays on the ground.
    to_face : str
        A face through ``vertex`` to land on.
    theta : float, optional
        The final orientation; default: the one reached by the shortest motion, a rotation
        about the horizontal axis through the vertex.
    angle_tol : float
        Angle tolerance in degrees.

    Raises
    ------
    ManeuverError
        The vertex is not on the bottom face or not on ``to_face``, or the motion would pass
        through the ground.
    """
    f = state.face
    if vertex not in poly.loop(f):
        raise ManeuverError(
            f"vertex {vertex} is not on the bottom face {f!r} (its vertices: {poly.loop(f)})"
        )
    if vertex not in poly.loop(to_face) or to_face == f:
        raise ManeuverError(
            f"face {to_face!r} does not meet the bottom face {f!r} at vertex {vertex}; the "
            f"faces there are {sorted(poly.vertex_faces[vertex])}"
        )
    rot, t = state_pose(poly, state)
    pivot = rot @ poly.vertices[vertex] + t
    if theta is None:
        n_w = rot @ poly.normals[to_face]
        down = np.array([0.0, 0.0, -1.0])
        axis = np.cross(n_w, down)
        ang = math.atan2(float(np.linalg.norm(axis)), float(n_w @ down))
        q = _rotation(axis / np.linalg.norm(axis), ang)
        end = state_of_pose(poly, q @ rot, tol=_landing_tol(poly, f, to_face, angle_tol))
    else:
        end = State(to_face, theta)
        q = state_pose(poly, end)[0] @ rot.T
    _require_clear(poly, state, end, q, pivot, "tumbling")
    ang_deg, axis_t = _axis_angle(q)
    return Maneuver(
        "tumbling", state, end, tuple(sorted(poly.vertex_faces[vertex])), ang_deg, axis_t
    )


def _require_clear(
    poly: Polyhedron, start: State, end: State, q: FloatArray, pivot: FloatArray, kind: str
) -> None:
    low = ground_clearance(poly, start, q, pivot)
    if low < -poly.atol:
        raise ManeuverError(
            f"{kind} from {start} to {end} would pass {-low:.3g} {poly.units} through the "
            "ground"
        )


def _axis_angle(q: FloatArray) -> tuple[float, tuple[float, float, float]]:
    """Angle (degrees) and unit axis of a rotation matrix."""
    rv = Rotation.from_matrix(q).as_rotvec()
    ang = float(np.linalg.norm(rv))
    axis = rv / ang if ang > 0 else np.array([0.0, 0.0, 1.0])
    return math.degrees(ang), (float(axis[0]), float(axis[1]), float(axis[2]))


def classify(
    poly: Polyhedron, start: State, end: State, *, angle_tol: float = DEFAULT_ANGLE_TOL
) -> Maneuver:
    """The maneuver that takes ``start`` to ``end``, read from the geometry.

    Rotating when the bottom face is the same; rolling when the faces share an edge and
    rolling over it gives ``end``; tumbling when they share a vertex about which the shortest
    motion stays clear of the ground.

    Raises
    ------
    ManeuverError
        When no single maneuver connects the two states.
    """
    poly.loop(start.face)
    poly.loop(end.face)
    if start.face == end.face:
        if abs(angle_diff(end.theta, start.theta)) <= angle_tol:
            raise ManeuverError(f"{start} and {end} are the same state: no maneuver")
        return rotate(poly, start, angle_diff(end.theta, start.theta))
    k = poly.adjacency[start.face].get(end.face)
    if k is not None:
        m = roll(poly, start, edge=k, angle_tol=angle_tol)
        if m.end.isclose(end, angle_tol):
            return m
    shared = poly.shared_vertices([start.face, end.face])
    problems = []
    for v in shared:
        try:
            return tumble(poly, start, v, end.face, theta=end.theta, angle_tol=angle_tol)
        except ManeuverError as exc:
            problems.append(str(exc))
    why = "; ".join(problems) if problems else (
        f"faces {start.face!r} and {end.face!r} share no edge or vertex"
    )
    raise ManeuverError(f"no single maneuver takes {start} to {end}: {why}")


def pivot_point(poly: Polyhedron, maneuver: Maneuver) -> FloatArray:
    """A point of the maneuver's rotation axis, in the pose of its start state.

    The start state's pose is :func:`~nonprehensile.states.state_pose` (centre of mass above
    the origin). Rolling: a vertex of the pivot edge; tumbling: the pivot vertex; rotating:
    the centre of mass (the object turns about the vertical through it).

    Returns
    -------
    array, shape (3,)
        Model units.
    """
    if maneuver.kind == "rolling":
        x = poly.vertices[poly.edges[frozenset(maneuver.pivot)][0]]
    elif maneuver.kind == "tumbling":
        x = poly.vertices[poly.shared_vertices(list(maneuver.pivot))[0]]
    else:
        x = poly.com
    r0, t0 = state_pose(poly, maneuver.start)
    return np.asarray(r0 @ x + t0)


def move_pose(
    poly: Polyhedron,
    maneuver: Maneuver,
    rotation: FloatArray,
    translation: FloatArray,
    scale: float = 1.0,
) -> tuple[FloatArray, FloatArray]:
    """Carry a pose of the maneuver's start state through the exact maneuver.

    The object is at ``scale * rotation @ x + translation`` (``x`` in model units): the start
    state's orientation, anywhere on the table. The maneuver turns it by ``angle`` about
    ``axis`` through its pivot, which moves with the object's position.

    Parameters
    ----------
    poly : Polyhedron
    maneuver : Maneuver
    rotation : array, shape (3, 3)
        Object-to-world rotation of the start pose (that of ``maneuver.start``).
    translation : array, shape (3,)
        World translation of the start pose (world units).
    scale : float
        World units per model unit.

    Returns
    -------
    (rotation, translation)
        The end pose, exact (the final state's orientation, its bottom face on the ground).
    """
    t0 = state_pose(poly, maneuver.start)[1]
    # the start pose differs from state_pose's by a horizontal shift only (same orientation)
    shift = np.asarray(translation, dtype=float) - scale * t0
    pivot = scale * pivot_point(poly, maneuver) + shift
    q = _rotation(np.asarray(maneuver.axis), math.radians(maneuver.angle))
    rot = q @ np.asarray(rotation, dtype=float)
    t = q @ (np.asarray(translation, dtype=float) - pivot) + pivot
    return np.asarray(rot), np.asarray(t)


@dataclass(frozen=True)
class ManeuverOption:
    """One maneuver available from a state, as a skill's author needs it.

    Attributes
    ----------
    maneuver : Maneuver
        The exact maneuver (its ``end`` is the final state to write in a skill).
    element : str
        What stays on the ground, in the skills file's notation: ``E(f,g)`` (rolling), the
        bottom face (rotating), ``V(f,g,...)`` (tumbling).
    edge : int or None
        Rolling: the edge number on the bottom face.
    vertex : int or None
        Tumbling: the pivot vertex (index into the model's vertices).
    direction : float or None
        World direction (degrees from ``+x``, counterclockwise from above) in which the
        centre of mass travels; None for a rotation (it stays put).
    stable : bool
        Whether the object rests on the final face (else it goes on tipping).
    """

    maneuver: Maneuver
    element: str
    edge: int | None
    vertex: int | None
    direction: float | None
    stable: bool

    def to_dict(self) -> dict[str, object]:
        """JSON-friendly form."""
        return {"kind": self.maneuver.kind, "from": self.maneuver.start.to_dict(),
                "to": self.maneuver.end.to_dict(), "element": self.element, "edge": self.edge,
                "vertex": self.vertex, "direction": self.direction, "stable": self.stable,
                "angle": self.maneuver.angle, "axis": list(self.maneuver.axis)}


def _travel(poly: Polyhedron, m: Maneuver) -> float | None:
    """Direction (degrees) in which the centre of mass moves on the table, None if it does
    not."""
    r0, t0 = state_pose(poly, m.start)
    r1, t1 = move_pose(poly, m, r0, t0)
    d = (r1 @ poly.com + t1) - (r0 @ poly.com + t0)
    if math.hypot(d[0], d[1]) <= poly.atol:
        return None
    return math.degrees(math.atan2(d[1], d[0])) % 360.0


def maneuvers_from(
    poly: Polyhedron,
    state: State,
    *,
    step: float = 90.0,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[ManeuverOption]:
    """Every roll, rotation and tumble from ``state`` (what ``nonprehensile maneuvers`` lists).

    * Rolling: over each edge of the bottom face (its final state is exact).
    * Rotating: by every multiple of ``step`` degrees.
    * Tumbling: over each vertex of the bottom face, onto each other face through it: the
      shortest motion (a turn about a horizontal axis) onto a face that shares no edge with
      the bottom face, and onto any face through the vertex every final theta that is a
      multiple of ``step`` and whose motion stays clear of the ground (the paper's Fig. 9
      tumble of a cube, ``a:0 -> d:90``), leaving out the rolls' own final states.

    Parameters
    ----------
    poly : Polyhedron
    state : State
        The initial state (its face must be a face of ``poly``).
    step : float
        Rotation and tumbling angles on this grid, degrees (0 < step <= 360).
    angle_tol : float
        Angle tolerance, degrees.

    Returns
    -------
    list of ManeuverOption
        Rolls by edge number, rotations by angle, tumbles by vertex and final state.
    """
    if not (isinstance(step, (int, float)) and math.isfinite(step) and 0 < step <= 360):
        raise ManeuverError(f"step must be a number of degrees in (0, 360], got {step!r}")
    f = state.face
    poly.loop(f)
    out: list[ManeuverOption] = []
    dirs = roll_directions(poly, state)
    rolled: list[State] = []
    for k in range(1, poly.n_edges(f) + 1):
        m = roll(poly, state, edge=k, angle_tol=angle_tol)
        rolled.append(m.end)
        out.append(ManeuverOption(m, f"E({f},{poly.neighbor(f, k)})", k, None, dirs[k],
                                  is_stable(poly, m.end.face)))
    grid = [i * step for i in range(math.ceil(360.0 / step - 1e-9))]
    for a in grid:
        if abs(angle_diff(a, 0.0)) > angle_tol:
            m = rotate(poly, state, a)
            out.append(ManeuverOption(m, f, None, None, None, True))
    for v in poly.loop(f):
        faces = sorted(poly.vertex_faces[v] - {f})
        element = "V(" + ",".join(sorted(poly.vertex_faces[v])) + ")"
        seen: list[State] = []
        for g in faces:
            tries: list[float | None] = [] if g in poly.adjacency[f] else [None]
            tries += grid
            for theta in tries:
                try:
                    m = tumble(poly, state, v, g, theta=theta, angle_tol=angle_tol)
                except ManeuverError:
                    continue
                if any(m.end.isclose(e, angle_tol) for e in rolled + seen):
                    continue
                seen.append(m.end)
                out.append(ManeuverOption(m, element, None, v, _travel(poly, m),
                                          is_stable(poly, g)))
    return out


def final_states(
    poly: Polyhedron, start: State, kind: str, face: str, *, step: float = 90.0,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[ManeuverOption]:
    """The maneuvers of type ``kind`` from ``start`` that end on ``face`` (the right final
    states for a skill whose stated one is wrong)."""
    return [o for o in maneuvers_from(poly, start, step=step, angle_tol=angle_tol)
            if o.maneuver.kind == kind and o.maneuver.end.face == face]
