"""Closed-loop execution (issue 21): the event-driven executor, transits, recovery, the CLI.

The physics tests run the planner's own plan of the main job's first step (``b:200`` at
(0.3, 0.1) m -> ``a:290``, a push-roll, references from the bundled demonstrations' clusters)
under the two perturbations the issue names, which end off the goal open loop; the verdict
is the judge's (MuJoCo's true final pose), never the controller's own observation.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nonprehensile.control import (
    ControlConfig,
    PlanarTransform,
    anchor_transform,
    correction_pushes,
    push_finger,
    replanner,
)
from nonprehensile.errors import InputError
from nonprehensile.geometry.build import cube
from nonprehensile.observation import (
    Observation,
    ObservationModel,
    ObservationStream,
    observed_contacts,
    rotvec_matrix,
)
from nonprehensile.skills.contacts import Edge, Face
from nonprehensile.states import State, state_pose
from nonprehensile.transit import (
    escape,
    guarded_push,
    hull_distance,
    limit_speed,
    limits_of,
    release,
    straight,
    transit,
)

CUBE = cube()
SCALE = 0.05


def _pose(state: State, xy: tuple[float, float] = (0.0, 0.0)):  # type: ignore[no-untyped-def]
    from nonprehensile.planning import ObjectPose

    r, t = state_pose(CUBE, state)
    tw = SCALE * t + np.array([xy[0], xy[1], 0.0])
    return ObjectPose(r, tw, SCALE * (r @ CUBE.com) + tw, SCALE)


# ------------------------------------------------------------------------ pure core
@settings(max_examples=40, deadline=None)
@given(st.floats(-20.0, 20.0), st.floats(-0.02, 0.02), st.floats(-0.02, 0.02),
       st.sampled_from(["a", "b", "d"]))
def test_anchor_recovers_a_planar_displacement(yaw: float, dx: float, dy: float,
                                               face: str) -> None:
    predicted = _pose(State(face, 30.0), (0.2, 0.1))
    observed = _pose(State(face, 30.0 + yaw), (0.2 + dx, 0.1 + dy))
    tf = anchor_transform(CUBE, Face(face), predicted, observed)
    assert math.degrees(tf.yaw) == pytest.approx(yaw, abs=1e-6)
    # the transform carries every predicted vertex onto the observed one
    np.testing.assert_allclose(tf.apply(predicted.to_world(CUBE.vertices)),
                               observed.to_world(CUBE.vertices), atol=1e-9)


def test_anchor_on_an_edge_fits_its_two_ends() -> None:
    predicted = _pose(State("a", 0.0))
    tf0 = PlanarTransform(math.radians(4.0), (0.0, 0.0), (0.003, -0.002))
    moved = tf0.apply(predicted.to_world(CUBE.vertices))
    a, b = CUBE.edges[frozenset({"a", "d"})]
    from nonprehensile.planning import ObjectPose

    c, s = math.cos(tf0.yaw), math.sin(tf0.yaw)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    observed = ObjectPose(rz @ predicted.rotation, moved[0] - SCALE * (rz @ predicted.rotation
                                                                       @ CUBE.vertices[0]),
                          np.zeros(3), SCALE)
    tf = anchor_transform(CUBE, Edge(frozenset({"a", "d"})), predicted, observed)
    np.testing.assert_allclose(tf.apply(predicted.to_world(CUBE.vertices[[a, b]])),
                               moved[[a, b]], atol=1e-9)


def test_observed_contacts_read_geometry_only() -> None:
    pose = _pose(State("a", 0.0))
    centre = pose.to_world(CUBE.face_centroids["f"][None])[0]
    n = pose.rotation @ CUBE.normals["f"]
    touching = Observation(0.0, pose, np.array([centre + 0.0065 * n]))
    apart = Observation(0.0, pose, np.array([centre + 0.02 * n]))
    kw = {"finger_radius": 0.006, "tol": 0.0015, "ground_tol": 0.0015}
    assert {str(p) for p in observed_contacts(CUBE, touching, **kw)} == {"(G,a)", "(R1,f)"}
    assert {str(p) for p in observed_contacts(CUBE, apart, **kw)} == {"(G,a)"}


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-4.0, 4.0), min_size=3, max_size=3),
       st.sampled_from([1.0, 1e-3, 1e-7, 1e-12]))
def test_rotvec_matrix_is_scipys_rotation(v: list[float], size: float) -> None:
    """The observation noise's rotation (Rodrigues by hand) against scipy's, from large
    angles down to the series branch."""
    from scipy.spatial.transform import Rotation

    rv = np.array(v) * size
    np.testing.assert_allclose(rotvec_matrix(rv), Rotation.from_rotvec(rv).as_matrix(),
                               atol=1e-14)


def test_observed_contacts_two_fingers_one_pressed_in() -> None:
    """Two fingertips at once, one pressed into a face (a compliant pad), one clear of the
    object, one on an edge: each named by geometry, in the order of ``fingers``."""
    pose = _pose(State("a", 0.0))
    centre = pose.to_world(CUBE.face_centroids["f"][None])[0]
    n = pose.rotation @ CUBE.normals["f"]
    kw = {"finger_radius": 0.006, "tol": 0.0015, "ground_tol": 0.0015}
    tips = np.array([centre - 0.002 * n, centre + 0.03 * n])
    got = observed_contacts(CUBE, Observation(0.0, pose, tips), fingers=(2, 3), **kw)
    assert {str(p) for p in got} == {"(G,a)", "(R2,f)"}
    g = next(g for g in CUBE.face_ids if g not in "af" and frozenset("f" + g) in CUBE.edges)
    shared = [v for v in CUBE.faces["f"] if v in CUBE.faces[g]]
    mid = pose.to_world(CUBE.vertices[shared].mean(axis=0)[None])[0]
    out = pose.rotation @ (CUBE.normals["f"] + CUBE.normals[g]) / math.sqrt(2.0)
    got = observed_contacts(CUBE, Observation(0.0, pose, np.array([mid + 0.0065 * out,
                                                                   tips[0]])), **kw)
    assert {str(p) for p in got} == {"(G,a)", f"(R1,{Edge(frozenset('f' + g))})", "(R2,f)"}


def test_observation_stream_rate_latency_and_seeded_noise() -> None:
    model = ObservationModel(rate=100.0, latency=0.02, position_noise=0.0005)
    pose = _pose(State("a", 0.0))
    got = []
    for seed in (1, 1, 2):
        s = ObservationStream(model, np.random.default_rng(seed))
        seen = []
        for i in range(100):  # 1 kHz for 0.1 s
            now = i * 0.001
            if s.due(now):
                s.push(now, pose, np.zeros((1, 3)))
            o = s.latest(now)
            if o is not None and (not seen or o is not seen[-1]):
                seen.append(o)
        got.append(seen)
    assert len(got[0]) == 8  # samples at 0, 10, ..., 70 ms arrive by 90 ms
    assert got[0][0].time == 0.0
    gaps = np.diff([o.time for o in got[0]])
    np.testing.assert_allclose(gaps, 0.01)
    np.testing.assert_array_equal(got[0][3].pose.com, got[1][3].pose.com)
    assert not np.array_equal(got[0][3].pose.com, got[2][3].pose.com)
    assert 0 < np.linalg.norm(got[0][3].pose.com - pose.com) < 0.005


@pytest.mark.parametrize("kw", [{"rate": float("nan")}, {"latency": -0.1},
                                {"position_noise": 1.0}])
def test_bad_observation_models_are_refused(kw: dict[str, float]) -> None:
    with pytest.raises(InputError, match=next(iter(kw))):
        ObservationModel(**kw)


@pytest.mark.parametrize("kw", [{"max_speed": 0.8}, {"slide_tol": float("nan")},
                                {"max_replans": -1}, {"max_replans": 10**6}])
def test_bad_control_settings_are_refused(kw: dict[str, float]) -> None:
    with pytest.raises(InputError, match=next(iter(kw))):
        ControlConfig(**kw)


def _box_distance(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Exact distance from points to an axis-aligned box (an independent truth)."""
    d = np.maximum(np.maximum(lo - p, 0.0), p - hi)
    return np.asarray(np.linalg.norm(d, axis=-1))


