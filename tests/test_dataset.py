"""Dataset folders: the annotations format, all-or-nothing loading with every problem listed,
saving, the summary, and the ``dataset`` commands.

Truths used: hand-made defects of a freshly generated dataset (each case below breaks one
thing on purpose and the loader must name the file, the demonstration and the culprit), and
round trips through the files.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from nonprehensile.cli.dataset import dataset_group
from nonprehensile.demonstrations import MarkerTrajectory, read_c3d, write_c3d
from nonprehensile.demonstrations.dataset import (
    DATASET_FORMAT,
    DEFAULT_MARKERS,
    check_dataset,
    dataset_path,
    dataset_summary,
    load_dataset,
    save_dataset,
)
from nonprehensile.demonstrations.synth import synthesize
from nonprehensile.errors import DemonstrationError, InputError

Doc = dict[str, Any]


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("pristine") / "ds"
    synthesize(root, seed=11, n_per_skill=2, mentors=2, dropouts=0.0)
    return root


@pytest.fixture
def ds_dir(pristine: Path, tmp_path: Path) -> Path:
    out = tmp_path / "ds"
    shutil.copytree(pristine, out)
    return out


def _edit(root: Path, change: Callable[[Doc], None]) -> None:
    path = root / "annotations.json"
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def _problems(root: Path) -> list[str]:
    ds, problems = check_dataset(root)
    assert (ds is None) == bool(problems)
    return [str(p) for p in problems]


def _one(root: Path, *needles: str) -> str:
    probs = _problems(root)
    assert len(probs) == 1, probs
    for n in needles:
        assert n in probs[0], probs[0]
    return probs[0]


# ----------------------------------------------------------------------- the good case


def test_pristine_dataset_loads(pristine: Path) -> None:
    ds = load_dataset(pristine)
    assert len(ds.demonstrations) == 12
    assert ds.mentors == ("ana", "ben")
    assert ds.scale == 0.05
    assert dict(ds.fingers) == {"R1": "index_tip", "R2": "thumb_tip"}
    doc = json.loads((pristine / "annotations.json").read_text())
    assert doc["format"] == DATASET_FORMAT
    assert doc["markers"] == list(DEFAULT_MARKERS)
    first = doc["demonstrations"][0]
    assert set(first) == {"file", "skill", "mentor", "initial", "final", "events"}
    d = ds.demonstrations[0]
    assert [e.id for e in d.events] == [e.id for e in d.skill.events]
    assert d.trajectory == read_c3d(pristine / first["file"])


def test_save_and_load_round_trip_in_motive_csv(pristine: Path, tmp_path: Path) -> None:
    ds = load_dataset(pristine)
    save_dataset(ds, tmp_path / "csv", trajectory_format="csv")
    back = load_dataset(tmp_path / "csv")
    assert all(f.endswith(".csv") for f in (d.file for d in back.demonstrations))
    for a, b in zip(ds.demonstrations, back.demonstrations, strict=True):
        assert a.events == b.events and a.skill.name == b.skill.name and a.mentor == b.mentor
        # Motive CSV keeps 6 decimals (of mm here)
        np.testing.assert_allclose(a.trajectory.positions, b.trajectory.positions, atol=1e-5)


def test_yaml_annotations_are_read(ds_dir: Path) -> None:
    yaml = pytest.importorskip("yaml")
    doc = json.loads((ds_dir / "annotations.json").read_text())
    (ds_dir / "annotations.json").unlink()
    (ds_dir / "annotations.yaml").write_text(yaml.safe_dump(doc))
    assert len(load_dataset(ds_dir).demonstrations) == 12


def test_summary_counts_and_durations(pristine: Path) -> None:
    ds = load_dataset(pristine)
    s = dataset_summary(ds)
    assert s["n_demonstrations"] == 12 and s["rate_hz"] == 120.0 and s["units"] == "mm"
    by = {k["name"]: k for k in s["skills"]}
    assert by["roll-arc"]["count"] == 2 and by["roll-arc"]["mentors"] == {"ana": 1, "ben": 1}
    d = [x.duration for x in ds.of_skill("twist")]
    assert by["twist"]["duration_s"]["max"] == pytest.approx(max(d), abs=1e-4)
    assert s["problems"] == []


def test_bundled_dataset_meets_the_issue() -> None:
    ds = load_dataset("cube")
    assert dataset_path("cube").name == "cube_demos"
    assert len(ds.skills) >= 4 and len(ds.mentors) >= 3
    for s in ds.skills:
        assert len(ds.of_skill(s.name)) >= 30
    assert {d.trajectory.rate for d in ds.demonstrations} == {120.0}
    assert any(d.trajectory.occluded.any() for d in ds.demonstrations)
    size = sum(p.stat().st_size for p in dataset_path("cube").iterdir())
    assert size < 5_000_000


# -------------------------------------------------------------------- every bad case


def test_unknown_skill(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d["demonstrations"][3].update(skill="moonwalk"))
    msg = _one(ds_dir, "(demonstration 3)", "unknown skill 'moonwalk'", "roll-arc")
    assert msg.startswith(json.loads((ds_dir / "annotations.json").read_text())
                          ["demonstrations"][3]["file"])


def test_event_time_after_the_recording(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d["demonstrations"][0]["events"][-1].update(time=99.0))
    _one(ds_dir, "(demonstration 0)", "out of the recording's range", "99 s")


def test_negative_event_time(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d["demonstrations"][1]["events"][0].update(time=-0.5))
    _one(ds_dir, "(demonstration 1)", "out of the recording's range")


def test_event_times_out_of_order(ds_dir: Path) -> None:
    def swap(d: Doc) -> None:
        ev = d["demonstrations"][2]["events"]
        ev[1]["time"], ev[2]["time"] = ev[2]["time"], ev[1]["time"]
    _edit(ds_dir, swap)
    _one(ds_dir, "(demonstration 2)", "out of order")


def test_equal_event_times_are_out_of_order(ds_dir: Path) -> None:
    def same(d: Doc) -> None:
        ev = d["demonstrations"][2]["events"]
        ev[2]["time"] = ev[1]["time"]
    _edit(ds_dir, same)
    _one(ds_dir, "out of order")


def test_two_problems_of_one_demonstration_are_both_reported(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d["demonstrations"][5]["events"][2].update(time=99.0))
    probs = _problems(ds_dir)
    assert len(probs) == 2
    assert "out of order" in probs[0] and "out of the recording's range" in probs[1]
    assert all("(demonstration 5)" in p for p in probs)


@pytest.mark.parametrize("change", ["drop", "rename", "swap"])
def test_events_that_do_not_match_the_chain(ds_dir: Path, change: str) -> None:
    def edit(d: Doc) -> None:
        ev = d["demonstrations"][4]["events"]
        if change == "drop":
            del ev[2]
        elif change == "rename":
            ev[1]["id"] = "poke"
        else:
            ev[1]["id"], ev[2]["id"] = ev[2]["id"], ev[1]["id"]
    _edit(ds_dir, edit)
    _one(ds_dir, "(demonstration 4)", "do not match the chain")


def test_nan_event_time(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d["demonstrations"][5]["events"][1].update(time=float("nan")))
    _one(ds_dir, "(demonstration 5)", "finite number of seconds")


def _rewrite(root: Path, index: int, change: Callable[[np.ndarray], None],
             names: tuple[str, ...] | None = None) -> None:
    doc = json.loads((root / "annotations.json").read_text())
    path = root / doc["demonstrations"][index]["file"]
    t = read_c3d(path)
    pos = np.array(t.positions)
    change(pos)
    write_c3d(MarkerTrajectory(pos, names or t.marker_names, t.rate, t.units), path)


def test_markers_exported_in_another_order_are_put_in_the_datasets(ds_dir: Path) -> None:
    before = load_dataset(ds_dir).demonstrations[5].trajectory
    doc = json.loads((ds_dir / "annotations.json").read_text())
    path = ds_dir / doc["demonstrations"][5]["file"]
    t = read_c3d(path)
    order = list(range(t.n_markers))[::-1]
    write_c3d(MarkerTrajectory(np.array(t.positions)[:, order],
                               tuple(t.marker_names[k] for k in order), t.rate, t.units), path)
    after = load_dataset(ds_dir).demonstrations[5].trajectory
    assert after.marker_names == before.marker_names
    np.testing.assert_array_equal(after.positions, before.positions)


def test_marker_missing_beyond_the_gap_limit(ds_dir: Path) -> None:
    def gap(p: np.ndarray) -> None:
        p[30:43, 2] = np.nan  # 13 frames > gap limit 12
    _rewrite(ds_dir, 6, gap)
    _one(ds_dir, "(demonstration 6)", "'thumb_tip'", "frames 30..42", "gap limit of 12")


def test_a_gap_at_the_limit_is_accepted(ds_dir: Path) -> None:
    def gap(p: np.ndarray) -> None:
        p[30:42, 2] = np.nan  # 12 frames
    _rewrite(ds_dir, 6, gap)
    assert _problems(ds_dir) == []


def test_marker_nan_in_every_frame(ds_dir: Path) -> None:
    _rewrite(ds_dir, 7, lambda p: p.__setitem__((slice(None), 1), np.nan))
    _one(ds_dir, "(demonstration 7)", "'index_knuckle'", "every frame")


def test_missing_marker(ds_dir: Path) -> None:
    names = ("index_tip", "index_knuckle", "Thumb", "thumb_knuckle")
    _rewrite(ds_dir, 8, lambda p: None, names)
    _one(ds_dir, "(demonstration 8)", "['thumb_tip']", "not in the recording")


def test_missing_and_unreadable_files(ds_dir: Path) -> None:
    doc = json.loads((ds_dir / "annotations.json").read_text())
    (ds_dir / doc["demonstrations"][0]["file"]).unlink()
    (ds_dir / doc["demonstrations"][1]["file"]).write_bytes(b"not a c3d file")
    probs = _problems(ds_dir)
    assert len(probs) == 2
    assert "(demonstration 0)" in probs[0] and "no such trajectory file" in probs[0]
    assert "(demonstration 1)" in probs[1] and "C3D" in probs[1]


def test_a_folder_named_as_a_recording_is_said_to_be_a_folder(ds_dir: Path) -> None:
    """A folder where a recording should be (not a rosbag2 folder) was 'no such trajectory
    file', though the name is there: the problem says it is a folder and what a bag holds."""
    doc = json.loads((ds_dir / "annotations.json").read_text())
    take = ds_dir / doc["demonstrations"][0]["file"]
    take.unlink()
    take.mkdir()
    (ds_dir / "take01").mkdir()
    _edit(ds_dir, lambda d: d["demonstrations"][1].update(file="take01"))
    probs = _problems(ds_dir)
    assert len(probs) == 2, probs
    for k, p in enumerate(probs):
        assert f"(demonstration {k})" in p and "a folder, not a trajectory file" in p, p
        assert "metadata.yaml" in p and "no such" not in p, p


