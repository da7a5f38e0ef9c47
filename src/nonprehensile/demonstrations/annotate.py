"""Contact events found from the tracked object and fingertips (paper Section IV, automated).

A demonstration is cut at its contact events (Section IV): the instants at which the set of
contact pairs ``(R_k, element)`` and ``(G, element)`` changes. Annotating them by hand is the
slow step of building a dataset; this module finds them from what a motion-capture lab
records: the object's pose (a rigid body, or markers stuck on the object) and the fingertip
markers.

Per frame
---------
* **Ground contact.** The object's vertices are put in the world by the pose; the table is
  at the median over frames of the lowest vertex (a calibration a few mm off does not
  matter). A vertex touches the table when it is below ``ground_on`` and leaves it above
  ``ground_off`` (hysteresis). Three or more touching vertices of one face: that face; the
  two ends of an edge: the edge; one: the vertex.
* **Finger contact.** The tip marker, in the object's frame, is compared with the nearest
  point of the polyhedron: the contact element is the face, edge or vertex on which that
  point lies (an edge or vertex when within ``element_tol`` of it). The finger touches when
  the distance less the pad radius is below ``contact_on`` and lets go above ``contact_off``.
* **Contact state.** The AND of those pairs. A state that lasts less than ``min_duration``
  is a flicker: it is dropped (the neighbouring states meet) and listed as a doubtful call.

Event times
-----------
Thresholds fire late: a hand starts and ends its motions smoothly (zero speed and
acceleration, as in the minimum-jerk model of human reaching), so a finger is within a
millimetre of the face for several frames before it touches and an object lifts by
hundredths of a millimetre in its first frames. Each change is therefore timed by fitting,
around the threshold crossing, a still signal followed by a smooth departure
``y = c + a (t - t0)^3 + b (t - t0)^4`` for ``t > t0`` (``c`` before) and taking ``t0``:
the fingertip's distance to the element when it makes (time reversed) or breaks contact,
the mean height of the vertices that leave (lift) or reach (landing) the table. The first
event, in which no finger touches yet, is timed at the onset of the fingertips' approach.
When several pairs change together (two fingers pinch), the event is at the last of them.

States and skills
-----------------
The initial and final states are those of the resting poses at the start and the end
(:func:`~nonprehensile.states.state_of_pose`, within ``state_tol`` degrees). The chain of
contact states is matched to the skills whose events are the same (elements normalised)
and whose states agree; several skills with the same events (roll-arc and roll-pull, which
differ only in their finger motion) are a doubtful call, resolved to the first and listed.
A chain that fits no skill gets a proposed skills-file entry.
"""

from __future__ import annotations

import contextlib
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from nonprehensile.checks import Range, check_number
from nonprehensile.demonstrations.dataset import Dataset, Demonstration, EventTime
from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory
from nonprehensile.demonstrations.tracking import ObjectSetup, object_setup
from nonprehensile.errors import DemonstrationError, GeometryError, ManeuverError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.maneuvers import classify
from nonprehensile.skills.contacts import (
    ContactEvent,
    ContactPair,
    Edge,
    Face,
    Finger,
    Ground,
    ObjectElement,
    Vertex,
    format_event,
    normalize_event,
)
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State, angle_diff, state_of_pose

