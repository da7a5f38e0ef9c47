"""Object pose from recordings: Motive rigid bodies (read, write, real exports) and Kabsch fits."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.spatial.transform import Rotation

from nonprehensile.demonstrations import (
    MarkerTrajectory,
    PoseTrajectory,
    kabsch_poses,
    read_c3d,
    read_motive_csv,
    write_c3d,
    write_motive_csv,
)
from nonprehensile.errors import DemonstrationError

# Real files nobody here made: <repo>/../shared/realdata (GUIDE.md), read in place;
# NONPREHENSILE_SHARED points elsewhere (a git worktree has no shared/ beside it).
REALDATA = Path(os.environ.get("NONPREHENSILE_SHARED")
                or Path(__file__).resolve().parents[1].parent / "shared") / "realdata"
ROFUNC = REALDATA / "motive" / "rofunc_Take 2023-03-29 06.23.40 PM_first3frames.csv"


def _angle_deg(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    return np.degrees((Rotation.from_quat(q1).inv() * Rotation.from_quat(q2)).magnitude())


@pytest.fixture
def rofunc() -> Path:
    if not ROFUNC.is_file():
        pytest.skip(f"real Motive export not found at {ROFUNC} (shared/ beside the repo)")
    return ROFUNC


def test_real_motive_rigid_bodies_are_read_with_their_header(rofunc: Path) -> None:
    traj = read_motive_csv(rofunc)
    assert [b.name for b in traj.rigid_bodies] == ["Left", "Right", "Box"]
    box = traj.rigid_body("Box")
    assert (box.n_frames, box.rate, box.units) == (3, 120.0, "mm")
    assert box.valid.all()
    # Motive's y-up (x, y, z) -> ours (x, -z, y): row 8 holds Box at (173.746262, 1087.327515,
    # -162.837524) mm and quaternion (0.001108, -0.016831, 0.001360, 0.999857)
    assert box.positions[0] == pytest.approx([173.746262, 162.837524, 1087.327515])
    q = np.array([0.001108, -0.016831, 0.001360, 0.999857])
    assert box.quaternions[0] == pytest.approx(
        np.array([0.001108, -0.001360, -0.016831, 0.999857]) / np.linalg.norm(q)
    )


def test_real_motive_rigid_body_markers_are_fixed_in_the_solved_body_frame(rofunc: Path) -> None:
    """Motive's own solve is the truth: its expected markers sit still in the body frame.

    Reading the quaternion order, its sign or the axis conversion wrong would move them.
    """
    traj = read_motive_csv(rofunc)
    expected = read_motive_csv(rofunc, marker_types=("Rigid Body Marker",))
    for body in traj.rigid_bodies:
        names = [m for m in expected.marker_names if m.startswith(f"{body.name}:")]
        assert len(names) == 4
        for m in names:
            local = np.einsum("nji,nj->ni", body.rotations, expected.marker(m) - body.positions)
            assert np.ptp(local, axis=0).max() < 2e-3  # mm, over the three frames
        # the measured markers lie within a few mm of where the solved body expects them
        for m in names:
            assert np.linalg.norm(traj.marker(m) - expected.marker(m), axis=1).max() < 5.0


def test_kabsch_on_real_markers_agrees_with_motive_solve(rofunc: Path) -> None:
    traj = read_motive_csv(rofunc)
    expected = read_motive_csv(rofunc, marker_types=("Rigid Body Marker",))
    for body in traj.rigid_bodies:
        names = [m for m in expected.marker_names if m.startswith(f"{body.name}:")]
        r0, p0 = body.rotations[0], body.positions[0]
        layout = {m: r0.T @ (expected.marker(m)[0] - p0) for m in names}
        fit = traj.pose_from_markers(body.name, layout)
        assert fit.valid.all()
        assert np.linalg.norm(fit.positions - body.positions, axis=1).max() < 2.0  # mm
        assert _angle_deg(fit.quaternions, body.quaternions).max() < 0.5


# ----------------------------------------------------------------------------- round trips

_quats = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 0.2
)


@st.composite
def _recordings(draw: st.DrawFn) -> MarkerTrajectory:
    n = draw(st.integers(1, 6))
    n_bodies = draw(st.integers(1, 2))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    units = draw(st.sampled_from(["mm", "m"]))
    bodies = []
    for b in range(n_bodies):
        q = np.array([draw(_quats) for _ in range(n)])
        p = rng.uniform(-2000, 2000, (n, 3))
        lost = rng.random(n) < 0.25
        q[lost] = np.nan
        p[lost] = np.nan
        bodies.append(PoseTrajectory(f"body {b}", p, q, 120.0, units))
    pos = rng.uniform(-500, 500, (n, 2, 3))
    return MarkerTrajectory(pos, ("m1", "m2"), 120.0, units, tuple(bodies))


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rec=_recordings(), up=st.sampled_from(["y", "z"]),
       rotation_type=st.sampled_from(["Quaternion", "XYZ", "ZYX", "YZX"]))
def test_motive_rigid_body_round_trip(
    rec: MarkerTrajectory, up: str, rotation_type: str, tmp_path_factory: pytest.TempPathFactory
) -> None:
    path = tmp_path_factory.mktemp("rb") / "take.csv"
    write_motive_csv(rec, path, up=up, rotation_type=rotation_type)  # type: ignore[arg-type]
    back = read_motive_csv(path, up=up)  # type: ignore[arg-type]
    assert back.marker_names == rec.marker_names
    assert np.allclose(back.positions, rec.positions, atol=5e-7)
    assert [b.name for b in back.rigid_bodies] == [b.name for b in rec.rigid_bodies]
    for got, want in zip(back.rigid_bodies, rec.rigid_bodies, strict=True):
        assert np.array_equal(got.valid, want.valid)
        ok = want.valid
        assert np.allclose(got.positions[ok], want.positions[ok], atol=5e-7)
        if rotation_type == "Quaternion":  # written as given, six decimals
            assert np.allclose(got.quaternions[ok], want.quaternions[ok], atol=2e-6)
        elif ok.any():  # Euler angles: the same rotations (gimbal lock costs a few digits)
            assert _angle_deg(got.quaternions[ok], want.quaternions[ok]).max() < 1e-3


def test_motive_euler_columns_follow_the_rotation_type(tmp_path: Path) -> None:
    """An Euler export of a known rotation reads back to it: 30 degrees about Motive's y."""
    rot = Rotation.from_euler("y", 30, degrees=True)  # about the file's up axis
    body = PoseTrajectory("cup", np.zeros((1, 3)), rot.as_quat()[None], 120.0, "mm")
    traj = MarkerTrajectory(np.zeros((1, 1, 3)), ("m",), 120.0, "mm", (body,))
    write_motive_csv(traj, tmp_path / "t.csv", up="z", rotation_type="XYZ")
    text = (tmp_path / "t.csv").read_text().splitlines()
    assert "Rotation Type,XYZ" in text[0]
    assert [float(c) for c in text[-1].split(",")[2:5]] == [0.0, 30.0, 0.0]
    # read as Motive's y-up: a turn about the vertical, which is our z
    back = read_motive_csv(tmp_path / "t.csv", up="y").rigid_body("cup")
    assert np.degrees(Rotation.from_quat(back.quaternions[0]).as_rotvec()) == pytest.approx(
        [0, 0, 30], abs=1e-6
    )


