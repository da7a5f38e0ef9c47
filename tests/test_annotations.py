"""Annotations that select markers and say the recordings' axes and units (docs/dataset.md).

Truths used: real recordings from several vendors (``../shared/realdata``, read in place and
copied unchanged into a temporary dataset folder, since a dataset is one folder), a y-up C3D
written from the bundled demonstrations (the issue's fingertips 98 mm below the table), and
object markers placed by the model's own pose formula.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from nonprehensile.cli.dataset import dataset_group
from nonprehensile.demonstrations.axes import AXES_PRESETS, axes_matrix, parse_axes
from nonprehensile.demonstrations.dataset import (
    Dataset,
    check_dataset,
    load_dataset,
    save_dataset,
)
from nonprehensile.demonstrations.formats import read_c3d, read_motive_csv, write_c3d
from nonprehensile.demonstrations.record import MarkerTrajectory
from nonprehensile.errors import DemonstrationError, InputError
from nonprehensile.io import read_skills
from nonprehensile.states import State, state_pose

# <repo>/../shared/realdata (GUIDE.md); NONPREHENSILE_SHARED points elsewhere (a git worktree
# has no shared/ beside it)
REALDATA = Path(os.environ.get("NONPREHENSILE_SHARED")
                or Path(__file__).resolve().parents[1].parent / "shared") / "realdata"
SKILLS = Path(__file__).resolve().parents[1] / "src" / "nonprehensile" / "data" / "cube_skills.json"

#: Every real recording that holds 3-D markers, with its vendor's axis convention.
REAL_RECORDINGS = {
    "c3d/BTS.c3d": "yup",  # BTS SMART: y up (heights 0.03..1.37 m in y)
    "c3d/FP_Type1.c3d": "yup",
    "c3d/FP_Type3.c3d": "zup",
    "c3d/Optotrak.c3d": {"x": "x", "y": "-y", "z": "-z"},  # a camera frame: z away from it
    "c3d/Qualisys.c3d": "qualisys-zup",
    "c3d/Vicon.c3d": "vicon-zup",
    "c3d/read_NOTworking2.c3d": "zup",
    "motive/ha5dzs_test_markers_enabled.csv": "motive-yup",
    "motive/jessicaxtang_Take 2024-10-24 04.26.46 PM.csv": "motive-yup",
    "motive/rofunc_Take 2023-03-29 06.23.40 PM_first3frames.csv": "motive-yup",
}

needs_realdata = pytest.mark.skipif(not REALDATA.is_dir(),
                                    reason=f"the real files are not at {REALDATA}")


def _read_raw(path: Path) -> MarkerTrajectory:
    return read_c3d(path, up="z") if path.suffix == ".c3d" else read_motive_csv(path, up="z")


def _finger_window(traj: MarkerTrajectory, axes: Any) -> tuple[str, float, float]:
    """A marker a user could name as the fingertip: the longest stretch in view, above the
    floor in the file's convention; and that stretch's start and end times."""
    rot = axes_matrix(parse_axes(axes))
    to_m = 0.001 if traj.units == "mm" else 1.0
    best: tuple[int, str, int, int] | None = None
    for k, name in enumerate(traj.marker_names):
        seen = ~traj.occluded[:, k]
        edges = np.diff(np.concatenate(([0], seen.astype(np.int8), [0])))
        for s, e in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            height = (traj.positions[s:e, k] @ rot.T)[:, 2] * to_m
            if height.min() >= 0 and (best is None or e - s > best[0]):
                best = (int(e - s), name, int(s), int(e))
    assert best is not None, "no marker stays above the floor"
    _, name, s, e = best
    return name, s / traj.rate, (e - 1) / traj.rate


@needs_realdata
@pytest.mark.parametrize("rel", sorted(REAL_RECORDINGS))
def test_every_real_recording_forms_a_one_demonstration_dataset(rel: str, tmp_path: Path) -> None:
    pytest.importorskip("ezc3d")
    src = REALDATA / rel
    raw = _read_raw(src)
    axes = REAL_RECORDINGS[rel]
    tip, t0, t1 = _finger_window(raw, axes)
    root = tmp_path / "ds"
    root.mkdir()
    shutil.copy(SKILLS, root / "skills.json")
    shutil.copy(src, root / src.name)  # unchanged: the loader reads it as the vendor wrote it
    times = np.linspace(t0, t1, 5).tolist()
    ids = ["rest", "touch", "pivot", "landed", "done"]
    (root / "annotations.json").write_text(json.dumps({
        "skills": "skills.json", "axes": axes, "fingers": {"R1": tip},
        "demonstrations": [{"file": src.name, "skill": "push-roll", "mentor": "lab",
                            "events": [{"id": i, "time": t} for i, t in zip(ids, times,
                                                                            strict=True)]}],
    }))
    ds, problems = check_dataset(root)
    assert problems == [] and ds is not None
    (demo,) = ds.demonstrations
    assert demo.trajectory.marker_names == (tip,)
    res = CliRunner().invoke(dataset_group, ["show", str(root)])
    assert res.exit_code == 0 and ": 1 demonstration of 6 skills on cube" in res.output
    if raw.n_markers > 1:  # the others are ignored, said once
        (note,) = ds.notes
        assert f"ignored {raw.n_markers - 1} marker(s)" in note
    # the tip is read in our axes (z up): above the table, as the vendor's frame has it
    t = demo.trajectory
    z = t.positions[round(t0 * t.rate):round(t1 * t.rate) + 1, 0, 2]
    assert z.min() >= 0 and np.isfinite(z).all()


@needs_realdata
def test_real_files_without_markers_are_the_only_ones_left_out() -> None:
    pytest.importorskip("ezc3d")
    others = sorted(str(p.relative_to(REALDATA)) for sub in ("c3d", "motive")
                    for p in (REALDATA / sub).iterdir()
                    if str(p.relative_to(REALDATA)) not in REAL_RECORDINGS)
    for rel in others:
        with pytest.raises(InputError):
            _read_raw(REALDATA / rel)


# ----------------------------------------------------------------------------- axes


def test_presets_and_explicit_axes() -> None:
    assert parse_axes("motive-yup") == parse_axes({"x": "x", "y": "-z", "z": "y"})
    m = axes_matrix(parse_axes("motive-yup"))
    # Motive's up axis y becomes our z; its z becomes our -y (docs/demonstrations.md)
    assert m @ np.array([1.0, 2.0, 3.0]) == pytest.approx([1.0, -3.0, 2.0])
    for spec in AXES_PRESETS.values():
        assert np.linalg.det(axes_matrix(spec)) == pytest.approx(1.0)
    with pytest.raises(InputError, match="mirror"):
        parse_axes({"x": "x", "y": "z", "z": "y"})
    with pytest.raises(InputError, match="presets"):
        parse_axes("optitrack")
    with pytest.raises(InputError, match="twice"):
        parse_axes({"x": "x", "y": "x", "z": "z"})


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Dataset:
    """Two bundled demonstrations (push-roll and tumble-lift, both fingers used)."""
    pytest.importorskip("ezc3d")
    ds = load_dataset("cube")
    picks = (ds.of_skill("push-roll")[0], ds.of_skill("tumble-lift")[0])
    return Dataset(ds.poly, ds.skills, picks, ds.scale, ds.gap_limit, ds.fingers)


def _write(root: Path, ds: Dataset, **top: Any) -> None:
    save_dataset(ds, root)
    path = root / "annotations.json"
    doc = json.loads(path.read_text())
    doc.update(top)
    path.write_text(json.dumps(doc))


def test_y_up_c3d_is_caught_with_the_numbers_and_read_with_the_preset(
    small: Dataset, tmp_path: Path
) -> None:
    root = tmp_path / "ds"
    _write(root, small)
    for d in small.demonstrations:  # as Motive exports C3D with its default axes
        write_c3d(d.trajectory, root / d.file, up="y")
    _, problems = check_dataset(root)
    assert problems and all("below the table" in p.message and "'zup'" in p.message
                            for p in problems)
    assert any(" mm below the table (z = -" in p.message for p in problems)
    doc = json.loads((root / "annotations.json").read_text())
    doc["axes"] = "motive-yup"
    (root / "annotations.json").write_text(json.dumps(doc))
    back = load_dataset(root)
    for a, b in zip(back.demonstrations, small.demonstrations, strict=True):
        assert np.nanmax(np.abs(a.trajectory.positions - b.trajectory.positions)) < 1e-3


def test_units_override(small: Dataset, tmp_path: Path) -> None:
    root = tmp_path / "ds"
    _write(root, small, units="cm")
    # the files say mm; the annotations say the numbers are cm: ten times larger, in mm
    back = load_dataset(root)
    a, b = back.demonstrations[0].trajectory, small.demonstrations[0].trajectory
    assert a.units == "mm" == b.units
    assert np.nanmax(np.abs(a.positions - 10 * b.positions)) < 1e-2
    _write(root, small, units="inch")
    (p,) = check_dataset(root)[1]
    assert "'units'" in p.message


# ------------------------------------------------------------------ marker selection


def test_unused_markers_are_ignored_with_one_note(small: Dataset, tmp_path: Path) -> None:
    demos = []
    for d in small.demonstrations:
        t = d.trajectory
        junk = np.full((t.n_frames, 2, 3), np.nan)  # labelled but never seen, as in Vicon's
        junk[::2, 1] = 1.0                          # ... or seen every other frame
        traj = MarkerTrajectory(np.concatenate([t.positions, junk], axis=1),
                                (*t.marker_names, "LASI", "RASI"), t.rate, t.units)
        demos.append(type(d)(d.file, d.skill, d.mentor, d.initial, d.final, d.events, traj))
    root = tmp_path / "ds"
    _write(root, Dataset(small.poly, small.skills, tuple(demos), small.scale, small.gap_limit,
                         small.fingers), markers=["index_knuckle"])
    ds = load_dataset(root)
    assert ds.notes == ("ignored 2 marker(s) that the annotations do not name in 'fingers', "
                        "'markers' or 'object_markers': thumb_knuckle, LASI, RASI"
                        .replace("2 marker", "3 marker"),)
    assert ds.demonstrations[0].trajectory.marker_names == ("index_tip", "index_knuckle",
                                                            "thumb_tip")
    res = CliRunner().invoke(dataset_group, ["show", str(root)])
    assert res.exit_code == 0 and res.stderr.count("note: ignored 3 marker(s)") == 1
    # a marker that matters and is never seen is still a problem
    _write(root, Dataset(small.poly, small.skills, tuple(demos), small.scale, small.gap_limit,
                         small.fingers), markers=["LASI"])
    problems = check_dataset(root)[1]
    assert len(problems) == 2 and all("'LASI' is missing (NaN) in every frame" in p.message
                                      for p in problems)


# -------------------------------------------------------------------- object markers


def _with_object_markers(small: Dataset, layout: dict[str, list[float]], shift_mm: float,
                         record_scale: float) -> Dataset:
    """Each demonstration with object markers recorded where the model puts them (times
    ``record_scale``), the first one shifted by ``shift_mm`` along x."""
    demos = []
    for d in small.demonstrations:
        t = d.trajectory
        rot, trans = state_pose(small.poly, d.initial)
        pts = (np.array(list(layout.values())) @ rot.T + trans) * small.scale * record_scale
        pts[0, 0] += shift_mm / 1000
        obj = np.broadcast_to(pts * 1000, (t.n_frames, len(layout), 3))  # mm, as the file
        traj = MarkerTrajectory(np.concatenate([t.positions, obj], axis=1),
                                (*t.marker_names, *layout), t.rate, t.units)
        demos.append(type(d)(d.file, d.skill, d.mentor, d.initial, d.final, d.events, traj))
    return Dataset(small.poly, small.skills, tuple(demos), small.scale, small.gap_limit,
                   small.fingers, object_markers={k: (v[0], v[1], v[2])
                                                  for k, v in layout.items()})


def test_object_markers_checked_against_the_model(small: Dataset, tmp_path: Path) -> None:
    poly, _ = read_skills(SKILLS)
    layout = {f"cube_{i}": [float(c) for c in poly.vertices[i]] for i in (0, 1, 2, 4)}
    root = tmp_path / "ds"
    _write(root, _with_object_markers(small, layout, 0.0, 1.0))
    ds = load_dataset(root)
    assert set(ds.object_markers) == set(layout)
    assert json.loads((root / "annotations.json").read_text())["object_markers"] == layout
    # one marker knocked 25 mm: named, with its distance
    _write(root, _with_object_markers(small, layout, 25.0, 1.0))
    problems = check_dataset(root)[1]
    assert len(problems) == 2
    assert all("'cube_0'" in p.message and "disagree with the model" in p.message
               for p in problems)
    # an object 20 % larger than the annotations' scale says: the distances give it away
    _write(root, _with_object_markers(small, layout, 0.0, 1.2))
    problems = check_dataset(root)[1]
    assert problems and all("mm apart" in p.message and "on the model" in p.message
                            for p in problems)
    with pytest.raises(DemonstrationError, match="three finite numbers"):
        _write(root, small, object_markers={"m": [1, 2]})
        load_dataset(root)


def test_state_pose_is_the_calibration(small: Dataset) -> None:
    # the check's reference: the resting cube's bottom face on z = 0, its centre of mass
    # above the origin
    rot, trans = state_pose(small.poly, State("a", 0))
    world = small.poly.vertices @ rot.T + trans
    assert world[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    com = small.poly.com @ rot.T + trans
    assert com[:2] == pytest.approx([0.0, 0.0], abs=1e-12)
