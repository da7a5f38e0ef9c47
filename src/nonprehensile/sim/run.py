"""Run fingertips along reference trajectories in MuJoCo and read back what happened.

:class:`Simulator` holds a compiled scene; :meth:`Simulator.run` places the object, drives the
fingertips through pre-interpolated targets with ``mj_step`` in a tight loop, reads the
contacts every few steps, lets the object settle and returns a :class:`SimResult`: the final
pose, the final state (:func:`~nonprehensile.states.state_of_pose`), and the debounced contact
events as the project's own :class:`~nonprehensile.skills.contacts.ContactEvent` values.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import GeometryError, InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams, scene_xml
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
from nonprehensile.states import State, state_of_pose, state_pose
from nonprehensile.geometry.units import UNIT_METRES

__all__ = [
    "SimEvent",
    "SimResult",
    "Simulator",
    "default_scale",
    "pose_of_state",
]

FloatArray = NDArray[np.float64]

#: Contacts are read every this many physics steps (5 ms at the default 1 ms step).
CONTACT_EVERY = 5
#: Tilt (degrees) of the bottom face from horizontal still read as resting on it.
REST_TILT_DEG = 3.0


def default_scale(poly: Polyhedron) -> float:
    """Metres per model unit from the model's ``units``."""
    try:
        return UNIT_METRES[poly.units]
    except KeyError:
        raise InputError(
            f"model {poly.name!r} has units {poly.units!r}; the simulation knows "
            f"{sorted(UNIT_METRES)}: give the scale (metres per model unit) explicitly"
        ) from None


def pose_of_state(poly: Polyhedron, state: State, position: Sequence[float] = (0.0, 0.0),
                  scale: float = 1.0) -> ObjectPose:
    """The pose of a resting state with its centre of mass above ``position`` (metres)."""
    r, t = state_pose(poly, state)
    tw = scale * t + np.array([float(position[0]), float(position[1]), 0.0])
    return ObjectPose(r, tw, scale * (r @ poly.com) + tw, scale)


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


@dataclass(frozen=True)
class SimResult:
    """What one simulated motion produced.

    Attributes
    ----------
    final_pose : ObjectPose
        The object's pose after settling.
    final_state : State or None
        The state it rests in, or None if it rests on no face of the model (still moving, or
        on an edge held by nothing).
    events : tuple of SimEvent
        Debounced contact events, in time order.
    settled : bool
        Whether the object came to rest within ``SimParams.settle``.
    sim_time : float
        Simulated seconds (motion and settling).
    wall_time : float
        Wall-clock seconds spent (building the targets and stepping).
    n_steps : int
        Physics steps taken.
    finger_table_contact : bool
        Whether a fingertip touched the table.
    """

    final_pose: ObjectPose
    final_state: State | None
    events: tuple[SimEvent, ...]
    settled: bool
    sim_time: float
    wall_time: float
    n_steps: int
    finger_table_contact: bool = False
    trace: FloatArray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "final_state": self.final_state.to_dict() if self.final_state is not None else None,
            "final_position": [round(v, 6) for v in self.final_pose.position],
            "final_pose": self.final_pose.to_dict(),
            "events": [e.to_dict() for e in self.events],
            "settled": self.settled,
            "sim_seconds": round(self.sim_time, 4),
            "wall_seconds": round(self.wall_time, 4),
            "steps": self.n_steps,
            "finger_table_contact": self.finger_table_contact,
        }