def test_motive_euler_file_with_quaternion_type_is_an_error(tmp_path: Path) -> None:
    body = PoseTrajectory("cup", np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), 120.0, "mm")
    traj = MarkerTrajectory(np.zeros((2, 1, 3)), ("m",), 120.0, "mm", (body,))
    write_motive_csv(traj, tmp_path / "t.csv", rotation_type="XYZ")
    path = tmp_path / "t.csv"
    path.write_text(path.read_text().replace("Rotation Type,XYZ", "Rotation Type,Quaternion"))
    with pytest.raises(DemonstrationError, match="three rotation columns"):
        read_motive_csv(path)
    with pytest.raises(DemonstrationError, match="rotation_type"):
        write_motive_csv(traj, path, rotation_type="XYX")


def test_rigid_body_must_match_the_recording() -> None:
    body = PoseTrajectory("cup", np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)), 100.0, "mm")
    with pytest.raises(DemonstrationError, match="same recording"):
        MarkerTrajectory(np.zeros((3, 1, 3)), ("m",), 120.0, "mm", (body,))
    with pytest.raises(DemonstrationError, match="zero length"):
        PoseTrajectory("cup", np.zeros((1, 3)), np.zeros((1, 4)), 100.0)
    traj = MarkerTrajectory(np.zeros((3, 1, 3)), ("m",), 100.0, "m", (body,))
    assert traj.rigid_body("cup").units == "m"  # converted with the markers
    assert traj.rigid_body("cup").positions.max() == 0.0
    with pytest.raises(DemonstrationError, match="no rigid body named 'box'"):
        traj.rigid_body("box")


# --------------------------------------------------------------------------- Kabsch, gaps


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(3, 6))
def test_kabsch_recovers_exact_poses(seed: int, m: int) -> None:
    rng = np.random.default_rng(seed)
    layout = rng.uniform(-50, 50, (m, 3))
    rots = Rotation.random(8, random_state=rng)
    p = rng.uniform(-1000, 1000, (8, 3))
    world = np.einsum("nij,mj->nmi", rots.as_matrix(), layout) + p[:, None]
    world[2, : m - 2] = np.nan  # two markers left: invalid
    if m > 3:
        world[3, 0] = np.nan  # one lost: still fitted
    pos, quat, rms = kabsch_poses(world, layout)
    ok = np.ones(8, bool)
    ok[2] = False
    assert np.isnan(pos[2]).all() and np.isnan(quat[2]).all()
    # conditioning: a nearly collinear random layout loses digits, never the pose
    assert np.abs(pos[ok] - p[ok]).max() < 1e-6
    assert _angle_deg(quat[ok], rots.as_quat()[ok]).max() < 1e-6
    assert np.nanmax(rms) < 1e-6


