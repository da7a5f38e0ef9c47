"""The executor's reads in floats and by ``a.dot(b)`` (issue 21's sweep cost, p21c): each
gives what its numpy form gives, bit for bit, or hands over to it.

* :func:`~nonprehensile.observation.observed_contacts` with a cache reads in floats
  (``_contacts_in_floats``): the same contact set as without one, and ``None`` (the numpy
  path decides) when a comparison is too close to call;
* the judge names a fingertip's element and the ground's in floats
  (``Judge._element_in_floats``, ``Judge._ground_in_floats``): the same elements as
  :meth:`Judge.element` and ``Judge._ground_and_margin``, and a margin no larger;
* ``a.dot(b)`` in place of ``a @ b`` (the same BLAS call without the matmul ufunc's
  dispatch) in :meth:`Judge.pose`, the observation noise, :func:`state_of_pose` and
  :func:`hull_distance`: the same numbers as the ``@`` forms they replaced;
* p21d: the observation noise drawn in two parts (the pose's, the tips'), the turned points
  of a follow-through or a top roll built at once, and the hand-written ``__init__`` of
  ``ObjectPose`` and ``Observation``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from nonprehensile.control import _slid_beyond, _turned_about
from nonprehensile.geometry import Polyhedron, cube, prism
from nonprehensile.observation import (
    Observation,
    ObservationModel,
    ObservationStream,
    PairCache,
    _contacts_in_floats,
    _planes,
    observed_contacts,
    rotvec_matrix,
)
from nonprehensile.planning import ObjectPose
from nonprehensile.states import State, state_of_pose, state_pose
from nonprehensile.step_paths import ease
from nonprehensile.transit import hull_distance

SOLIDS = {"cube": cube(), "prism6": prism(6)}
SCALE = 0.025
KW = {"finger_radius": 0.006, "tol": 0.0015, "ground_tol": 0.0015}


def _posed(poly: Polyhedron, seed: int, tilt: float) -> ObjectPose:
    """A resting pose of ``poly`` turned by a random rotation of up to ``tilt`` radians (a
    pivoting or tumbling object), at a random place on the table."""
    rng = np.random.default_rng(seed)
    face = poly.face_ids[int(rng.integers(len(poly.face_ids)))]
    r0, t0 = state_pose(poly, State(face, float(rng.uniform(0, 360))))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    dr = Rotation.from_rotvec(axis * rng.uniform(0.0, tilt)).as_matrix()
    r = dr @ r0
    shift = np.array([*rng.uniform(-0.3, 0.3, 2), 0.0])
    t = SCALE * (dr @ t0) + shift
    t[2] -= float((SCALE * (poly.vertices @ r.T) + t)[:, 2].min())  # down onto the table
    t[2] += float(rng.choice([0.0, 0.0, rng.uniform(-0.002, 0.003)]))
    return ObjectPose(r, t, SCALE * (r @ poly.com) + t, SCALE)


def _tips(poly: Polyhedron, pose: ObjectPose, rng: np.random.Generator, n: int) -> np.ndarray:
    """Fingertips near the posed surface (faces, edges, corners), pressed in up to 3 mm or
    off it up to 12 mm, and now and then far away."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # a surface point along each direction out of the centre of mass
    c = poly.com
    ts = []
    for v in d:
        dots = poly.normal_matrix @ v
        off = poly.plane_offsets - poly.normal_matrix @ c
        ts.append(float(np.min(off[dots > 0] / dots[dots > 0])))
    surf = c + d * np.array(ts)[:, None]
    world = pose.to_world(surf)
    out = world + (pose.rotation @ d.T).T * rng.uniform(-0.003, 0.012, size=(n, 1))
    far = rng.uniform(size=n) < 0.15
    out[far] += np.array([0.2, -0.1, 0.15])
    return np.asarray(out)


@settings(max_examples=60, deadline=None)
@given(name=st.sampled_from(sorted(SOLIDS)), seed=st.integers(0, 2**31 - 1),
       tilt=st.sampled_from([0.0, 0.05, 0.6]), fingers=st.integers(1, 3))