class Simulator:
    """A compiled MuJoCo scene of one object and ``n_fingers`` fingertips.

    Parameters
    ----------
    poly : Polyhedron
        A convex object model.
    scale : float, optional
        Metres per model unit; default from the model's ``units``.
    n_fingers : int
        Fingertips ``R1 .. Rn``.
    params : SimParams
    """

    def __init__(self, poly: Polyhedron, *, scale: float | None = None, n_fingers: int = 2,
                 params: SimParams = DEFAULT_PARAMS) -> None:
        if isinstance(n_fingers, bool) or not isinstance(n_fingers, int) or not \
                1 <= n_fingers <= 10:
            raise InputError(f"n_fingers must be a whole number in 1..10, got {n_fingers!r}")
        self.poly = poly
        self.scale = float(scale) if scale is not None else default_scale(poly)
        self.n_fingers = n_fingers
        self.params = params
        self.xml = scene_xml(poly, scale=self.scale, n_fingers=n_fingers, params=params)
        try:
            self.model = mujoco.MjModel.from_xml_string(self.xml)
        except ValueError as exc:  # MuJoCo's compiler refuses the mesh
            raise InputError(f"MuJoCo cannot build a scene of {poly.name!r}: {exc}") from None
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        self._obj_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
        self._table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        self._finger_geoms = {
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"finger{k}"): k
            for k in range(1, n_fingers + 1)
        }
        adr = m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "object")]
        self._qadr = int(adr)
        self._dadr = int(m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT,
                                                        "object")])
        self._finger_qadr = np.array([
            m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"finger{k}_{a}")]
            for k in range(1, n_fingers + 1) for a in "xyz"])
        self._finger_dadr = np.array([
            m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"finger{k}_{a}")]
            for k in range(1, n_fingers + 1) for a in "xyz"])
        # face planes in the model frame (model units) and vertices, to name touched elements
        self._normals = np.array([poly.normals[f] for f in poly.face_ids])
        self._offsets = np.array([poly.normals[f] @ poly.vertices[poly.faces[f][0]]
                                  for f in poly.face_ids])

    # ------------------------------------------------------------------------ state access
    def pose(self) -> ObjectPose:
        """The object's current pose."""
        d = self.data
        r = d.xmat[self._body].reshape(3, 3).copy()
        t = d.xpos[self._body].copy()
        return ObjectPose(r, t, self.scale * (r @ self.poly.com) + t, self.scale)

    def set_pose(self, pose: ObjectPose) -> None:
        """Put the object at ``pose`` (at rest)."""
        q = np.empty(4)
        mujoco.mju_mat2Quat(q, np.ascontiguousarray(pose.rotation, dtype=np.float64).ravel())
        self.data.qpos[self._qadr:self._qadr + 3] = pose.translation
        self.data.qpos[self._qadr + 3:self._qadr + 7] = q
        self.data.qvel[:] = 0.0

    def state(self, tol_deg: float = REST_TILT_DEG) -> State | None:
        """The state the object rests in now, or None."""
        try:
            return state_of_pose(self.poly, self.pose().rotation, tol=tol_deg)
        except GeometryError:
            return None

    # ---------------------------------------------------------------------------- contacts
    def _element(self, x: FloatArray) -> ObjectElement:
        """The face, edge or vertex of the model nearest a surface point (model frame)."""
        tol = self.params.contact_tol / self.scale
        d = self._normals @ x - self._offsets
        near = [self.poly.face_ids[i] for i in np.flatnonzero(d > -tol)]
        if not near:
            near = [self.poly.face_ids[int(np.argmax(d))]]
        if len(near) == 1:
            return Face(near[0])
        if len(near) == 2 and frozenset(near) in self.poly.edges:
            return Edge(frozenset(near))
        shared = self.poly.shared_vertices(near) if len(near) >= 3 else []
        if shared:
            return Vertex(self.poly.vertex_faces[shared[0]])
        return Face(self.poly.face_ids[int(np.argmax(d))])

    def _ground_element(self, pose_r: FloatArray, pose_t: FloatArray) -> ObjectElement:
        z = self.scale * (self.poly.vertices @ pose_r[2]) + pose_t[2]
        low = np.flatnonzero(z < z.min() + self.params.contact_tol)
        vf = self.poly.vertex_faces
        common = frozenset.intersection(*(vf[i] for i in low))
        if len(low) >= 3 and len(common) == 1:
            return Face(next(iter(common)))
        if len(low) >= 3:  # several vertices low, no single face: the lowest face's plane
            normals_z = self._normals @ pose_r[2]
            return Face(self.poly.face_ids[int(np.argmin(normals_z))])
        if len(low) == 2 and len(common) == 2:
            return Edge(common)
        return Vertex(vf[int(np.argmin(z))])

    def _contacts(self) -> tuple[frozenset[ContactPair], bool]:
        d = self.data
        n = d.ncon
        if n == 0:
            return frozenset(), False
        con = d.contact
        g1, g2, dist = con.geom1[:n], con.geom2[:n], con.dist[:n]
        r = d.xmat[self._body].reshape(3, 3)
        t = d.xpos[self._body]
        pairs: set[ContactPair] = set()
        finger_table = False
        ground = False
        for i in range(n):
            if dist[i] > 1e-4:
                continue
            a, b = int(g1[i]), int(g2[i])
            if self._obj_geom in (a, b):
                other = b if a == self._obj_geom else a
                if other == self._table:
                    ground = True
                elif other in self._finger_geoms:
                    x = r.T @ (con.pos[i] - t) / self.scale
                    pairs.add(ContactPair(Finger(self._finger_geoms[other]), self._element(x)))
            else:
                finger_table = True
        if ground:
            pairs.add(ContactPair(Ground(), self._ground_element(r, t)))
        return frozenset(pairs), finger_table

    # --------------------------------------------------------------------------------- run
    def run(
        self,
        start: ObjectPose | None,
        targets: Mapping[int, FloatArray],
        rate: float,
        *,
        settle: float | None = None,
        keep_trace: int = 0,
    ) -> SimResult:
        """Drive the fingertips through ``targets`` with the object starting at ``start``.

        Parameters
        ----------
        start : ObjectPose or None
            The object's pose at rest before the motion (metres); None: carry on from the
            object's current pose and velocity (the fingertips jump to their first targets).
        targets : mapping of int to array, shape (n_frames, 3)
            Finger number -> its centre's trajectory in the world (metres), sampled at
            ``rate``; fingers not given stay parked away from the object. NaN is refused.
        rate : float
            Sample rate of the targets, Hz (interpolated linearly to the physics step).
        settle : float, optional
            Longest time to let the object come to rest after the motion (default the
            parameters').
        keep_trace : int
            If > 0, keep the object's and fingers' poses every this many steps in
            ``SimResult.trace`` (for rendering): rows ``[t, x, y, z, qw, qx, qy, qz,
            finger xyz ...]``.

        Raises
        ------
        InputError
            Targets with NaN or infinities, of the wrong shape, naming unknown fingers.
        """
        wall0 = time.perf_counter()
        p = self.params
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
            raise InputError(f"the trajectory rate must be a finite positive number of Hz, "
                             f"got {rate!r}")
        lengths = set()
        for k, tr in targets.items():
            if k not in range(1, self.n_fingers + 1):
                raise InputError(f"finger R{k} is not in the scene (R1..R{self.n_fingers})")
            arr = np.asarray(tr, dtype=float)
            if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) < 2:
                raise InputError(f"the trajectory of R{k} must have shape (n_frames >= 2, 3), "
                                 f"got {arr.shape}")
            if not np.isfinite(arr).all():
                bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
                raise InputError(f"the trajectory of R{k} has NaN or infinite values (first at "
                                 f"frame {bad}); fill the gaps before simulating")
            if np.abs(arr).max() > 100.0:
                raise InputError(f"the trajectory of R{k} goes {np.abs(arr).max():.3g} m from "
                                 "the origin: give it in metres")
            lengths.add(len(arr))
        if len(lengths) > 1:
            raise InputError(f"the fingers' trajectories differ in length: {sorted(lengths)}")
        n_frames = lengths.pop() if lengths else 2
        duration = (n_frames - 1) / rate
        n_move = max(1, round(duration / p.timestep))
        t_move = np.arange(n_move + 1) * p.timestep
        t_ref = np.arange(n_frames) / rate
        ctrl = np.empty((n_move + 1, 3 * self.n_fingers))
        park = self.scale * self.poly.diameter * 3.0 + 0.05
        for k in range(1, self.n_fingers + 1):
            cols = slice(3 * (k - 1), 3 * k)
            if k in targets:
                arr = np.asarray(targets[k], dtype=float)
                ctrl[:, cols] = np.column_stack(
                    [np.interp(t_move, t_ref, arr[:, j]) for j in range(3)])
            else:  # parked far above the table
                ctrl[:, cols] = np.array([park * k, park, park])

        m, d = self.model, self.data
        if start is not None:
            mujoco.mj_resetData(m, d)
            self.set_pose(start)
        d.time = 0.0
        d.qpos[self._finger_qadr] = ctrl[0]
        d.qvel[self._finger_dadr] = 0.0
        d.ctrl[:] = ctrl[0]
        mujoco.mj_forward(m, d)

        events: list[SimEvent] = []
        current: frozenset[ContactPair] | None = None
        candidate: frozenset[ContactPair] | None = None
        cand_since = 0.0
        touched_table = False
        hold = p.debounce
        trace: list[FloatArray] = []

        def observe(now: float) -> None:
            nonlocal current, candidate, cand_since, touched_table
            pairs, ft = self._contacts()
            touched_table = touched_table or ft
            if pairs != candidate:
                candidate, cand_since = pairs, now
            if candidate != current and now - cand_since >= hold - 1e-12 and candidate:
                current = candidate
                events.append(SimEvent(cand_since, ContactEvent("", candidate)))

        def record(now: float) -> None:
            row = np.concatenate(([now], d.qpos[self._qadr:self._qadr + 7],
                                  d.qpos[self._finger_qadr]))
            trace.append(row)

        step = mujoco.mj_step
        ctrl_view = d.ctrl
        observe(0.0)
        for i in range(1, n_move + 1):
            ctrl_view[:] = ctrl[i]
            step(m, d)
            if i % CONTACT_EVERY == 0:
                observe(i * p.timestep)
            if keep_trace and i % keep_trace == 0:
                record(i * p.timestep)
        # settle: the fingers hold their last targets; stop once the object is still
        settle_s = p.settle if settle is None else float(settle)
        n_settle = round(settle_s / p.timestep)
        still = 0
        settled = False
        qv = slice(self._dadr, self._dadr + 6)  # the object's free joint
        j = 0
        for j in range(1, n_settle + 1):
            step(m, d)
            now = (n_move + j) * p.timestep
            if j % CONTACT_EVERY == 0:
                observe(now)
                if float(np.abs(d.qvel[qv]).max()) < 1e-3:
                    still += 1
                    if still * CONTACT_EVERY * p.timestep >= 0.05:
                        settled = True
                        break
                else:
                    still = 0
            if keep_trace and j % keep_trace == 0:
                record(now)
        # a final contact set that had not yet lasted the debounce time still counts at rest
        pairs, _ = self._contacts()
        if pairs and pairs != current:
            events.append(SimEvent((n_move + j) * p.timestep, ContactEvent("", pairs)))
        state = self.state()
        return SimResult(
            self.pose(), state, tuple(events), settled,
            (n_move + j) * p.timestep, time.perf_counter() - wall0, n_move + j,
            touched_table, np.array(trace) if trace else None,
        )