def test_two_fingers_on_one_tip_marker_is_a_problem(ds_dir: Path) -> None:
    """R1 and R2 mapped to the same marker loaded, exported and segmented: the thumb of every
    pinch moved as the index did."""
    _edit(ds_dir, lambda d: d.update(fingers={"R1": "index_tip", "R2": "index_tip"}))
    _one(ds_dir, "annotations.json", "R1 and R2 both name the tip marker 'index_tip'")


@pytest.mark.parametrize("scale", [1e308, 1e-300])
def test_a_scale_past_any_object_is_a_problem(ds_dir: Path, scale: float) -> None:
    """'scale': 1e308 loaded (`dataset show`: no problems) and `plan --dataset` then failed
    half-way, after writing references, with overflow warnings and 'coordinate -1e+308 is
    beyond 1e+09'."""
    _edit(ds_dir, lambda d: d.update(scale=scale))
    _one(ds_dir, "annotations.json", "'scale' (metres per model unit) must be a number from "
                                     "1e-06 to 100")


def test_recordings_read_in_the_wrong_unit_are_a_problem(ds_dir: Path) -> None:
    """'units': 'm' over recordings in millimetres put the hand a kilometre from the table
    (`dataset show`: no problems unless object markers were given)."""
    _edit(ds_dir, lambda d: d.update(units="m"))
    problems = _problems(ds_dir)
    # (the synthetic takes' markers are 0.1-0.14 m from the origin: read as metres, all but
    # one are past 100 m; that one's markers, every number below 100, move faster than a
    # hand)
    n = len(json.loads((ds_dir / "annotations.json").read_text())["demonstrations"])
    far = [p for p in problems if "m from the recording's origin, farther than any capture "
           "volume (100 m): 'units': 'm' says m" in p]
    fast = [p for p in problems if "m/s (the median over the markers of each one's 90th "
            "percentile speed between frames), faster than any hand (50 m/s): 'units': 'm' "
            "says m at " in p]
    assert len(problems) == n and len(far) + len(fast) == n and fast, problems[:2]
    _edit(ds_dir, lambda d: d.update(units="mm"))
    assert _problems(ds_dir) == []