def test_observed_contacts_in_floats_equal_numpy(name: str, seed: int, tilt: float,
                                                 fingers: int) -> None:
    """Many observations of one object through one cache (a step's monitor): every answer
    equals the uncached numpy answer, and once the cache knows the elements most answers
    come from floats."""
    poly = SOLIDS[name]
    rng = np.random.default_rng(seed)
    cache: PairCache = {}
    planes = _planes(poly)
    by_floats = 0
    for k in range(40):
        pose = _posed(poly, seed + k % 4, tilt)  # a few poses, seen again and again
        obs = Observation(0.0, pose, _tips(poly, pose, rng, fingers))
        truth = observed_contacts(poly, obs, **KW)  # no cache: numpy alone
        got = observed_contacts(poly, obs, planes=planes, cache=cache, **KW)
        assert got == truth
        fast = _contacts_in_floats(poly, obs, KW["finger_radius"], KW["tol"],
                                   KW["ground_tol"], None, planes, cache)
        if fast is not None:
            assert fast == truth
            by_floats += 1
    assert by_floats > 0


def test_observed_contacts_in_floats_hand_over_at_the_threshold() -> None:
    """A fingertip exactly at its reach from a face, or a vertex exactly at the ground
    tolerance: too close to call in floats, so ``None`` (the numpy path decides)."""
    poly = cube()
    pose = _posed(poly, 3, 0.0)
    planes = _planes(poly)
    cache: PairCache = {}
    reach = KW["finger_radius"] + KW["tol"]
    centre = pose.com
    # straight above the top face's centre, its centre exactly ``reach`` above the face
    top = float(pose.to_world(poly.vertices)[:, 2].max())
    at = np.array([[centre[0], centre[1], top + reach]])
    obs = Observation(0.0, pose, at)
    observed_contacts(poly, obs, planes=planes, cache=cache, **KW)  # the memo knows them
    assert _contacts_in_floats(poly, obs, KW["finger_radius"], KW["tol"],
                               KW["ground_tol"], None, planes, cache) is None
    assert observed_contacts(poly, obs, planes=planes, cache=cache, **KW) == \
        observed_contacts(poly, obs, **KW)
    # the object lifted so that its lowest vertex is exactly at the ground tolerance
    t = pose.translation.copy()
    t[2] += KW["ground_tol"] - float(pose.to_world(poly.vertices)[:, 2].min())
    lifted = ObjectPose(pose.rotation, t, pose.com + (t - pose.translation), SCALE)
    obs = Observation(0.0, lifted, np.array([[1.0, 1.0, 1.0]]))
    assert _contacts_in_floats(poly, obs, KW["finger_radius"], KW["tol"],
                               KW["ground_tol"], None, planes, cache) is None
    # and NaN in the pose: never decided in floats
    bad = ObjectPose(pose.rotation, pose.translation * math.nan, pose.com, SCALE)
    assert _contacts_in_floats(poly, Observation(0.0, bad, at), KW["finger_radius"],
                               KW["tol"], KW["ground_tol"], None, planes, cache) is None


@pytest.fixture(scope="module")
def judges() -> dict[str, object]:
    from nonprehensile.sim import Simulator

    return {name: Simulator(poly, scale=SCALE, n_fingers=2).judge
            for name, poly in SOLIDS.items()}


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(sorted(SOLIDS)), seed=st.integers(0, 2**31 - 1),
       tilt=st.sampled_from([0.0, 0.05, 0.6]))
