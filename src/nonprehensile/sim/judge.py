"""The judge: what physics did, read the same way whatever moves the fingers.

A :class:`Judge` reads a compiled scene (the object, the table, the fingertip geoms by finger
number) and knows nothing of how the fingertips are moved (free spheres today, a robot arm's
tool tomorrow: :mod:`nonprehensile.sim.driver`). It gives every driver the same rules:

* **contact reading**: MuJoCo's contacts named as the skill model's contact pairs, the touched
  face, edge or vertex found from the contact point in the object's frame
  (:meth:`Judge.contacts`);
* **events**: contact sets debounced into :class:`SimEvent` values (:class:`EventLog`);
* **settling**: the object is at rest when its free joint's velocity stays below
  :data:`STILL_VELOCITY` for :data:`STILL_TIME` (:meth:`Judge.is_still`);
* **the state** it rests in (:meth:`Judge.state`); the comparison with a prediction is
  :func:`nonprehensile.sim.compare.compare`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import GeometryError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose
from nonprehensile.sim.scene import SimParams
from nonprehensile.skills.contacts import (
    ContactEvent,
    ContactPair,
    Edge,
    Face,
    Finger,
    Ground,
    ObjectElement,
    Vertex,
)
from nonprehensile.states import State, state_of_pose

__all__ = [
    "CONTACT_EVERY",
    "REST_TILT_DEG",
    "STILL_TIME",
    "STILL_VELOCITY",
    "EventLog",
    "Judge",
    "SimEvent",
]

FloatArray = NDArray[np.float64]

#: Contacts are read every this many physics steps (5 ms at the default 1 ms step).
CONTACT_EVERY = 5
#: Tilt (degrees) of the bottom face from horizontal still read as resting on it.
REST_TILT_DEG = 3.0
#: The object is still when no component of its free joint's velocity (m/s, rad/s) exceeds
#: this ...
STILL_VELOCITY = 1e-3
#: ... for this long (s).
STILL_TIME = 0.05
#: The contact set of no contact (one object: reads compare it with itself).
_NO_CONTACT: frozenset[ContactPair] = frozenset()
#: Reads in floats (guarded, the same results as numpy's) for objects up to this many
#: vertices; beyond, numpy's products are faster.
_FLOAT_VERTICES = 32
#: A comparison computed in floats stands when its margin exceeds this times the magnitudes
#: involved: a sum of three products rounded otherwise (numpy's products may fuse or
#: reorder them) moves by a few units in the last place, about 1e-15 of them.
_GUARD = 1e-9


@dataclass(frozen=True)
class SimEvent:
    """A debounced contact event read from the simulation.

    Attributes
    ----------
    time : float
        When the contact set began (s from the start of the motion).
    event : ContactEvent
        The contact pairs (fingers and ground with the face, edge or vertex touched); the id
        is empty. Fingers touching the table are not contact pairs of the skill model's kind
        that skills name, and are left out.
    """

    time: float
    event: ContactEvent

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"time": round(self.time, 4),
                "contacts": [str(p) for p in self.event.ordered_pairs]}


class Judge:
    """Contact reading, settling and the resting state of one compiled scene.

    Parameters
    ----------
    poly : Polyhedron
        The object model (model units).
    scale : float
        Metres per model unit.
    params : SimParams
        ``contact_tol`` names touched elements; ``debounce`` makes events.
    model : mujoco.MjModel
        A scene with a body and geom ``object``, a geom ``table`` and, per finger ``k``, a
        geom ``finger{k}`` (its tip: the only part of a finger that may touch the object).
    n_fingers : int
    """

    def __init__(self, poly: Polyhedron, scale: float, params: SimParams, model: Any,
                 n_fingers: int) -> None:
        self.poly = poly
        self.scale = scale
        self.params = params
        self._model = model  # mj_contactForce reads the contacts' solver parameters
        m = model
        self.body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        self.obj_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
        self.table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        self.finger_geoms = {
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"finger{k}"): k
            for k in range(1, n_fingers + 1)
        }
        # each fingertip geom's finger, built once (contacts are named at every read)
        self._tip_fingers = {g: Finger(k) for g, k in self.finger_geoms.items()}
        self._com = np.asarray(poly.com, dtype=np.float64)
        jnt = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "object")
        self.qadr = int(m.jnt_qposadr[jnt])
        self.dadr = int(m.jnt_dofadr[jnt])
        # the ground pair last read, the pose row and height it was read at, and how far
        # the vertices' heights may move before the set of low vertices can change
        self._ground_last: tuple[float, float, float, float, float, ContactPair] | None = None
        self._reach = scale * float(np.linalg.norm(poly.vertices, axis=1).max())
        # face planes in the model frame (model units), to name touched elements
        self._normals = np.array([poly.normals[f] for f in poly.face_ids])
        self._offsets = np.array([poly.normals[f] @ poly.vertices[poly.faces[f][0]]
                                  for f in poly.face_ids])
        # the same planes and the vertices as floats, for a small object (reads in floats,
        # guarded: see _element_in_floats); None for a large one, read by numpy alone
        self._float_rows: list[tuple[float, float, float, float]] | None = None
        self._float_verts: list[tuple[float, float, float]] | None = None
        self._big = 0.0
        if len(poly.vertices) <= _FLOAT_VERTICES:
            self._float_rows = [(a, b, c, o) for (a, b, c), o in zip(
                self._normals.tolist(), self._offsets.tolist(), strict=True)]
            self._float_verts = [(a, b, c) for a, b, c in
                                 np.asarray(poly.vertices, dtype=np.float64).tolist()]
            self._big = max(max(abs(v) for p in self._float_verts for v in p),
                            max(abs(r[3]) for r in self._float_rows))
        # contacts are read every few steps and name the same few elements and pairs over and
        # over: an element that the set of near planes (or of low vertices) decides alone is
        # kept by that set, and a pair by its ends (the results are those computed afresh)
        self._element_memo: dict[tuple[float, bytes], ObjectElement] = {}
        # each fingertip's last element read in floats: (tol, the point in the model frame,
        # the square of the distance it may move and stay near the same planes, element)
        self._last_elements: dict[int, tuple[float, float, float, float, float,
                                             ObjectElement]] = {}
        self._ground_memo: dict[tuple[float, bytes], ObjectElement] = {}
        self._pair_memo: dict[tuple[Any, ObjectElement], ContactPair] = {}
        self._set_memo: dict[frozenset[int], frozenset[ContactPair]] = {}
        # the object on the table and nothing else, the commonest read: its geom pair either
        # way round, and the last ground pair with its contact set
        self._on_table = ([self.obj_geom, self.table], [self.table, self.obj_geom])
        self._ground_set: tuple[ContactPair, frozenset[ContactPair]] | None = None
        # the object's rotation and position as views of the last data read (MuJoCo's
        # arrays stay where they are for the data's life): read through, never copied
        self._bound: Any = None
        self._bound_vel: Any = None
        self._vel: FloatArray = np.zeros(6)
        self._r: FloatArray = np.eye(3)
        self._t: FloatArray = np.zeros(3)
        self._r2: FloatArray = self._r[2]

    def _views(self, data: Any) -> tuple[FloatArray, FloatArray]:
        """The object's rotation matrix and position in ``data`` (views)."""
        if data is not self._bound:
            self._r = data.xmat[self.body].reshape(3, 3)
            self._t = data.xpos[self.body]
            self._r2 = self._r[2]  # the ground's read needs the last row alone
            self._bound = data
        return self._r, self._t

    # ------------------------------------------------------------------------ the object
    def pose(self, data: Any) -> ObjectPose:
        """The object's current pose."""
        rv, tv = self._views(data)
        r, t = rv.copy(), tv.copy()
        # ``scale * (r @ com) + t``: ``a.dot(b)`` is the BLAS call ``a @ b`` makes, the
        # same numbers, without the matmul ufunc's dispatch; the product and sum element
        # by element in floats, the same correctly rounded operations as numpy's
        c0, c1, c2 = r.dot(self._com).tolist()
        t0, t1, t2 = t.tolist()
        s = self.scale
        return ObjectPose(r, t, np.array([s * c0 + t0, s * c1 + t1, s * c2 + t2]), s)

    def state(self, data: Any, tol_deg: float = REST_TILT_DEG) -> State | None:
        """The state the object rests in now, or None."""
        try:
            return state_of_pose(self.poly, data.xmat[self.body].reshape(3, 3), tol=tol_deg)
        except GeometryError:
            return None

    def speed(self, data: Any) -> float:
        """Largest component of the object's free-joint velocity (m/s and rad/s)."""
        if data is not self._bound_vel:  # a view of the free joint's velocity, kept
            self._vel = data.qvel[self.dadr:self.dadr + 6]
            self._bound_vel = data
        # (in floats: the same largest magnitude as numpy's, without its call overhead; but
        # max() skips a NaN that is not first, and a blown-up object must not read as still)
        v = self._vel.tolist()
        total = sum(v)  # NaN if any component is
        return float(max(map(abs, v))) if total == total else math.nan

    def is_still(self, data: Any) -> bool:
        """Whether the object's velocity is below :data:`STILL_VELOCITY` now."""
        return self.speed(data) < STILL_VELOCITY

    # ---------------------------------------------------------------------------- contacts
    def element(self, x: FloatArray) -> ObjectElement:
        """The face, edge or vertex of the model nearest a surface point (model frame)."""
        tol = self.params.contact_tol / self.scale
        d = self._normals.dot(x) - self._offsets
        mask = d > -tol
        key = (tol, mask.tobytes())
        got = self._element_memo.get(key)
        if got is not None:
            return got
        near = [self.poly.face_ids[i] for i in np.flatnonzero(mask)]
        if not near:  # the nearest plane decides: not kept
            return Face(self.poly.face_ids[int(np.argmax(d))])
        el: ObjectElement
        if len(near) == 1:
            el = Face(near[0])
        elif len(near) == 2 and frozenset(near) in self.poly.edges:
            el = Edge(frozenset(near))
        else:
            shared = self.poly.shared_vertices(near) if len(near) >= 3 else []
            if not shared:  # the nearest plane decides: not kept
                return Face(self.poly.face_ids[int(np.argmax(d))])
            el = Vertex(self.poly.vertex_faces[shared[0]])
        self._element_memo[key] = el
        return el

    def _element_in_floats(self, p: list[float], r: list[list[float]], t: list[float],
                           key: int = -1) -> ObjectElement | None:
        """:meth:`element` of the world contact point ``p`` at the pose ``(r, t)`` (as
        lists), computed in floats, or None where that may differ from :meth:`element`.

        The element depends on the point only through which face planes it is within
        ``contact_tol`` of. Floats differ from numpy's products by a few units in the last
        place; a plane whose margin to the tolerance exceeds :data:`_GUARD` times the
        magnitudes involved is near (or not) either way. A smaller margin, a NaN, or a set
        of near planes not named before (the memo) gives None: :meth:`element` decides.

        With ``key`` (the fingertip's geom), a point that has moved less than the last
        one's margin since (each plane's distance moves no more than the point: unit
        normals) is near the same planes: the last element, without the planes.
        """
        rows = self._float_rows
        if rows is None:
            return None
        tol = self.params.contact_tol / self.scale
        d0, d1, d2 = p[0] - t[0], p[1] - t[1], p[2] - t[2]
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = r
        sc = self.scale
        # ``r.T @ (p - t) / scale``: the point in the model frame (model units)
        x0 = (r00 * d0 + r10 * d1 + r20 * d2) / sc
        x1 = (r01 * d0 + r11 * d1 + r21 * d2) / sc
        x2 = (r02 * d0 + r12 * d1 + r22 * d2) / sc
        eps = _GUARD * (1.0 + abs(x0) + abs(x1) + abs(x2) + self._big)
        last = self._last_elements.get(key)
        if last is not None and last[0] == tol:
            e0, e1, e2 = x0 - last[1], x1 - last[2], x2 - last[3]
            if e0 * e0 + e1 * e1 + e2 * e2 < last[4]:  # (a NaN compares False)
                return last[5]
        mask = []
        margin = math.inf
        for n0, n1, n2, off in rows:
            v = n0 * x0 + n1 * x1 + n2 * x2 - off
            a = abs(v + tol)
            if not a > eps:
                return None
            if a < margin:
                margin = a
            mask.append(v > -tol)
        el = self._element_memo.get((tol, bytes(mask)))
        if el is not None and key >= 0:
            # (less the guard twice: this point's rounding and the next one's)
            m = margin - 2.0 * eps
            self._last_elements[key] = (tol, x0, x1, x2, m * m if m > 0 else 0.0, el)
        return el

    def ground_element(self, pose_r: FloatArray, pose_t: FloatArray) -> ObjectElement:
        """The face, edge or vertex of the object lowest on the table (within
        ``contact_tol``) at the pose ``(R, t)``."""
        return self._ground_and_margin(pose_r, pose_t)[0]

    def _ground_and_margin(self, pose_r: FloatArray, pose_t: FloatArray
                           ) -> tuple[ObjectElement, float]:
        """:meth:`ground_element`, and the margin (m) by which the vertices' heights above
        the lowest one clear ``contact_tol`` when the set of low vertices alone decides the
        element (else 0: the pose itself decides)."""
        tol = self.params.contact_tol
        z = self.scale * self.poly.vertices.dot(pose_r[2]) + pose_t[2]
        above = z - z.min() - tol
        mask = above < 0
        key = (tol, mask.tobytes())
        got = self._ground_memo.get(key)
        if got is not None:
            return got, float(np.abs(above).min())
        low = np.flatnonzero(mask)
        vf = self.poly.vertex_faces
        common = frozenset.intersection(*(vf[i] for i in low))
        el: ObjectElement
        if len(low) >= 3 and len(common) == 1:
            el = Face(next(iter(common)))
        elif len(low) >= 3:  # several vertices low, no single face: the lowest face's plane
            normals_z = self._normals @ pose_r[2]
            return Face(self.poly.face_ids[int(np.argmin(normals_z))]), 0.0  # the pose decides
        elif len(low) == 2 and len(common) == 2:
            el = Edge(common)
        elif len(low) == 1:
            el = Vertex(vf[int(low[0])])
        else:  # two low vertices on no common edge: the lower one, the pose decides
            return Vertex(vf[int(np.argmin(z))]), 0.0
        self._ground_memo[key] = el
        return el, float(np.abs(above).min())

    def _ground_in_floats(self, rx: float, ry: float, rz: float, tz: float
                          ) -> tuple[ObjectElement, float] | None:
        """:meth:`_ground_and_margin` at the pose whose rotation's last row is
        ``(rx, ry, rz)`` and height ``tz``, in floats: the element when the set of low
        vertices is clear of the tolerance by :data:`_GUARD` times the heights' magnitudes
        and was named before (the memo), with a margin less that guard (a smaller one is
        safe: the pair is then read again sooner); else None."""
        verts = self._float_verts
        if verts is None:
            return None
        tol = self.params.contact_tol
        sc = self.scale
        z = [sc * (vx * rx + vy * ry + vz * rz) + tz for vx, vy, vz in verts]
        zmin = min(z)
        eps = _GUARD * (1.0 + abs(sc) * self._big + abs(tz))
        mask = []
        margin = math.inf
        for h in z:
            above = h - zmin - tol
            a = abs(above)
            if not a > eps:
                return None
            if a < margin:
                margin = a
            mask.append(above < 0)
        el = self._ground_memo.get((tol, bytes(mask)))
        if el is None:
            return None
        return el, margin - eps

    def _pair(self, a: Any, b: ObjectElement) -> ContactPair:
        key = (a, b)
        got = self._pair_memo.get(key)
        if got is None:
            got = self._pair_memo[key] = ContactPair(a, b)
        return got

    def contacts(self, data: Any) -> tuple[frozenset[ContactPair], bool, bool]:
        """The contact pairs now, whether a fingertip touches the table, and whether any
        part of a finger other than its tip (a link of a robot arm) touches the object or
        the table."""
        con = data.contact
        # the arrays read in bulk, once: each field read builds a numpy view (MuJoCo's
        # contact arrays are ``ncon`` long: their length is ``ncon``, without reading it)
        geoms = con.geom.tolist()
        n = len(geoms)
        if n == 0:
            return _NO_CONTACT, False, False
        dist = con.dist.tolist()
        r, t = self._views(data)
        on, no = self._on_table
        if geoms.count(on) + geoms.count(no) == n and max(dist) <= 1e-4:
            # every contact the object's on the table (what the loop below finds then: the
            # ground alone), counted at C speed
            pair = self._ground_pair_at(r, t, self._r2)
            last = self._ground_set
            if last is None or last[0] is not pair:
                last = self._ground_set = (pair, self._contact_set([pair]))
            return last[1], False, False
        found: list[ContactPair] = []
        finger_table = other_contact = ground = False
        obj, table, tips = self.obj_geom, self.table, self._tip_fingers
        pos: list[list[float]] | None = None
        rl: list[list[float]] = []
        tl: list[float] = []
        for i, ((a, b), dd) in enumerate(zip(geoms, dist, strict=True)):
            if dd > 1e-4:
                continue
            if a == obj or b == obj:
                other = b if a == obj else a
                if other == table:
                    ground = True
                elif other in tips:
                    if pos is None:  # read once, as floats (the pose too)
                        pos, rl, tl = con.pos.tolist(), r.tolist(), t.tolist()
                    el = self._element_in_floats(pos[i], rl, tl, other)
                    if el is None:  # not decided in floats: numpy's products decide
                        el = self.element(r.T.dot(con.pos[i] - t) / self.scale)
                    found.append(self._pair(tips[other], el))
                else:
                    other_contact = True
            elif a in tips or b in tips:
                finger_table = True
            else:
                other_contact = True
        if ground:
            found.append(self._ground_pair_at(r, t))
        return self._contact_set(found), finger_table, other_contact

    def _contact_set(self, found: list[ContactPair]) -> frozenset[ContactPair]:
        """``frozenset(found)``, one object per set: the same contact set comes back read
        after read, so that comparing two reads is mostly comparing an object with itself."""
        key = frozenset(map(id, found))
        got = self._set_memo.get(key)
        if got is None:
            got = self._set_memo[key] = frozenset(found)
        return got

    def _ground_pair_at(self, r: FloatArray, t: FloatArray,
                        row: FloatArray | None = None) -> ContactPair:
        """The ground's contact pair at the pose ``(r, t)``, read again only when the
        object has moved enough since the last read to change the set of low vertices: a
        vertex's height changes by at most ``|dR[2]| * reach + |dt_z|`` and its height above
        the lowest one by twice that (most reads find the object resting or rolling on the
        same element: the pair is then the one computed afresh). ``row``: ``r[2]``, if
        kept (indexing builds a new view at every read)."""
        rx, ry, rz = (r[2] if row is None else row).tolist()
        tz = t.item(2)  # (the float ``float(t[2])`` gives, without the numpy scalar)
        last = self._ground_last
        if last is not None:
            dx, dy, dz = rx - last[0], ry - last[1], rz - last[2]
            move = self._reach * math.sqrt(dx * dx + dy * dy + dz * dz) + abs(tz - last[3])
            if 2.0 * move + 1e-12 < last[4]:  # (1e-12 m: the heights' rounding)
                return last[5]
        got = self._ground_in_floats(rx, ry, rz, tz)
        el, margin = got if got is not None else self._ground_and_margin(r, t)
        pair = self._pair(Ground(), el)
        self._ground_last = (rx, ry, rz, tz, margin, pair)
        return pair

    def forces_and_slip(self, data: Any, n_fingers: int) -> tuple[FloatArray, float]:
        """Each fingertip's normal force on the object now (N, shape (n_fingers,)), and the
        object's slip on the table (m/s: the largest horizontal speed of its points touching
        the table; NaN when it touches none)."""
        force = np.zeros(n_fingers)
        slip = math.nan
        f6 = np.zeros(6)
        r = data.xmat[self.body].reshape(3, 3)
        v = data.qvel[self.dadr:self.dadr + 3]  # the free joint: world linear velocity
        w = r @ data.qvel[self.dadr + 3:self.dadr + 6]  # and body-frame angular velocity
        origin = data.xpos[self.body]
        con = data.contact
        for i in range(data.ncon):
            a, b = int(con.geom1[i]), int(con.geom2[i])
            if self.obj_geom not in (a, b) or con.dist[i] > 1e-4:
                continue
            other = b if a == self.obj_geom else a
            if other in self.finger_geoms:
                mujoco.mj_contactForce(self._model, data, i, f6)
                force[self.finger_geoms[other] - 1] += abs(float(f6[0]))
            elif other == self.table:
                speed = float(np.hypot(*(v + np.cross(w, con.pos[i] - origin))[:2]))
                slip = speed if math.isnan(slip) else max(slip, speed)
        return force, slip

    def finger_object_contact(self, data: Any) -> bool:
        """Whether any fingertip touches the object now (transits measure it)."""
        n = data.ncon
        if n == 0:
            return False
        con = data.contact
        obj, tips = self.obj_geom, self.finger_geoms
        for (a, b), dd in zip(con.geom[:n].tolist(), con.dist[:n].tolist(), strict=True):
            if dd <= 1e-4 and ((a == obj and b in tips) or (b == obj and a in tips)):
                return True
        return False

    @staticmethod
    def touches_finger(pairs: frozenset[ContactPair]) -> bool:
        """Whether a contact set of :meth:`contacts` has a fingertip on the object (what
        :meth:`finger_object_contact` reads from the simulator, without reading it
        again)."""
        return any(isinstance(p.x, Finger) for p in pairs)


