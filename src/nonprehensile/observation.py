"""Observations: what a controller sees of the object and its fingertips.

One interface for every source: the simulator's ground truth today
(:class:`~nonprehensile.sim.observe.SimObserver`), a motion-capture tracker's rigid body or
object markers later. An :class:`Observation` is the object's pose and the fingertips'
positions at one time; an :class:`ObservationModel` says how a real sensor degrades them
(rate, latency, position and orientation noise, fingertip noise) and an
:class:`ObservationStream` applies it to a stream of true samples, seeded.

The contact events a controller acts on are read from an observation by geometry alone
(:func:`observed_contacts`): the object's element lowest on the table, and for each fingertip
the face, edge or vertex its sphere touches. A controller never reads the simulator's contact
list; the judge (:mod:`nonprehensile.sim.judge`) does, for the records.

Pure core: no simulator import.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose
from nonprehensile.skills.contacts import (
    ContactPair,
    Edge,
    Face,
    Finger,
    Ground,
    ObjectElement,
    Vertex,
)

__all__ = [
    "Observation",
    "ObservationModel",
    "ObservationStream",
    "PairCache",
    "element_at",
    "ground_element",
    "hull_distance",
    "observed_contacts",
    "rotvec_matrix",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Observation:
    """The object's pose and the fingertips' centres as a sensor reports them.

    Attributes
    ----------
    time : float
        When the sample was taken (s, the controller's clock), not when it arrived.
    pose : ObjectPose
        The object's pose (world, metres).
    tips : array, shape (n_fingers, 3)
        Fingertip centres (world, metres).
    """

    time: float
    pose: ObjectPose
    tips: FloatArray

    def __init__(self, time: float, pose: ObjectPose, tips: FloatArray) -> None:
        # by hand, as :class:`~nonprehensile.planning.ObjectPose`'s (one per sample)
        v = self.__dict__
        v["time"] = time
        v["pose"] = pose
        v["tips"] = tips


@dataclass(frozen=True)
class ObservationModel:
    """How a sensor degrades the truth.

    Attributes
    ----------
    rate : float
        Samples per second (a motion-capture system: 100-240 Hz).
    latency : float
        Seconds from a sample's time to its arrival.
    position_noise : float
        Standard deviation (m) of the object's position, per axis (tracking noise).
    angle_noise_deg : float
        Standard deviation (degrees) of the object's orientation, as a random rotation vector.
        A rigid body fitted to markers ``b`` metres apart with ``s`` m of marker noise has
        about ``degrees(s / b)``; None derives it so from ``position_noise`` and a 5 cm
        baseline.
    finger_noise : float
        Standard deviation (m) of each fingertip position, per axis.
    """

    rate: float = 120.0
    latency: float = 0.0
    position_noise: float = 0.0
    angle_noise_deg: float | None = None
    finger_noise: float = 0.0

    def __post_init__(self) -> None:
        limits = {"rate": (1.0, 1e5), "latency": (0.0, 1.0), "position_noise": (0.0, 0.05),
                  "finger_noise": (0.0, 0.05)}
        for name, (lo, hi) in limits.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise InputError(f"observation {name} must be a number in [{lo:g}, {hi:g}], "
                                 f"got {v!r}")
            object.__setattr__(self, name, float(v))
        a = self.angle_noise_deg
        if a is None:
            object.__setattr__(self, "angle_noise_deg",
                               math.degrees(self.position_noise / 0.05))
        elif isinstance(a, bool) or not isinstance(a, (int, float)) or not math.isfinite(a) \
                or not 0.0 <= a <= 30.0:
            raise InputError(f"observation angle_noise_deg must be a number in [0, 30], "
                             f"got {a!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"rate": self.rate, "latency": self.latency,
                "position_noise": self.position_noise,
                "angle_noise_deg": self.angle_noise_deg, "finger_noise": self.finger_noise}


#: A perfect sensor at 120 Hz (the paper's OptiTrack V120).
PERFECT = ObservationModel()


class ObservationStream:
    """Turns true samples into what the sensor reports, in order.

    :meth:`push` a true sample whenever :meth:`due` says one is due (the sensor's rate);
    :meth:`latest` gives the newest degraded sample that has arrived (``latency`` old).

    Parameters
    ----------
    model : ObservationModel
    rng : numpy.random.Generator
        Draws the noise (seeded by the caller: same seed, same observations).
    """

    def __init__(self, model: ObservationModel, rng: np.random.Generator) -> None:
        self.model = model
        self.rng = rng
        self.period = 1.0 / model.rate
        self._next = 0.0
        self._queue: deque[Observation] = deque()
        self._latest: Observation | None = None

    def due(self, now: float) -> bool:
        """Whether the sensor takes a sample at ``now``."""
        return now >= self._next - 1e-9

    def push(self, now: float, pose: ObjectPose, tips: FloatArray) -> None:
        """Record the true pose and tips at ``now`` (degraded by the model)."""
        m = self.model
        self._next = max(self._next + self.period, now + 0.5 * self.period)
        noisy_pose = m.position_noise > 0 or (m.angle_noise_deg or 0.0) > 0
        tips = np.asarray(tips, dtype=np.float64)
        n_tips = tips.size if m.finger_noise > 0 else 0
        # a draw for the pose, then one for the tips: the same numbers, in the same order,
        # as a draw per quantity (``normal(0, s)`` is ``0 + s * z`` of the generator's next
        # ``z``, in C; the generator keeps no spare normals between draws)
        if noisy_pose:
            a = math.radians(m.angle_noise_deg or 0.0)
            p = m.position_noise
            z0, z1, z2, z3, z4, z5 = self.rng.standard_normal(6).tolist()
            dr = _rotvec_matrix(0.0 + a * z0, 0.0 + a * z1, 0.0 + a * z2)
            com = pose.com + np.array([0.0 + p * z3, 0.0 + p * z4, 0.0 + p * z5])
            # the noisy rotation turns the body about its (noisy) centre of mass
            # (``a.dot(b)``: the BLAS call ``a @ b`` makes, the same numbers, without the
            # matmul ufunc's dispatch)
            trans = com - dr.dot(pose.com - pose.translation)
            pose = ObjectPose(dr.dot(pose.rotation), trans, com, pose.scale)
        if n_tips:
            tips = tips + self.rng.normal(0.0, m.finger_noise, tips.shape)
        else:
            tips = np.array(tips, dtype=np.float64)
        self._queue.append(Observation(now, pose, tips))

    def next_time(self) -> float:
        """When something next happens: a sample is due, or a queued one arrives."""
        nxt = self._next
        if self._queue:
            nxt = min(nxt, self._queue[0].time + self.model.latency)
        return nxt

    def latest(self, now: float) -> Observation | None:
        """The newest sample that has arrived by ``now``, or None before the first."""
        lat = self.model.latency
        q = self._queue
        while q and q[0].time + lat <= now + 1e-9:
            self._latest = q.popleft()
        return self._latest


def hull_distance(poly: Polyhedron, pose: ObjectPose, points: FloatArray) -> FloatArray:
    """Lower bound of each point's distance (m) to the posed object (the largest signed
    distance to its face planes: exact off a face, smaller off an edge or vertex; negative
    inside). ``points`` has shape (..., 3)."""
    p = np.asarray(points, dtype=np.float64)
    # (``a.dot(b)``: the BLAS call ``a @ b`` makes, the same numbers, without the matmul
    # ufunc's dispatch: a let-go measures its fingertips at every observation)
    normals, offsets = poly.normal_matrix, poly.plane_offsets  # (kept by the object)
    if p.ndim > 2:  # (``dot`` of a stack is not matmul's product of each matrix)
        x = (p - pose.translation) @ pose.rotation / pose.scale
        return np.asarray((x @ normals.T - offsets).max(axis=-1) * pose.scale)
    x = (p - pose.translation).dot(pose.rotation) / pose.scale  # model frame
    return np.asarray((x.dot(normals.T) - offsets).max(axis=-1) * pose.scale)


def rotvec_matrix(v: FloatArray) -> FloatArray:
    """The rotation matrix (shape (3, 3)) of a rotation vector ``v`` (shape (3,), radians:
    axis times angle), by Rodrigues' formula.

    Written by hand: :class:`scipy.spatial.transform.Rotation` does the same in about 20
    times the time, and the observation noise draws one rotation per sample (120 Hz and
    more, every execution of a sweep).
    """
    return _rotvec_matrix(float(v[0]), float(v[1]), float(v[2]))


def _rotvec_matrix(x: float, y: float, z: float) -> FloatArray:
    """:func:`rotvec_matrix` of the rotation vector ``(x, y, z)``."""
    th2 = x * x + y * y + z * z
    if th2 < 1e-12:  # the series to second order: exact in double precision here
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    # (a flat list reshaped: numpy builds it faster than from nested lists)
    return np.array([
        1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y,
        b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x,
        b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y),
    ]).reshape(3, 3)


# ---------------------------------------------------------------- contacts from geometry
def _planes(poly: Polyhedron) -> tuple[FloatArray, FloatArray]:
    normals = np.array([poly.normals[f] for f in poly.face_ids])
    offsets = np.array([poly.normals[f] @ poly.vertices[poly.faces[f][0]]
                        for f in poly.face_ids])
    return normals, offsets


def element_at(poly: Polyhedron, x: FloatArray, tol: float,
               planes: tuple[FloatArray, FloatArray] | None = None) -> ObjectElement:
    """The face, edge or vertex of the model at a point on (or near) its surface.

    Parameters
    ----------
    poly : Polyhedron
    x : array, shape (3,)
        A point in the model frame (model units).
    tol : float
        Face planes within this distance (model units) of the point count: one face names a
        face, two an edge ``E(f,g)``, three or more the vertex ``V(...)`` they share.
    planes : (normals, offsets), optional
        The face planes, precomputed.
    """
    normals, offsets = planes if planes is not None else _planes(poly)
    d = normals @ x - offsets
    return _element_of(poly, d, tol)


def _element_of(poly: Polyhedron, d: FloatArray, tol: float,
                memo: dict[Any, ObjectElement] | None = None) -> ObjectElement:
    """:func:`element_at` from the point's signed distances ``d`` to the face planes (model
    units). With ``memo``, an element that the set of near planes decides alone is kept by
    that set (what it names is the one computed afresh)."""
    mask = d > -tol
    key = ("element", tol, mask.tobytes())
    if memo is not None:
        got = memo.get(key)
        if got is not None:
            return got
    near = [poly.face_ids[i] for i in np.flatnonzero(mask)]
    el: ObjectElement
    if not near:  # the nearest plane decides: not kept
        return Face(poly.face_ids[int(np.argmax(d))])
    if len(near) == 1:
        el = Face(near[0])
    elif len(near) == 2 and frozenset(near) in poly.edges:
        el = Edge(frozenset(near))
    else:
        shared = poly.shared_vertices(near) if len(near) >= 3 else []
        if not shared:  # the nearest plane decides: not kept
            return Face(poly.face_ids[int(np.argmax(d))])
        el = Vertex(poly.vertex_faces[shared[0]])
    if memo is not None:
        memo[key] = el
    return el


def ground_element(poly: Polyhedron, rotation: FloatArray, translation: FloatArray,
                   scale: float, tol: float,
                   planes: tuple[FloatArray, FloatArray] | None = None) -> ObjectElement:
    """The face, edge or vertex of the posed object lowest on the table.

    Vertices within ``tol`` (metres) of the lowest one count: three or more on one face name
    that face, two on one edge that edge, else the lowest vertex.
    """
    z = scale * (poly.vertices @ rotation[2]) + translation[2]
    return _ground_of_heights(poly, z, rotation, tol, planes)


def _ground_of_heights(poly: Polyhedron, z: FloatArray, rotation: FloatArray, tol: float,
                       planes: tuple[FloatArray, FloatArray] | None,
                       zmin: float | None = None,
                       memo: dict[Any, Any] | None = None) -> ObjectElement:
    """:func:`ground_element` from the vertices' heights ``z`` (shape (n_vertices,), m;
    ``zmin`` their least, when known). With ``memo``, an element that the set of low
    vertices decides alone is kept by that set."""
    mask = z < (z.min() if zmin is None else zmin) + tol
    key = ("ground", tol, mask.tobytes())
    if memo is not None:
        got: ObjectElement | None = memo.get(key)
        if got is not None:
            return got
    low = np.flatnonzero(mask)
    vf = poly.vertex_faces
    common = frozenset.intersection(*(vf[i] for i in low))
    el: ObjectElement
    if len(low) >= 3 and len(common) == 1:
        el = Face(next(iter(common)))
    elif len(low) >= 3:  # several vertices low, no single face: the lowest face's plane
        normals = planes[0] if planes is not None else _planes(poly)[0]
        return Face(poly.face_ids[int(np.argmin(normals @ rotation[2]))])
    elif len(low) == 2 and len(common) == 2:
        el = Edge(common)
    elif len(low) == 1:  # (the lowest vertex: the set decides it, as the judge keeps it)
        el = Vertex(vf[int(low[0])])
    else:
        return Vertex(vf[int(np.argmin(z))])
    if memo is not None:
        memo[key] = el
    return el


#: Contact pairs already built, by their elements, and the elements that a set of near face
#: planes or of low vertices names (see :func:`observed_contacts`).
PairCache = dict[tuple[Any, ...], Any]


#: The ground (a value: one serves every contact pair).
_GROUND = Ground()


def _finger(k: int, cache: PairCache | None) -> Finger:
    """``Finger(k)``, built once per cache (building one checks its number)."""
    if cache is None:
        return Finger(k)
    got: Finger | None = cache.get(("finger", k))
    if got is None:
        got = cache[("finger", k)] = Finger(k)
    return got


def _pair(a: Ground | Finger, b: ObjectElement, cache: PairCache | None) -> ContactPair:
    """One :class:`ContactPair` per pair of elements: the same few pairs are observed at
    every sample, and building one checks and orders its elements. ``cache`` is the caller's
    (a controller keeps one per step); it holds at most one pair per finger or the ground
    and element of one object, so it stays small."""
    if cache is None:
        return ContactPair(a, b)
    got = cache.get((a, b))
    if got is None:
        got = cache[(a, b)] = ContactPair(a, b)
    return got


def observed_contacts(
    poly: Polyhedron, obs: Observation, *, finger_radius: float, tol: float,
    ground_tol: float, fingers: tuple[int, ...] | None = None,
    planes: tuple[FloatArray, FloatArray] | None = None,
    cache: PairCache | None = None,
) -> frozenset[ContactPair]:
    """The contact pairs an observation shows, by geometry.

    The ground touches the element lowest on the table (:func:`ground_element`, within
    ``ground_tol`` m) when that element is within ``ground_tol`` of the table plane ``z = 0``.
    A fingertip touches the object when its centre is within ``finger_radius + tol`` (m) of
    the object's surface (outside, or pressed inside as a compliant pad is); the element is
    named from the surface point nearest it (:func:`element_at`, ``tol``).

    Parameters
    ----------
    fingers : tuple of int, optional
        Finger numbers of the rows of ``obs.tips`` (default 1..n).
    planes : tuple of array, optional
        The face planes' unit normals, shape (n_faces, 3), and offsets, shape (n_faces,)
        (model frame), when the caller keeps them.
    cache : dict, optional
        Pairs built by earlier calls on the same object (filled here): a caller observing at
        the sensor rate passes its own and skips building the same few pairs again.
    """
    planes = planes if planes is not None else _planes(poly)
    if cache is not None:
        # at the sensor rate the same few elements come back sample after sample: read them
        # in floats when that gives what follows (None: it may not, read it as below)
        got = _contacts_in_floats(poly, obs, finger_radius, tol, ground_tol, fingers,
                                  planes, cache)
        if got is not None:
            return got
    pose = obs.pose
    s = pose.scale
    rot, trans = pose.rotation, pose.translation
    pairs: list[ContactPair] = []
    z = s * poly.vertices.dot(rot[2]) + trans[2]
    zmin = float(z.min())
    if zmin < ground_tol:
        pairs.append(_pair(_GROUND, _ground_of_heights(poly, z, rot, ground_tol, planes,
                                                        zmin, cache), cache))
    normals, offsets = planes
    tips = np.asarray(obs.tips, dtype=np.float64)
    numbers = fingers if fingers is not None else tuple(range(1, len(tips) + 1))
    if len(numbers) != len(tips):
        raise InputError(f"{len(numbers)} finger numbers for {len(tips)} fingertips")
    xs = (tips - trans).dot(rot) / s  # the tips in the model frame, shape (n_fingers, 3)
    ds = xs.dot(normals.T) - offsets  # signed distances to the face planes, model units
    reach = finger_radius + tol
    for j, top in enumerate(ds.max(axis=1).tolist()):
        if not top * s <= reach:
            # (a larger top distance is a lower bound of the distance: surely apart)
            continue
        x, d = xs[j], ds[j]
        if top > 0:
            y = _nearest_on_hull(x, d, planes)
            dist = _norm3(x - y) * s
        else:  # pressed inside (a compliant pad): nearest the plane it is least inside
            y = x - normals[int(np.argmax(d))] * top
            dist = top * s
        if dist <= reach:
            pairs.append(_pair(_finger(numbers[j], cache),
                               _element_of(poly, normals.dot(y) - offsets, tol / s, cache),
                               cache))
    return frozenset(pairs)


#: The float path's guard (see :func:`_contacts_in_floats`): a quantity this close (relative
#: to the magnitudes it is computed from) to the threshold it is compared with may compare
#: otherwise in numpy's arithmetic. Sums of three products rounded differently (numpy's
#: matrix products may fuse or reorder them) differ by a few units in the last place,
#: about 1e-15 of the magnitudes: 1e-9 leaves a factor of a million.
_GUARD = 1e-9
#: Objects up to this many vertices are read in floats: beyond, numpy's products win.
_FLOAT_VERTICES = 32


def _float_tables(poly: Polyhedron, planes: tuple[FloatArray, FloatArray], cache: PairCache
                  ) -> tuple[list[tuple[float, float, float]],
                             list[tuple[float, float, float, float]], float] | None:
    """The vertices and face planes as floats, kept in ``cache`` with the polyhedron and
    planes they were read from (None for a large object)."""
    got = cache.get(("floats",))
    if got is not None and got[0] is poly and got[1] is planes:
        return got[2]  # type: ignore[no-any-return]
    if len(poly.vertices) > _FLOAT_VERTICES:
        return None
    normals, offsets = planes
    verts = [(float(a), float(b), float(c)) for a, b, c in np.asarray(poly.vertices).tolist()]
    rows = [(float(a), float(b), float(c), float(o))
            for (a, b, c), o in zip(np.asarray(normals).tolist(),
                                    np.asarray(offsets).tolist(), strict=True)]
    big = max(max((abs(v) for p in verts for v in p), default=0.0),
              max((abs(r[3]) for r in rows), default=0.0))
    tables = (verts, rows, big)
    cache[("floats",)] = (poly, planes, tables)
    return tables


def _contacts_in_floats(
    poly: Polyhedron, obs: Observation, finger_radius: float, tol: float, ground_tol: float,
    fingers: tuple[int, ...] | None, planes: tuple[FloatArray, FloatArray], cache: PairCache,
) -> frozenset[ContactPair] | None:
    """:func:`observed_contacts` in Python floats, or None where it may differ.

    The contact set depends on the observation only through comparisons: the lowest vertex
    against ``ground_tol``, each vertex's height against it, each fingertip's distances to
    the face planes against zero and its reach, and the nearest surface point's against
    ``tol``. Each is computed here in floats, which differ from numpy's arithmetic by a few
    units in the last place; a comparison whose margin is above :data:`_GUARD` times the
    magnitudes involved comes out the same either way, and any smaller margin (or a NaN)
    gives None. The projection onto the hull is non-expansive, so what is projected carries
    no more than what went in. The elements and pairs are those of earlier calls (``cache``):
    one not seen yet, or one the nearest plane or the lowest vertex decides, gives None.
    The result is then the set the numpy path gives, bit for bit in what it names.
    """
    tables = _float_tables(poly, planes, cache)
    if tables is None:
        return None
    verts, rows, big = tables
    pose = obs.pose
    s = float(pose.scale)
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = pose.rotation.tolist()
    t0, t1, t2 = pose.translation.tolist()
    # heights (m): the guard scales with the largest term of the sums
    eps_z = _GUARD * (1.0 + abs(s) * big + abs(t2))
    z = [s * (vx * r20 + vy * r21 + vz * r22) + t2 for vx, vy, vz in verts]
    zmin = min(z)
    if not abs(zmin - ground_tol) > eps_z:
        return None
    pairs: list[ContactPair] = []
    if zmin < ground_tol:
        cut = zmin + ground_tol
        mask = []
        for h in z:
            if not abs(h - cut) > eps_z:
                return None
            mask.append(h < cut)
        el = cache.get(("ground", ground_tol, bytes(mask)))
        if el is None:
            return None
        pairs.append(_pair(_GROUND, el, cache))
    tips = obs.tips.tolist()
    numbers = fingers if fingers is not None else tuple(range(1, len(tips) + 1))
    if len(numbers) != len(tips):
        return None  # the numpy path says why
    reach = finger_radius + tol
    tol_u = tol / s
    for j, (p0, p1, p2) in enumerate(tips):
        # the tip in the model frame (model units), as ``(tip - t) @ R / s``
        d0, d1, d2 = p0 - t0, p1 - t1, p2 - t2
        x0 = (d0 * r00 + d1 * r10 + d2 * r20) / s
        x1 = (d0 * r01 + d1 * r11 + d2 * r21) / s
        x2 = (d0 * r02 + d1 * r12 + d2 * r22) / s
        eps = _GUARD * (1.0 + abs(x0) + abs(x1) + abs(x2) + big)  # model units
        ds = [n0 * x0 + n1 * x1 + n2 * x2 - off for n0, n1, n2, off in rows]
        top = max(ds)
        if not abs(top * s - reach) > eps * s:
            return None
        if not top * s <= reach:
            continue
        if top > 0:
            # the planes it lies outside of decide the projection: none near zero
            out = []
            for i, v in enumerate(ds):
                if not abs(v) > eps:
                    return None
                if v > 0:
                    out.append(rows[i])
            y0, y1, y2 = x0, x1, x2
            for _ in range(3 if len(out) > 1 else 1):
                for n0, n1, n2, off in out:
                    over = n0 * y0 + n1 * y1 + n2 * y2 - off
                    if over > 0:
                        y0, y1, y2 = y0 - n0 * over, y1 - n1 * over, y2 - n2 * over
            e0, e1, e2 = x0 - y0, x1 - y1, x2 - y2
            dist = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) * s
        else:  # pressed inside: the plane it is least inside decides, by a clear margin
            if not top < -eps:
                return None
            k = ds.index(top)
            if sum(1 for v in ds if not top - v > eps) != 1:
                return None
            n0, n1, n2, _ = rows[k]
            y0, y1, y2 = x0 - n0 * top, x1 - n1 * top, x2 - n2 * top
            dist = top * s
        if not abs(dist - reach) > eps * s:
            return None
        if dist <= reach:
            mask = []
            for n0, n1, n2, off in rows:
                v = n0 * y0 + n1 * y1 + n2 * y2 - off
                if not abs(v + tol_u) > eps:
                    return None
                mask.append(v > -tol_u)
            el = cache.get(("element", tol_u, bytes(mask)))
            if el is None:
                return None
            pairs.append(_pair(_finger(numbers[j], cache), el, cache))
    return frozenset(pairs)


def _norm3(v: FloatArray) -> float:
    """``np.linalg.norm`` of a 3-vector, the same number (its square is summed in order, as
    ``v @ v`` is) without numpy's call overhead."""
    a, b, c = v.tolist()
    return math.sqrt(a * a + b * b + c * c)