def test_judge_elements_in_floats_equal_numpy(judges: dict[str, object], name: str,
                                              seed: int, tilt: float) -> None:
    """Contact points on and near the posed surface: the element read in floats (when it
    is) is the one :meth:`Judge.element` names; the ground's element read in floats is
    ``_ground_and_margin``'s, with a margin no larger than its own."""
    from nonprehensile.sim.judge import Judge

    judge = judges[name]
    assert isinstance(judge, Judge)
    poly = SOLIDS[name]
    rng = np.random.default_rng(seed)
    by_floats = 0
    for k in range(30):
        pose = _posed(poly, seed + k % 3, tilt)
        r, t = pose.rotation, pose.translation
        for p in _tips(poly, pose, rng, 3):
            truth = judge.element(r.T @ (p - t) / SCALE)
            got = judge._element_in_floats(p.tolist(), r.tolist(), t.tolist())
            if got is not None:
                assert got == truth
                by_floats += 1
            # a fingertip's contact point wandering from there (a slide, a roll): the last
            # element kept while the point stays within its margin is the one named afresh
            for _ in range(8):
                p = p + rng.normal(size=3) * rng.choice([1e-5, 1e-4, 1e-3, 5e-3])
                truth = judge.element(r.T @ (p - t) / SCALE)
                got = judge._element_in_floats(p.tolist(), r.tolist(), t.tolist(), key=7)
                assert got is None or got == truth
        el, margin = judge._ground_and_margin(r, t)
        fast = judge._ground_in_floats(*r[2].tolist(), float(t[2]))
        if fast is not None:
            assert fast[0] == el
            assert margin - 1e-8 <= fast[1] <= margin
    assert by_floats > 0


def test_judge_element_in_floats_hands_over_on_a_plane(judges: dict[str, object]) -> None:
    """A contact point exactly ``contact_tol`` off a face plane is not decided in floats."""
    from nonprehensile.sim.judge import Judge

    judge = judges["cube"]
    assert isinstance(judge, Judge)
    r, t = np.eye(3), np.zeros(3)
    tol = judge.params.contact_tol
    # above the bottom face's centre (the unit cube's plane z = 0), inside by exactly tol
    p = [SCALE * 0.5, SCALE * 0.5, tol]
    judge.element(r.T @ (np.array(p) - t) / SCALE)
    assert judge._element_in_floats(p, r.tolist(), t.tolist()) is None


@given(seed=st.integers(0, 2**31 - 1))
def test_dot_forms_equal_their_matmul_forms(seed: int) -> None:
    """``a.dot(b)`` where ``a @ b`` stood: the state read from a pose, the pose's centre of
    mass, the noisy observed pose and the hull distance are the numbers of the ``@`` forms,
    bit for bit."""
    rng = np.random.default_rng(seed)
    poly = SOLIDS["prism6"] if seed % 2 else SOLIDS["cube"]
    rot = Rotation.random(random_state=seed).as_matrix()
    # state_of_pose: near a resting pose (within the tolerance), or anywhere (an error)
    pose = _posed(poly, seed, 0.02)
    for r in (pose.rotation, rot):
        try:
            got = state_of_pose(poly, r, tol=5.0)
        except Exception:
            continue
        i = int(np.argmin(poly.normal_matrix @ r[2]))
        e1 = r @ poly.first_edge_directions[poly.face_ids[i]]
        assert got.face == poly.face_ids[i]
        assert got == State(got.face, math.degrees(math.atan2(e1[1], e1[0])))
    # the observation noise's pose (numpy's form inline, as it was)
    model = ObservationModel(position_noise=0.0005, finger_noise=0.001)
    stream = ObservationStream(model, np.random.default_rng(seed))
    tips = _tips(poly, pose, rng, 2)
    stream.push(0.0, pose, tips)
    got_obs = stream.latest(0.0)
    assert got_obs is not None
    z = np.random.default_rng(seed).standard_normal(12)
    a = math.radians(model.angle_noise_deg or 0.0)
    dr = rotvec_matrix(np.array([0.0 + a * v for v in z[:3].tolist()]))
    com = pose.com + np.array([0.0 + model.position_noise * v for v in z[3:6].tolist()])
    trans = com - dr @ (pose.com - pose.translation)
    assert got_obs.pose.rotation.tobytes() == (dr @ pose.rotation).tobytes()
    assert got_obs.pose.translation.tobytes() == trans.tobytes()
    assert got_obs.pose.com.tobytes() == com.tobytes()
    assert got_obs.tips.tobytes() == (tips + (0.0 + 0.001 * z[6:]).reshape(2, 3)).tobytes()
    # hull distances of a stack of points (the let-go's and the transit's)
    pts = _tips(poly, pose, rng, 4)
    x = (pts - pose.translation) @ pose.rotation / pose.scale
    want = (x @ poly.normal_matrix.T - poly.plane_offsets).max(axis=-1) * pose.scale
    assert hull_distance(poly, pose, pts).tobytes() == want.tobytes()
    assert hull_distance(poly, pose, pts[None]).tobytes() == want[None].tobytes()