class EventLog:
    """Debounced contact events of one motion, read from a :class:`Judge`.

    A contact set becomes an event once it has held for ``SimParams.debounce``;
    :meth:`close` adds a final set that had not yet lasted that long (it counts at rest).
    """

    def __init__(self, judge: Judge, t0: float = 0.0) -> None:
        self.judge = judge
        self.t0 = t0
        self.events: list[SimEvent] = []
        self.current: frozenset[ContactPair] | None = None
        self._candidate: frozenset[ContactPair] | None = None
        self._since = 0.0
        self.finger_table = False
        self.other_contact = False
        self._hold = judge.params.debounce - 1e-12

    def observe(self, data: Any, now: float) -> frozenset[ContactPair]:
        """Read the contacts at simulated time ``now`` (s); returns the contact set."""
        pairs, ft, oc = self.judge.contacts(data)
        if ft:
            self.finger_table = True
        if oc:
            self.other_contact = True
        # (``is`` first: the judge hands back the same object for the same set)
        if pairs is not self._candidate and pairs != self._candidate:
            self._candidate, self._since = pairs, now
        if self._candidate is not self.current and self._candidate != self.current \
                and now - self._since >= self._hold and self._candidate:
            self.current = self._candidate
            self.events.append(SimEvent(self._since - self.t0,
                                        ContactEvent("", self._candidate)))
        return pairs

    def close(self, data: Any, now: float) -> None:
        """A final contact set that had not yet lasted the debounce time counts at rest."""
        pairs, _, _ = self.judge.contacts(data)
        if pairs and pairs != self.current:
            self.current = pairs
            self.events.append(SimEvent(now - self.t0, ContactEvent("", pairs)))
