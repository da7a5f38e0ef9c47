"""LeRobot v3.0 export: the files' schema as LeRobot's own code reads it, and round trips
against the recordings they came from (issue 23).

The truth is the source: the dataset's own recordings (markers read back from the files the
generator wrote, the object's pose the loader fits) and LeRobot's layout as its code writes it
(``lerobot/datasets``: ``utils.py`` paths, ``DEFAULT_FEATURES``, the tasks frame indexed by
task, one episode-metadata row per episode with its frame range). The real ``LeRobotDataset``
opening these files is ``benchmarks/lerobot_check.py`` (it pulls torch: not in CI).
"""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nonprehensile.demonstrations.dataset import load_dataset, save_dataset
from nonprehensile.demonstrations.synth import synthesize_dataset
from nonprehensile.errors import InputError
from nonprehensile.export import dataset_episodes, export_dataset
from nonprehensile.export.episodes import (
    Episode,
    continuous_quaternions,
    resample_positions,
    resample_quaternions,
)

pa = pytest.importorskip("pyarrow", reason="the LeRobot export needs pyarrow (extra 'scale')")
pq = pytest.importorskip("pyarrow.parquet")

from nonprehensile.export.lerobot import read_lerobot, write_lerobot  # noqa: E402


@pytest.fixture(scope="module")
def tracked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small synthetic dataset with the object tracked (markers on it), in Motive CSV."""
    ds = synthesize_dataset(seed=7, n_per_skill=1, track_object=True)
    root = tmp_path_factory.mktemp("tracked")
    save_dataset(ds, root / "ds", trajectory_format="csv")
    return root / "ds"


@pytest.fixture(scope="module")
def exported(tracked: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("export") / "lerobot"
    export_dataset(tracked, out)
    return out


def test_layout_and_schema_are_lerobots(exported: Path) -> None:
    for rel in ("meta/info.json", "meta/stats.json", "meta/tasks.parquet",
                "meta/episodes/chunk-000/file-000.parquet", "data/chunk-000/file-000.parquet"):
        assert (exported / rel).is_file(), rel
    info = json.loads((exported / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0"
    assert info["fps"] == 120 and isinstance(info["fps"], int)
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["video_path"] is None
    assert info["splits"] == {"train": f"0:{info['total_episodes']}"}
    feats = info["features"]
    # LeRobot's DEFAULT_FEATURES, exactly
    assert feats["timestamp"] == {"dtype": "float32", "shape": [1], "names": None}
    for k in ("frame_index", "episode_index", "index", "task_index"):
        assert feats[k] == {"dtype": "int64", "shape": [1], "names": None}
    state = feats["observation.state"]
    assert state["dtype"] == "float32"
    assert state["names"][:7] == ["object.x", "object.y", "object.z", "object.qx", "object.qy",
                                  "object.qz", "object.qw"]
    assert state["names"][7:] == ["R1.x", "R1.y", "R1.z", "R2.x", "R2.y", "R2.z"]
    assert state["shape"] == [13]
    assert feats["action"]["names"] == state["names"][7:]
    assert feats["skill_index"]["labels"] == ["push-roll", "roll-arc", "roll-pull",
                                              "tumble-lift", "tumble-twist", "twist"]
    assert "push-roll: touch -> pivot" in feats["arc_index"]["labels"]
    assert "(R1,f) ∧ (G,a)" in feats["event_index"]["labels"]
    # the data file: one column per feature, Arrow types as LeRobot's writer makes them
    # (datasets' fixed-length sequences), one row group per episode
    pf = pq.ParquetFile(exported / "data/chunk-000/file-000.parquet")
    schema = pf.schema_arrow
    assert set(schema.names) == set(feats)
    assert schema.field("observation.state").type == pa.list_(pa.float32(), 13)
    assert schema.field("timestamp").type == pa.float32()
    assert schema.field("index").type == pa.int64()
    assert pf.metadata.num_row_groups == info["total_episodes"]
    assert pf.metadata.num_rows == info["total_frames"]
    # tasks: pandas restores the task strings as the index (LeRobot: tasks.iloc[i].name)
    tasks = pq.read_table(exported / "meta/tasks.parquet")
    meta = json.loads(tasks.schema.metadata[b"pandas"])
    assert meta["index_columns"] == ["task"]
    assert tasks.column("task").to_pylist()[0] == "push-roll: a:0 -> d:0"
    # episodes: the keys LeRobot's reader looks up, and the frame ranges tile the data
    ep = pq.read_table(exported / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [r["episode_index"] for r in ep] == list(range(len(ep)))
    assert ep[0]["dataset_from_index"] == 0
    for a, b in itertools.pairwise(ep):
        assert b["dataset_from_index"] == a["dataset_to_index"]
    assert ep[-1]["dataset_to_index"] == info["total_frames"]
    assert all(r["data/chunk_index"] == 0 and r["data/file_index"] == 0 for r in ep)
    assert {"stats/observation.state/mean", "stats/action/q99", "skill", "mentor",
            "initial", "final"} <= set(ep[0])
    stats = json.loads((exported / "meta/stats.json").read_text())
    assert set(stats["observation.state"]) == {"min", "max", "mean", "std", "count", "q01",
                                               "q10", "q50", "q90", "q99"}
    assert stats["observation.state"]["count"] == [info["total_frames"]]


def test_round_trip_equals_the_recordings(tracked: Path, exported: Path) -> None:
    ds = load_dataset(tracked)
    back = read_lerobot(exported)
    f = back.frames
    skills = back.labels("skill_index")
    arcs = back.labels("arc_index")
    for i, d in enumerate(ds.demonstrations):
        row = back.episodes[i]
        sel = f["episode_index"] == i
        assert row["skill"] == d.skill.name and row["mentor"] == d.mentor
        assert row["initial"] == str(d.initial) and row["final"] == str(d.final)
        assert back.tasks[int(f["task_index"][sel][0])] == f"{d.skill.name}: {d.initial} -> " \
                                                            f"{d.final}"
        i0 = row["source_frame"]
        n = int(sel.sum())
        traj = d.trajectory.to_units("m")
        rec = traj.positions[i0:i0 + n]
        seen = ~np.isnan(rec).any(axis=2)
        # markers and fingertips as recorded (where recorded; gaps are filled)
        mk = f["observation.markers"][sel].reshape(n, -1, 3)
        assert np.abs(mk - rec)[seen].max() < 1e-6
        tips = f["observation.state"][sel][:, 7:].reshape(n, -1, 3)
        for k, finger in enumerate(("R1", "R2")):
            j = traj.marker_names.index(ds.fingers[finger])
            ok = seen[:, j]
            assert np.abs(tips[ok, k] - rec[ok, j]).max() < 1e-6
        # the action is the next frame's fingertips
        act = f["action"][sel].reshape(n, -1, 3)
        assert np.abs(act[:-1] - tips[1:]).max() < 1e-7
        # the object pose: the loader's fit, model frame; its points where the markers are
        pose = ds.object_setup.pose(d.trajectory, ds.scale)  # type: ignore[union-attr]
        p = f["observation.state"][sel][:, :3]
        ok = pose.valid[i0:i0 + n]
        assert np.abs(p[ok] - pose.to_units("m").positions[i0:i0 + n][ok]).max() < 1e-6
        q = f["observation.state"][sel][:, 3:7]
        qq = pose.quaternions[i0:i0 + n][ok]
        assert np.abs(np.abs(np.einsum("ij,ij->i", q[ok], qq)) - 1).max() < 1e-6
        # labels: every frame between two events on the arc between them
        assert set(f["skill_index"][sel]) == {skills.index(d.skill.name)}
        t = i0 / traj.rate + f["timestamp"][sel].astype(np.float64)
        for e0, e1 in zip(d.events[:-1], d.events[1:], strict=True):
            inside = (t > e0.time + 1e-6) & (t < e1.time - 1e-6)
            name = f"{d.skill.name}: {e0.id} -> {e1.id}"
            assert set(f["arc_index"][sel][inside]) == {arcs.index(name)}
        assert (np.diff(f["index"][sel]) == 1).all()
        assert (f["frame_index"][sel] == np.arange(n)).all()


def test_resampling_is_exact_at_recorded_instants() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(50) / 120.0
    x = rng.normal(size=(50, 2, 3))
    assert np.array_equal(resample_positions(t, x, t[::4]), x[::4])
    from scipy.spatial.transform import Rotation

    q = Rotation.random(50, random_state=3).as_quat()
    back = resample_quaternions(t, q, t[::2])
    assert np.allclose(np.abs(np.einsum("ij,ij->i", back, q[::2])), 1.0, atol=1e-12)
    c = continuous_quaternions(q)
    assert (np.einsum("ij,ij->i", c[1:], c[:-1]) >= 0).all() and c[0, 3] >= 0


def test_fps_resamples_and_labels_follow(tracked: Path) -> None:
    ds = load_dataset(tracked)
    eps = dataset_episodes(ds, fps=40)
    native = dataset_episodes(ds)
    for a, b in zip(eps, native, strict=True):
        assert a.fps == 40
        # 120 / 40 = 3: every third recorded frame, as recorded
        assert np.array_equal(a.fingertips, b.fingertips[::3][:a.n_frames])
        assert np.array_equal(a.arc, b.arc[::3][:a.n_frames])


def test_write_refuses_an_existing_folder_and_mixed_rates(tmp_path: Path,
                                                           tracked: Path) -> None:
    ds = load_dataset(tracked)
    eps = dataset_episodes(ds)
    (tmp_path / "x").mkdir()
    with pytest.raises(InputError, match="exists"):
        write_lerobot(eps, tmp_path / "x")
    with pytest.raises(InputError, match="whole number"):
        write_lerobot(dataset_episodes(ds, fps=33.5), tmp_path / "y")
    assert not (tmp_path / "y").exists()


def test_a_dataset_of_no_demonstration_is_named_not_the_export_folder(tmp_path: Path,
                                                                      tracked: Path) -> None:
    """It was 'OUT: no episodes to export', naming the folder to write, not the dataset."""
    import shutil

    src = tmp_path / "takes"
    shutil.copytree(tracked, src)
    doc = json.loads((src / "annotations.json").read_text())
    doc["demonstrations"] = []
    (src / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="the dataset has no demonstration") as info:
        export_dataset(src, tmp_path / "out")
    assert str(info.value).startswith(f"{src}: "), info.value
    assert not (tmp_path / "out").exists()


def test_an_episode_rate_below_one_hz_is_not_written_as_fps_0(tmp_path: Path,
                                                               tracked: Path) -> None:
    """A rate within 1e-9 of the whole number 0 passed the whole-number check, and info.json
    said fps 0, which LeRobot divides by."""
    import dataclasses

    eps = [dataclasses.replace(e, fps=1e-30) for e in dataset_episodes(load_dataset(tracked))]
    with pytest.raises(InputError, match="whole number of frames per second, at least 1"):
        write_lerobot(eps, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_an_fps_that_would_exhaust_memory_is_refused_before_resampling(
        tracked: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`dataset export cube OUT --fps 100000` made 40 million frames of 48,064 recorded ones
    (about 1 kB of memory each while writing): it ran until memory was exhausted."""
    import nonprehensile.export.demonstrations as dem

    ds = load_dataset(tracked)
    recorded = sum(e.n_frames for e in dataset_episodes(ds))
    monkeypatch.setattr(dem, "MAX_RESAMPLED_FRAMES", 5 * recorded)
    assert sum(e.n_frames for e in dataset_episodes(ds, fps=480)) < 5 * recorded
    called: list[object] = []
    monkeypatch.setattr(dem, "demonstration_episode", lambda *a, **k: called.append(a))
    with pytest.raises(InputError, match=r"--fps 100000 makes [\d,]+ frames of its "
                                         rf"{recorded:,} recorded ones \(at 120 Hz\)"):
        dataset_episodes(ds, fps=100000)
    assert not called  # refused before any episode was made


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nonprehensile.cli", *args],
                          capture_output=True, text=True, check=False)