def test_judge_pose_equals_its_matmul_form(judges: dict[str, object]) -> None:
    """The judge's pose of the simulated object: the centre of mass ``scale * R @ com + t``
    bit for bit."""
    from nonprehensile.sim.judge import Judge

    judge = judges["prism6"]
    assert isinstance(judge, Judge)
    data = type("D", (), {})()
    rng = np.random.default_rng(2)
    for k in range(20):
        xmat = np.zeros((judge.body + 1, 9))
        xmat[judge.body] = Rotation.random(random_state=k).as_matrix().ravel()
        xpos = np.zeros((judge.body + 1, 3))
        xpos[judge.body] = rng.normal(size=3)
        data.xmat, data.xpos = xmat, xpos  # type: ignore[attr-defined]
        judge._bound = None
        pose = judge.pose(data)
        r = xmat[judge.body].reshape(3, 3)
        want = judge.scale * (r @ np.asarray(SOLIDS["prism6"].com)) + xpos[judge.body]
        assert pose.com.tobytes() == want.tobytes()


@given(x=st.floats(-0.1, 0.1), y=st.floats(-0.1, 0.1), tol=st.floats(0.0, 0.05))
def test_slid_beyond_equals_numpy(x: float, y: float, tol: float) -> None:
    """The monitor's slide check in floats: numpy's answer, and at the threshold too."""
    com = np.array([0.3 + x, -0.2 + y, 0.025])
    origin = np.array([0.3, -0.2])
    want = bool(float(np.hypot(*(com[:2] - origin))) > tol)
    assert _slid_beyond(com, origin, tol) == want
    at = float(np.hypot(*(com[:2] - origin)))  # exactly at the distance: numpy decides
    assert _slid_beyond(com, origin, at) is False


def _push_as_one_draw(model: ObservationModel, rng: np.random.Generator, pose: ObjectPose,
                      tips: np.ndarray) -> tuple[ObjectPose, np.ndarray]:
    """The observation noise as p21c drew it: one ``standard_normal`` for the whole sample
    (the pose's six numbers, then the tips'), scaled by numpy."""
    noisy_pose = model.position_noise > 0 or (model.angle_noise_deg or 0.0) > 0
    n_pose = 6 if noisy_pose else 0
    n_tips = tips.size if model.finger_noise > 0 else 0
    z = rng.standard_normal(n_pose + n_tips) if n_pose + n_tips else None
    if z is not None and noisy_pose:
        a = math.radians(model.angle_noise_deg or 0.0)
        p = model.position_noise
        z0, z1, z2, z3, z4, z5 = z[:6].tolist()
        dr = rotvec_matrix(np.array([0.0 + a * z0, 0.0 + a * z1, 0.0 + a * z2]))
        com = pose.com + np.array([0.0 + p * z3, 0.0 + p * z4, 0.0 + p * z5])
        trans = com - dr @ (pose.com - pose.translation)
        pose = ObjectPose(dr @ pose.rotation, trans, com, pose.scale)
    if z is not None and n_tips:
        tips = tips + (0.0 + model.finger_noise * z[n_pose:]).reshape(tips.shape)
    else:
        tips = np.array(tips, dtype=np.float64)
    return pose, tips


@settings(max_examples=200)
@given(seed=st.integers(0, 2**31 - 1), position=st.sampled_from([0.0, 0.0005, 0.003]),
       angle=st.sampled_from([None, 0.0, 0.8]), finger=st.sampled_from([0.0, 0.001, 0.004]),
       n_tips=st.integers(1, 3), samples=st.integers(1, 4))