def test_state_that_is_not_the_skills(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d["demonstrations"][9].update(final={"face": "b", "theta": 0}))
    _one(ds_dir, "(demonstration 9)", "final state b:0", "d:")


def test_one_file_for_two_demonstrations(ds_dir: Path) -> None:
    def dup(d: Doc) -> None:
        d["demonstrations"][1]["file"] = d["demonstrations"][0]["file"]
    _edit(ds_dir, dup)
    _one(ds_dir, "(demonstration 1)", "also demonstration 0")


def test_bad_dataset_wide_keys(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d.update(scale=-1, gap_limit="many", colour="red"))
    probs = _problems(ds_dir)
    assert len(probs) == 3
    assert all(p.startswith("annotations.json: ") for p in probs)
    assert any("'scale'" in p for p in probs) and any("'gap_limit'" in p for p in probs)
    assert any("colour" in p for p in probs)


def test_missing_skills_file_still_checks_the_rest(ds_dir: Path) -> None:
    (ds_dir / "skills.json").unlink()
    _edit(ds_dir, lambda d: d["demonstrations"][2]["events"][0].update(time=-1.0))
    probs = _problems(ds_dir)
    assert probs[0].startswith("skills.json: ") and "no such file" in probs[0]
    assert any("(demonstration 2)" in p and "out of the recording's range" in p for p in probs)