def test_a_transit_clears_the_object_within_its_bounds() -> None:
    pose = _pose(State("a", 0.0), (0.3, 0.1))
    world = pose.to_world(CUBE.vertices)
    lo, hi = world.min(axis=0), world.max(axis=0)
    # from pressing one side face to the start of an approach on the opposite side
    start = np.array([[hi[0] + 0.004, 0.1, 0.02]])
    end = np.array([[lo[0] - 0.03, 0.1, 0.03]])
    path = transit(CUBE, pose, start, end, dt=0.001, clearance=0.015, finger_radius=0.006,
                   max_speed=0.45, max_accel=10.0)
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], end)
    dist = _box_distance(path[:, 0], lo, hi)
    # it leaves the object straight away and stays clear by the margin once away
    away = np.flatnonzero(dist >= 0.006 + 0.015 - 1e-9)
    assert (away.size and (dist[away[0]:] >= 0.006 + 0.015 - 1e-9).all()) or \
        dist[-1] < 0.021  # the end point itself may be nearer: the approach starts there
    assert dist.min() >= 0.004 - 1e-9
    assert (hull_distance(CUBE, pose, path[:, 0]) > 0).all()
    speed, accel = limits_of(path, 0.001)
    assert speed <= 0.45 + 1e-9 and accel <= 10.0 + 1e-6


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["a", "b", "c", "d", "e", "f"]), st.sampled_from([0.0, 90.0, 180.0]),
       st.lists(st.tuples(st.floats(-0.04, 0.04), st.floats(-0.04, 0.04),
                          st.floats(0.0, 0.08)), min_size=1, max_size=4),
       st.floats(0.001, 0.03))
def test_escape_leaves_the_object_along_its_normal(face: str, theta: float,
                                                   pts: list[tuple[float, float, float]],
                                                   reach: float) -> None:
    pose = _pose(State(face, theta), (0.3, 0.1))
    world = pose.to_world(CUBE.vertices)
    lo, hi = world.min(axis=0), world.max(axis=0)  # an axis-aligned box: exact distances
    p = np.array(pts) + np.array([0.3, 0.1, 0.0])
    out = escape(CUBE, pose, p, reach)
    d_out = _box_distance(out, lo, hi)
    # beyond one face's plane by the reach already (off an edge, nearer may do)
    far = np.maximum(lo - p, p - hi).max(axis=1) >= reach
    assert (d_out >= reach - 1e-9).all()  # out of the object by the reach at least
    # a bounded move (the way out is never a face looking down: at most the object's size
    # and the reach, over cos 45 degrees)
    assert (np.linalg.norm(out - p, axis=1) <= (reach + SCALE) * math.sqrt(2.0) + 1e-9).all()
    np.testing.assert_allclose(out[far], p[far])  # what was that far stays
    assert (out[:, 2] >= p[:, 2] - 1e-12).all()  # never down, into the table
    moved = out - p
    # one straight move per point, along a face's normal (a box's normals are its axes)
    assert ((np.abs(moved) > 1e-9).sum(axis=1) <= 1).all()


def _surface_samples(pose, n: int = 41) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Points every 1.25 mm over the posed cube's faces (an independent distance truth)."""
    g = np.linspace(-0.5, 0.5, n)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    pts = []
    for axis in range(3):
        for side in (-0.5, 0.5):
            q = np.zeros((len(u), 3))
            q[:, axis] = side
            q[:, (axis + 1) % 3], q[:, (axis + 2) % 3] = u, v
            pts.append(q)
    model = np.concatenate(pts) + CUBE.com  # the unit cube's faces about its centre
    return np.asarray(pose.to_world(model))