def test_observation_noise_equals_one_draw(seed: int, position: float, angle: float | None,
                                           finger: float, n_tips: int, samples: int) -> None:
    """The noise drawn as the pose's ``standard_normal(6)`` and the tips' ``normal(0, s)``
    (p21d): the numbers of one ``standard_normal`` for the sample scaled by numpy, bit for
    bit, sample after sample (the generator keeps no spare normals between draws)."""
    poly = SOLIDS["prism6"] if seed % 2 else SOLIDS["cube"]
    pose = _posed(poly, seed, 0.3)
    model = ObservationModel(position_noise=position, angle_noise_deg=angle,
                             finger_noise=finger)
    stream = ObservationStream(model, np.random.default_rng(seed))
    rng = np.random.default_rng(seed)
    for k in range(samples):
        tips = _tips(poly, pose, np.random.default_rng(seed + k), n_tips)
        stream.push(0.01 * k, pose, tips)
        got = stream.latest(0.01 * k)
        assert got is not None
        want_pose, want_tips = _push_as_one_draw(model, rng, pose, tips)
        assert got.pose.rotation.tobytes() == want_pose.rotation.tobytes()
        assert got.pose.translation.tobytes() == want_pose.translation.tobytes()
        assert got.pose.com.tobytes() == want_pose.com.tobytes()
        assert got.pose.scale == want_pose.scale
        assert got.tips.tobytes() == want_tips.tobytes()
        assert got.tips.shape == want_tips.shape and got.tips.flags.c_contiguous


@settings(max_examples=300)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 80), k=st.integers(0, 3),
       small=st.booleans())
def test_turned_about_equals_a_rotation_per_sample(seed: int, n: int, k: int,
                                                   small: bool) -> None:
    """The follow-through's and the top roll's turned points, built at once (p21d): the
    numbers of one scipy rotation per sample, bit for bit, for a point or a stack of one to
    three, small angles (scipy's series) included."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = float(rng.uniform(-3.5, 3.5)) * (1e-4 if small else 1.0)
    s = ease(np.linspace(0.0, 1.0, n)) if seed % 2 else np.sort(rng.uniform(0.0, 1.0, n))
    pts = rng.normal(size=3) * 0.05 if k == 0 else rng.normal(size=(k, 3)) * 0.05
    want = np.stack([Rotation.from_rotvec(axis * angle * si).apply(pts) for si in s])
    got = _turned_about(axis, angle, s, pts)
    assert got.shape == want.shape
    assert got.tobytes() == want.tobytes()


def test_hand_written_inits_keep_the_dataclasses() -> None:
    """``ObjectPose`` and ``Observation`` with their own ``__init__`` (p21d): the same
    fields, defaults, equality, frozen fields, ``replace`` and pickling."""
    import dataclasses
    import pickle

    r, t, c = np.eye(3), np.array([0.1, 0.2, 0.3]), np.array([0.1, 0.2, 0.35])
    pose = ObjectPose(r, t, c)
    assert pose.scale == 1.0 and pose.rotation is r and pose.translation is t and pose.com is c
    assert [f.name for f in dataclasses.fields(ObjectPose)] == [
        "rotation", "translation", "com", "scale"]
    assert ObjectPose(rotation=r, translation=t, com=c, scale=0.5).scale == 0.5
    with pytest.raises(dataclasses.FrozenInstanceError):
        pose.scale = 2.0  # type: ignore[misc]
    moved = dataclasses.replace(pose, scale=0.05)
    assert moved.scale == 0.05 and moved.rotation is r
    back = pickle.loads(pickle.dumps(moved))
    assert back.scale == 0.05 and back.com.tobytes() == c.tobytes()
    obs = Observation(0.25, pose, np.zeros((2, 3)))
    assert obs.time == 0.25 and obs.pose is pose
    assert Observation(time=0.25, pose=pose, tips=obs.tips) == obs
    with pytest.raises(dataclasses.FrozenInstanceError):
        obs.time = 1.0  # type: ignore[misc]
    assert "time=0.25" in repr(obs)
