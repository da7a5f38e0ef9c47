"""Transit motions: how the fingertips get from one place to the next without touching.

Between two steps (and before the first) a fingertip **retreats** from the object along
the outward normal of the face it is nearest (:func:`escape`), **moves clear** of the
object's posed hull by a margin (up to a safe height above it, across, and down to a point
the margin out along the next point's normal), and **approaches** the next reference's
first point along that normal, slowly. Each leg is a rest-to-rest
minimum-jerk motion timed so that its peak speed and acceleration stay within the given
bounds (a minimum-jerk leg of length ``L`` and duration ``T`` peaks at ``1.875 L / T`` and
``5.774 L / T^2``). Several fingers move together, each on its own legs, all legs timed
by the slowest finger. Before a transit the fingertips **let go** of the object
(:func:`release`): the quickest motion within the bounds, from the command as it moves, out
of the plane of the face each pad touches (:func:`escape` with ``faces_of``).

Pure core: numpy only.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron

# (the observed object's distance lives with what a controller observes, below both
# the transits and the controller's decisions; re-exported here, where it began)
from nonprehensile.observation import hull_distance
from nonprehensile.planning import ObjectPose
from nonprehensile.step_paths import ease

__all__ = ["APPROACH_SPEED", "PEAK_ACCEL", "PEAK_SPEED", "escape", "guarded_push",
           "hull_distance", "limit_speed", "limits_of", "release", "straight", "transit"]

FloatArray = NDArray[np.float64]

#: Peak speed and acceleration of a rest-to-rest minimum-jerk leg, per length / duration
#: (``L / T``) and per ``L / T^2``.
PEAK_SPEED = 1.875
PEAK_ACCEL = 5.7735
#: Peak speed (m/s) of a transit's last leg, the approach along the next point's normal: a
#: compliant fingertip lags and overshoots its targets in proportion to its speed.
APPROACH_SPEED = 0.1


def _planes(poly: Polyhedron) -> tuple[FloatArray, FloatArray]:
    """The face planes' unit normals (shape (n_faces, 3)) and offsets (model frame), kept
    by the object (read only): the let-go measures its fingertips against them at every
    observation."""
    return poly.normal_matrix, poly.plane_offsets


def escape(poly: Polyhedron, pose: ObjectPose, points: FloatArray, reach: float, *,
           faces_of: FloatArray | None = None) -> FloatArray:
    """Each point moved straight out of the posed object until it is ``reach`` (m) beyond
    the face plane it is farthest beyond (its contact normal when it touches a face), so
    that its :func:`hull_distance` is at least ``reach``; points already that far stay.

    A normal that points down (a face of a tilted object that looks at the table) is
    followed horizontally, so that no point is driven into the table; faces looking more
    than 45 degrees down are not left through. ``points`` has shape (n, 3); returns the
    same shape. With ``faces_of`` (shape (n, 3)), each point leaves through the face plane
    its ``faces_of`` point is farthest beyond instead (a compliant pad's command, deep in
    the object and off to the side, leaves through the face its pad touches: outside one
    face's plane a point is outside the whole convex object).
    """
    p = np.array(points, dtype=np.float64)
    normals, offsets = _planes(poly)
    x = (p - pose.translation) @ pose.rotation / pose.scale
    dist = (x @ normals.T - offsets) * pose.scale  # (n, faces)
    by = dist
    if faces_of is not None:
        xf = (np.asarray(faces_of, dtype=np.float64) - pose.translation) @ pose.rotation
        by = (xf / pose.scale @ normals.T - offsets) * pose.scale
    world = normals @ pose.rotation.T
    # a face that looks down at the table (its normal more than 45 degrees below the
    # horizon) is no way out: the point would be driven into the table
    usable = world[:, 2] >= -math.sqrt(0.5)
    for k in range(len(p)):
        if float(dist[k].max()) >= reach:
            continue
        best = int(np.flatnonzero(usable)[by[k, usable].argmax()])
        n = world[best]
        go = np.array([n[0], n[1], max(n[2], 0.0)])
        go /= float(np.linalg.norm(go))
        # the plane's distance grows by go . n (>= 0.7) per metre along go
        p[k] += go * (reach - float(dist[k, best])) / float(go @ n)
    return p


def _clear_column(poly: Polyhedron, pose: ObjectPose, point: FloatArray, z_top: float,
                  need: float) -> FloatArray:
    """``point`` (shape (3,)) moved horizontally until the vertical segment from it up to
    ``z_top`` stays ``need`` (m) from the posed object (a tilted object may overhang it)."""
    q = np.array(point, dtype=np.float64)
    for _ in range(8):
        zs = np.linspace(q[2], max(q[2], z_top), max(2, math.ceil((z_top - q[2]) / 0.002)))
        col = np.repeat(q[None], len(zs), axis=0)
        col[:, 2] = zs
        gap = hull_distance(poly, pose, col)
        worst = int(gap.argmin())
        if gap[worst] >= need - 1e-9:
            return q
        moved = escape(poly, pose, col[worst:worst + 1], need)[0]
        step = moved[:2] - col[worst, :2]
        if float(np.hypot(*step)) < 1e-9:  # straight up only: away from the centre
            away = q[:2] - pose.com[:2]
            norm = float(np.hypot(*away))
            step = (away / norm if norm > 1e-9 else np.array([1.0, 0.0])) * (
                need - float(gap[worst]))
        q[:2] += step
    return q


def _leg(a: FloatArray, b: FloatArray, n: int) -> FloatArray:
    s = ease(np.linspace(0.0, 1.0, n))
    return np.asarray(a[:, None, :] + s[None, :, None] * (b - a)[:, None, :])


def transit(
    poly: Polyhedron,
    pose: ObjectPose,
    start: FloatArray,
    end: FloatArray,
    *,
    dt: float,
    clearance: float,
    finger_radius: float,
    max_speed: float,
    max_accel: float,
    moving: FloatArray | None = None,
) -> FloatArray:
    """Fingertip targets from ``start`` to ``end`` clear of the object.

    Parameters
    ----------
    poly : Polyhedron
    pose : ObjectPose
        Where the object is (the observed pose in closed loop, the predicted one open loop).
    start, end : array, shape (n_fingers, 3)
        Fingertip centres now and where the next motion begins (world, m).
    dt : float
        Sample period of the result (the physics step), s.
    clearance : float
        Margin (m) between the fingertip's surface and the object's hull along the way.
    finger_radius : float
    max_speed, max_accel : float
        Bounds (m/s, m/s^2) on every fingertip's speed and acceleration.
    moving : array of bool, shape (n_fingers,), optional
        Fingers that move (others hold ``start``); default all.

    Returns
    -------
    array, shape (n_samples, n_fingers, 3)
        Targets every ``dt``, from ``start`` to ``end`` (both included).
    """
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    nf = len(start)
    mv = np.ones(nf, dtype=bool) if moving is None else np.asarray(moving, dtype=bool)
    end = np.where(mv[:, None], end, start)
    top = float(pose.to_world(poly.vertices)[:, 2].max())
    safe = top + finger_radius + clearance
    need = clearance + finger_radius
    # waypoints per finger: retreat (along the contact normal to the margin, and clear of
    # any overhang above), up to the safe height, across, down to the margin out along the
    # end point's normal, and the approach along that normal onto the end point
    out = start.copy()
    pre = end.copy()
    for k in np.flatnonzero(mv):
        out[k] = _clear_column(poly, pose, escape(poly, pose, start[k:k + 1], need)[0],
                               safe, need)
        pre[k] = _clear_column(poly, pose, escape(poly, pose, end[k:k + 1], need)[0],
                               safe, need)
    up = out.copy()
    up[:, 2] = np.where(mv, np.maximum(out[:, 2], safe), out[:, 2])
    across = pre.copy()
    across[:, 2] = np.where(mv, np.maximum(pre[:, 2], safe), pre[:, 2])
    # a straight line between the two safe points may not be clear (the end point beside the
    # object, low): the safe height clears the whole hull
    ways = [start, out, up, across, pre, end]
    speeds = [max_speed] * 4 + [min(max_speed, APPROACH_SPEED)]
    legs = []
    for (a, b), vmax in zip(itertools.pairwise(ways), speeds, strict=True):
        length = float(np.linalg.norm(b - a, axis=1).max())
        if length < 1e-6:
            continue
        t = max(PEAK_SPEED * length / vmax, math.sqrt(PEAK_ACCEL * length / max_accel))
        n = max(2, math.ceil(t / dt) + 1)
        legs.append(_leg(a, b, n).transpose(1, 0, 2))
    if not legs:
        return np.asarray(np.stack([start, end]))
    return np.asarray(np.concatenate([legs[0], *(leg[1:] for leg in legs[1:])]))


def straight(start: FloatArray, end: FloatArray, *, dt: float, max_speed: float,
             max_accel: float) -> FloatArray:
    """One rest-to-rest minimum-jerk leg from ``start`` to ``end`` (shape (n_fingers, 3)),
    within the bounds; shape (n_samples, n_fingers, 3)."""
    a = np.asarray(start, dtype=np.float64)
    b = np.asarray(end, dtype=np.float64)
    length = float(np.linalg.norm(b - a, axis=1).max())
    t = max(PEAK_SPEED * length / max_speed, math.sqrt(PEAK_ACCEL * length / max_accel))
    n = max(2, math.ceil(t / dt) + 1)
    return np.asarray(_leg(a, b, n).transpose(1, 0, 2))


def release(start: FloatArray, velocity: FloatArray, end: FloatArray, *, dt: float,
            max_speed: float, max_accel: float) -> FloatArray:
    """The quickest motion from ``start``, moving at ``velocity``, to rest at ``end``, its
    speed within ``max_speed`` and its acceleration within ``max_accel`` (a let-go: the
    fingertip off the object as soon as the bounds allow).

    Each fingertip accelerates at the bound toward its end point (turning its initial
    velocity into that direction), cruises at ``max_speed`` and brakes at the bound onto
    it: a time-optimal bang-coast-bang profile, steered every ``dt`` (a closed-form
    minimum-jerk leg, :func:`straight`, spends its first fifth below a tenth of its peak
    speed, which is where a pad pressed into the object lingers on it). The acceleration is
    bounded, its rate is not (the speed is continuous).

    Parameters
    ----------
    start, velocity, end : array, shape (n_fingers, 3)
        Fingertip positions (m), commanded velocities (m/s) and end points (m).
    dt : float
        Sample period (s).
    max_speed, max_accel : float
        Bounds (m/s, m/s^2).

    Returns
    -------
    array, shape (n_samples, n_fingers, 3)
        Targets every ``dt`` from ``start`` (first sample) to ``end`` (last), at least two.
    """
    x0 = np.array(start, dtype=np.float64)
    goal = np.asarray(end, dtype=np.float64)
    # braking a little below the bound leaves the steering room to absorb the sampling
    brake = 0.8 * max_accel
    dv_max = max_accel * dt
    tol = dv_max * dt
    two_brake = 2.0 * brake
    # each fingertip in floats, step by step: the very sums and products numpy's row-wise
    # norms (``(x * x + y * y) + z * z``) and element-wise updates make, without a dozen
    # array calls per sample
    xs = x0.tolist()
    vs = np.array(velocity, dtype=np.float64).tolist()
    gs = goal.tolist()
    k = len(xs)
    out = [x0.copy()]
    rows: list[list[float]] = []
    for _ in range(100_000):  # bounded: a 1 m let-go at 0.01 m/s^2 would take longer
        done = [False] * k
        dists = [0.0] * k
        for j in range(k):
            (px, py, pz), (vx, vy, vz), (gx, gy, gz) = xs[j], vs[j], gs[j]
            ax, ay, az = gx - px, gy - py, gz - pz
            dist = math.sqrt(ax * ax + ay * ay + az * az)
            dists[j] = dist
            # snapped onto the end point once that step, and the stop after it, stay
            # within the acceleration bound
            if dist <= tol:
                bx, by, bz = ax - vx * dt, ay - vy * dt, az - vz * dt
                done[j] = math.sqrt(bx * bx + by * by + bz * bz) <= tol
        if all(done):
            break
        for j in range(k):
            if done[j]:
                vs[j] = [0.0, 0.0, 0.0]
                xs[j] = list(gs[j])
                continue
            (px, py, pz), (vx, vy, vz), (gx, gy, gz) = xs[j], vs[j], gs[j]
            ax, ay, az = gx - px, gy - py, gz - pz
            dist = dists[j]
            # the speed from which braking at ``brake`` stops at the end point
            want = min(max_speed, math.sqrt(two_brake * dist))
            if dist > 0:
                ux, uy, uz = ax / dist, ay / dist, az / dist
            else:
                ux = uy = uz = 0.0
            dx, dy, dz = ux * want - vx, uy * want - vy, uz * want - vz
            size = math.sqrt(dx * dx + dy * dy + dz * dz)
            f = min(1.0, dv_max / max(size, 1e-300))
            vx, vy, vz = vx + dx * f, vy + dy * f, vz + dz * f
            vs[j] = [vx, vy, vz]
            xs[j] = [px + vx * dt, py + vy * dt, pz + vz * dt]
        rows.append([c for p in xs for c in p])
    if rows:
        out.append(np.array(rows, dtype=np.float64).reshape(len(rows), *x0.shape))
    out.append(goal.copy()[None])
    out[0] = out[0][None]
    return np.asarray(np.concatenate(out))


def guarded_push(length: float, gap: float, speed: float, *, dt: float,
                 fast: float = APPROACH_SPEED, accel: float = 2.0,
                 hold: float = 0.0) -> FloatArray:
    """Distances along a push, one every ``dt``: across the ``gap`` (m) to the face
    quickly, then on at the push's ``speed``, to ``length`` (m) in all.

    A guarded move: the fingertip runs at ``speed`` for ``hold`` seconds (the caller's
    cross-fade into the push from rest, which a speed change inside it would overshoot:
    from rest into a path that accelerated at once, the command peaked at 0.15 m/s and
    6.7 m/s^2), then speeds up at ``accel`` (m/s^2) towards ``fast`` (m/s) and slows
    down, at the same rate, back to ``speed`` by the time it has come ``gap`` along (a
    triangle where the gap is too short to reach ``fast``); from there it runs at
    ``speed``. Never behind the constant-speed push anywhere. A push that starts ``gap``
    short of the face at its own slow speed spent most of its time before touching (15 mm
    at 0.02 m/s: 0.75 s, the longest part of a robot's turn correction). ``gap`` is where
    the face was observed: the caller keeps a margin of it for the observation's errors.

    Parameters
    ----------
    length : float
        The whole push, m (``>= 0``).
    gap : float
        Distance run before being back at ``speed``, m (clipped to ``[0, length]``).
    speed : float
        The push's speed, m/s (``> 0``).
    dt : float
        Sample period, s (``> 0``).
    fast : float
        The approach's peak speed, m/s. Where it, the gap left after the hold or ``accel``
        allows no speed above ``speed``, the push runs at ``speed`` throughout (the
        constant-speed push).
    accel : float
        The approach's acceleration and deceleration, m/s^2.
    hold : float
        Time at ``speed`` before speeding up, s (``>= 0``).

    Returns
    -------
    ndarray, shape (n,)
        ``s[0] = 0``, increasing, ``s[-1] >= length`` (within half a sample for the
        constant-speed push, which has ``round(length / speed / dt) + 1`` samples).

    Raises
    ------
    InputError
        A length, gap or hold that is not a finite number, a speed or ``dt`` not above 0.
    """
    for name, v, low in (("length", length, 0.0), ("gap", gap, -math.inf),
                         ("hold", hold, 0.0)):
        if not (math.isfinite(v) and v >= low):
            raise InputError(f"guarded_push: {name} must be a finite number"
                             f"{'' if low == -math.inf else ' >= 0'}, got {v!r}")
    for name, v in (("speed", speed), ("dt", dt)):
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"guarded_push: {name} must be a finite number > 0, got {v!r}")
    gap = min(max(gap, 0.0), length)
    d_hold = min(speed * hold, gap)  # the gap left to speed up in, after the hold
    room = gap - d_hold
    # the peak: where speeding up from ``speed`` and slowing back to it cover the room
    # exactly (``2 (v^2 - speed^2) / 2a = room``), at most ``fast``
    peak = (min(fast, math.sqrt(accel * room + speed * speed))
            if accel > 0.0 and math.isfinite(accel) and math.isfinite(fast) else 0.0)
    if peak <= speed:  # nothing to gain: the constant-speed push
        n = round(length / speed / dt) + 1
        return np.asarray(np.arange(n) * dt * speed, dtype=np.float64)
    t_hold = d_hold / speed
    t_ramp = (peak - speed) / accel
    d_ramp = 0.5 * (peak + speed) * t_ramp
    t_cruise = max(room - 2.0 * d_ramp, 0.0) / peak
    t_gap = t_hold + 2.0 * t_ramp + t_cruise
    # where the braking ends, as the phases compute it (the gap itself up to rounding, which
    # a tiny ``accel`` magnifies): the push runs on from there, so that no sample jumps
    s_gap = d_hold + 2.0 * d_ramp + peak * t_cruise
    total = t_gap + max(length - s_gap, 0.0) / speed
    # (at least two samples: a push shorter than a step still ends at its length)
    t = np.arange(max(1, math.ceil(total / dt - 1e-9)) + 1) * dt
    u = t - t_hold  # time since the speeding up began
    u2 = u - t_ramp - t_cruise  # time into the braking
    s = np.where(
        u < 0.0, speed * t,
        np.where(u < t_ramp, d_hold + speed * u + 0.5 * accel * u * u,
                 np.where(u < t_ramp + t_cruise, d_hold + d_ramp + peak * (u - t_ramp),
                          np.where(t < t_gap,
                                   d_hold + d_ramp + peak * t_cruise + peak * u2
                                   - 0.5 * accel * u2 * u2,
                                   s_gap + speed * (t - t_gap)))))
    return np.asarray(s, dtype=np.float64)


def limits_of(targets: FloatArray, dt: float) -> tuple[float, float]:
    """Peak speed (m/s) and acceleration (m/s^2) of targets of shape (n, n_fingers, 3)
    sampled every ``dt``."""
    t = np.asarray(targets, dtype=np.float64)
    if len(t) < 3:
        return 0.0, 0.0
    v = np.diff(t, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    return float(np.linalg.norm(v, axis=-1).max()), float(np.linalg.norm(a, axis=-1).max())


def limit_speed(targets: FloatArray, dt: float, max_speed: float) -> FloatArray:
    """``targets`` (shape (n, n_fingers, 3), one sample every ``dt``) retimed so that no
    fingertip moves faster than ``max_speed``: each step that would is stretched to the time
    the bound allows, and the path is sampled again every ``dt`` (the same path, run slower
    where it was too fast; unchanged where it was not)."""
    t = np.asarray(targets, dtype=np.float64)
    if len(t) < 2:
        return t
    step = np.linalg.norm(np.diff(t, axis=0), axis=-1).max(axis=1)
    if float(step.max()) <= max_speed * dt * (1.0 + 1e-9):
        return t
    durations = np.maximum(dt, step / max_speed)
    clock = np.concatenate([[0.0], np.cumsum(durations)])
    new = np.arange(0.0, clock[-1] + 0.5 * dt, dt)
    flat = t.reshape(len(t), -1)
    out = np.column_stack([np.interp(new, clock, flat[:, j]) for j in range(flat.shape[1])])
    out[-1] = flat[-1]
    return np.asarray(out.reshape((len(new), *t.shape[1:])))