def _nearest_on_hull(x: FloatArray, d: FloatArray,
                     planes: tuple[FloatArray, FloatArray]) -> FloatArray:
    """The point of the convex polyhedron nearest ``x`` (model frame, outside it), by
    projecting in turn onto the face planes it lies outside of.

    Exact off a face, and off an edge or vertex whose faces meet at right angles (a box);
    between oblique faces a few rounds come within a fraction of the tolerance. Written by
    hand: a general convex distance (GJK) is more than the contact naming needs, and this
    runs at the observation rate.
    """
    normals, offsets = planes
    idx = [i for i, v in enumerate(d.tolist()) if v > 0]
    # in floats: the same sums, in the same order, as numpy's ``normals[i] @ y`` (a dot of
    # three) and ``y - normals[i] * over``, without its call overhead
    y0, y1, y2 = np.asarray(x, dtype=np.float64).tolist()
    rows = [(*normals[i].tolist(), float(offsets[i])) for i in idx]
    for _ in range(3 if len(idx) > 1 else 1):
        for n0, n1, n2, off in rows:
            over = n0 * y0 + n1 * y1 + n2 * y2 - off
            if over > 0:
                y0, y1, y2 = y0 - n0 * over, y1 - n1 * over, y2 - n2 * over
    return np.array([y0, y1, y2])
