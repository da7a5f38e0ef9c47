"""States of an object resting on the ground: the paper's ``{F_b, theta}`` (Section II).

A state is a face on the ground and the orientation ``theta`` of that face's edge 1, projected
on the ground and counted counterclockwise seen from above from ``+x`` (docs/object-model.md).
This module gives the value type, the pose (a rigid transform) of a state and the state of a
pose, static stability, and state sets.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from nonprehensile.checks import (
    ANGLE_TOL_RANGE,
    DEFAULT_ANGLE_TOL,
    MARGIN_RANGE,
    STEP_RANGE,
    check_number,
    check_tolerance,
)
from nonprehensile.errors import GeometryError, StateError

if TYPE_CHECKING:
    # annotations only: importing the geometry here would make ``import nonprehensile.states``
    # circular (the geometry's symmetry module imports the states), and it fails when the
    # states are imported first, as ``nonprehensile demo`` parsing --from does
    from nonprehensile.geometry.polyhedron import Polyhedron

__all__ = [
    "DEFAULT_ANGLE_TOL",
    "MAX_STATE_DEG",
    "State",
    "StateIndex",
    "angle_diff",
    "angles_close",
    "check_states",
    "is_stable",
    "stability_margin",
    "stability_margins",
    "stable_faces",
    "state_of_pose",
    "state_pose",
    "states_by_step",
]

#: Largest state set built from an angle step (a finer step is almost surely a typo); sized so
#: that the ``states`` command (classes included) stays within seconds and a few hundred MB.
MAX_STATES = 500_000

#: Largest magnitude (degrees) of a state's theta read from the command line or a file: beyond
#: it an angle reduced modulo 360 keeps fewer digits than the angle tolerance needs (1e300
#: degrees came out as 0).
MAX_STATE_DEG = 1e6

FloatArray = NDArray[np.float64]

_STATE_RE = re.compile(r"^\s*([^:\s]+)\s*:\s*([-+0-9.eE]+)\s*$")


def _normalize_deg(theta: float) -> float:
    t = float(theta) % 360.0
    # keep round-off from producing 359.99999999999 where 0 is meant, and make the value
    # stable for hashing; 1e-9 degree is far below any tolerance in use
    t = round(t, 9)
    return 0.0 if t >= 360.0 else t + 0.0


def angle_diff(a: float, b: float) -> float:
    """Signed difference ``a - b`` of two angles in degrees, in ``(-180, 180]``."""
    d = (a - b) % 360.0
    return d - 360.0 if d > 180.0 else d


def angles_close(a: float, b: float, tol: float = DEFAULT_ANGLE_TOL) -> bool:
    """Whether two angles in degrees are equal modulo 360 within ``tol`` degrees."""
    return abs(angle_diff(a, b)) <= tol


@dataclass(frozen=True, order=True)
class State:
    """A resting state ``{F_b, theta}`` of the object.

    Parameters
    ----------
    face : str
        ID of the bottom face ``F_b``.
    theta : float
        Orientation of edge 1 of ``F_b`` in degrees, normalised to ``[0, 360)``.
    """

    face: str
    theta: float

    def __post_init__(self) -> None:
        if not isinstance(self.face, str) or not self.face:
            raise StateError(f"a state's face must be a face ID (a string), got {self.face!r}")
        try:
            theta = float(self.theta)
        except (TypeError, ValueError):
            raise StateError(
                f"state {self.face}: theta must be a number of degrees, got {self.theta!r}"
            ) from None
        if not math.isfinite(theta):
            raise StateError(f"state {self.face}: theta must be finite, got {self.theta!r}")
        object.__setattr__(self, "theta", _normalize_deg(theta))

    def __str__(self) -> str:
        text = f"{self.theta:g}"
        if "e" in text:  # (a tiny angle: d:0.000005157, not d:5.157e-06)
            text = f"{self.theta:.9f}".rstrip("0").rstrip(".")
        return f"{self.face}:{'0' if text == '360' else text}"  # 359.9999997 is not "360"

    def exact(self) -> str:
        """``FACE:THETA`` with as many digits as the angle needs to be read back within
        1e-9 degrees: ``str``'s six significant digits where they do (``a:90``), nine
        decimals where they do not (a model from a mesh: ``b:359.999989973``, which ``str``
        prints as ``b:0``; a prism's ``a:33.333333333``), never in exponent notation. The
        form to write in a file that is checked at the default angle tolerance."""
        short = str(self)
        if angles_close(State.parse(short).theta, self.theta, 1e-9):
            return short
        text = f"{self.theta:.9f}".rstrip("0").rstrip(".")
        return f"{self.face}:{'0' if text == '360' else text}"

    @classmethod
    def parse(cls, text: str) -> State:
        """Parse the command-line form ``FACE:THETA`` (e.g. ``a:0``, ``d:90``).

        Raises
        ------
        StateError
            If ``text`` is not of that form, or its theta is not below
            :data:`MAX_STATE_DEG` in magnitude.
        """
        m = _STATE_RE.match(text)
        if not m:
            raise StateError(f"expected a state written FACE:THETA (e.g. a:90), got {text!r}")
        try:
            theta = float(m.group(2))
        except ValueError:
            raise StateError(
                f"expected a state written FACE:THETA (e.g. a:90), got {text!r}"
            ) from None
        if math.isfinite(theta) and abs(theta) >= MAX_STATE_DEG:
            # reduced modulo 360 such an angle has lost its digits (1e300 degrees read as 0)
            raise StateError(f"expected a state's theta in degrees below {MAX_STATE_DEG:g} in "
                             f"magnitude (write it within one turn, 0 to 360), got {text!r}")
        return cls(m.group(1), theta)

    def to_dict(self) -> dict[str, object]:
        """The spec's JSON form ``{"face": ..., "theta": ...}``."""
        return {"face": self.face, "theta": self.theta}

    @classmethod
    def from_dict(cls, data: object) -> State:
        """Read ``{"face": ..., "theta": ...}``.

        Raises
        ------
        StateError
            If keys are missing or of the wrong type.
        """
        if not isinstance(data, dict) or "face" not in data or "theta" not in data:
            raise StateError(f'expected a state {{"face": ..., "theta": ...}}, got {data!r}')
        theta = data["theta"]
        if isinstance(theta, bool) or not isinstance(theta, (int, float)):
            raise StateError(f"state {data!r}: theta must be a number of degrees")
        try:
            degrees = float(theta)
            if math.isfinite(degrees) and abs(degrees) >= MAX_STATE_DEG:
                # reduced modulo 360 it has lost its digits: 1e300 was read as 0
                raise StateError(f"state face {str(data['face'])[:20]!r}: theta {degrees:g} "
                                 f"is not below {MAX_STATE_DEG:g} degrees in magnitude; write "
                                 "it within one turn, 0 to 360")
            return cls(str(data["face"]), degrees)
        except OverflowError:  # an integer beyond floats (10**400)
            raise StateError(f"state face {str(data['face'])[:20]!r}: theta "
                             f"{str(theta)[:12]}... is too large; give degrees as a float"
                             ) from None

    def isclose(self, other: State, tol: float = DEFAULT_ANGLE_TOL) -> bool:
        """Same face and angles equal within ``tol`` degrees."""
        return self.face == other.face and angles_close(self.theta, other.theta, tol)


class StateIndex:
    """Find states of a state set by face and angle, within a tolerance.

    Parameters
    ----------
    states : sequence of State
        The state set; positions in it are what :meth:`find` returns.
    """

    def __init__(self, states: Sequence[State]) -> None:
        by_face: dict[str, list[tuple[float, int]]] = {}
        for i, s in enumerate(states):
            by_face.setdefault(s.face, []).append((s.theta, i))
        self._by_face = {
            f: (np.array([t for t, _ in sorted(lst)]), [i for _, i in sorted(lst)])
            for f, lst in by_face.items()
        }

    def find_all(self, state: State, tol: float = DEFAULT_ANGLE_TOL) -> list[int]:
        """Positions of the states equal to ``state`` within ``tol`` degrees."""
        entry = self._by_face.get(state.face)
        if entry is None:
            return []
        thetas, idx = entry
        tol = check_tolerance(tol, "angle tolerance", allow_zero=True)
        # thetas are sorted in [0, 360): bisect the window [theta - tol, theta + tol], in up
        # to three pieces where it wraps around 0 or 360
        out: list[int] = []
        for shift in (-360.0, 0.0, 360.0):
            lo = np.searchsorted(thetas, state.theta - tol + shift, side="left")
            hi = np.searchsorted(thetas, state.theta + tol + shift, side="right")
            out.extend(idx[int(j)] for j in range(lo, hi))
        return sorted(set(out))

    def find(self, state: State, tol: float = DEFAULT_ANGLE_TOL) -> int | None:
        """Position of the state closest to ``state`` within ``tol`` degrees, or None."""
        found = self.find_all(state, tol)
        return found[0] if found else None


def _frame(u: FloatArray, up: FloatArray) -> FloatArray:
    """Right-handed orthonormal frame ``[u, up x u, up]`` as columns, shape (3, 3)."""
    return np.column_stack([u, np.cross(up, u), up])


def state_pose(poly: Polyhedron, state: State) -> tuple[FloatArray, FloatArray]:
    """The rigid transform that puts the object in ``state``.

    The bottom face lies on the ground plane ``z = 0`` with its outward normal pointing down;
    the centre of mass is above the origin.

    Parameters
    ----------
    poly : Polyhedron
        The object.
    state : State
        ``{F_b, theta}``.

    Returns
    -------
    R : array, shape (3, 3)
        Rotation from the object frame to the world frame.
    t : array, shape (3,)
        Translation: a point ``x`` of the object is at ``R @ x + t`` in the world.
    """
    f = state.face
    poly.loop(f)
    n_in = -poly.normals[f]
    e1 = poly.edge_direction(f, 1)
    # edge 1 lies in the face; project it anyway so that a face planar only within the
    # tolerance still gives an exactly orthonormal frame
    e1 = e1 - (e1 @ n_in) * n_in
    e1 /= np.linalg.norm(e1)
    th = math.radians(state.theta)
    c = np.array([math.cos(th), math.sin(th), 0.0])
    rot = _frame(c, np.array([0.0, 0.0, 1.0])) @ _frame(e1, n_in).T
    world = poly.vertices @ rot.T
    com = rot @ poly.com
    t = np.array([-com[0], -com[1], -world[:, 2].min()])
    return rot, t


def state_of_pose(
    poly: Polyhedron, rotation: FloatArray, tol: float = DEFAULT_ANGLE_TOL
) -> State:
    """The state whose bottom face points straight down under ``rotation``.

    Parameters
    ----------
    poly : Polyhedron
        The object.
    rotation : array, shape (3, 3)
        Object-to-world rotation.
    tol : float
        Angle tolerance in degrees between the face's normal and straight down.

    Returns
    -------
    State

    Raises
    ------
    GeometryError
        If no face points down within ``tol``: the object would rest on an edge or a vertex
        that is not a face of the model.
    """
    tol = float(check_number(tol, "angle tolerance", ANGLE_TOL_RANGE, StateError))
    rot = np.asarray(rotation, dtype=float)
    # the face pointing lowest (its normal's world z, the normals times the rotation's last
    # row), then that normal in the world
    # (``a.dot(b)``: the BLAS call ``a @ b`` makes, the same numbers, without the matmul
    # ufunc's dispatch: observers read the state at the sensor rate)
    i = int(poly.normal_matrix.dot(rot[2]).argmin())
    best = poly.face_ids[i]
    n = rot.dot(poly.normals[best])
    # atan2 of sine and cosine keeps full precision near 0, where acos(cos) loses half the
    # digits (1e-6 degree from one rounding error)
    off = math.degrees(math.atan2(float(np.hypot(n[0], n[1])), float(-n[2])))
    if off > tol:
        raise GeometryError(
            f"no face of {poly.name!r} points down (closest: face {best!r}, {off:.6g} degrees "
            f"off; tolerance {tol:g}); the pose does not rest on a face"
        )
    e1 = rot.dot(poly.first_edge_directions[best])
    return State(best, math.degrees(math.atan2(e1[1], e1[0])))


def stability_margin(poly: Polyhedron, face: str) -> float:
    """Distance from the centre of mass's projection on ``face`` to the face's boundary.

    Gravity acts along the outward normal of the bottom face, so the centre of mass projects
    along that normal. Positive inside the face, negative outside.

    Returns
    -------
    float
        Signed distance in the model's length units.
    """
    loop = poly.loop(face)
    n_out = poly.normals[face]
    p = poly.vertices[list(loop)]
    q = poly.com - ((poly.com - p[0]) @ n_out) * n_out
    e = np.roll(p, -1, axis=0) - p
    e /= np.linalg.norm(e, axis=1)[:, None]
    # the loop is counterclockwise about the inward normal, so the interior is to the left
    inward = np.cross(-n_out, e)
    return float(np.min(np.einsum("ij,ij->i", q - p, inward)))


def stability_margins(poly: Polyhedron) -> dict[str, float]:
    """:func:`stability_margin` of every face at once (vectorised over faces and edges)."""
    lp = poly._loops
    v = poly.vertices
    n_out = poly._normal_array
    p = v[lp.flat]
    e = v[lp.flat[lp.nxt]] - p
    e /= np.linalg.norm(e, axis=1)[:, None]
    n = n_out[lp.owner]
    anchor = v[lp.flat[lp.starts]][lp.owner]
    q = poly.com - np.einsum("ij,ij->i", poly.com - anchor, n)[:, None] * n
    # the loop is counterclockwise about the inward normal, so the interior is to the left
    d = np.einsum("ij,ij->i", q - p, np.cross(-n, e))
    low = -np.maximum.reduceat(-d, lp.starts)
    return dict(zip(poly.faces, low.tolist(), strict=True))


def is_stable(poly: Polyhedron, face: str, margin: float = 0.0) -> bool:
    """Whether the object rests statically on ``face``.

    Parameters
    ----------
    poly : Polyhedron
    face : str
    margin : float
        Required distance (model length units) between the centre of mass's projection and
        the face's boundary; at least the model's tolerance is always required.
    """
    margin = float(check_number(margin, "stability margin", MARGIN_RANGE, StateError))
    return stability_margin(poly, face) > max(margin, poly.atol)


def stable_faces(poly: Polyhedron, margin: float = 0.0) -> list[str]:
    """The faces the object can rest on, in model order."""
    need = max(float(check_number(margin, "stability margin", MARGIN_RANGE, StateError)),
               poly.atol)
    return [f for f, m in stability_margins(poly).items() if m > need]


def states_by_step(
    poly: Polyhedron,
    step: float,
    *,
    faces: Iterable[str] | None = None,
    margin: float = 0.0,
) -> list[State]:
    """The discretised state set: every stable face at ``theta = 0, step, 2 step, ...``.

    Parameters
    ----------
    poly : Polyhedron
    step : float
        Angle step in degrees; must divide 360 (the paper's cube example uses 90).
    faces : iterable of str, optional
        Restrict to these faces; default all stable faces.
    margin : float
        Stability margin (see :func:`is_stable`).

    Returns
    -------
    list of State
        Face-major, in model order then increasing ``theta``.
    """
    step = float(check_number(step, "the angle step", STEP_RANGE, StateError))
    chosen = stable_faces(poly, margin) if faces is None else list(faces)
    for f in chosen:
        poly.loop(f)
    if 360.0 / step > 1e9:  # 360 / 1e-320 is infinite: no whole number of steps
        raise StateError(
            f"the angle step (--step) of {step!r} degrees is too small: over 1e9 orientations "
            f"per face, more than the limit of {MAX_STATES} states; {_coarser(len(chosen))}")
    n = round(360.0 / step)
    if abs(n * step - 360.0) > 1e-9 * 360:
        raise StateError(
            f"the angle step must divide 360 degrees evenly, got {step:g} (360/{step:g} = "
            f"{360 / step:.6g}); try one of 1, 5, 15, 30, 45, 60, 90, 120, 180"
        )
    if n * len(chosen) > MAX_STATES:
        raise StateError(
            f"the angle step (--step) of {step:g} degrees gives {n * len(chosen)} states on "
            f"{len(chosen)} faces, more than the limit of {MAX_STATES}; {_coarser(len(chosen))}"
        )
    return [State(f, i * step) for f in chosen for i in range(n)]


def _coarser(n_faces: int) -> str:
    """The fix a refusal of a too-fine angle step names: a step written short that divides
    360 degrees and keeps ``n_faces`` faces' states within :data:`MAX_STATES`, the first at or
    above the finest the limit allows (``360 / n`` itself, 0.00432... for the cube's six
    faces, would be refused as not dividing 360 once rounded for the message)."""
    per_face = MAX_STATES // max(n_faces, 1)
    if per_face < 1:
        return (f"{n_faces} faces are more than the limit even at one orientation each: "
                "choose fewer faces")
    finest = 360.0 / per_face
    # the first step at or above the finest, counting up in its second significant digit
    # (then the third, ...), that divides 360: 0.0045 for the cube (80,000 a face)
    for digits in (2, 3, 4, 6):
        unit = 10.0 ** (math.floor(math.log10(finest)) - (digits - 1))
        k = math.ceil(finest / unit - 1e-9)
        for _ in range(100):
            text = f"{k * unit:.{digits + 1}g}"
            x = float(text)
            if x >= finest and abs(round(360.0 / x) * x - 360.0) <= 1e-9 * 360:
                return (f"use a coarser step that divides 360 degrees, such as {text} (the "
                        f"finest the limit allows on this object is {finest:.3g})")
            k += 1
    return (f"use a coarser step that divides 360 degrees, such as {finest!r} (the finest the "
            "limit allows on this object)")


def check_states(
    poly: Polyhedron,
    states: Sequence[State],
    *,
    margin: float = 0.0,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[State]:
    """Validate an explicit state set against the object.

    Raises
    ------
    StateError
        Naming the first state whose face the object lacks or cannot rest on, or that is
        listed twice (within ``angle_tol``).
    """
    by_face: dict[str, list[State]] = {}
    for s in states:
        by_face.setdefault(s.face, []).append(s)
    for same in by_face.values():
        # neighbours in angle order, and the pair across 360/0
        same = sorted(same, key=lambda s: s.theta)
        for i in range(len(same) if len(same) > 1 else 0):
            a, b = same[i - 1], same[i]
            if angles_close(a.theta, b.theta, angle_tol):
                raise StateError(
                    f"state {b} is listed twice (as {a} and {b}, within {angle_tol:g} degrees)"
                )
    out: list[State] = []
    for s in states:
        if s.face not in poly.faces:
            raise StateError(
                f"state {s} names face {s.face!r}, which {poly.name!r} does not have; its "
                f"faces are {list(poly.faces)}"
            )
        if not is_stable(poly, s.face, margin):
            raise StateError(
                f"state {s}: {poly.name!r} cannot rest on face {s.face!r} (its centre of mass "
                "projects outside it)"
            )
        out.append(s)
    return out