def test_cli_bad_input_is_one_line_and_exit_2(tmp_path: Path) -> None:
    (tmp_path / "there").mkdir()
    r = _cli("dataset", "export", "cube", str(tmp_path / "there"), "--format", "lerobot")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "there" in lines[0] and "exists" in lines[0]
    # the bundled dataset does not track the object: an export that needs its pose says so
    r = _cli("dataset", "export", "cube", str(tmp_path / "new"), "--object")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "object is not tracked" in lines[0] and "cube_demos" in lines[0]
    assert not (tmp_path / "new").exists()
    # LeRobot's fps is a whole number: a fraction is the option's error, before loading (it
    # was refused after loading, saying "give --fps N" to a user who had)
    r = _cli("dataset", "export", "cube", str(tmp_path / "new"), "--fps", "29.5")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--fps" in lines[0] and "whole number" in lines[0], r.stderr


def test_cli_exports_the_bundled_dataset(tmp_path: Path) -> None:
    r = _cli("dataset", "export", "cube", str(tmp_path / "out"), "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["n_episodes"] == 180 and doc["object_pose"] is False
    back = read_lerobot(tmp_path / "out")
    assert back.info["features"]["observation.state"]["names"][0] == "R1.x"
    assert back.info["total_frames"] == doc["n_frames"]



def test_simulated_plan_records_physics_as_it_was(tmp_path: Path) -> None:
    """Each executed step is an episode whose frames are physics' own states: at 100 fps
    every 10th physics step (1 ms), the trace rows the simulator kept, to float32."""
    pytest.importorskip("mujoco", reason="simulation needs MuJoCo (extra 'sim')")
    from importlib import resources

    from nonprehensile.inference import expand
    from nonprehensile.io import read_skills
    from nonprehensile.pipeline import motions_from_dataset
    from nonprehensile.planning import plan
    from nonprehensile.sim import Simulator
    from nonprehensile.sim.episodes import plan_episodes
    from nonprehensile.sim.execute import simulate_plan
    from nonprehensile.states import State, states_by_step

    skills_file = Path(str(resources.files("nonprehensile") / "data" / "cube_skills.json"))
    poly, skills = read_skills(skills_file)
    exp = expand(poly, skills, states_by_step(poly, 90.0))
    ds, motions = motions_from_dataset("cube", skills=skills, poly=poly)
    result = plan(poly, exp, State("a", 0), State("d", 0), motions=motions, scale=ds.scale)
    sim = Simulator(poly, scale=ds.scale, n_fingers=2)
    outcomes = simulate_plan(poly, result, scale=ds.scale, fingers=ds.fingers, sim=sim,
                             keep_trace=1)
    eps = plan_episodes(poly, result, outcomes, n_fingers=2, fingers=ds.fingers, fps=100)
    out = write_lerobot(eps, tmp_path / "rec")
    back = read_lerobot(out)
    trace = outcomes[0].result.trace
    assert trace is not None
    n = back.episodes[0]["length"]
    rows = trace[::10][:n]  # rows at 1 ms, 11 ms, ...: frame k is step 1 + 10 k
    assert len(rows) == n
    state = back.frames["observation.state"][:n].astype(np.float64)
    assert np.abs(state[:, :3] - rows[:, 1:4]).max() < 1e-6
    quat_xyzw = np.column_stack([rows[:, 5:8], rows[:, 4:5]])
    assert np.abs(np.abs(np.einsum("ij,ij->i", state[:, 3:7], quat_xyzw)) - 1).max() < 1e-6
    assert np.abs(state[:, 7:] - rows[:, 8:14]).max() < 1e-6
    # the action: the actuators' set points (the trace's last columns) at the next frame
    act = back.frames["action"][:n].astype(np.float64)
    ctrl = trace[::10][:n + 1, -6:]
    assert np.abs(act[:-1] - ctrl[1:n]).max() < 1e-6
    ep = back.episodes[0]
    assert ep["success"] is outcomes[0].success and ep["skill"] == "push-roll"
    # the labels are the simulator's own events, in order
    names = back.labels("event_index")
    seen = [names[i] for i in back.frames["event_index"][:n] if i >= 0]
    firsts = list(dict.fromkeys(seen))
    from nonprehensile.export.demonstrations import event_name

    assert firsts == list(dict.fromkeys(event_name(poly, e.event)
                                        for e in outcomes[0].result.events))


def test_cli_records_a_closed_loop_execution(tmp_path: Path) -> None:
    pytest.importorskip("mujoco", reason="simulation needs MuJoCo (extra 'sim')")
    from importlib import resources

    skills_file = str(resources.files("nonprehensile") / "data" / "cube_skills.json")
    r = _cli("simulate", "plan", skills_file, "--from", "a:0", "--to", "d:0", "--step", "90",
             "--record", str(tmp_path / "rec"), "--json")
    assert r.returncode in (0, 1), r.stderr
    doc = json.loads(r.stdout)
    back = read_lerobot(tmp_path / "rec")
    assert back.info["total_frames"] == doc["record"]["n_frames"]
    assert back.episodes[0]["skill"] == "push-roll" and back.episodes[0]["loop"] == "closed"
    assert back.info["features"]["observation.state"]["names"][0] == "object.x"


def test_cli_record_refuses_an_existing_folder_before_simulating(tmp_path: Path) -> None:
    pytest.importorskip("mujoco", reason="simulation needs MuJoCo (extra 'sim')")
    (tmp_path / "rec").mkdir()
    from importlib import resources

    skills_file = str(resources.files("nonprehensile") / "data" / "cube_skills.json")
    r = _cli("simulate", "plan", skills_file, "--from", "a:0", "--to", "d:0", "--step", "90",
             "--record", str(tmp_path / "rec"))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--record folder exists" in lines[0], r.stderr


def test_cli_record_refuses_a_folder_it_cannot_create_before_simulating(tmp_path: Path) -> None:
    """A --record folder under a file was found out only when the simulation was over."""
    pytest.importorskip("mujoco", reason="simulation needs MuJoCo (extra 'sim')")
    (tmp_path / "file").write_text("")
    from importlib import resources

    skills_file = str(resources.files("nonprehensile") / "data" / "cube_skills.json")
    r = _cli("simulate", "plan", skills_file, "--from", "a:0", "--to", "d:0", "--step", "90",
             "--record", str(tmp_path / "file" / "rec"))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot create the --record folder" in lines[0], r.stderr
    assert "is a file, not a folder" in lines[0], r.stderr


def test_an_export_that_fails_midway_leaves_no_folder(tmp_path: Path, tracked: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """A write that failed (a full disk) left a cut data file in the export folder, which the
    next export then refused as existing; now the folder appears whole or not at all."""
    import pyarrow.parquet as pq

    eps = dataset_episodes(load_dataset(tracked))
    real = pq.write_table

    def full(table: object, where: object, **kw: object) -> None:
        real(table, where, **kw)  # type: ignore[arg-type]
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pq, "write_table", full)
    with pytest.raises(OSError, match="nothing was written") as info:
        write_lerobot(eps, tmp_path / "out")
    assert info.value.filename == str(tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no folder, no partial one
    monkeypatch.undo()
    write_lerobot(eps, tmp_path / "out")
    assert read_lerobot(tmp_path / "out").info["total_episodes"] == len(eps)
    with pytest.raises(InputError, match="is a file, not a folder"):
        export_dataset(tracked, tmp_path / "out" / "meta" / "info.json" / "x")


@pytest.mark.parametrize("content", [None, "theirs.txt"])
def test_an_export_never_lands_on_a_folder_that_appeared_while_it_was_written(
        tmp_path: Path, tracked: Path, monkeypatch: pytest.MonkeyPatch,
        content: str | None) -> None:
    """POSIX ``rename`` replaces an empty folder silently: a folder made at the target while
    the export was written was replaced (empty) or the error said 'free space' (not empty).
    Two exports from one process also shared one scratch folder named by the process id, and
    one published the other's frames under its own info.json."""
    import nonprehensile.export.lerobot as lr

    eps = dataset_episodes(load_dataset(tracked))
    out = tmp_path / "out"
    real = lr._write_json
    scratch: list[Path] = []

    def meanwhile(path: Path, doc: object) -> None:
        real(path, doc)
        if path.name == "info.json":
            scratch.append(path.parent.parent)
            out.mkdir()
            if content:
                (out / content).write_text("not the export's")

    monkeypatch.setattr(lr, "_write_json", meanwhile)
    with pytest.raises(InputError, match="appeared there while the export was written"):
        write_lerobot(eps, out)
    # the other folder is left as it was; no scratch folder is left
    assert sorted(p.name for p in out.iterdir()) == ([content] if content else [])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    monkeypatch.undo()
    # each export writes into a scratch folder of its own (not one named by the process id)
    monkeypatch.setattr(lr, "_write_json", meanwhile)
    out.rename(tmp_path / "kept")
    with pytest.raises(InputError):
        write_lerobot(eps, out)
    assert len(scratch) == 2 and scratch[0] != scratch[1]
    monkeypatch.undo()
    # published with the user's umask (a scratch folder of tempfile.mkdtemp's was 0700, and
    # so was the dataset: no other account could read it)
    import os
    import shutil

    shutil.rmtree(out)  # (the folder made meanwhile above)
    mask = os.umask(0o022)
    try:
        write_lerobot(eps, out)
    finally:
        os.umask(mask)
    assert out.stat().st_mode & 0o777 == 0o755
    # a symbolic link at the path, even one to nothing, is there: refused before any work
    (tmp_path / "link").symlink_to(tmp_path / "nothing")
    with pytest.raises(InputError, match="link: the export folder exists"):
        write_lerobot(eps, tmp_path / "link")


@st.composite
def _episodes(draw: st.DrawFn) -> list[Episode]:
    n_fingers = draw(st.integers(1, 3))
    with_pose = draw(st.booleans())
    out = []
    for i in range(draw(st.integers(1, 4))):
        n = draw(st.integers(1, 30))
        rng = np.random.default_rng(draw(st.integers(0, 2**31)))
        tips = rng.normal(0, 0.1, (n, n_fingers, 3))
        quat = rng.normal(size=(n, 4))
        pose = np.concatenate([rng.normal(0, 0.1, (n, 3)), continuous_quaternions(quat)],
                              axis=1) if with_pose else None
        names = tuple(f"e{k}" for k in range(draw(st.integers(1, 4))))
        out.append(Episode(
            task=draw(st.sampled_from(["a: x -> y", "b ∧ c: a:0 -> d:90", "t"])), fps=30.0,
            fingertips=tips, action=np.roll(tips, -1, axis=0),
            finger_names=tuple(f"R{k + 1}" for k in range(n_fingers)), object_pose=pose,
            skill_names=(f"s{i % 2}",), skill=np.zeros(n, np.int64), event_names=names,
            event=rng.integers(-1, len(names), n), meta={"mentor": f"m{i}", "n": i}))
    return out


@settings(max_examples=15, deadline=None)
@given(eps=_episodes())
def test_any_episodes_round_trip(tmp_path_factory: pytest.TempPathFactory,
                                 eps: list[Episode]) -> None:
    out = write_lerobot(eps, tmp_path_factory.mktemp("rt") / "x")
    back = read_lerobot(out)
    f = back.frames
    assert back.info["total_frames"] == sum(e.n_frames for e in eps) == len(f["index"])
    events = back.labels("event_index")
    start = 0
    for i, e in enumerate(eps):
        sl = slice(start, start + e.n_frames)
        state = e.fingertips.reshape(e.n_frames, -1)
        if e.object_pose is not None:
            state = np.concatenate([e.object_pose, state], axis=1)
        assert np.array_equal(f["observation.state"][sl], state.astype(np.float32))
        assert np.array_equal(f["action"][sl], e.action.reshape(e.n_frames, -1)
                              .astype(np.float32))
        assert [events[j] if j >= 0 else None for j in f["event_index"][sl]] == [
            e.event_names[j] if j >= 0 else None for j in e.event]
        assert back.tasks[f["task_index"][sl][0]] == e.task
        assert back.episodes[i]["mentor"] == e.meta["mentor"]
        assert back.episodes[i]["length"] == e.n_frames
        start += e.n_frames


def test_cli_records_a_robustness_sweep(tmp_path: Path) -> None:
    pytest.importorskip("mujoco", reason="simulation needs MuJoCo (extra 'sim')")
    from importlib import resources

    skills_file = str(resources.files("nonprehensile") / "data" / "cube_skills.json")
    r = _cli("simulate", "robustness", skills_file, "--step", "90", "--from", "a:0", "--to",
             "d:0", "--samples", "2", "--loop", "open", "--workers", "1", "--record",
             str(tmp_path / "rec"), "--json", "--no-records")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    back = read_lerobot(tmp_path / "rec")
    assert len(back.episodes) == doc["record"]["n_episodes"] == 2
    assert [e["sample"] for e in back.episodes] == [0, 1]
    # each episode is its sample's execution: its verdict and its physical parameters
    assert all("param.mass" in e and e["loop"] == "open" for e in back.episodes)
    assert sum(e["success"] for e in back.episodes) == doc["overall"]["open"]["k"]
    r = _cli("simulate", "robustness", skills_file, "--step", "90", "--from", "a:0", "--to",
             "d:0", "--samples", "2", "--loop", "open", "--record", str(tmp_path / "rec"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
