"""The seeded demonstration generator: contact consistency, styles, reproducibility.

Truths used: the object's pose at each event is rebuilt here from the states alone
(``state_pose`` of the initial state; for the final state, ``state_pose``'s rotation with the
translation that keeps the pivot edge / vertex / centre of mass where it was), and distances
to faces, edges and vertices are computed here by elementary geometry (projection on a plane,
clamped projection on a segment). None of the generator's code is used for the check.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nonprehensile.demonstrations.dataset import DEFAULT_MARKERS, Dataset, load_dataset
from nonprehensile.demonstrations.synth import (
    DEFAULT_MENTORS,
    MentorStyle,
    event_progress,
    synthesize,
    synthesize_dataset,
    synthesize_demonstration,
)
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.io import read_skills
from nonprehensile.motion.trajectory import fill_gaps, resample
from nonprehensile.skills.contacts import Edge, Face, Finger, Ground, Vertex
from nonprehensile.skills.skill import Skill, skill_from_dict
from nonprehensile.states import state_pose

SKILLS = Path(__file__).parents[1] / "src" / "nonprehensile" / "data" / "cube_skills.json"
FloatArray = np.ndarray


@pytest.fixture(scope="module")
def small() -> Dataset:
    return synthesize_dataset(seed=7, n_per_skill=6)


# ----------------------------------------------------------------------------- geometry


def _pose_at_event(poly: Polyhedron, skill: Skill, i: int) -> tuple[FloatArray, FloatArray]:
    """The object's pose at event ``i``, from the states and the pivot alone."""
    ev = skill.events[i]
    grounds = {p.y for p in ev.pairs if isinstance(p.x, Ground)}
    if skill.maneuver == "rotating":
        at_end = i == len(skill.events) - 1
    else:
        at_end = Face(skill.final.face) in grounds
    r0, t0 = state_pose(poly, skill.initial)
    if not at_end:
        return r0, t0
    r1, t1 = state_pose(poly, skill.final)
    if skill.maneuver == "rotating":
        return r1, t1  # the centre of mass stays above the origin
    # the pivot event names what stays put: the edge or vertex on the ground
    pivot = next(p.y for e in skill.events for p in e.pairs
                 if isinstance(p.x, Ground) and isinstance(p.y, (Edge, Vertex)))
    x = poly.vertices[_vertices(poly, pivot)[0]]
    return r1, (r0 @ x + t0) - r1 @ x


def _vertices(poly: Polyhedron, el: object) -> list[int]:
    if isinstance(el, Face):
        return list(poly.faces[el.id])
    assert isinstance(el, (Edge, Vertex))
    return [i for i, fs in enumerate(poly.vertex_faces) if el.faces <= fs]


def _seg_dist(p: FloatArray, a: FloatArray, b: FloatArray) -> float:
    s = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + s * (b - a))))


def _dist_to_element(p: FloatArray, poly: Polyhedron, el: object, r: FloatArray,
                     t: FloatArray) -> float:
    pts = poly.vertices[_vertices(poly, el)] @ r.T + t
    if len(pts) == 1:
        return float(np.linalg.norm(p - pts[0]))
    if len(pts) == 2:
        return _seg_dist(p, pts[0], pts[1])
    n = r @ poly.normals[el.id]  # type: ignore[attr-defined]
    foot = p - ((p - pts[0]) @ n) * n
    # inside the convex polygon iff on the inner side of each edge (loop order is free)
    c = pts.mean(axis=0)
    e = np.roll(pts, -1, axis=0) - pts
    side = np.cross(e, foot - pts) @ n
    ref = np.cross(e, c - pts) @ n
    if np.all(side * ref >= -1e-12):
        return float(abs((p - pts[0]) @ n))
    return min(_seg_dist(p, a, b) for a, b in zip(pts, np.roll(pts, -1, axis=0), strict=True))


def _outside_by(p: FloatArray, poly: Polyhedron, r: FloatArray, t: FloatArray) -> float:
    """Signed distance outside the object's hull: > 0 outside, < 0 inside (depth)."""
    return max(
        float((p - (r @ poly.vertices[poly.faces[f][0]] + t)) @ (r @ poly.normals[f]))
        for f in poly.faces
    )