def test_a_transit_clears_a_tilted_object_along_its_normals() -> None:
    from nonprehensile.planning import ObjectPose

    # the cube tipped 30 degrees onto an edge (a tumble mid-way): its upper side overhangs
    c, s_ = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    rot = np.array([[c, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c]])
    world = (CUBE.vertices @ rot.T) * SCALE
    t = np.array([0.3, 0.1, 0.0]) - np.array([0.0, 0.0, world[:, 2].min()])
    pose = ObjectPose(rot, t, SCALE * (rot @ CUBE.com) + t, SCALE)
    surface = _surface_samples(pose)
    r, clearance = 0.006, 0.015
    # from pressing the upper side face (1 mm into the pad's radius) to 3 mm off the
    # opposite one, which overhangs the table
    n_up = next(n for n in (rot @ CUBE.normals[f] for f in CUBE.face_ids)
                if n[0] < -0.8 and n[2] > 0.4)
    centre = pose.com + n_up * 0.5 * SCALE
    start = (centre + n_up * (r - 0.001))[None]
    n_low = -n_up
    end = (pose.com + n_low * (0.5 * SCALE + r + 0.003))[None]
    end[0, 2] = max(end[0, 2], r + 0.002)
    path = transit(CUBE, pose, start, end, dt=0.001, clearance=clearance, finger_radius=r,
                   max_speed=0.45, max_accel=10.0)
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], end)
    from scipy.spatial import cKDTree

    # each path point's nearest surface sample, exactly (a k-d tree, not a path x samples
    # distance matrix, which took 10-30 s)
    dist = cKDTree(surface).query(path[:, 0])[0]
    # it leaves along the pressed face's normal (straight away, no scraping) ...
    first = path[1:40, 0] - start
    cos = first @ n_up / np.maximum(np.linalg.norm(first, axis=1), 1e-12)
    assert (cos > 0.999).all()
    # ... stays clear by the margin between the retreat and the approach (the overhang
    # included), and approaches the end along the end face's normal
    away = np.flatnonzero(dist >= r + clearance - 0.0015)
    last = np.flatnonzero(dist < r + clearance - 0.0015)
    assert away.size and last[last > away[0]].size
    approach = last[last > away[0]]
    assert (np.diff(approach) == 1).all()  # one approach, at the end
    tail = path[approach, 0] - end
    # the end face looks down at the table: approached horizontally, never from below
    level = np.array([n_low[0], n_low[1], 0.0]) / math.hypot(n_low[0], n_low[1])
    cos = tail @ level / np.maximum(np.linalg.norm(tail, axis=1), 1e-12)
    assert (cos[:-1] > 0.999).all()
    assert dist.min() >= r - 0.001 - 0.0015  # never nearer than where it started
    speed, accel = limits_of(path, 0.001)
    assert speed <= 0.45 + 1e-9 and accel <= 10.0 + 1e-6


def test_limit_speed_retimes_only_what_is_too_fast() -> None:
    t = np.linspace(0.0, 1.0, 1001)
    fast = np.zeros((1001, 1, 3))
    fast[:, 0, 0] = 0.2 * t + 0.3 * (t > 0.5) * (t - 0.5) * 4  # 0.2 then 1.4 m/s
    out = limit_speed(fast, 0.001, 0.5)
    speed, _ = limits_of(out, 0.001)
    assert speed <= 0.5 + 1e-9
    np.testing.assert_allclose(out[0], fast[0])
    np.testing.assert_allclose(out[-1], fast[-1])
    assert len(out) > len(fast)  # run slower where it was too fast
    np.testing.assert_allclose(out[:400], fast[:400])  # and unchanged where it was not
    slow = fast[:400]
    assert limit_speed(slow, 0.001, 0.5) is slow or np.array_equal(
        limit_speed(slow, 0.001, 0.5), slow)


vec3 = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3)


@settings(max_examples=60, deadline=None)
@given(start=st.lists(vec3, min_size=2, max_size=2), vel=st.lists(vec3, min_size=2, max_size=2),
       move=st.lists(vec3, min_size=2, max_size=2), scale=st.sampled_from([1e-4, 0.003, 0.03]))
def test_release_is_quick_and_within_its_bounds(start, vel, move, scale) -> None:  # type: ignore[no-untyped-def]
    """A let-go's motion: from a moving command to rest at its aim, speed and acceleration
    within the bounds from the first sample (the motion it takes over included), and at
    least as quick as a minimum-jerk leg from rest (a bang-coast-bang profile: time-optimal
    up to its braking margin)."""
    dt, vmax, amax = 0.001, 0.45, 20.0
    a = 0.01 * np.array(start)
    v = 0.3 * np.array(vel)  # up to 0.52 m/s: a step's motion taken over, slowed first
    b = a + scale * np.array(move)
    out = release(a, v, b, dt=dt, max_speed=vmax, max_accel=amax)
    np.testing.assert_allclose(out[0], a)
    np.testing.assert_allclose(out[-1], b)
    full = np.concatenate([(a - v * dt)[None], out, out[-1:]])  # moving in, at rest out
    acc = np.linalg.norm(np.diff(full, 2, axis=0), axis=-1) / dt**2
    assert float(acc.max()) <= amax * (1 + 1e-6)
    speed = np.linalg.norm(np.diff(full, axis=0), axis=-1) / dt
    # never faster than the bound, or than the motion it took over while slowing it
    assert float(speed[1:].max()) <= max(vmax, float(np.linalg.norm(v, axis=1).max())) + 1e-9
    if not np.abs(v).any():
        rest_leg = straight(a, b, dt=dt, max_speed=vmax, max_accel=amax)
        assert len(out) <= len(rest_leg) + 2


@settings(max_examples=80, deadline=None)
@given(length=st.floats(0.0, 0.1), gap=st.floats(-0.01, 0.12), speed=st.floats(0.005, 0.2),
       fast=st.floats(0.0, 0.4), accel=st.floats(0.0, 20.0), hold=st.floats(0.0, 0.2))
def test_guarded_push_crosses_the_gap_quickly_within_its_bounds(length, gap, speed, fast,  # type: ignore[no-untyped-def]
                                                               accel, hold) -> None:
    """A correction push's distances: never backwards, at most the approach's peak and
    its acceleration (from the push's own speed), at the push's speed from the gap on, to
    the whole length; nowhere later than the old constant-speed push."""
    dt = 0.001
    s = guarded_push(length, gap, speed, dt=dt, fast=fast, accel=accel, hold=hold)
    assert s[0] == 0.0
    g = min(max(gap, 0.0), length)
    peak = math.sqrt(accel * (g - min(speed * hold, g)) + speed * speed)
    if min(fast, peak) <= speed:  # no approach to speed up: the old constant-speed push
        n = round(length / speed / dt) + 1
        np.testing.assert_array_equal(s, np.arange(n) * dt * speed)
        return
    assert float(s[-1]) >= length - 1e-12
    assert float(s[-1]) <= length + speed * dt + 1e-9
    v = np.diff(s) / dt
    assert float(v.min()) >= -1e-12
    assert float(v.max()) <= max(fast, speed) * (1 + 1e-9) + 1e-12
    a = np.diff(s, 2) / dt**2
    # (a sample straddling a switch of the profile averages the two sides)
    assert float(np.abs(a).max(initial=0.0)) <= accel * (1 + 1e-6) + 1e-9
    assert abs(float(v[0]) - speed) <= accel * dt * (1 + 1e-6)  # it starts at the speed
    # past the gap, the push's own speed
    past = np.flatnonzero(s[:-1] >= g + 1e-9)
    if len(past) > 1:
        np.testing.assert_allclose(v[past[1:]], speed, rtol=1e-6)
    # nowhere behind the old push (``s = speed t`` from the first sample), and at its
    # speed through the hold
    assert bool(np.all(s >= speed * dt * np.arange(len(s)) - 1e-12))
    k = int(min(hold, g / speed) / dt)
    np.testing.assert_allclose(np.diff(s[:k + 1]) / dt, speed, rtol=1e-6)