def test_no_annotations_file(ds_dir: Path) -> None:
    (ds_dir / "annotations.json").unlink()
    _one(ds_dir, "no annotations file")
    with pytest.raises(InputError, match="no such dataset folder"):
        check_dataset(ds_dir / "nowhere")


def test_every_problem_is_reported_and_nothing_is_loaded(ds_dir: Path) -> None:
    def many(d: Doc) -> None:
        d["demonstrations"][0]["skill"] = "moonwalk"
        d["demonstrations"][3]["events"][-1]["time"] = 99.0
        d["demonstrations"][5]["events"][1]["id"] = "poke"
        d["demonstrations"][7]["mentor"] = ""
    _edit(ds_dir, many)
    _rewrite(ds_dir, 10, lambda p: p.__setitem__((slice(5, 40), 0), np.nan))
    ds, problems = check_dataset(ds_dir)
    assert ds is None
    assert [p.demonstration for p in problems] == [0, 3, 5, 7, 10]
    with pytest.raises(DemonstrationError) as info:
        load_dataset(ds_dir)
    text = str(info.value)
    assert "5 problem(s)" in text and "nothing was loaded" in text
    for p in problems:
        assert str(p) in text


# ------------------------------------------------------------------------ the commands


def test_show_prints_the_summary() -> None:
    res = CliRunner().invoke(dataset_group, ["show", "cube"])
    assert res.exit_code == 0, res.output
    for word in ("push-roll", "tumble-twist", "ana", "ben", "chen", "180 demonstrations"):
        assert word in res.output