def _check_contacts(ds: Dataset, tol_mm: float) -> int:
    """Every named finger's tip is on its element, not inside; returns the checks made."""
    checks = 0
    unit_mm = ds.scale * 1000.0
    poses: dict[tuple[str, int], tuple[FloatArray, FloatArray]] = {}
    for d in ds.demonstrations:
        traj = d.trajectory.to_units("mm")
        filled = fill_gaps(traj.positions, ds.gap_limit)
        for i, ev in enumerate(d.events):
            frame = round(ev.time * traj.rate)
            assert abs(frame / traj.rate - ev.time) < 1e-6
            key = (d.skill.name, i)
            if key not in poses:
                poses[key] = _pose_at_event(ds.poly, d.skill, i)
            r, t = poses[key]
            for pair in d.skill.events[i].pairs:
                if not isinstance(pair.x, Finger):
                    continue
                marker = ds.fingers[f"R{pair.x.index}"]
                tip = filled[frame, traj.marker_names.index(marker)] / unit_mm
                dist = _dist_to_element(tip, ds.poly, pair.y, r, t) * unit_mm
                out = _outside_by(tip, ds.poly, r, t) * unit_mm
                assert dist <= tol_mm, (d.file, ev.id, pair, dist)
                assert out >= -tol_mm / 2, (d.file, ev.id, pair, out)
                checks += 1
    return checks


# -------------------------------------------------------------------------------- tests


def test_fingers_touch_the_named_elements_at_every_event(small: Dataset) -> None:
    # tip offset <= 2 mm, noise 0.5 mm (4 sigma = 2 mm), plus gap filling
    n = _check_contacts(small, tol_mm=4.5)
    assert n == 6 * (3 + 3 + 3 + 2 * 3 + 2 * 3 + 2)


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_mentors=st.integers(1, 6))
def test_contact_consistency_for_any_seed_and_drawn_mentors(seed: int, n_mentors: int) -> None:
    # beyond three mentors the styles are drawn at random, so this explores other styles too.
    # Without tracker noise and dropouts: the property is the generator's geometry (tip offset
    # <= 2 mm), which holds for every seed; Gaussian noise has no hard bound, so with it a
    # random seed eventually lands a tip past any fixed tolerance (seen at 4.62 mm > 4.5 mm).
    # The noisy data are checked on fixed seeds above.
    ds = synthesize_dataset(seed=seed, n_per_skill=n_mentors, mentors=n_mentors,
                            noise_mm=0.0, dropouts=0.0)
    assert _check_contacts(ds, tol_mm=2.5) == n_mentors * 23


def test_the_check_can_fail(small: Dataset) -> None:
    # move one tip 10 mm away from its face at the touch event: the check must notice
    d = small.of_skill("push-roll")[0]
    pos = np.array(d.trajectory.positions)
    frame = round(d.events[1].time * d.trajectory.rate)
    pos[frame, 0] += [10.0, 0.0, 0.0]
    bad = type(d)(d.file, d.skill, d.mentor, d.initial, d.final, d.events,
                  type(d.trajectory)(pos, d.trajectory.marker_names, d.trajectory.rate, "mm"))
    ds = Dataset(small.poly, small.skills, (bad,), small.scale, 40, small.fingers)
    with pytest.raises(AssertionError):
        _check_contacts(ds, tol_mm=4.5)


def test_measurement_noise_and_dropouts(small: Dataset) -> None:
    for d in small.demonstrations:
        assert d.trajectory.rate == 120.0
        assert d.trajectory.units == "mm"
        assert d.trajectory.marker_names == DEFAULT_MARKERS
        fill_gaps(d.trajectory.positions, small.gap_limit)  # every dropout is fillable
    occluded = sum(int(d.trajectory.occluded.sum()) for d in small.demonstrations)
    total = sum(d.trajectory.occluded.size for d in small.demonstrations)
    assert 0 < occluded / total < 0.05
    # noise: a still hovering marker before the first event scatters by about 0.5 mm
    poly, skills = read_skills(SKILLS)
    quiet = MentorStyle("q", 1.0, 1.0, (1.0, 1.0, 1.0), 1.0, (0.0, 0.0, 0.0), (0.2, 0.0))
    traj, _ = synthesize_demonstration(poly, skills[0], quiet, 3, noise_mm=0.5, dropouts=0)
    clean, _ = synthesize_demonstration(poly, skills[0], quiet, 3, noise_mm=0.0, dropouts=0)
    resid = traj.positions - clean.positions
    assert abs(float(resid.std()) - 0.5) < 0.03


def test_same_seed_same_data_other_seed_other_data() -> None:
    a = synthesize_dataset(seed=1, n_per_skill=2)
    b = synthesize_dataset(seed=1, n_per_skill=2)
    c = synthesize_dataset(seed=2, n_per_skill=2)
    assert all(x.trajectory == y.trajectory and x.events == y.events
               for x, y in zip(a.demonstrations, b.demonstrations, strict=True))
    assert any(x.trajectory != y.trajectory
               for x, y in zip(a.demonstrations, c.demonstrations, strict=True))