@pytest.mark.parametrize("kw", [{"speed": 0.0}, {"speed": -0.02}, {"length": math.nan},
                                {"gap": math.inf}, {"hold": -1.0}, {"dt": 0.0}])
def test_guarded_push_refuses_what_is_not_a_push(kw) -> None:  # type: ignore[no-untyped-def]
    args = {"length": 0.05, "gap": 0.012, "speed": 0.02, "dt": 0.001, **kw}
    with pytest.raises(InputError, match=next(iter(kw))):
        guarded_push(args.pop("length"), args.pop("gap"), args.pop("speed"), **args)


def test_guarded_push_reaches_a_correction_face_in_under_half_the_time() -> None:
    """The correction pushes' numbers (12 mm to cover of a 15 mm clearance, turns at
    0.02 m/s, 2 m/s^2 up to 0.1 m/s): the face is reached in 40 % of the old time, the
    peak speed held to 0.1 m/s, and the push runs at 0.02 m/s from there (worked by hand:
    0.02 -> 0.1 m/s in 0.04 s over 2.4 mm, back down likewise, 7.2 mm at 0.1 m/s in
    0.072 s: 0.152 s to the gap, then 3 mm at 0.02 m/s: 0.302 s to the face against
    0.75 s)."""
    s = guarded_push(0.05, 0.012, 0.02, dt=0.001, fast=0.1, accel=2.0)
    assert abs(int(np.searchsorted(s, 0.012 - 1e-12)) - 152) <= 1
    assert abs(int(np.searchsorted(s, 0.015 - 1e-12)) - 302) <= 1
    assert abs(float(np.diff(s).max()) / 0.001 - 0.1) <= 1e-9
    assert len(s) - 1 == 2052  # 0.152 s, then 38 mm at 0.02 m/s


def _release_by_arrays(start, velocity, end, *, dt, max_speed, max_accel):  # type: ignore[no-untyped-def]
    """The let-go's bang-coast-bang stepping written with numpy arrays (the form
    ``transit.release`` had before it stepped in floats): the truth it must equal."""
    x = np.array(start, dtype=np.float64)
    v = np.array(velocity, dtype=np.float64)
    goal = np.asarray(end, dtype=np.float64)
    brake, dv_max = 0.8 * max_accel, max_accel * dt
    out = [x.copy()]
    for _ in range(100_000):
        gap = goal - x
        dist = np.linalg.norm(gap, axis=1)
        done = (dist <= dv_max * dt) & (np.linalg.norm(gap - v * dt, axis=1) <= dv_max * dt)
        if done.all():
            break
        want = np.minimum(max_speed, np.sqrt(2.0 * brake * dist))
        unit = np.divide(gap, dist[:, None], out=np.zeros_like(gap), where=dist[:, None] > 0)
        dv = unit * want[:, None] - v
        size = np.linalg.norm(dv, axis=1)
        dv *= np.minimum(1.0, dv_max / np.maximum(size, 1e-300))[:, None]
        v = np.where(done[:, None], 0.0, v + dv)
        x = np.where(done[:, None], goal, x + v * dt)
        out.append(x.copy())
    out.append(goal.copy())
    return np.stack(out)


@settings(max_examples=60, deadline=None)
@given(start=st.lists(vec3, min_size=2, max_size=2), vel=st.lists(vec3, min_size=2, max_size=2),
       move=st.lists(vec3, min_size=2, max_size=2), scale=st.sampled_from([0.0, 1e-5, 0.003, 0.03]),
       amax=st.sampled_from([8.0, 20.0]))
def test_release_equals_its_array_form_bit_for_bit(start, vel, move, scale, amax) -> None:  # type: ignore[no-untyped-def]
    """``release`` steps each fingertip in floats for speed; its samples are those of the
    same stepping in numpy arrays, to the last bit (a sweep's records stay identical)."""
    a = 0.01 * np.array(start)
    v = 0.3 * np.array(vel)
    b = a + scale * np.array(move)
    kw = {"dt": 0.001, "max_speed": 0.45, "max_accel": amax}
    got, want = release(a, v, b, **kw), _release_by_arrays(a, v, b, **kw)
    assert got.shape == want.shape
    assert np.array_equal(got, want)


def test_correction_pushes_span_the_displacement() -> None:
    pose = _pose(State("a", 0.0), (0.3, 0.1))
    pushes = correction_pushes(CUBE, pose, (0.31, 0.095), finger_radius=0.006,
                               clearance=0.015, tol=0.003)
    total = sum(p.distance * p.direction[:2] for p in pushes)
    np.testing.assert_allclose(total, [0.01, -0.005], atol=1e-9)
    assert correction_pushes(CUBE, pose, (0.301, 0.1), finger_radius=0.006,
                             clearance=0.015, tol=0.003) == []



def _circular_gap(a: float, b: float) -> float:
    d = abs(a - b) % 360.0
    return min(d, 360.0 - d)


@settings(max_examples=60, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(0.3, 1.0), st.floats(0.3, 1.0),
       st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.booleans())
def test_push_finger_gives_a_push_to_the_finger_behind_it(heading: float, r_behind: float,
                                                           r_front: float, sx: float,
                                                           sy: float, first: bool) -> None:
    """A correction push goes to the finger whose origin (an arm's base) lies behind it:
    with one origin behind the push's start and one in front (each off the push's line by
    less than its distance along it), the one behind, in either order; finger 1 without
    origins (free fingertips) or with one."""
    d = np.array([math.cos(heading), math.sin(heading), 0.0])
    side = np.array([-d[1], d[0]])
    start = np.array([sx, sy, 0.01])
    behind = start[:2] - r_behind * d[:2] + 0.5 * r_behind * side
    front = start[:2] + r_front * d[:2] - 0.5 * r_front * side
    origins = [tuple(behind), tuple(front)] if first else [tuple(front), tuple(behind)]
    assert push_finger(start, d, origins) == (1 if first else 2)
    assert push_finger(start, d, None) == 1
    assert push_finger(start, d, [tuple(front)]) == 1


