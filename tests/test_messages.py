"""The messages of issue 24 point 5: each is one line naming the file or field and the fix."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from nonprehensile.cli import main
from nonprehensile.demonstrations.annotate import annotate_recording
from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory
from nonprehensile.demonstrations.synth import DEFAULT_MENTORS, synthesize, synthesize_dataset
from nonprehensile.errors import DemonstrationError
from nonprehensile.io import load_document, save_document

ROOT = Path(__file__).resolve().parents[1]
MOTIVE = ROOT.parent / "shared" / "realdata" / "motive" / \
    "jessicaxtang_Take 2024-10-24 04.26.46 PM.csv"
#: A real Motive export of a take with nothing selected: header rows, frames and times only
EMPTY_MOTIVE = MOTIVE.with_name("ha5dzs_test_default.csv")


def _problem_lines(output: str) -> list[str]:
    """The lines naming a problem of demonstration 0 (a list item, or the error line itself
    when it is the only problem), from the file's name on."""
    return [line[line.index("(demonstration 0)"):].strip() for line in output.splitlines()
            if "(demonstration 0)" in line]


@pytest.mark.skipif(not MOTIVE.is_file(),
                    reason=f"real Motive export not found at {MOTIVE} (shared/ beside the repo)")
def test_a_motive_csv_without_the_finger_markers_names_file_and_markers(tmp_path: Path) -> None:
    folder = tmp_path / "takes"
    synthesize(folder, seed=5, n_per_skill=1, mentors=1, trajectory_format="csv")
    doc = load_document(folder / "annotations.json")
    first = doc["demonstrations"][0]
    shutil.copy(MOTIVE, folder / "take.csv")  # a real export of one unlabeled marker
    doc["demonstrations"] = [{**first, "file": "take.csv"}]
    save_document(doc, folder / "annotations.json")
    r = CliRunner().invoke(main, ["dataset", "show", str(folder)])
    assert r.exit_code == 2
    lines = _problem_lines(r.output)
    assert len(lines) == 1, r.output
    line = lines[0]
    assert "take.csv (demonstration 0)" in r.output
    assert line.startswith("(demonstration 0): marker(s) ['index_tip', ")
    assert "Unlabeled 1014" in line and "'markers'" in line  # its own markers, and the fix
    assert "shape" not in r.output and "Traceback" not in r.output


def test_show_says_what_it_could_not_check() -> None:
    r = CliRunner().invoke(main, ["dataset", "show", "cube"])
    assert r.exit_code == 0, r.output
    first = next(line for line in r.output.splitlines() if "no problems" in line)
    assert "no problems found; not checked: the initial states against the object's pose" in first
    assert "the event times against the object's motion" in first
    doc = json.loads(CliRunner().invoke(main, ["dataset", "show", "cube", "--json"]).stdout)
    assert len(doc["not_checked"]) == 2 and doc["problems"] == []


def test_empty_events_say_which_events_to_give(tmp_path: Path) -> None:
    folder = tmp_path / "takes"
    synthesize(folder, seed=5, n_per_skill=1, mentors=1, trajectory_format="csv")
    doc = load_document(folder / "annotations.json")
    doc["demonstrations"][0]["events"] = []
    save_document(doc, folder / "annotations.json")
    r = CliRunner().invoke(main, ["dataset", "show", str(folder)])
    assert r.exit_code == 2
    [line] = _problem_lines(r.output)
    name = doc["demonstrations"][0]["file"]
    assert f"{name} (demonstration 0)" in r.output
    assert line.startswith("(demonstration 0): 'events' is empty: give the time of "
                           "each event of the skill, in order (['rest', 'touch', 'pivot', ")
    assert "got []" not in line and "dataset annotate" in line


def _cut(traj: MarkerTrajectory, n: int) -> MarkerTrajectory:
    bodies = tuple(PoseTrajectory(b.name, b.positions[:n], b.quaternions[:n], b.rate, b.units)
                   for b in traj.rigid_bodies)
    return MarkerTrajectory(traj.positions[:n], traj.marker_names, traj.rate, traj.units,
                            bodies)


def test_a_three_frame_take_is_too_short() -> None:
    ds = synthesize_dataset(seed=11, n_per_skill=1, mentors=DEFAULT_MENTORS[:1],
                            track_object=True)
    demo = ds.demonstrations[0]
    short = _cut(demo.trajectory, 3)
    pose = ds.object_setup.pose(short, ds.scale)
    with pytest.raises(DemonstrationError) as exc:
        annotate_recording(ds.poly, ds.skills, short, pose, ds.fingers, ds.scale)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("the recording is too short to annotate: 3 "
                                              "frame(s) (0.025 s at 120 Hz)")
    assert "export the whole take" in msg
    # a take long enough is annotated as before
    full = annotate_recording(ds.poly, ds.skills, demo.trajectory,
                              ds.object_setup.pose(demo.trajectory, ds.scale), ds.fingers,
                              ds.scale)
    assert full.skill is not None and np.isfinite(full.times).all()


@pytest.mark.skipif(not EMPTY_MOTIVE.is_file(),
                    reason=f"real Motive export not found at {EMPTY_MOTIVE} (shared/ beside the "
                           "repo)")
def test_a_motive_csv_with_no_data_column_says_so() -> None:
    # it said "row 6: expected the row naming each column's data", true but not the fault
    from nonprehensile.demonstrations.formats import read_motive_csv

    with pytest.raises(DemonstrationError, match="no marker or rigid-body column") as got:
        read_motive_csv(EMPTY_MOTIVE)
    assert "\n" not in str(got.value) and "export it again" in str(got.value)