__all__ = [
    "AnnotatedRecording",
    "AnnotationReport",
    "DetectionParams",
    "FrameLabels",
    "RecordingAnnotation",
    "SkillNamer",
    "annotate_dataset",
    "annotate_recording",
    "contact_states",
    "frame_labels",
    "ground_elements",
    "nearest_elements",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class DetectionParams:
    """Thresholds of contact detection; lengths in metres, times in seconds.

    Attributes
    ----------
    pad_radius : float
        How far the finger's contact surface (the pad) is from its tip marker.
    contact_on, contact_off : float
        A finger touches when its distance to the object less ``pad_radius`` falls below
        ``contact_on``, and lets go when it rises above ``contact_off`` (hysteresis).
    ground_on, ground_off : float
        A vertex touches the table below ``ground_on`` and leaves it above ``ground_off``.
    element_tol : float
        A finger contact point this close to an edge (a vertex) names the edge (vertex).
    min_duration : float
        Shortest contact state kept; shorter ones are flickers, dropped and reported.
    state_tol : float
        Degrees: tolerance of the resting poses against the skills' states, and of a face
        pointing down.
    gap_limit : int
        Frames: longer runs of missing markers or poses are left unfilled (and reported).
    refine : bool
        Time each event by the smooth-onset fit (else: the threshold crossing).
    """

    pad_radius: float = 0.0
    contact_on: float = 0.004
    contact_off: float = 0.007
    ground_on: float = 0.0015
    ground_off: float = 0.003
    element_tol: float = 0.001
    min_duration: float = 0.05
    state_tol: float = 5.0
    gap_limit: int = 12
    refine: bool = True

    def __post_init__(self) -> None:
        # upper bounds far past real set-ups, so that no product (a duration times a rate,
        # a length squared) overflows: lengths in metres, durations in s, angles in degrees
        for name, high in (("pad_radius", 1.0), ("contact_on", 1.0), ("contact_off", 1.0),
                           ("ground_on", 1.0), ("ground_off", 1.0), ("element_tol", 1.0),
                           ("min_duration", 60.0), ("state_tol", 90.0)):
            # a state tolerance of 0 matches no measured pose: above 0, as the command
            # line's ``--state-tol`` asks
            object.__setattr__(self, name, float(check_number(
                getattr(self, name), name,
                Range(0.0, high, low_open=name == "state_tol"), DemonstrationError)))
        if not (self.contact_off > self.contact_on > 0 and self.ground_off > self.ground_on > 0):
            raise DemonstrationError(
                "thresholds need contact_off > contact_on > 0 and ground_off > ground_on > 0 "
                f"(hysteresis), got contact {self.contact_on:g}/{self.contact_off:g}, ground "
                f"{self.ground_on:g}/{self.ground_off:g}"
            )
        if isinstance(self.gap_limit, bool) or not isinstance(self.gap_limit, int) \
                or self.gap_limit < 0:
            raise DemonstrationError(f"gap_limit must be a whole number >= 0, got "
                                     f"{self.gap_limit!r}")


# ------------------------------------------------------------------------------ geometry


def _vertex_element(poly: Polyhedron, i: int) -> Vertex:
    return Vertex(frozenset(poly.vertex_faces[i]))


def nearest_elements(
    poly: Polyhedron, points: FloatArray, tol: float
) -> tuple[FloatArray, list[ObjectElement]]:
    """Distance from each point to the polyhedron's surface, and the element it is nearest.

    Parameters
    ----------
    poly : Polyhedron
        The object (model units).
    points : array, shape (n, 3)
        Points in the model frame, model units (no NaN).
    tol : float
        Model units: a nearest point this close to an edge (or vertex) names it.

    Returns
    -------
    distance : array, shape (n,)
        Outside: the Euclidean distance to the surface; inside: minus the depth below the
        nearest face.
    elements : list of Face, Edge or Vertex
        The element the nearest surface point lies on.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ids = poly.face_ids
    normals = np.array([poly.normals[f] for f in ids])
    offsets = np.array([normals[i] @ poly.vertices[poly.faces[f][0]] for i, f in
                        enumerate(ids)])
    signed = pts @ normals.T - offsets  # (n, F)
    best = np.full(len(pts), np.inf)
    near = np.zeros((len(pts), 3))
    # faces: the projection inside the polygon
    for i, f in enumerate(ids):
        loop = poly.vertices[list(poly.faces[f])]
        proj = pts - signed[:, i:i + 1] * normals[i]
        c = loop.mean(axis=0)
        inside = np.ones(len(pts), bool)
        for k in range(len(loop)):
            a, b = loop[k], loop[(k + 1) % len(loop)]
            side_c = np.cross(b - a, c - a) @ normals[i]
            side = np.cross(b - a, proj - a) @ normals[i]
            inside &= side * np.sign(side_c) >= 0
        d = np.abs(signed[:, i])
        take = inside & (signed[:, i] >= 0) & (d < best)
        best[take] = d[take]
        near[take] = proj[take]
    # edges (and so vertices)
    for i, j in poly.edges.values():
        a, b = poly.vertices[i], poly.vertices[j]
        ab = b - a
        s = np.clip((pts - a) @ ab / (ab @ ab), 0.0, 1.0)
        q = a + s[:, None] * ab
        d = np.linalg.norm(pts - q, axis=1)
        take = d < best
        best[take] = d[take]
        near[take] = q[take]
    inside_all = (signed <= 0).all(axis=1)
    deepest = signed.max(axis=1)
    best[inside_all] = deepest[inside_all]
    face_of = signed.argmax(axis=1)
    near[inside_all] = (pts - deepest[:, None] * normals[face_of])[inside_all]
    # the element: the faces whose planes pass (within tol) through the nearest point
    on = np.abs(near @ normals.T - offsets) <= tol
    elements: list[ObjectElement] = []
    for n_i in range(len(pts)):
        faces = [ids[k] for k in np.flatnonzero(on[n_i])]
        if len(faces) <= 1:
            elements.append(Face(faces[0] if faces else ids[int(face_of[n_i])]))
        elif len(faces) == 2 and frozenset(faces) in poly.edges:
            elements.append(Edge(frozenset(faces)))
        else:
            v = int(np.argmin(np.linalg.norm(poly.vertices - near[n_i], axis=1)))
            elements.append(_vertex_element(poly, v))
    return best, elements


def ground_elements(poly: Polyhedron, touching: NDArray[np.bool_]) -> list[ObjectElement | None]:
    """The element on the table, from which vertices touch it, frame by frame.

    Parameters
    ----------
    poly : Polyhedron
    touching : array of bool, shape (n, n_vertices)

    Returns
    -------
    list of Face, Edge, Vertex or None
        A face with three or more touching vertices (the one with most), else the edge of two
        touching vertices, else the lowest touching vertex; None when none touches.
    """
    out: list[ObjectElement | None] = []
    faces = [(f, np.array(poly.faces[f])) for f in poly.face_ids]
    edge_of = {frozenset(v): k for k, v in poly.edges.items()}
    for row in touching:
        idx = np.flatnonzero(row)
        if len(idx) == 0:
            out.append(None)
            continue
        counts = [(int(row[v].sum()), f) for f, v in faces]
        n_best, f_best = max(counts)
        if n_best >= 3:
            out.append(Face(f_best))
        elif len(idx) == 2 and frozenset(idx.tolist()) in edge_of:
            out.append(Edge(edge_of[frozenset(idx.tolist())]))
        else:
            out.append(_vertex_element(poly, int(idx[0])))
    return out


def _hysteresis(value: FloatArray, on: float, off: float) -> NDArray[np.bool_]:
    """True from when ``value`` drops below ``on`` until it rises above ``off``, per column.

    NaN keeps the previous state. ``value`` has shape (n,) or (n, k).
    """
    v = np.asarray(value)
    flat = v.reshape(len(v), -1)
    state = np.zeros(flat.shape, bool)
    # the first frame has no history: within the band, the nearer threshold decides
    cur = flat[0] < 0.5 * (on + off)
    for i in range(len(flat)):
        x = flat[i]
        cur = np.where(x < on, True, np.where(x > off, False, cur))
        state[i] = cur
    return state.reshape(v.shape)


def _fill_short(x: FloatArray, limit: int) -> FloatArray:
    """Linear interpolation over runs of at most ``limit`` NaN rows (axis 0), per column."""
    out = np.array(x, dtype=np.float64)
    flat = out.reshape(len(out), -1)
    for c in range(flat.shape[1]):
        col = flat[:, c]
        bad = np.isnan(col)
        if not bad.any() or bad.all():
            continue
        d = np.diff(np.concatenate(([0], bad.astype(np.int8), [0])))
        for s, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
            if s == 0 or e == len(col) or e - s > limit:
                continue
            col[s:e] = np.interp(np.arange(s, e), [s - 1, e], [col[s - 1], col[e]])
    return out


# ------------------------------------------------------------------------------- timing


def _onset(y: FloatArray, lo: int, hi: int, step: float = 0.1) -> float | None:
    """Where a still signal starts a smooth departure, by least squares (frames, sub-frame).

    Fits ``y_i = c + a tau^3 + b tau^4`` with ``tau = max(0, i - t0)`` over frames
    ``lo..hi`` for ``t0`` on a grid of ``step`` frames, with ``a >= 0 >= b`` (a departure
    that starts smoothly and slows, as a minimum-jerk motion does; the pure cubic when the
    free fit breaks that); returns the best ``t0``, or None when the window holds too few
    frames.
    """
    idx = np.arange(lo, hi + 1)
    yy = y[lo:hi + 1]
    ok = ~np.isnan(yy)
    idx, yy = idx[ok], yy[ok]
    if len(idx) < 6:
        return None
    cand = np.arange(lo, hi - 2 + 1e-9, step)
    tau = np.maximum(0.0, idx[None, :] - cand[:, None]) / max(1, hi - lo)  # (K, m)
    x = np.stack([np.ones_like(tau), tau**3, tau**4], axis=2)  # (K, m, 3)
    g = np.einsum("kmi,kmj->kij", x, x) + 1e-12 * np.eye(3)
    rhs = np.einsum("kmi,m->ki", x, yy)
    coef = np.linalg.solve(g, rhs[..., None])[..., 0]
    res = ((np.einsum("kmi,ki->km", x, coef) - yy) ** 2).sum(axis=1)
    g2 = g[:, :2, :2]
    coef2 = np.linalg.solve(g2, rhs[:, :2, None])[..., 0]
    res2 = ((np.einsum("kmi,ki->km", x[..., :2], coef2) - yy) ** 2).sum(axis=1)
    bad = (coef[:, 1] < 0) | (coef[:, 2] > 0)
    res = np.where(bad, res2, res)
    res = np.where(bad & (coef2[:, 1] < 0), np.inf, res)
    if not np.isfinite(res).any():
        return None
    return float(cand[int(np.argmin(res))])


def _refine(y: FloatArray, k: int, forward: bool, lo: int, hi: int, rate: float,
            span: float = 0.008, back_s: float = 0.4) -> float:
    """Time (frames) of a departure seen at the threshold crossing ``k``.

    ``forward``: ``y`` is still before the change and departs after it (a break, a lift, a
    start); else it departs before and is still after (a make, a landing), so time runs
    backward for the fit. ``lo..hi`` bounds the search (the neighbouring changes). The fit
    window reaches back 0.4 s on the still side and, on the moving side, until ``y`` has
    departed by ``span`` from its still level (the early part of the motion, where the
    smooth-onset model holds).
    """
    n = len(y)
    if not forward:
        t = _refine(y[::-1], n - 1 - k, True, n - 1 - hi, n - 1 - lo, rate, span, back_s)
        return float(n - 1 - t)
    back = round(back_s * rate)
    a = max(lo, k - back, 0)
    still = y[a:k + 1]
    if np.isnan(still).all():
        return float(k)
    base = float(np.nanmedian(still))
    b = min(hi, n - 1, k + back)
    over = np.flatnonzero(np.abs(y[k:b + 1] - base) > span)
    b = k + int(over[0]) if len(over) else b
    b = max(b, min(k + 3, hi, n - 1))
    t0 = _onset(y, a, b)
    return float(k) if t0 is None else t0


# ------------------------------------------------------------------------------ results


@dataclass(frozen=True)
class RecordingAnnotation:
    """What was found in one recording.

    Attributes
    ----------
    chain : tuple of ContactEvent
        The contact states in order (ids ``e0``, ``e1``, ... or the matched skill's).
    times : tuple of float
        When each began, seconds (the first: the onset of the fingers' approach).
    initial, final : State or None
        From the resting poses at the start and the end (None: not resting on a face).
    skill : str or None
        The matched skill; None when none fits.
    candidates : tuple of str
        Every skill whose events and states fit (more than one: the call is doubtful).
    proposal : dict or None
        A skills-file entry for the chain when no skill fits.
    doubts : tuple of str
        Every doubtful call, one line each.
    frames : tuple of int
        The frame at which each event began (rounded times).
    """

    chain: tuple[ContactEvent, ...]
    times: tuple[float, ...]
    initial: State | None
    final: State | None
    skill: str | None
    candidates: tuple[str, ...] = ()
    proposal: dict[str, Any] | None = None
    doubts: tuple[str, ...] = ()
    frames: tuple[int, ...] = field(default=())

    @property
    def events(self) -> tuple[EventTime, ...]:
        """The events with their times (the annotations' form)."""
        return tuple(EventTime(e.id, t) for e, t in zip(self.chain, self.times, strict=True))

    def labels(self, n_frames: int, rate: float) -> FrameLabels:
        """Per-frame labels (skill, event with its contacts, arc) of the recording."""
        return frame_labels(self.events, n_frames, rate, self.skill, self.chain)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (``dataset annotate --json``)."""
        return {
            "skill": self.skill,
            "candidates": list(self.candidates),
            "initial": None if self.initial is None else self.initial.to_dict(),
            "final": None if self.final is None else self.final.to_dict(),
            "events": [{"id": e.id, "time": round(t, 6), "contacts": format_event(e)}
                       for e, t in zip(self.chain, self.times, strict=True)],
            "proposal": self.proposal,
            "doubts": list(self.doubts),
        }


# ---------------------------------------------------------------------------- detection


def _finger_index(name: str) -> int:
    return int(name[1:])


def contact_states(
    poly: Polyhedron,
    pose: PoseTrajectory,
    tips: Mapping[str, FloatArray],
    scale: float,
    params: DetectionParams,
) -> tuple[list[frozenset[ContactPair]], dict[str, Any]]:
    """The contact state of every frame, before flickers are dropped.

    Parameters
    ----------
    poly : Polyhedron
        The object model (model units).
    pose : PoseTrajectory
        The model frame's pose in metres (``R @ (scale * x) + p``), short gaps filled.
    tips : mapping of str to array, shape (n, 3)
        Finger (``"R1"``, ...) -> its tip marker in the world, metres (NaN where missing).
    scale : float
        Metres per model unit.
    params : DetectionParams

    Returns
    -------
    states : list of frozenset of ContactPair, length n
    signals : dict
        The per-frame signals the timing fit uses: ``heights`` (n, n_vertices), ``distance``
        (finger -> (n,)), ``elements`` (finger -> list), ``ground`` (list).
    """
    n = pose.n_frames
    rot = pose.rotations
    valid = pose.valid
    verts = np.einsum("nij,vj->nvi", rot, poly.vertices * scale) + pose.positions[:, None]
    # the table: where the lowest vertex is, over the tracked frames
    table = float(np.median(verts[valid, :, 2].min(axis=1))) if valid.any() else 0.0
    heights = verts[..., 2] - table
    touching = _hysteresis(heights, params.ground_on, params.ground_off)
    ground = ground_elements(poly, touching)
    dist: dict[str, FloatArray] = {}
    elems: dict[str, list[ObjectElement | None]] = {}
    on: dict[str, NDArray[np.bool_]] = {}
    raw: dict[str, list[ObjectElement | None]] = {}
    for finger, tip in tips.items():
        local = np.einsum("nji,nj->ni", rot, np.asarray(tip) - pose.positions) / scale
        ok = ~np.isnan(local).any(axis=1)
        d = np.full(n, np.nan)
        el: list[ObjectElement | None] = [None] * n
        if ok.any():
            dd, ee = nearest_elements(poly, local[ok], params.element_tol / scale)
            d[ok] = dd * scale - params.pad_radius
            for i_ok, e_ok in zip(np.flatnonzero(ok).tolist(), ee, strict=True):
                el[i_ok] = e_ok
        raw[finger] = list(el)
        dist[finger] = d
        on[finger] = _hysteresis(d, params.contact_on, params.contact_off)
        # one element per contact: a pad near an edge of the face it presses is on the face
        for r0, r1 in _true_runs(on[finger]):
            chosen = _vote(poly, el[r0:r1])
            if chosen is not None:
                el[r0:r1] = [chosen] * (r1 - r0)
        elems[finger] = el
    states: list[frozenset[ContactPair]] = []
    for i in range(n):
        pairs: set[ContactPair] = set()
        if ground[i] is not None:
            pairs.add(ContactPair(Ground(), ground[i]))  # type: ignore[arg-type]
        for finger in tips:
            if on[finger][i] and elems[finger][i] is not None:
                pairs.add(ContactPair(Finger(_finger_index(finger)), elems[finger][i]))  # type: ignore[arg-type]
        states.append(frozenset(pairs))
    return states, {"heights": heights, "distance": dist, "elements": elems, "raw": raw,
                    "ground": ground, "table": table}


def _true_runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


def _vote(poly: Polyhedron, elements: Sequence[ObjectElement | None]) -> ObjectElement | None:
    """The element of one contact from the nearest element of each of its frames.

    Each frame votes for the faces of its element (a face: itself; an edge: its two faces;
    a vertex: its faces). The faces with at least 90 % of the top vote make the element: one
    face, the edge of two, the vertex of three or more.
    """
    votes: Counter[str] = Counter()
    for el in elements:
        if isinstance(el, Face):
            votes[el.id] += 1
        elif isinstance(el, (Edge, Vertex)):
            votes.update(el.faces)
    if not votes:
        return None
    top = max(votes.values())
    faces = frozenset(f for f, v in votes.items() if v >= 0.9 * top)
    if len(faces) == 1:
        return Face(next(iter(faces)))
    if len(faces) == 2 and faces in poly.edges:
        return Edge(faces)
    shared = poly.shared_vertices(faces)
    if len(shared) == 1:
        return _vertex_element(poly, shared[0])
    return Face(votes.most_common(1)[0][0])


def _runs_of(labels: Sequence[Any]) -> list[tuple[int, int, Any]]:
    out: list[tuple[int, int, Any]] = []
    for i, x in enumerate(labels):
        if out and out[-1][2] == x:
            out[-1] = (out[-1][0], i + 1, x)
        else:
            out.append((i, i + 1, x))
    return out


def _fmt_state(pairs: frozenset[ContactPair]) -> str:
    return " & ".join(format_event(ContactEvent("", pairs))) if pairs else "(no contact)"


def _merge_flickers(
    runs: list[tuple[int, int, Any]], min_frames: int, rate: float, doubts: list[str]
) -> list[tuple[int, int, Any]]:
    """Drop runs shorter than ``min_frames``, shortest first (a short first or last run
    joins its neighbour)."""
    runs = list(runs)
    while len(runs) > 1:
        short = [(e - s, j) for j, (s, e, _) in enumerate(runs) if e - s < min_frames]
        if not short:
            return runs
        _, j = min(short)
        s, e, x = runs[j]
        doubts.append(f"contact state {_fmt_state(x)} lasted {e - s} frame(s) at "
                      f"{s / rate:.3f} s (a flicker, shorter than the minimum duration): "
                      "dropped")
        if j == 0:
            runs[0:2] = [(0, runs[1][1], runs[1][2])]
            continue
        if j == len(runs) - 1:
            runs[j - 1:] = [(runs[j - 1][0], e, runs[j - 1][2])]
            continue
        prev, nxt = runs[j - 1], runs[j + 1]
        if prev[2] == nxt[2]:
            runs[j - 1:j + 2] = [(prev[0], nxt[1], prev[2])]
        else:
            # the change happens where the next state begins; the flicker joins the previous
            runs[j - 1:j + 1] = [(prev[0], e, prev[2])]
    return runs


def _changes(a: frozenset[ContactPair], b: frozenset[ContactPair]) -> list[tuple[str, Any]]:
    """What changed between two states: ("make"/"break", finger) and ("ground", (old, new))."""
    out: list[tuple[str, Any]] = []
    fa = {p.x: p.y for p in a if isinstance(p.x, Finger)}
    fb = {p.x: p.y for p in b if isinstance(p.x, Finger)}
    for f in sorted(set(fa) | set(fb), key=lambda f: f.index):
        if f not in fa:
            out.append(("make", f))
        elif f not in fb:
            out.append(("break", f))
        elif fa[f] != fb[f]:
            out.append(("slide", f))
    ga = next((p.y for p in a if isinstance(p.x, Ground)), None)
    gb = next((p.y for p in b if isinstance(p.x, Ground)), None)
    if ga != gb:
        out.append(("ground", (ga, gb)))
    return out


def _vertex_set(poly: Polyhedron, el: Any) -> set[int]:
    if el is None:
        return set()
    if isinstance(el, Face):
        return set(poly.faces[el.id])
    if isinstance(el, Edge):
        return set(poly.edges[el.faces])
    return set(poly.shared_vertices(el.faces)[:1])


def _resting_state(
    poly: Polyhedron, pose: PoseTrajectory, frames: slice, tol: float
) -> State | None:
    rot = pose.rotations[frames]
    rot = rot[~np.isnan(rot[:, 0, 0])]
    if len(rot) == 0:
        return None
    u, _, vt = np.linalg.svd(rot.mean(axis=0))  # the chordal mean of the rotations
    mean = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    try:
        return state_of_pose(poly, mean, tol=tol)
    except GeometryError:
        return None


def _states_close(a: State | None, b: State, tol: float) -> bool:
    return a is not None and a.face == b.face and abs(angle_diff(a.theta, b.theta)) <= tol


def annotate_recording(
    poly: Polyhedron,
    skills: Sequence[Skill],
    traj: MarkerTrajectory,
    pose: PoseTrajectory,
    fingers: Mapping[str, str],
    scale: float,
    params: DetectionParams | None = None,
    hand_markers: Sequence[str] = (),
) -> RecordingAnnotation:
    """Find the contact events, states and skill of one recording.

    Parameters
    ----------
    poly : Polyhedron
        The object model (model units).
    skills : sequence of Skill
        The skills a chain may match.
    traj : MarkerTrajectory
        The recording (any units).
    pose : PoseTrajectory
        The object model frame's pose (any units; ``R @ (scale * x) + p``).
    fingers : mapping of str to str
        Finger (``"R1"``) -> its tip marker in ``traj``.
    scale : float
        Metres per model unit.
    params : DetectionParams, optional
    hand_markers : sequence of str
        Other markers on the hand (knuckles): they time the start of the approach with the
        tips.

    Returns
    -------
    RecordingAnnotation

    Raises
    ------
    DemonstrationError
        A tip marker is not in the recording, or the object is never tracked.
    """
    p = params or DetectionParams()
    rate = traj.rate
    # the states are read over 0.1 s at each end: a take needs rest, a manipulation, rest
    edge = max(2, round(0.1 * rate))
    if traj.n_frames < 3 * edge:
        raise DemonstrationError(
            f"the recording is too short to annotate: {traj.n_frames} frame(s) "
            f"({traj.n_frames / rate:.3g} s at {rate:g} Hz); a take needs at least {3 * edge} "
            f"frames ({3 * edge / rate:.3g} s): the object at rest, the manipulation, at rest "
            "again; export the whole take"
        )
    t_m = traj.to_units("m")
    pose_m = pose.to_units("m").filled(p.gap_limit)
    doubts: list[str] = []
    if not pose_m.valid.any():
        raise DemonstrationError(f"the object ({pose.name!r}) is not tracked in any frame")
    lost = [(s, e) for s, e in pose_m.gaps()]
    for s, e in lost:
        doubts.append(f"the object is not tracked in frames {s}..{e - 1} ({e - s} frames); "
                      "contacts there are carried over")
    tips = {f: _fill_short(t_m.marker(m), p.gap_limit) for f, m in fingers.items()}
    hand_names = list(dict.fromkeys([*fingers.values(), *hand_markers]))
    hand = _fill_short(np.stack([t_m.marker(m) for m in hand_names], axis=1), p.gap_limit)
    for f, tip in tips.items():
        miss = np.isnan(tip[:, 0])
        if miss.any():
            doubts.append(f"finger {f} ({fingers[f]!r}) is missing in {int(miss.sum())} frames "
                          "beyond the gap limit; its contact is carried over there")
    states, sig = contact_states(poly, pose_m, tips, scale, p)
    # frames where the object is lost keep the state before them
    for i in range(1, len(states)):
        if not pose_m.valid[i]:
            states[i] = states[i - 1]
    runs = _merge_flickers(_runs_of(states), max(1, round(p.min_duration * rate)), rate,
                           doubts)
    n = traj.n_frames

    # --- timing ---
    frames_f: list[float] = []
    for j, (s, _e, x) in enumerate(runs):
        if j == 0:
            frames_f.append(_approach_onset(hand, runs, rate, doubts, refine=p.refine))
            continue
        lo = runs[j - 1][0]
        hi = runs[j + 1][0] if j + 1 < len(runs) else n - 1
        times_j: list[float] = []
        for kind, what in _changes(runs[j - 1][2], x):
            if not p.refine:
                times_j.append(float(s))
                continue
            if kind in ("make", "break"):
                y = sig["distance"][f"R{what.index}"]
                times_j.append(_refine(y, s, kind == "break", lo, hi, rate))
            elif kind == "ground":
                old, new = (_vertex_set(poly, e) for e in what)
                if old - new:  # vertices leave the table: still before, rising after
                    y = np.nanmean(sig["heights"][:, sorted(old - new)], axis=1)
                    times_j.append(_refine(y, s, True, lo, hi, rate))
                if new - old:  # vertices land: falling before, still after
                    y = np.nanmean(sig["heights"][:, sorted(new - old)], axis=1)
                    times_j.append(_refine(y, s, False, lo, hi, rate))
            else:
                times_j.append(float(s))
                doubts.append(f"finger {what} moves to another element without letting go at "
                              f"{s / rate:.3f} s")
        t = max(times_j) if times_j else float(s)
        frames_f.append(min(max(t, frames_f[-1] + 1.0), float(n - 1)))
    # element consistency within each finger contact
    for f in tips:
        el = sig["raw"][f]
        for s, e, x in runs:
            named = [q.y for q in x if isinstance(q.x, Finger) and f"R{q.x.index}" == f]
            if not named:
                continue
            seen = Counter(str(el[i]) for i in range(s, e) if el[i] is not None)
            agree = sum(c for k, c in seen.items() if k == str(named[0]) or (
                isinstance(named[0], Face) and named[0].id in k))
            share = agree / max(1, sum(seen.values()))
            if share < 0.8:
                doubts.append(f"finger {f} on {named[0]} from {s / rate:.3f} s: the nearest "
                              f"element is that one in only {share:.0%} of the frames "
                              f"({dict(seen.most_common(3))})")

    initial = _resting_state(poly, pose_m, slice(0, edge), p.state_tol)
    final = _resting_state(poly, pose_m, slice(n - edge, n), p.state_tol)
    if initial is None:
        doubts.append("the object does not rest on a face at the start")
    if final is None:
        doubts.append("the object does not rest on a face at the end")

    chain = [ContactEvent(f"e{j}", x if x else frozenset()) if x else None
             for j, (_, _, x) in enumerate(runs)]
    if any(c is None for c in chain):
        doubts.append("a contact state with no contact at all (the object in the air)")
        chain_ev = [c for c in chain if c is not None]
        keep = [j for j, c in enumerate(chain) if c is not None]
        frames_f = [frames_f[j] for j in keep]
    else:
        chain_ev = [c for c in chain if c is not None]
    norm = [normalize_event(e, poly) for e in chain_ev]

    # exact: the chain is the skill's; else the skill's events in order within the chain,
    # from its first state to its last (extra states between them are listed, not used)
    candidates: list[Skill] = []
    picks: dict[str, list[int]] = {}
    for exact in (True, False):
        for sk in skills:
            ev = [normalize_event(e, poly) for e in sk.events]
            idx = _embed([e.pairs for e in ev], [e.pairs for e in norm], exact)
            if idx is None:
                continue
            if _states_close(initial, sk.initial, p.state_tol) and _states_close(
                    final, sk.final, p.state_tol):
                candidates.append(sk)
                picks[sk.name] = idx
            elif exact:
                doubts.append(f"the events are those of skill {sk.name!r}, but the states "
                              f"{initial} -> {final} are not its {sk.initial} -> {sk.final}")
        if candidates:
            break
    skill = candidates[0] if candidates else None
    proposal = None
    if skill is None:
        proposal = _proposal(poly, norm, initial, final)
        doubts.append("the chain fits no skill of the skills file; a new skill is proposed")
        chain_out = tuple(norm)
    else:
        if len(candidates) > 1:
            doubts.append(f"skills {[s.name for s in candidates]} have these same events and "
                          f"states (they differ in their finger motion only): chose "
                          f"{skill.name!r}; the motion model tells them apart (name some "
                          "recordings' skill, or give a motion library: --motions)")
        idx = picks[skill.name]
        for j in sorted(set(range(len(norm))) - set(idx)):
            doubts.append(f"contact state {_fmt_state(norm[j].pairs)} from "
                          f"{frames_f[j] / rate:.3f} s is not an event of skill "
                          f"{skill.name!r}, whose events occur around it in order: left out")
        frames_f = [frames_f[j] for j in idx]
        chain_out = tuple(ContactEvent(e.id, e.pairs) for e in skill.events)
        initial, final = skill.initial, skill.final
    times = tuple(float(f) / rate for f in frames_f)
    return RecordingAnnotation(
        chain_out, times, initial, final, None if skill is None else skill.name,
        tuple(s.name for s in candidates), proposal, tuple(doubts),
        tuple(round(f) for f in frames_f),
    )


def _embed(
    want: Sequence[frozenset[ContactPair]], got: Sequence[frozenset[ContactPair]], exact: bool
) -> list[int] | None:
    """Indices of ``got`` holding ``want`` in order (each at its earliest), or None.

    ``exact``: ``got`` is ``want``. Otherwise ``want`` must be a subsequence of ``got`` that
    starts at its first state and ends at its last.
    """
    if exact:
        return list(range(len(got))) if list(want) == list(got) else None
    if not want or not got or want[0] != got[0] or want[-1] != got[-1]:
        return None
    idx = [0]
    j = 1
    for w in want[1:-1]:
        while j < len(got) - 1 and got[j] != w:
            j += 1
        if j >= len(got) - 1:
            return None
        idx.append(j)
        j += 1
    if len(want) > 1:
        if len(got) - 1 in idx:
            return None
        idx.append(len(got) - 1)
    return idx


def _approach_onset(
    hand: FloatArray, runs: list[tuple[int, int, Any]], rate: float, doubts: list[str],
    threshold: float = 0.003, span: float = 0.004, refine: bool = True,
) -> float:
    """Frame at which the hand starts moving, before the first change of contact.

    The signal is the mean, over the hand's markers (shape (n, m, 3), metres), of each
    marker's distance from where it was in the first frames: the whole hand moves off
    together, and averaging the markers halves the noise.
    """
    end = runs[1][0] if len(runs) > 1 else runs[0][1] - 1
    if end < 6:
        return 0.0
    seg = hand[: end + 1]
    ref = np.nanmedian(seg[: max(3, min(10, end // 4))], axis=0)  # (m, 3)
    disp = np.nanmean(np.linalg.norm(seg - ref, axis=2), axis=1)
    over = np.flatnonzero(disp > threshold)
    if not len(over):
        doubts.append("the hand does not move before the first contact: the first event is "
                      "put at the first frame")
        return 0.0
    k = int(over[0])
    if not refine:
        return float(k)
    t = _refine(disp, k, True, 0, end, rate, span=span, back_s=0.8)
    return max(0.0, t)


def _proposal(
    poly: Polyhedron, chain: Sequence[ContactEvent], initial: State | None,
    final: State | None,
) -> dict[str, Any]:
    """A skills-file entry for a chain that fits no skill (for a person to review)."""
    entry: dict[str, Any] = {"name": "proposed"}
    if initial is not None and final is not None:
        ini = State(initial.face, round(initial.theta) % 360)
        fin = State(final.face, round(final.theta) % 360)
        entry["initial"], entry["final"] = ini.to_dict(), fin.to_dict()
        with contextlib.suppress(ManeuverError, GeometryError):  # no single maneuver
            entry["maneuver"] = classify(poly, ini, fin).kind
    entry["events"] = [{"id": f"e{j}", "contacts": format_event(e)}
                       for j, e in enumerate(chain)]
    entry["motions"] = [{"from": f"e{j}", "to": f"e{j + 1}", "label": ""}
                        for j in range(len(chain) - 1)]
    return entry


# --------------------------------------------------------------------------- frame labels


@dataclass(frozen=True)
class FrameLabels:
    """Per-frame labels of an annotated recording, for export.

    Attributes
    ----------
    skill : str or None
        The demonstrated skill.
    event : array of int, shape (n_frames,)
        Index of the last event at or before each frame (-1 before the first).
    arc : array of int, shape (n_frames,)
        Index of the motion (arc ``event[i] -> event[i + 1]``) each frame belongs to; -1
        before the first event and after the last.
    event_ids : tuple of str
        The events' ids, indexed by ``event``.
    contacts : tuple of tuple of str
        Each event's contact pairs (``"(R1,f)"``, ...), indexed by ``event``; empty when not
        given.
    """

    skill: str | None
    event: IntArray
    arc: IntArray
    event_ids: tuple[str, ...]
    contacts: tuple[tuple[str, ...], ...] = ()

    def to_records(self) -> list[dict[str, Any]]:
        """One dict per frame: ``{"frame", "skill", "event", "arc"}`` (arc as ``from->to``),
        and ``"contacts"`` (the event's pairs) when known."""
        out = []
        for i, (e, a) in enumerate(zip(self.event.tolist(), self.arc.tolist(), strict=True)):
            row: dict[str, Any] = {
                "frame": i,
                "skill": self.skill,
                "event": self.event_ids[e] if e >= 0 else None,
                "arc": (f"{self.event_ids[a]}->{self.event_ids[a + 1]}" if a >= 0 else None),
            }
            if self.contacts:
                row["contacts"] = list(self.contacts[e]) if e >= 0 else []
            out.append(row)
        return out


def frame_labels(
    events: Sequence[EventTime], n_frames: int, rate: float, skill: str | None = None,
    chain: Sequence[ContactEvent] = (),
) -> FrameLabels:
    """Label every frame with its event and arc (from detected or annotated event times).

    A frame at time ``t`` belongs to event ``j`` when ``t_j <= t < t_{j+1}``, and to arc
    ``j`` (from event ``j`` to ``j + 1``) in the same interval; the last event's frames
    belong to no arc. ``chain`` (the skill's events, same order) adds each frame's contacts.
    """
    t = np.arange(n_frames) / rate
    times = np.array([e.time for e in events])
    ev = np.searchsorted(times, t + 1e-9, side="right") - 1
    arc = np.where((ev >= 0) & (ev < len(times) - 1), ev, -1)
    contacts = tuple(tuple(format_event(c)) for c in chain)
    if contacts and len(contacts) != len(events):
        raise DemonstrationError(f"frame_labels: {len(events)} event times for a chain of "
                                 f"{len(contacts)} events")
    return FrameLabels(skill, ev.astype(np.int64), arc.astype(np.int64),
                       tuple(e.id for e in events), contacts)


# ------------------------------------------------------------------------------ datasets


@dataclass(frozen=True)
class AnnotatedRecording:
    """One recording of a folder and what was found in it.

    Attributes
    ----------
    file : str
        The trajectory file, relative to the folder being annotated.
    mentor : str
        Who demonstrated it.
    result : RecordingAnnotation
    """

    file: str
    mentor: str
    result: RecordingAnnotation

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return {"file": self.file, "mentor": self.mentor, **self.result.to_dict()}


@dataclass(frozen=True)
class AnnotationReport:
    """The outcome of annotating a folder of recordings.

    Attributes
    ----------
    annotations : dict
        The complete annotations (the dataset format), for every recording that fits a skill,
        with paths relative to the folder of the file they are to be written to.
    recordings : tuple of AnnotatedRecording
        Every recording, in the input's order.
    proposals : tuple of dict
        One per distinct chain (and pair of states) that fits no skill: ``{"skill": a
        skills-file entry, "recordings": [the files showing it]}``.
    """

    annotations: dict[str, Any]
    recordings: tuple[AnnotatedRecording, ...]
    proposals: tuple[dict[str, Any], ...]

    @property
    def unmatched(self) -> tuple[AnnotatedRecording, ...]:
        """Recordings whose chain fits no skill (left out of :attr:`annotations`)."""
        return tuple(r for r in self.recordings if r.result.skill is None)

    @property
    def doubts(self) -> list[str]:
        """Every doubtful call, ``file: what``."""
        return [f"{r.file}: {d}" for r in self.recordings for d in r.result.doubts]

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (``dataset annotate --json``)."""
        return {
            "n_recordings": len(self.recordings),
            "n_annotated": len(self.recordings) - len(self.unmatched),
            "n_unmatched": len(self.unmatched),
            "n_doubts": len(self.doubts),
            "recordings": [r.to_dict() for r in self.recordings],
            "proposed_skills": list(self.proposals),
            "annotations": self.annotations,
        }


class SkillNamer(Protocol):
    """Breaks ties between skills with the same events and states (``annotate_dataset``'s
    ``namer``; :class:`nonprehensile.naming.MotionNamer` asks the motion model)."""

    def name(
        self, poly: Polyhedron, skills: Sequence[Skill], traj: MarkerTrajectory,
        pose: PoseTrajectory, result: RecordingAnnotation, scale: float, gap: int,
    ) -> RecordingAnnotation:
        """``result`` with one of its ``candidates`` named, or with a doubt saying why not."""
        ...


def annotate_dataset(
    path: str | Path,
    *,
    relative_to: str | Path | None = None,
    params: DetectionParams | None = None,
    progress: Callable[[int, int], None] | None = None,
    namer: SkillNamer | None = None,
    namer_from: Callable[[Dataset], SkillNamer] | None = None,
    annotations: Mapping[str, Any] | None = None,
) -> AnnotationReport:
    """Annotate a folder whose annotations list only the recordings and the set-up.

    The folder's annotations file has the dataset format's top-level keys (``skills``,
    ``scale``, ``gap_limit``, ``fingers``, ``markers``, ``axes``, ``units``) and says how the
    object is tracked (``rigid_body`` or ``object_markers``, required:
    :mod:`nonprehensile.demonstrations.tracking`); each demonstration needs only ``file``
    and ``mentor``. A demonstration may also name its ``skill``: it is then preferred
    among skills with the same events, and a chain that does not fit it is a doubt. Other
    keys (``events``, ``initial``, ``final``) are ignored and replaced.

    Parameters
    ----------
    path : str or Path
        The folder.
    relative_to : str or Path, optional
        The folder the complete annotations will be written to; it must be the folder or
        hold it. Paths in :attr:`AnnotationReport.annotations` are relative to it. Default:
        the folder itself.
    params : DetectionParams, optional
        Thresholds; ``gap_limit`` defaults to the annotations'.
    progress : callable (done, total) -> None, optional
    namer : SkillNamer, optional
        Asked to name the skill where several have the events and states found and the
        recording names none (:class:`nonprehensile.naming.MotionNamer`: the motion model).
    namer_from : callable (Dataset) -> SkillNamer, optional
        Without ``namer``: made from the folder's own named recordings (those whose entry
        names its skill, with the events found), when some recording's tie is left, and
        asked as ``namer`` is.
    annotations : mapping, optional
        The recordings list to read instead of the folder's annotations file (which must
        still be there: messages name it, and paths are relative to the folder).

    Raises
    ------
    DemonstrationError
        Listing every problem of the input (missing set-up, unreadable or missing files,
        unknown markers), one per line, by file.
    """
    from nonprehensile.demonstrations.dataset import (
        DATASET_FORMAT,
        _annotations_file,
        _Collector,
        _read,
        _top_level,
    )
    from nonprehensile.io import load_document

    root = Path(path)
    out = _Collector()
    ann = _annotations_file(root) if root.is_dir() else None
    if ann is None:
        raise DemonstrationError(
            f"{root}: no annotations file listing the recordings (expected one of "
            "annotations.json / .yaml / .yml in the folder)"
        )
    data = load_document(ann) if annotations is None else annotations
    if not isinstance(data, Mapping) or not isinstance(data.get("demonstrations"), list):
        raise DemonstrationError(f"{ann}: the annotations must be an object with a "
                                 "'demonstrations' list of {\"file\", \"mentor\"}")
    settings = _top_level(data, ann, root, out)
    poly, skills, scale, gap = settings.poly, settings.skills, settings.scale, settings.gap
    fingers, markers = settings.fingers, settings.markers
    setup = None
    try:
        setup = object_setup(settings.rigid_body, settings.object_markers)
    except DemonstrationError as exc:
        out.add(ann.name, None, str(exc))
    if setup is None and not out.problems:
        out.add(ann.name, None, "no object tracking: say how the object is tracked, "
                                '"rigid_body": "<name>" or "object_markers": {"<name>": [x, y, '
                                "z], ...} (see docs/dataset.md)")
    dest = Path(relative_to) if relative_to is not None else root
    try:
        rel = root.resolve().relative_to(dest.resolve())
    except ValueError:
        raise DemonstrationError(
            f"{dest}: the annotations must be written in the folder {root} or a folder that "
            "holds it, so that the recordings they name lie inside the dataset"
        ) from None
    p = params or DetectionParams(gap_limit=gap)
    items: list[Any] = data["demonstrations"]
    todo: list[tuple[int, str, str, str | None, MarkerTrajectory]] = []
    for i, item in enumerate(items):
        if not isinstance(item, Mapping):
            out.add(ann.name, i, f"a recording must be an object with 'file' and 'mentor', "
                                 f"got {item!r:.60}")
            continue
        file, mentor = item.get("file"), item.get("mentor")
        where = (file if isinstance(file, str) and file else ann.name, i)
        if not isinstance(file, str) or not file:
            out.add(ann.name, i, f"'file' must name the trajectory file, got {file!r}")
            continue
        if not isinstance(mentor, str) or not mentor.strip():
            out.add(*where, f"'mentor' must be a non-empty name, got {mentor!r}")
            continue
        hint = item.get("skill")
        if hint is not None and hint not in [s.name for s in skills]:
            out.add(*where, f"unknown skill {hint!r}; the skills file has "
                            f"{[s.name for s in skills]}")
        traj = _read(root / file, out, where, settings)
        if traj is None:
            continue
        missing = [m for m in markers if m not in traj.marker_names]
        if missing:
            out.add(*where, f"marker(s) {missing} are not in the recording, which has "
                            f"{list(traj.marker_names)}")
            continue
        if setup is not None and setup.rigid_body is not None and setup.rigid_body not in [
                b.name for b in traj.rigid_bodies]:
            out.add(*where, f"rigid body {setup.rigid_body!r} is not in the recording, which "
                            f"has {[b.name for b in traj.rigid_bodies] or 'none'}")
            continue
        todo.append((i, file, mentor.strip(), hint if isinstance(hint, str) else None, traj))
    if len(out.problems) == 1:  # one line naming the culprit
        raise DemonstrationError(f"{root}: {out.problems[0]}; nothing was annotated")
    if out.problems or poly is None or setup is None:
        lines = "\n".join(f"  - {q}" for q in out.problems)
        raise DemonstrationError(
            f"{root}: {len(out.problems)} problem(s), nothing was annotated:\n{lines}"
        )
    object_markers = set(setup.marker_names)
    hand = [m for m in markers if m not in object_markers and m not in fingers.values()]
    done: list[AnnotatedRecording] = []
    for n_done, (_, file, mentor, hint, traj) in enumerate(todo):
        if progress is not None:
            progress(n_done, len(todo))
        try:
            pose = setup.pose(traj, scale)
            res = annotate_recording(poly, skills, traj, pose, fingers, scale, p,
                                     hand_markers=hand)
            if namer is not None and hint is None and len(res.candidates) > 1:
                res = namer.name(poly, skills, traj, pose, res, scale, p.gap_limit)
        except DemonstrationError as exc:
            res = RecordingAnnotation((), (), None, None, None, doubts=(
                f"cannot annotate it: {exc}",))
        if hint is not None:
            res = _apply_hint(res, hint, skills)
        done.append(AnnotatedRecording(file, mentor, res))
    if progress is not None:
        progress(len(todo), len(todo))
    if namer is None and namer_from is not None:
        done = _name_from_own(done, todo, namer_from, poly, skills, setup, scale, p, settings)

    entries = []
    for r in done:
        if r.result.skill is None:
            continue
        res = r.result
        entries.append({
            "file": str(rel / r.file) if str(rel) != "." else r.file,
            "skill": res.skill,
            "mentor": r.mentor,
            "initial": None if res.initial is None else res.initial.to_dict(),
            "final": None if res.final is None else res.final.to_dict(),
            "events": [{"id": e.id, "time": round(e.time, 6)} for e in res.events],
        })
    doc: dict[str, Any] = {k: data[k] for k in data if k != "demonstrations"}
    doc["format"] = DATASET_FORMAT
    doc["skills"] = str(rel / str(data["skills"])) if str(rel) != "." else data["skills"]
    doc["demonstrations"] = entries
    proposals: dict[str, dict[str, Any]] = {}
    for r in done:
        prop = r.result.proposal
        if prop is None:
            continue
        key = repr({k: v for k, v in prop.items() if k != "name"})
        if key not in proposals:
            proposals[key] = {"skill": {**prop, "name": f"proposed-{len(proposals) + 1}"},
                              "recordings": []}
        proposals[key]["recordings"].append(r.file)
    return AnnotationReport(doc, tuple(done), tuple(proposals.values()))


def canonical_recording(
    poly: Polyhedron, traj: MarkerTrajectory, pose: PoseTrajectory, initial: State,
    scale: float, gap: int, markers: Sequence[str],
) -> MarkerTrajectory:
    """The recording's ``markers`` moved rigidly so that the object's pose at the start (the
    mean over the first 0.1 s) is ``initial`` as :func:`~nonprehensile.states.state_pose`
    puts it (scaled): the frame datasets are calibrated to, where recordings of different
    labs (and a motion library) can be compared. Metres.

    Raises
    ------
    DemonstrationError
        A marker not in the recording, or the object never tracked.
    """
    from scipy.spatial.transform import Rotation

    from nonprehensile.states import state_pose

    t = traj.to_units("m")
    absent = [m for m in markers if m not in t.marker_names]
    if absent:
        raise DemonstrationError(f"marker(s) {absent} are not in the recording")
    p = pose.to_units("m").filled(gap)
    edge = max(2, round(0.1 * traj.rate))
    ok = np.flatnonzero(p.valid[:edge])
    if not len(ok):
        ok = np.flatnonzero(p.valid)[:edge]
    if not len(ok):
        raise DemonstrationError(f"the object ({pose.name!r}) is not tracked in any frame")
    r0 = Rotation.from_quat(p.quaternions[ok]).mean()
    p0 = p.positions[ok].mean(axis=0)
    rc, pc = state_pose(poly, initial)
    m = Rotation.from_matrix(rc) * r0.inv()
    x = t.positions[:, [t.marker_names.index(n) for n in markers]]
    flat = x.reshape(-1, 3)
    moved = m.apply(np.nan_to_num(flat - p0)) + pc * scale
    moved[np.isnan(flat).any(axis=1)] = np.nan
    return MarkerTrajectory(moved.reshape(x.shape), tuple(markers), t.rate, "m")


def _name_from_own(
    done: list[AnnotatedRecording],
    todo: list[tuple[int, str, str, str | None, MarkerTrajectory]],
    namer_from: Callable[[Dataset], SkillNamer],
    poly: Polyhedron,
    skills: Sequence[Skill],
    setup: ObjectSetup,
    scale: float,
    p: DetectionParams,
    settings: Any,
) -> list[AnnotatedRecording]:
    """Break the ties left with a namer made from the folder's own named recordings."""
    tied = [i for i, (r, t) in enumerate(zip(done, todo, strict=True))
            if t[3] is None and len(r.result.candidates) > 1]
    skill_of = {s.name: s for s in skills}
    wanted = {c for i in tied for c in done[i].result.candidates}
    hand = [m for m in settings.markers if m not in setup.marker_names]
    named = []
    for r, t in zip(done, todo, strict=True):
        if t[3] is None or r.result.skill != t[3] or r.result.skill not in wanted:
            continue
        sk = skill_of[r.result.skill]
        # the hand's markers in the calibrated frame, as the tied recordings are compared
        try:
            moved = canonical_recording(poly, t[4], setup.pose(t[4], scale), sk.initial,
                                        scale, p.gap_limit, hand)
        except DemonstrationError:  # the object not tracked at the start: not a reference
            continue
        named.append(Demonstration(r.file, sk, r.mentor, sk.initial, sk.final,
                                   r.result.events, moved))
    if not tied or not named:
        return done
    library = Dataset(poly, tuple(skills), tuple(named), scale, settings.gap,
                      dict(settings.fingers))
    namer = namer_from(library)
    out = list(done)
    for i in tied:
        r, traj = done[i], todo[i][4]
        res = namer.name(poly, skills, traj, setup.pose(traj, scale), r.result, scale,
                         p.gap_limit)
        out[i] = AnnotatedRecording(r.file, r.mentor, res)
    return out


def _apply_hint(
    res: RecordingAnnotation, hint: str, skills: Sequence[Skill]
) -> RecordingAnnotation:
    """Prefer the skill the recording names among those that fit; a misfit is a doubt."""
    if hint in res.candidates:
        sk = next(s for s in skills if s.name == hint)
        doubts = tuple(d for d in res.doubts if "differ in their finger motion only" not in d)
        return RecordingAnnotation(
            tuple(ContactEvent(e.id, e.pairs) for e in sk.events), res.times, sk.initial,
            sk.final, hint, res.candidates, None, doubts, res.frames)
    return RecordingAnnotation(
        res.chain, res.times, res.initial, res.final, res.skill, res.candidates,
        res.proposal, (*res.doubts, f"the recording names skill {hint!r}, but its events or "
                                    f"states do not fit it (found {res.skill or 'no skill'})"),
        res.frames)