def test_push_finger_falls_back_to_finger_1_on_degenerate_input() -> None:
    """No direction, or a NaN: finger 1; equal origins (a hand): the lower number; an origin
    on the push's start is never preferred; an origin's height is not used."""
    start = np.array([0.1, 0.0, 0.01])
    behind_second = [(0.5, 0.0), (-0.5, 0.0)]  # pushing +x: the second stands behind
    assert push_finger(start, np.array([1.0, 0.0, 0.0]), behind_second) == 2
    assert push_finger(start, np.zeros(3), behind_second) == 1
    assert push_finger(start, np.array([math.nan, 0.0, 0.0]), behind_second) == 1
    assert push_finger(np.array([math.nan, 0.0, 0.01]), np.array([1.0, 0.0, 0.0]),
                       behind_second) == 1
    # an origin on the start itself is never chosen over another (it has no direction)
    assert push_finger(start, np.array([1.0, 0.0, 0.0]), [(0.1, 0.0), (0.5, 0.0)]) == 2
    assert push_finger(start, np.array([1.0, 0.0, 0.0]), [(0.1, 0.0), (0.1, 0.0)]) == 1
    assert push_finger(start, np.array([1.0, 0.0, 0.0]), [(-0.5, 0.0), (-0.5, 0.0)]) == 1
    assert push_finger(start, np.array([1.0, 0.0, 0.0]),
                       [(0.5, 0.0, 0.3), (-0.5, 0.0, 0.3)]) == 2


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.sampled_from("abcdef"),
                          # on a 0.01 degree grid: two states are the same or 0.01 apart
                          # (the function takes turns under 0.001 degrees for one state)
                          st.integers(0, 35999).map(lambda k: k / 100.0)),
                min_size=1, max_size=12),
       st.floats(0.0, 360.0, allow_nan=False))
def test_angular_step_is_the_smallest_turn_between_two_states_on_a_face(
        states: list[tuple[str, float]], turn: float) -> None:
    """The model's angular step is the smallest turn between two distinct states on one face
    (brute force over every pair, the circular distance: the truth), for any states, even
    or uneven steps; None when no face has two; the same for the states turned together."""
    from nonprehensile.control import angular_step

    pairs = [_circular_gap(a, b) for i, (fa, a) in enumerate(states)
             for fb, b in states[i + 1:] if fa == fb]
    pairs = [g for g in pairs if g > 1e-3]  # the same state twice is one state
    got = angular_step([State(f, t) for f, t in states])
    if not pairs:
        assert got is None
    else:
        assert got == pytest.approx(min(pairs), abs=2e-6)
    turned = angular_step([State(f, (t + turn) % 360.0) for f, t in states])
    assert (turned is None) == (got is None)
    if got is not None:
        assert turned == pytest.approx(got, abs=1e-5)


@settings(max_examples=100, deadline=None)
@given(st.sampled_from([10.0, 15.0, 20.0, 24.0, 30.0, 36.0, 45.0, 60.0, 72.0, 90.0, 120.0,
                        180.0]),
       st.floats(0.0, 360.0, allow_nan=False), st.floats(0.01, 0.99))
def test_for_step_derives_and_checks_align_tol_at_every_even_step(
        step: float, offset: float, frac: float) -> None:
    """States every ``step`` degrees on each face (any offset): the derived ``align_tol`` is a
    third of the step, at most 30 degrees; an explicit one below half the step is kept, one at
    or above it refused naming the setting and the bound."""
    from nonprehensile.control import angular_step

    n = round(360.0 / step)
    states = [State(f, (offset + k * step) % 360.0) for f in "ab" for k in range(n)]
    got = angular_step(states)
    assert got == pytest.approx(step, abs=1e-5)
    assert ControlConfig().for_step(got).align_tol == pytest.approx(min(30.0, step / 3.0))
    below = frac * step / 2.0
    assert ControlConfig(align_tol=below).for_step(got).align_tol == below
    with pytest.raises(InputError, match="align_tol must be below half"):
        ControlConfig(align_tol=step / 2.0 + frac).for_step(got)
    # one state per face: no step, the 30 degree default
    assert ControlConfig().for_step(angular_step(states[::n])).align_tol == 30.0


# ---------------------------------------------------------------------------- physics
# headless offscreen rendering, set before mujoco is first imported (as nonprehensile.sim
# sets it): later tests render
if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")


@pytest.fixture(scope="module")
def first_step():  # type: ignore[no-untyped-def]
    """The planner's plan of the main job's first step, with its re-planner."""
    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.states import states_by_step

    poly, skills = read_skills(os.path.join(os.path.dirname(__file__), "..", "examples",
                                            "cube_skills.json"))
    exp = expand(poly, skills, states_by_step(poly, 90))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    goal = State("a", 290.0)
    pl = plan(poly, exp, State("b", 200.0), goal, position=(0.3, 0.1), motions=motions,
              scale=ds.scale)
    assert [s.transition.skill.name for s in pl.steps] == ["push-roll"]
    return poly, ds, pl, replanner(poly, exp, goal, motions=motions, scale=ds.scale), exp


def _execute(first_step, loop: str, **kw):  # type: ignore[no-untyped-def]
    from nonprehensile.sim import SimParams, Simulator
    from nonprehensile.sim.closed_loop import execute_plan, scene_fingers
    from nonprehensile.sim.distribution import Perturbation

    poly, ds, pl, rp, exp = first_step
    yaw = kw.pop("yaw", 0.0)
    sim = Simulator(poly, scale=ds.scale, n_fingers=scene_fingers(pl, exp),
                    params=SimParams(**kw))
    return execute_plan(sim, pl, fingers=ds.fingers, loop=loop, replan=rp,
                        perturbation=Perturbation((0.0, 0.0, yaw)))


@pytest.mark.parametrize("physics", [{"yaw": -3.0}, {"friction_table": 0.45}],
                         ids=["start yaw -3 deg", "table friction 0.45"])
def test_a_closed_loop_step_recovers_where_open_loop_fails(first_step, physics) -> None:  # type: ignore[no-untyped-def]
    open_ = _execute(first_step, "open", **dict(physics))
    closed = _execute(first_step, "closed", **dict(physics))
    assert not open_.success, open_.to_dict()
    assert closed.success, closed.to_dict()
    # the judge's truth: the goal face, theta and position
    assert closed.final_state is not None and closed.final_state.face == "a"
    assert abs(closed.theta_error or 99.0) <= 5.0 and (closed.position_error or 1.0) <= 0.010
    # every arc ended on its observed event, and the record says so
    events = [e["event"] for e in closed.steps[0]["observed"] if "event" in e]
    assert events[:3] == ["rest", "touch", "pivot"] and events[-1] == "done"
    # no teleport: bounded commanded motion, no fingertip-object contact in any transit
    assert closed.commanded_speed <= 0.5 and closed.commanded_accel <= 20.0 + 1e-6
    assert closed.transit_contact_s == 0.0 and len(closed.transits) >= 2