def test_show_json_with_arcs() -> None:
    res = CliRunner().invoke(dataset_group, ["show", "cube", "--json", "--arcs"])
    assert res.exit_code == 0
    doc = json.loads(res.stdout)
    assert doc["n_demonstrations"] == 180 and doc["problems"] == []
    assert sum(a["segments"] for a in doc["arcs"]) == 30 * (5 * 4 + 2)
    labels = {a["label"] for a in doc["arcs"] if a["from"] == "pivot" and a["to"] == "landed"}
    assert {"quarter-circle", "straight-pull"} <= labels


def test_show_a_bad_dataset_exits_2_listing_problems(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d["demonstrations"][1].update(skill="moonwalk"))
    res = CliRunner().invoke(dataset_group, ["show", str(ds_dir), "--json"])
    assert res.exit_code == 2
    doc = json.loads(res.stdout)
    assert doc["problems"][0]["demonstration"] == 1
    assert "moonwalk" in doc["problems"][0]["message"]
    assert "moonwalk" in res.stderr


def test_show_an_empty_dataset(ds_dir: Path) -> None:
    _edit(ds_dir, lambda d: d.update(demonstrations=[]))
    res = CliRunner().invoke(dataset_group, ["show", str(ds_dir)])
    assert res.exit_code == 0 and "no demonstrations" in res.output
    res = CliRunner().invoke(dataset_group, ["show", str(ds_dir), "--json"])
    assert json.loads(res.stdout)["n_demonstrations"] == 0


def test_malformed_entries_are_problems_not_tracebacks(ds_dir: Path) -> None:
    def junk(d: Doc) -> None:
        d["demonstrations"][0] = "take1.c3d"
        d["demonstrations"][1].update(mentor=5, initial="a:0")
        d["demonstrations"][2]["events"][0]["time"] = True
        d["demonstrations"][3]["file"] = 7
        d["fingers"] = {"R1": 5, "R2": "thumb_tip"}
        d["markers"] = "index_tip"
    _edit(ds_dir, junk)
    probs = _problems(ds_dir)
    assert len(probs) == 7
    text = "\n".join(probs)
    for needle in ("'fingers'", "'markers'", "(demonstration 0)", "'mentor'", "'initial'",
                   "finite number", "'file' must name"):
        assert needle in text