def test_mentor_styles_differ_in_speed(small: Dataset) -> None:
    mean = {m: np.mean([d.duration for d in small.demonstrations if d.mentor == m])
            for m in small.mentors}
    assert small.mentors == tuple(m.name for m in DEFAULT_MENTORS)
    # ana is the fastest (speed 1.35), ben the slowest (0.8)
    assert mean["ana"] < mean["chen"] < mean["ben"]
    assert mean["ben"] / mean["ana"] > 1.3


def _arc_paths(ds: Dataset, skill: str, arc: int) -> FloatArray:
    """The index tip along one arc, resampled to 50 points, mm: shape (n_demos, 50, 3)."""
    out = []
    for d in ds.of_skill(skill):
        traj = d.trajectory
        a, b = (round(d.events[k].time * traj.rate) for k in (arc, arc + 1))
        pos = fill_gaps(traj.positions, ds.gap_limit)[a:b + 1, :1]
        out.append(resample(pos, 50)[:, 0])
    return np.asarray(out)


@pytest.mark.parametrize(("one", "other", "arc"), [
    ("roll-arc", "roll-pull", 2),  # quarter circle vs straight pull (Fig. 5 skills 2, 3)
    ("tumble-lift", "tumble-twist", 2),  # the two tumbling skills of Fig. 9
])
def test_skills_with_the_same_events_move_the_fingers_differently(
    small: Dataset, one: str, other: str, arc: int
) -> None:
    p, q = _arc_paths(small, one, arc), _arc_paths(small, other, arc)
    between = float(np.linalg.norm(p.mean(axis=0) - q.mean(axis=0), axis=1).mean())
    within = max(
        float(np.linalg.norm(x - x.mean(axis=0), axis=2).mean()) for x in (p, q)
    )
    assert between > 12.0  # mm, on a 50 mm cube
    assert between > 2.0 * within


def test_straight_pull_is_straight_and_arc_is_a_circle(small: Dataset) -> None:
    for d in small.of_skill("roll-pull"):
        traj = d.trajectory
        a, b = (round(d.events[k].time * traj.rate) for k in (2, 3))
        path = fill_gaps(traj.positions, small.gap_limit)[a:b + 1, 0]
        chord = path[-1] - path[0]
        u = chord / np.linalg.norm(chord)
        off = path - path[0] - np.outer((path - path[0]) @ u, u)
        assert np.linalg.norm(off, axis=1).max() < 3.5  # mm: noise plus the tip offset
    for d in small.of_skill("roll-arc"):
        traj = d.trajectory
        a, b = (round(d.events[k].time * traj.rate) for k in (2, 3))
        path = fill_gaps(traj.positions, small.gap_limit)[a:b + 1, 0]
        # the rolling edge E(a,d) lies along y at x = -25 mm, z = 0: constant radius about it
        radius = np.hypot(path[:, 0] + 25.0, path[:, 2])
        assert radius.std() < 1.0 and radius.mean() > 50.0


def test_synthesize_writes_a_loadable_dataset(tmp_path: Path) -> None:
    written = synthesize(tmp_path / "ds", seed=3, n_per_skill=3, mentors=3)
    loaded = load_dataset(tmp_path / "ds")
    assert len(loaded.demonstrations) == len(written.demonstrations) == 18
    for x, y in zip(written.demonstrations, loaded.demonstrations, strict=True):
        assert x.events == y.events and x.mentor == y.mentor
        # C3D stores float32
        np.testing.assert_allclose(x.trajectory.positions, y.trajectory.positions,
                                   atol=1e-3, equal_nan=True)


def test_bad_arguments_are_input_errors() -> None:
    with pytest.raises(InputError, match="n_per_skill"):
        synthesize_dataset(n_per_skill=0)
    with pytest.raises(InputError, match="mentors"):
        synthesize_dataset(n_per_skill=1, mentors=0)
    with pytest.raises(InputError, match="scale"):
        synthesize_dataset(n_per_skill=1, scale=-1.0)


def test_a_skill_the_generator_cannot_play_is_named() -> None:
    poly, _ = read_skills(SKILLS)
    # a rolling skill that never touches the object while it rolls
    data = {
        "name": "ghost", "initial": {"face": "a", "theta": 0}, "final": {"face": "d", "theta": 0},
        "events": [{"id": "rest", "contacts": ["(G,a)"]},
                   {"id": "pivot", "contacts": ["(G,E(a,d))"]},
                   {"id": "done", "contacts": ["(G,d)"]}],
        "motions": [{"from": "rest", "to": "pivot"}, {"from": "pivot", "to": "done"}],
    }
    skill = skill_from_dict(data, poly)
    with pytest.raises(InputError, match="ghost"):
        event_progress(skill)