def test_no_contact_in_the_transits_after_aborted_steps(first_step) -> None:  # type: ignore[no-untyped-def]
    """A push on a slippery table with a large, stiff fingertip slides the cube instead of
    tipping it: the step is aborted with the pad pressed on the moving cube. Its fingertip
    lets go (out along the contact normal, fleeing the cube until it rests) before the
    recovery transit, which touches nothing; the executor before this let go straight up
    and away from the centre and touched the cube for 0.115 s in 4 recovery transits."""
    from nonprehensile.sim.closed_loop import LET_GO_SEPARATION

    ex = _execute(first_step, "closed", friction_table=0.3, finger_radius=0.011,
                  stiffness=3000.0, max_force=15.0)
    aborted = [s for s in ex.steps if s["outcome"] == "aborted"]
    assert len(aborted) >= 2
    # every aborted step ends with its fingertips observed off the object and it at rest
    assert all(s["let_go"]["outcome"] == "finished" for s in aborted), aborted
    recoveries = [t for t in ex.transits if t["before"].startswith("recovery")]
    assert len(recoveries) >= 2
    assert ex.transit_contact_s == 0.0, [t for t in ex.transits
                                         if t["finger_object_contact_s"] > 0]
    # the record says where each transit ends and what follows begins: a step's first arc
    # starts on the observation its transit ended on; transits follow one another in time
    ends = {t["end_s"] for t in ex.transits}
    assert all(s["arc_start_s"] in ends for s in ex.steps)
    starts = [t["start_s"] for t in ex.transits]
    assert starts == sorted(starts)
    assert all(t["end_s"] >= t["start_s"] for t in ex.transits)
    assert ex.commanded_speed <= 0.5 and ex.transit_accel <= 10.0 + 1e-6
    # each aborted step's let-go frees the cube promptly (the judge's MuJoCo contacts): the
    # pad pressed into it is off within the documented time (here 32-39 ms; the let-go
    # before this one, a minimum-jerk leg at half the acceleration bound begun after the
    # next observation and a fade out of the stopped push, kept contact 60-70 ms in these
    # same let-gos), and no fingertip touches it again through the hold and the recovery
    # transit
    gos = [g for g in [s.get("let_go") for s in aborted] if g]
    assert len(gos) == len(aborted)
    assert any(g["separated_s"] > 0 for g in gos)  # pressed in when it stopped
    assert all(g["separated_s"] is not None and g["separated_s"] <= LET_GO_SEPARATION
               for g in gos), gos
    assert all(g["recontacts"] == 0 for g in gos), gos
    assert ex.let_go_separation_s <= LET_GO_SEPARATION