def test_synth_command_writes_a_dataset(tmp_path: Path) -> None:
    res = CliRunner().invoke(dataset_group, [
        "synth", str(tmp_path / "s"), "--n-per-skill", "1", "--mentors", "1", "--seed", "5",
        "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["n_demonstrations"] == 6
    assert len(load_dataset(tmp_path / "s").demonstrations) == 6


def test_synth_command_bad_input_exits_2(tmp_path: Path) -> None:
    res = CliRunner().invoke(dataset_group, ["synth", str(tmp_path / "s"), "--n-per-skill", "0"])
    assert res.exit_code == 2 and "--n-per-skill" in res.stderr


def test_figure_command(pristine: Path, tmp_path: Path) -> None:
    res = CliRunner().invoke(dataset_group, [
        "figure", str(pristine), "-o", str(tmp_path / "f.png"), "--color-by", "mentor"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_trajectory_figure_draws_one_line_per_demonstration(pristine: Path) -> None:
    from nonprehensile.viz.trajectories import trajectory_figure

    ds = load_dataset(pristine)
    fig = trajectory_figure(ds)  # default: the tumbling pair of Fig. 12
    ax = fig.axes[0]
    n_demos = len(ds.of_skill("tumble-lift")) + len(ds.of_skill("tumble-twist"))
    # one collection of paths (a line each), one of the cube's 12 edges
    paths, edges = (c._segments3d for c in ax.collections)  # type: ignore[attr-defined]
    assert (len(paths), len(edges)) == (n_demos, 12)
    legend = ax.get_legend()
    assert legend is not None
    assert sorted(t.get_text() for t in legend.get_texts()) == ["tumble-lift", "tumble-twist"]
    # the drawn index-tip path is the recording between the first and last events
    d = ds.of_skill("tumble-lift")[0]
    a, b = (round(d.events[k].time * 120) for k in (0, -1))
    np.testing.assert_array_equal(np.asarray(paths[0])[:, 0],
                                  d.trajectory.marker("index_tip")[a:b + 1, 0])
    fig = trajectory_figure(ds, ["twist"], color_by="mentor", marker="thumb_tip")
    legend = fig.axes[0].get_legend()
    assert legend is not None
    assert sorted(t.get_text() for t in legend.get_texts()) == ["ana", "ben"]
    with pytest.raises(InputError, match="moonwalk"):
        trajectory_figure(ds, ["moonwalk"])
    with pytest.raises(InputError, match="no marker"):
        trajectory_figure(ds, marker="pinky")
    with pytest.raises(InputError, match="color_by"):
        trajectory_figure(ds, color_by="colour")


def test_a_folder_without_annotations_is_named_once(tmp_path: Path) -> None:
    """`dataset show EMPTY` said 'EMPTY: EMPTY: no annotations file' (and `dataset export`,
    `cluster fit --dataset` through load_dataset, and a file: 'x: x: not a folder')."""
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("not a dataset")
    for name, what in [("empty", "no annotations file"), ("notes.txt", "not a folder")]:
        path = str(tmp_path / name)
        res = CliRunner().invoke(dataset_group, ["show", path])
        assert res.exit_code == 2, res.output
        line = res.stderr.strip()
        assert len(line.splitlines()) == 1 and what in line, line
        assert line.count(path) == 1, line
        with pytest.raises(DemonstrationError) as info:
            load_dataset(path)
        assert str(info.value).count(path) == 1 and what in str(info.value), info.value
    with pytest.raises(DemonstrationError) as info:  # a trailing slash: named once too
        load_dataset(f"{tmp_path / 'empty'}/")
    assert str(info.value).count(str(tmp_path / "empty")) == 1, info.value
    res = CliRunner().invoke(dataset_group, ["export", str(tmp_path / "empty"),
                                             str(tmp_path / "out")])
    assert res.exit_code == 2 and res.stderr.count(str(tmp_path / "empty")) == 1, res.stderr


def test_a_dataset_of_some_skills_draws_and_an_empty_one_is_refused_early(ds_dir: Path) -> None:
    """A skills file names skills a dataset need not demonstrate: the default figure (the
    demo report's) drew the tumbling pair because the skills file has it and failed with
    'the dataset has no demonstration of [...]', naming no dataset; a dataset of no
    demonstration ran the whole demo before failing at the figures."""
    pytest.importorskip("matplotlib")
    from nonprehensile.pipeline import run_demo
    from nonprehensile.viz.trajectories import trajectory_figure

    _edit(ds_dir, lambda d: d.update(demonstrations=[
        e for e in d["demonstrations"] if e["skill"] == "push-roll"]))
    ds = load_dataset(ds_dir)
    assert {d.skill.name for d in ds.demonstrations} == {"push-roll"}
    assert trajectory_figure(ds) is not None
    with pytest.raises(InputError, match=r"no demonstration of \['twist'\]; it demonstrates "
                                         r"\['push-roll'\]") as info:
        trajectory_figure(ds, ["twist"])
    assert str(ds_dir) in str(info.value)
    _edit(ds_dir, lambda d: d.update(demonstrations=[]))
    with pytest.raises(InputError, match="no demonstration, so there is no trajectory") as info:
        trajectory_figure(load_dataset(ds_dir))
    assert str(ds_dir) in str(info.value)
    with pytest.raises(InputError, match="the dataset has no demonstration, and the main job"):
        run_demo(ds_dir.parent / "report", dataset=ds_dir, robot=False, cache=False)
    assert not (ds_dir.parent / "report").exists()