def test_object_markers_in_c3d_give_the_pose(tmp_path: Path) -> None:
    pytest.importorskip("ezc3d")
    layout = {"obj:1": [0, 0, 30.0], "obj:2": [25.0, 0, 10], "obj:3": [0, -20.0, 5],
              "obj:4": [-15.0, 15, 25]}
    rots = Rotation.from_rotvec(np.outer(np.linspace(0, 1.5, 20), [1, 2, 0.5]))
    p = np.column_stack([np.linspace(0, 100, 20), np.zeros(20), np.full(20, 25.0)])
    world = np.einsum("nij,mj->nmi", rots.as_matrix(), np.array(list(layout.values()))) + p[:, None]
    world[5:7, 1] = np.nan
    traj = MarkerTrajectory(world, tuple(layout), 120.0, "mm")
    write_c3d(traj, tmp_path / "t.c3d")
    pose = read_c3d(tmp_path / "t.c3d").pose_from_markers("cube", layout)
    assert pose.valid.all()
    assert np.abs(pose.positions - p).max() < 1e-3  # float32 in the file
    assert _angle_deg(pose.quaternions, rots.as_quat()).max() < 1e-4
    with pytest.raises(DemonstrationError, match="not in the recording"):
        traj.pose_from_markers("cube", {**layout, "obj:9": [0, 0, 0]})


def test_short_gaps_are_slerped_and_long_ones_stay_invalid() -> None:
    n = 40
    # a constant-rate turn about a fixed axis and a straight, constant-speed path: slerp and
    # linear interpolation rebuild them exactly
    rots = Rotation.from_rotvec(np.outer(np.linspace(0, 2.0, n), [0.3, -0.5, 0.8]))
    p = np.outer(np.arange(n), [1.0, -2.0, 0.5])
    q = rots.as_quat()
    q[::2] *= -1  # the sign of a quaternion does not matter
    lost = np.zeros(n, bool)
    lost[[0, 1]] = True  # at the start: held invalid (one side only)
    lost[5:9] = True  # 4 frames: filled
    lost[20:30] = True  # 10 frames: too long
    qq, pp = q.copy(), p.copy()
    qq[lost] = np.nan
    pp[lost] = np.nan
    pose = PoseTrajectory("cube", pp, qq, 120.0, "mm").filled(4)
    assert pose.valid.tolist() == [not (i < 2 or 20 <= i < 30) for i in range(n)]
    ok = pose.valid
    assert np.abs(pose.positions[ok] - p[ok]).max() < 1e-9
    assert _angle_deg(pose.quaternions[ok], rots.as_quat()[ok]).max() < 1e-7
    assert pose.gaps() == [(0, 2), (20, 30)]


def test_a_huge_quaternion_is_normalised_not_zeroed() -> None:
    """A Motive cell of 1e300 in each rotation column: the quaternion's norm overflowed to inf
    and it was divided down to (0, 0, 0, 0), silently; a dataset then failed with 'frame 13
    has a quaternion of zero length', naming no file, when its axes were turned."""
    q = np.array([[0.0, 0.0, 0.0, 1.0], [1e300, 1e300, 1e300, 1e300],
                  [-1e308, 0.0, 0.0, 1e308], [np.nan, 0.0, 0.0, 1.0]])
    pose = PoseTrajectory("Box", np.zeros((4, 3)), q, 120.0)
    np.testing.assert_allclose(pose.quaternions[1], [0.5, 0.5, 0.5, 0.5])
    np.testing.assert_allclose(pose.quaternions[2], np.array([-1.0, 0.0, 0.0, 1.0]) / 2**0.5)
    assert np.isnan(pose.quaternions[3]).all() and not pose.valid[3]
    turned = PoseTrajectory("Box", pose.positions, pose.quaternions, 120.0)
    np.testing.assert_allclose(turned.quaternions[:3], pose.quaternions[:3])
    with pytest.raises(DemonstrationError, match="frame 1 has a quaternion of zero length"):
        PoseTrajectory("Box", np.zeros((2, 3)), [[0, 0, 0, 1], [1e-12, 0, 0, 0]], 120.0)
    # components near the largest float: the length overflows (inf, not zero), and no
    # RuntimeWarning reaches the user
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        big = PoseTrajectory("Box", np.zeros((1, 3)), [[1.7e308, 1.7e308, 1.7e308, 1.7e308]],
                             120.0)
    np.testing.assert_allclose(big.quaternions[0], [0.5, 0.5, 0.5, 0.5])