def test_simulate_plan_cli_records_events_and_refuses_bad_options(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from click.testing import CliRunner

    from nonprehensile.cli import main as cli

    skills = os.path.join(os.path.dirname(__file__), "..", "examples", "cube_skills.json")
    base = ["simulate", "plan", skills, "--from", "b:200", "--to", "a:290", "--at", "0.3",
            "0.1", "--step", "90", "--dataset", "cube"]
    runner = CliRunner()
    got = runner.invoke(cli, [*base, "--json", "--start-error", "0", "0", "-3"])
    assert got.exit_code == 0, got.output
    doc = json.loads(got.stdout)
    assert doc["loop"] == "closed" and doc["success"]
    ex = doc["execution"]
    assert {"replans", "retries", "corrections", "transits", "limits"} <= set(ex)
    assert any("event" in e for e in ex["steps"][0]["observed"])
    assert ex["steps"][0]["simulated_events"]
    for bad in (["--observation-rate", "nan"], ["--latency", "-1"], ["--position-tol", "nan"],
                ["--max-replans", "-2"], ["--friction", "1e9"], ["--tracking-noise", "1"],
                ["--loop", "sideways"]):
        got = runner.invoke(cli, [*base, *bad])
        assert got.exit_code == 2, (bad, got.output)
        lines = [ln for ln in (got.stderr or got.output).strip().splitlines() if ln.strip()]
        assert "Traceback" not in got.output
        assert len(lines) <= 3, (bad, lines)  # click's usage line, or the project's one


def test_replans_are_made_in_the_goals_frame(first_step) -> None:  # type: ignore[no-untyped-def]
    """A tumble can leave the object turned on a face the plan never visits: planned from
    there as observed, no route reaches the goal's theta (a turn of the scene changes no
    transition, so every reachable theta keeps the start's offset); from the nearest state of
    the re-planner's frame it does."""
    from nonprehensile.control import snap_state
    from nonprehensile.errors import NonprehensileError
    from nonprehensile.planning import plan

    poly, ds, _pl, rp, exp = first_step
    # the goal a:290 sits 20 deg off the model's 90-degree grid: so does every frame state
    by_face: dict[str, set[float]] = {}
    for s in rp.frame:
        by_face.setdefault(s.face, set()).add(round(s.theta, 6))
    assert by_face == {f: {20.0, 110.0, 200.0, 290.0} for f in "abcdef"}
    turned = State("c", 152.5)
    with pytest.raises(NonprehensileError, match="no sequence of known skills"):
        plan(poly, exp, turned, rp.goal, position=(0.3, 0.1), motions=None, scale=ds.scale)
    near = snap_state(turned, rp.frame, 45.0)
    assert near == State("c", 110.0)
    again = rp(near, (0.3, 0.1), frozenset())
    assert again.steps[0].start_world == near and again.steps[-1].end_world == rp.goal


@pytest.mark.parametrize(("observed", "action", "target"), [
    (State("a", 290.0 + 2.0), "next", None),     # within the 5 deg tolerance
    (State("a", 290.0 - 9.0), "align", State("a", 290.0)),  # turned: turned back, on
    (State("a", 290.0 + 29.0), "align", State("a", 290.0)),
    (State("a", 290.0 - 40.0), "replan", None),  # past align_tol: another state
    (State("e", 97.0), "align", State("e", 110.0)),  # the goal's face, turned
    (State("b", 200.0), "retry", None),          # never tipped: the same step again
])
def test_after_step_turns_back_a_turned_end_state(first_step, observed, action,  # type: ignore[no-untyped-def]
                                                   target) -> None:
    from nonprehensile.control import after_step, angular_step, step_spec

    poly, ds, pl, rp, _exp = first_step
    spec = step_spec(poly, pl.steps[0], ds.fingers)  # b:200 -> a:290
    cfg = ControlConfig().for_step(angular_step(rp.frame))
    assert cfg.align_tol == 30.0  # a third of the model's 90-degree step
    for replans in (0, cfg.max_replans):
        nxt = after_step(spec, "", observed, State("e", 110.0), replans=replans,
                         avoid=frozenset(), last=False, config=cfg)
        if replans and action in ("replan", "retry"):
            # retries and re-plans are bounded; a turn back is not a re-plan
            assert nxt.action == "fail"
            continue
        assert nxt.action == action and nxt.target == target


def test_a_step_begun_on_an_object_touching_nothing_logs_no_contacts(first_step) -> None:  # type: ignore[no-untyped-def]
    """An object observed in the air at a step's start (thrown by the last push, or tracked
    above the table) is an observation with no contact pair, not an event: the monitor logs
    none and runs the step (a bundled demonstration's replay raised ``ContactError`` here)."""
    from nonprehensile.control import StepMonitor, step_spec
    from nonprehensile.planning import ObjectPose

    poly, ds, pl, _, _ = first_step
    spec = step_spec(poly, pl.steps[0], ds.fingers)
    p = spec.start_pose
    up = np.array([0.0, 0.0, 0.03])  # 3 cm above the table: geometry says nothing touches
    lifted = ObjectPose(p.rotation, p.translation + up, p.com + up, p.scale)
    tips = np.array([[0.0, 0.0, 0.5]])
    obs = Observation(0.0, lifted, tips)
    kw = {"finger_radius": 0.006, "tol": 0.0015, "ground_tol": 0.0015}
    assert observed_contacts(poly, obs, **kw) == frozenset()
    mon = StepMonitor(poly, spec, ControlConfig(), dt=0.002, finger_radius=0.006, rest=tips)
    dec = mon.begin(obs, tips)
    assert dec.segment is not None and not dec.done
    assert mon.log[0]["contacts"] == []
    # resting where the plan put it, the same monitor reads the table under face b (its
    # first logged contact set once the debounce has passed)
    for k in range(1, 30):
        later = mon.update(Observation(0.01 * k, p, tips), tips)
        assert not later.done
    seen = [e["contacts"] for e in mon.log[1:] if e.get("contacts")]
    assert seen and seen[0] == ["(G,b)"], seen  # the ground G against face b


def test_the_replans_turn_follows_the_observation_not_the_simulators_truth(first_step) -> None:  # type: ignore[no-untyped-def]
    """A push that slides on a slippery table leaves the cube turned on its start face, off
    the goal's frame: it is turned back onto the frame by pushes before the re-plan. Every
    decision on that path reads the observed object (and the goal's position), never the
    simulator's true pose: with ``Simulator.pose`` lying by 0.3 m, the controller's turns,
    re-plans and transits are the same, to the bit (the turn once took the true position)."""
    from nonprehensile.sim import Simulator
    from nonprehensile.sim.closed_loop import execute_plan, scene_fingers
    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION

    poly, ds, pl, rp, exp = first_step
    sample = DEFAULT_DISTRIBUTION.samples(20, 0)[19]  # a slippery table: the push slides

    def run(lie: bool):  # type: ignore[no-untyped-def]
        sim = Simulator(poly, scale=ds.scale, n_fingers=scene_fingers(pl, exp),
                        params=sample.params)
        if lie:
            true_pose = sim.pose

            def wrong():  # type: ignore[no-untyped-def]
                p = true_pose()
                shift = np.array([0.3, 0.0, 0.0])
                return type(p)(p.rotation, p.translation + shift, p.com + shift, p.scale)

            sim.pose = wrong  # type: ignore[method-assign]
        return execute_plan(sim, pl, fingers=ds.fingers, replan=rp,
                            perturbation=sample.perturbation)

    honest, lied = run(False), run(True)
    turned = [r for r in honest.replans if "turned_onto" in r]
    assert turned, honest.replans  # the path under test was taken
    turns = [c for c in honest.corrections if c["kind"] == "turn"]
    assert turns

    def decisions(ex):  # type: ignore[no-untyped-def]
        return ([{k: r[k] for k in ("from", "position", "turned_onto", "steps") if k in r}
                 for r in ex.replans],
                [{k: c[k] for k in ("kind", "face", "start", "direction") if k in c}
                 for c in ex.corrections],
                [(t["before"], t["start_s"], t["end_s"]) for t in ex.transits])

    assert decisions(lied) == decisions(honest)
    # and the judge's verdict (the true pose: read through the judge, not the lying method)
    assert lied.sim_time == honest.sim_time


@pytest.mark.parametrize("where", [0, 1, 5])
def test_a_blown_up_object_never_reads_as_still(where: int) -> None:
    """The judge's speed is the largest magnitude of the object's free-joint velocity, read
    in floats; a NaN anywhere in it (a blown-up simulation) gives NaN, never the largest
    of the others, so the object is not "still" (numpy's ``abs(v).max()`` is the truth)."""
    from nonprehensile.sim import Simulator

    sim = Simulator(cube(), n_fingers=1)
    d, j = sim.data, sim.judge
    d.qvel[j.dadr:j.dadr + 6] = [0.0, 0.3, -0.7, 0.1, 0.0, 0.2]
    assert j.speed(d) == float(np.abs(d.qvel[j.dadr:j.dadr + 6]).max()) == 0.7
    d.qvel[j.dadr + where] = math.nan
    assert math.isnan(j.speed(d)) and not j.is_still(d)


def test_flat_rows_are_the_control_rows() -> None:
    """The step loop's controls as one flat memoryview (p21d): row ``i`` of any layout is
    ``[i * nu:(i + 1) * nu]``, and copying it into ``d.ctrl``'s memoryview writes the row's
    doubles."""
    from nonprehensile.sim.closed_loop import _flat_rows

    ctrl = np.arange(40.0).reshape(8, 5)[:, ::-1][::2]  # neither C- nor F-contiguous
    rows, width = _flat_rows(ctrl)
    assert width == 5
    out = np.full(5, np.nan)
    view = memoryview(out)
    assert rows is not None
    for i in range(len(ctrl)):
        view[:] = rows[i * width:(i + 1) * width]
        assert out.tobytes() == ctrl[i].tobytes()
    # a robot's controls, solved as they are read, are read row by row
    assert _flat_rows([[0.0] * 5]) == (None, 0)  # type: ignore[arg-type]


@pytest.mark.parametrize("bound", [0.0, 0.004, 0.006])
def test_a_bounded_follow_through_never_drives_the_pad_deeper(first_step, bound) -> None:  # type: ignore[no-untyped-def]
    """A cube that does not turn (balanced on its pivot edge under the pad): the
    follow-through turns the fingertip about the pivot only as far as the pad stays within
    ``follow_depth`` of the object's surface as observed. The depth is read here from
    scipy's convex hull of the posed vertices, not from the model's face planes; unbounded,
    the same turn goes more than a centimetre into the cube."""
    from scipy.spatial import ConvexHull

    from nonprehensile.control import StepMonitor, step_spec

    poly, ds, pl, _, _ = first_step
    spec = step_spec(poly, pl.steps[0], ds.fingers)
    pose = spec.start_pose
    radius = 0.006
    world = pose.to_world(poly.vertices)
    eqs = ConvexHull(world).equations  # outward unit normals and offsets, world metres

    def depth(points: np.ndarray) -> np.ndarray:
        signed = (points @ eqs[:, :3].T + eqs[:, 3]).max(axis=-1)
        return radius - signed

    # the pad pressed 2 mm into the pushed face (c), half-way up it
    arc = 2  # pivot -> landed: its end event puts the cube on its landing face
    assert spec.grounds[arc + 1] is not None
    c = pose.rotation @ poly.normals["c"]
    centre = pose.com + (0.025 + radius - 0.002) * c
    tips = np.array([centre, [0.0, 0.0, 0.5]])
    depths = {}
    for follow in (bound, None):
        cfg = ControlConfig(follow_depth=follow)
        mon = StepMonitor(poly, spec, cfg, dt=0.001, finger_radius=radius, rest=tips)
        mon.arc, mon.current = arc, spec.events[arc]
        dec = mon._follow_through(Observation(1.0, pose, tips), tips)
        assert dec is not None and dec.segment is not None
        depths[follow] = depth(dec.segment[:, 0]).max()
    assert depths[None] > 0.01  # unbounded: more than a centimetre into the cube
    # bounded: no deeper than the bound, or than where the pad began when it began deeper
    assert depths[bound] <= max(bound, 0.002) + 1e-3
    assert depths[bound] < depths[None]


def test_follow_depth_is_checked_and_robots_get_theirs() -> None:
    from nonprehensile.sim.robot_run import ROBOT_FOLLOW_DEPTH, robot_control

    for bad in (-0.001, math.nan, math.inf, "2 mm"):
        with pytest.raises(InputError, match="follow_depth"):
            ControlConfig(follow_depth=bad)  # type: ignore[arg-type]
    assert ControlConfig().follow_depth is None  # the free fingertips: unbounded
    assert robot_control(n_fingers=1).follow_depth == ROBOT_FOLLOW_DEPTH
    assert robot_control(ControlConfig(follow_depth=0.01), n_fingers=2).follow_depth == 0.01


def test_push_approach_is_checked_and_robots_get_theirs() -> None:
    """The correction pushes' guarded approach: off for the free fingertips (a compliant pad
    lags its command), the transits' approach speed for robots, the caller's own kept;
    a speed that is not one, or over the fingertips' 0.5 m/s, is refused by name."""
    from nonprehensile.sim.robot_run import ROBOT_PUSH_APPROACH, robot_control
    from nonprehensile.transit import APPROACH_SPEED

    for bad in (-0.1, 0.6, math.nan, math.inf, "fast", True):
        with pytest.raises(InputError, match="push_approach"):
            ControlConfig(push_approach=bad)  # type: ignore[arg-type]
    assert ControlConfig().push_approach is None
    assert robot_control(n_fingers=1).push_approach == ROBOT_PUSH_APPROACH == APPROACH_SPEED
    assert robot_control(ControlConfig(push_approach=0.05), n_fingers=2).push_approach == 0.05
    # 0: a robot's pushes at their own speed throughout (the caller's choice kept)
    assert robot_control(ControlConfig(push_approach=0.0), n_fingers=1).push_approach == 0.0
    # a bool is no number for any numeric setting (True would read as 1)
    for name in ("max_replans", "max_speed", "clearance"):
        with pytest.raises(InputError, match=name):
            ControlConfig(**{name: True})  # type: ignore[arg-type]
    with pytest.raises(InputError, match="correct_position"):
        ControlConfig(correct_position="no")  # type: ignore[arg-type]


def test_a_guarded_push_faded_in_from_rest_keeps_its_bounds() -> None:
    """The push as the executor sends it: the cross-fade from the held command into the
    guarded distances (``_Runner._crossfade``, the executor's own), for a turn (20 mm/s)
    and a slide (30 mm/s), 12 mm of a 15 mm clearance to cover. Holding the push's speed
    through the fade, the command stays within 0.1 m/s and the fade's own acceleration
    (that of the constant-speed push's fade, 1.6-2.4 m/s^2); speeding up inside the fade
    overshot to 0.15 m/s and 6.7 m/s^2. Without the hold this test fails."""
    from nonprehensile.sim.closed_loop import CROSSFADE, PUSH_ACCEL, PUSH_MARGIN, _Runner
    from nonprehensile.transit import APPROACH_SPEED

    class Clock:  # what ``_crossfade`` reads of its runner
        dt = 0.001

    direction = np.array([1.0, 0.0, 0.0])
    start = np.array([0.1, 0.2, 0.01])
    for speed in (0.02, 0.03):
        length = 0.015 + 0.006 + 0.03
        s = guarded_push(length, 0.015 - PUSH_MARGIN, speed, dt=0.001, fast=APPROACH_SPEED,
                         accel=PUSH_ACCEL, hold=CROSSFADE)
        plain = np.arange(round(length / speed / 0.001) + 1) * 0.001 * speed
        held = np.array([[start]])
        limits = []
        for dist in (s, plain):
            path = (start[None] + dist[:, None] * direction[None])[:, None, :]
            faded = _Runner._crossfade(Clock(), held, 0, path)  # type: ignore[arg-type]
            limits.append(limits_of(faded, 0.001))
        (v, a), (v0, a0) = limits
        assert v <= APPROACH_SPEED + 1e-9
        assert a <= max(a0, PUSH_ACCEL) * (1 + 1e-6)
        assert v >= 0.9 * APPROACH_SPEED > 1.5 * v0  # and it is faster across the gap
