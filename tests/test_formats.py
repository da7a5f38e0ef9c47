"""Marker trajectories and their files: C3D (through ezc3d) and OptiTrack Motive CSV.

Truths used: ezc3d reading and writing raw C3D structures, cells copied by hand from
tests/data/motive_sample.csv, scipy's rotation of +90 degrees about x for Motive's y-up axes,
and hand-worked small cases.
"""

from __future__ import annotations

import math
import sys
import tempfile
from datetime import datetime
from pathlib import Path

import ezc3d
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from nonprehensile.demonstrations import (
    C3D_MAX_FRAMES,
    MarkerTrajectory,
    read_c3d,
    read_motive_csv,
    write_c3d,
    write_motive_csv,
)
from nonprehensile.errors import DemonstrationError, InputError

SAMPLE = Path(__file__).parent / "data" / "motive_sample.csv"
NAMES = ("Hand:IndexTip", "Hand:IndexKnuckle", "Hand:ThumbTip", "Hand:ThumbKnuckle")


def _traj(n_frames: int = 5, n_markers: int = 2, *, units: str = "mm") -> MarkerTrajectory:
    pos = np.arange(n_frames * n_markers * 3, dtype=float).reshape(n_frames, n_markers, 3) - 7.5
    pos[1, 0] = np.nan
    pos[3, 1] = np.nan
    return MarkerTrajectory.from_arrays(
        pos, [f"m{k}" for k in range(n_markers)], 120.0, units=units
    )


# ------------------------------------------------------------------------------------------
# MarkerTrajectory


def test_times_duration_hand_case() -> None:
    t = MarkerTrajectory.from_arrays(np.zeros((3, 1, 3)), ["a"], 4.0)
    assert t.n_frames == 3 and t.n_markers == 1
    assert t.times.tolist() == [0.0, 0.25, 0.5]
    assert t.duration == 0.5
    assert t.units == "m"


def test_positions_are_a_read_only_copy() -> None:
    src = np.zeros((2, 1, 3))
    t = MarkerTrajectory.from_arrays(src, ["a"], 100.0)
    src[0, 0, 0] = 5.0
    assert t.positions[0, 0, 0] == 0.0
    with pytest.raises(ValueError):
        t.positions[0, 0, 0] = 1.0
    with pytest.raises(ValueError):
        t.marker("a")[0, 0] = 1.0
    with pytest.raises(AttributeError):
        t.rate = 10.0  # type: ignore[misc]


def test_to_units_scales_and_keeps_nan() -> None:
    t = MarkerTrajectory.from_arrays([[[1.5, -2.0, 0.25]], [[np.nan] * 3]], ["a"], 50.0, "m")
    mm = t.to_units("mm")
    assert mm.units == "mm"
    assert mm.positions[0, 0].tolist() == [1500.0, -2000.0, 250.0]
    assert np.isnan(mm.positions[1]).all()
    assert mm.to_units("m") == t
    assert t.to_units("m") is t


def test_marker_selects_the_column_and_names_the_unknown() -> None:
    t = _traj()
    np.testing.assert_array_equal(t.marker("m1"), t.positions[:, 1, :])
    with pytest.raises(DemonstrationError, match=r"'thumb'.*\['m0', 'm1'\]"):
        t.marker("thumb")


def test_partly_nan_point_becomes_occluded() -> None:
    t = MarkerTrajectory.from_arrays([[[1.0, np.nan, 3.0]], [[1.0, 2.0, 3.0]]], ["a"], 10.0)
    assert np.isnan(t.positions[0, 0]).all()
    assert t.occluded.tolist() == [[True], [False]]


def test_equality_treats_nan_as_equal_and_hash_agrees() -> None:
    a, b = _traj(), _traj()
    assert a == b and hash(a) == hash(b)
    c = MarkerTrajectory.from_arrays(a.positions + 1e-9, a.marker_names, a.rate, a.units)
    assert a != c
    assert a != MarkerTrajectory.from_arrays(a.positions, a.marker_names, 60.0, a.units)


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        ({"positions": np.zeros((4, 3))}, "shape"),
        ({"positions": np.zeros((4, 2, 2))}, "shape"),
        ({"positions": np.zeros((0, 2, 3))}, "at least one frame"),
        ({"positions": [[["x", 1, 2]] * 2]}, "numbers"),
        ({"positions": np.full((1, 2, 3), np.inf)}, "infinite"),
        ({"marker_names": ("a",)}, "1 marker names for 2 markers"),
        ({"marker_names": ("a", "a")}, "'a' appears more than once"),
        ({"marker_names": ("a", " ")}, "non-empty"),
        ({"marker_names": "ab"}, "sequence of strings"),
        ({"rate": 0.0}, "from 0.01 to 100000"),
        ({"rate": math.nan}, "from 0.01 to 100000"),
        ({"rate": math.inf}, "from 0.01 to 100000"),
        ({"rate": 1e-30}, "from 0.01 to 100000"),
        ({"rate": 1e9}, "from 0.01 to 100000"),
        ({"rate": "120"}, "number of Hz"),
        ({"rate": True}, "number of Hz"),
        ({"units": "cm"}, "'cm'"),
    ],
)
def test_invalid_fields_name_the_culprit(kwargs: dict[str, object], culprit: str) -> None:
    fields: dict[str, object] = {
        "positions": np.zeros((1, 2, 3)),
        "marker_names": ("a", "b"),
        "rate": 120.0,
        "units": "mm",
    }
    fields.update(kwargs)
    with pytest.raises(DemonstrationError, match=culprit) as info:
        MarkerTrajectory(**fields)  # type: ignore[arg-type]
    assert isinstance(info.value, InputError)


# ------------------------------------------------------------------------------------------
# C3D


def test_c3d_round_trip_keeps_positions_nan_names_rate_units(tmp_path: Path) -> None:
    for units in ("mm", "m"):
        t = _traj(7, 3, units=units)
        path = tmp_path / f"t_{units}.c3d"
        write_c3d(t, path)
        back = read_c3d(path)
        assert back.marker_names == t.marker_names
        assert back.rate == t.rate and back.units == units
        # values are small integers and halves: exact in the file's float32
        assert back == t


def test_c3d_written_file_follows_the_c3d_conventions(tmp_path: Path) -> None:
    t = _traj(4, 2)
    path = tmp_path / "t.c3d"
    write_c3d(t, path)
    raw = ezc3d.c3d(str(path))
    point = raw["parameters"]["POINT"]
    assert list(point["LABELS"]["value"]) == ["m0", "m1"]
    assert float(point["RATE"]["value"][0]) == 120.0
    assert point["UNITS"]["value"][0] == "mm"
    res = raw["data"]["meta_points"]["residuals"][0]  # (points, frames)
    assert res[0, 1] < 0 and res[1, 3] < 0  # C3D's invalid-point mark where occluded
    assert (res[0, [0, 2, 3]] >= 0).all()
    np.testing.assert_array_equal(raw["data"]["points"][:3, 1, 0], t.positions[0, 1])


def test_c3d_negative_residual_reads_as_occluded(tmp_path: Path) -> None:
    # a file built directly with ezc3d, as another program would: point 'b' at frame 2 has
    # real-looking coordinates but residual -1
    c3d = ezc3d.c3d()
    pts = np.ones((4, 2, 4))
    pts[:3] = 7.0
    res = np.zeros((1, 2, 4))
    res[0, 1, 2] = -1.0
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = ("a", "b")
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["m"]
    c3d["data"]["points"] = pts
    c3d["data"]["meta_points"] = {"residuals": res, "camera_masks": np.zeros((7, 2, 4), bool)}
    path = tmp_path / "other.c3d"
    c3d.write(str(path))
    t = read_c3d(path)
    assert t.occluded.tolist() == [[False, False], [False, False], [False, True], [False, False]]
    assert t.marker("a").tolist() == [[7.0, 7.0, 7.0]] * 4
    assert t.rate == 100.0 and t.units == "m"


def test_c3d_y_up_axes(tmp_path: Path) -> None:
    t = MarkerTrajectory.from_arrays([[[1.0, 2.0, 3.0]]], ["a"], 60.0, "mm")
    path = tmp_path / "y.c3d"
    write_c3d(t, path, up="y")
    raw = ezc3d.c3d(str(path))
    # ours (x, y, z) is the file's (x, z, -y) in a y-up file
    assert raw["data"]["points"][:3, 0, 0].tolist() == [1.0, 3.0, -2.0]
    assert read_c3d(path, up="y") == t


def _ezc3d_file(path: Path, *, units: str = "mm", labels: tuple[str, ...] = ("a", "b"),
                rate: float = 120.0) -> Path:
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["UNITS"]["value"] = [units]
    c3d["data"]["points"] = np.ones((4, len(labels), 3))
    c3d.write(str(path))
    return path


def test_c3d_centimetres_become_millimetres(tmp_path: Path) -> None:
    t = read_c3d(_ezc3d_file(tmp_path / "cm.c3d", units="cm"))
    assert t.units == "mm"
    assert (t.positions == 10.0).all()


@pytest.mark.parametrize(
    ("make", "culprit"),
    [
        (lambda p: p, "no such C3D file"),
        (lambda p: p.write_bytes(b"not a c3d file at all" * 40) and p, "cannot read it as a C3D"),
        (lambda p: _ezc3d_file(p, units="in"), "POINT:UNITS is 'in'"),
        (lambda p: _ezc3d_file(p, labels=("a", "a")), "label 'a' names points 1 and 2"),
        (lambda p: _ezc3d_file(p, labels=("a", "")), "point 2 has a blank label"),
        # a damaged rate read as it was: a recording of 1e31 s and a LeRobot export of fps 0
        (lambda p: _ezc3d_file(p, rate=1e-30), "the point rate is 1e-30 Hz, outside 0.01"),
        (lambda p: _ezc3d_file(p, rate=1e38), "the point rate is 1e[+]38 Hz, outside"),
    ],
)
def test_c3d_errors_name_file_and_culprit(tmp_path: Path, make: object, culprit: str) -> None:
    path = tmp_path / "bad.c3d"
    make(path)  # type: ignore[operator]
    with pytest.raises(DemonstrationError, match=culprit) as info:
        read_c3d(path)
    assert str(path) in str(info.value)


def test_c3d_more_than_255_markers_use_labels2(tmp_path: Path) -> None:
    names = [f"M{k}" for k in range(300)]
    t = MarkerTrajectory.from_arrays(np.arange(2 * 300 * 3).reshape(2, 300, 3), names, 50.0)
    path = tmp_path / "many.c3d"
    write_c3d(t, path)
    assert "LABELS2" in ezc3d.c3d(str(path))["parameters"]["POINT"]  # the C3D spec's overflow
    assert read_c3d(path) == t


def test_c3d_refuses_more_frames_than_it_can_count(tmp_path: Path) -> None:
    t = MarkerTrajectory.from_arrays(np.zeros((C3D_MAX_FRAMES + 1, 1, 3)), ["a"], 120.0)
    path = tmp_path / "long.c3d"
    with pytest.raises(DemonstrationError, match=r"65536 frames do not fit a C3D file"):
        write_c3d(t, path)
    assert not path.exists()


def test_c3d_without_ezc3d_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ezc3d", None)  # makes `import ezc3d` fail
    with pytest.raises(DemonstrationError, match=r"nonprehensile\[mocap\]"):
        read_c3d(tmp_path / "x.c3d")
    with pytest.raises(DemonstrationError, match=r"nonprehensile\[mocap\]"):
        write_c3d(_traj(), tmp_path / "x.c3d")


# ------------------------------------------------------------------------------------------
# Motive CSV: the sample export


def test_motive_sample_metadata_and_names() -> None:
    t = read_motive_csv(SAMPLE)
    assert t.marker_names == NAMES
    assert t.rate == 120.0  # "Export Frame Rate,120.000000"
    assert t.units == "mm"  # "Length Units,Millimeters"
    assert t.n_frames == 24


def test_motive_sample_cells_by_hand() -> None:
    t = read_motive_csv(SAMPLE)
    # line 13, frame 5: "5,0.041667,-58.443696,32.744589,13.024614,..." (Motive x, y up, z)
    assert t.marker("Hand:IndexTip")[5].tolist() == [-58.443696, -13.024614, 32.744589]
    # line 31, frame 23, last triple: "...,-112.980393,55.158334,49.042313"
    assert t.marker("Hand:ThumbKnuckle")[23].tolist() == [-112.980393, -49.042313, 55.158334]
    # frames 9-12 leave Hand:ThumbTip blank, frame 17 leaves Hand:IndexKnuckle blank
    occluded = {(int(i), t.marker_names[k]) for i, k in np.argwhere(t.occluded)}
    assert occluded == {(i, "Hand:ThumbTip") for i in (9, 10, 11, 12)} | {(17, "Hand:IndexKnuckle")}


def test_motive_y_up_mapping_is_the_rotation_about_x() -> None:
    file_axes = read_motive_csv(SAMPLE, up="z")  # the file's own numbers
    assert file_axes.marker("Hand:IndexTip")[5].tolist() == [-58.443696, 32.744589, 13.024614]
    ours = read_motive_csv(SAMPLE)
    rot = Rotation.from_euler("x", 90, degrees=True)  # y -> z, z -> -y: a proper rotation
    seen = ~file_axes.occluded
    np.testing.assert_allclose(
        ours.positions[seen], rot.apply(file_axes.positions[seen]), rtol=0, atol=1e-12
    )
    # the up axis of the file (its y) is our z: fingertips are above the table top
    assert (ours.positions[seen][:, 2] > 0).all()


def test_motive_round_trip_of_the_sample(tmp_path: Path) -> None:
    t = read_motive_csv(SAMPLE)
    out = tmp_path / "again.csv"
    write_motive_csv(t, out)
    assert read_motive_csv(out) == t
    # data rows come out as Motive wrote them, cell for cell
    original = SAMPLE.read_text().splitlines()[7:]
    assert out.read_text().splitlines()[7:] == original


def test_motive_writer_header_layout(tmp_path: Path) -> None:
    t = _traj(4, 2, units="m")
    out = tmp_path / "w.csv"
    write_motive_csv(
        t, out, take_name="demo 1", start_time=datetime(2021, 6, 14, 15, 27, 41, 208000)
    )
    lines = out.read_text().splitlines()
    assert lines[0].startswith("Format Version,1.23,Take Name,demo 1,")
    assert "Capture Start Time,2021-06-14 03.27.41.208 PM," in lines[0]
    assert "Export Frame Rate,120.000000," in lines[0] and "Length Units,Meters," in lines[0]
    assert lines[1] == ""
    assert lines[2] == ",Type,Marker,Marker,Marker,Marker,Marker,Marker"
    assert lines[3] == ",Name,m0,m0,m0,m1,m1,m1"
    assert lines[5] == ",,Position,Position,Position,Position,Position,Position"
    assert lines[6] == "Frame,Time (Seconds),X,Y,Z,X,Y,Z"
    # frame 1: m0 occluded -> three blank cells; m1 ours (1.5, 2.5, 3.5) -> file (x, z, -y)
    assert lines[8] == "1,0.008333,,,,1.500000,3.500000,-2.500000"


finite = st.floats(-5e3, 5e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    pos=arrays(
        np.float64, st.tuples(st.integers(1, 6), st.integers(1, 4), st.just(3)), elements=finite
    ),
    mask=st.data(),
    rate=st.sampled_from([30.0, 100.0, 120.0, 240.0, 119.88]),
    units=st.sampled_from(["m", "mm"]),
    up=st.sampled_from(["y", "z"]),
)
def test_round_trips_property(
    pos: np.ndarray, mask: st.DataObject, rate: float, units: str, up: str
) -> None:
    occ = mask.draw(arrays(np.bool_, pos.shape[:2]))
    pos = pos.copy()
    pos[occ] = np.nan
    t = MarkerTrajectory.from_arrays(pos, [f"M{k}" for k in range(pos.shape[1])], rate, units)
    with tempfile.TemporaryDirectory() as d:
        csv_path, c3d_path = Path(d) / "t.csv", Path(d) / "t.c3d"
        write_motive_csv(t, csv_path, up=up)  # type: ignore[arg-type]
        back = read_motive_csv(csv_path, up=up)  # type: ignore[arg-type]
        assert back.marker_names == t.marker_names and back.rate == rate
        assert back.units == units
        np.testing.assert_array_equal(back.occluded, t.occluded)
        # six decimals: half a unit in the sixth place, plus float64 round-off
        np.testing.assert_allclose(back.positions, t.positions, rtol=0, atol=5e-7 + 1e-9)

        write_c3d(t, c3d_path, up=up)  # type: ignore[arg-type]
        back = read_c3d(c3d_path, up=up)  # type: ignore[arg-type]
        assert back.marker_names == t.marker_names and back.units == units
        assert back.rate == pytest.approx(rate, rel=1e-7)  # C3D stores float32
        np.testing.assert_array_equal(back.occluded, t.occluded)
        np.testing.assert_allclose(back.positions, t.positions, rtol=1e-6, atol=1e-9)


# ------------------------------------------------------------------------------------------
# Motive CSV: other layouts and options

# Motive 1.x (CSV format 1.21): no labels in column 2, "Time" without units, a rigid body with
# a quality column, its expected markers with quality columns, then the measured markers
FORMAT_121 = """\
Format Version,1.21,Take Name,Take 2016-01-05 03.49.50 PM,Capture Frame Rate,100.000000,\
Export Frame Rate,100.000000,Capture Start Time,2016-01-05 03.49.50.755 PM,Total Frames in Take,3,\
Total Exported Frames,3,Rotation Type,Quaternion,Length Units,Meters,Coordinate Space,Global

,,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,\
Rigid Body Marker,Rigid Body Marker,Rigid Body Marker,Rigid Body Marker,Marker,Marker,Marker
,,Cube,Cube,Cube,Cube,Cube,Cube,Cube,Cube,Cube:Marker1,Cube:Marker1,Cube:Marker1,Cube:Marker1,\
Cube:Marker1,Cube:Marker1,Cube:Marker1
,,"CF51","CF51","CF51","CF51","CF51","CF51","CF51","CF51","CF51","CF51","CF51","CF51",\
"8392","8392","8392"
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Error Per Marker,\
Position,Position,Position,Marker Quality,Position,Position,Position
Frame,Time,X,Y,Z,W,X,Y,Z,,X,Y,Z,,X,Y,Z
0,0.000000,0,0,0,1,0.06,0.019,0.076,0.00001,0.010,0.020,0.030,0.99,0.011,0.021,0.031
1,0.010000,0,0,0,1,0.06,0.019,0.076,0.00001,0.012,0.022,0.032,0.98,,,
2,0.020000,0,0,0,1,0.06,0.019,0.076,0.00001,0.014,0.024,0.034,0.97,0.015,0.025,0.035
"""


def test_motive_format_121_reads_marker_columns_only(tmp_path: Path) -> None:
    path = tmp_path / "old.csv"
    path.write_text(FORMAT_121)
    t = read_motive_csv(path)
    assert t.marker_names == ("Cube:Marker1",) and t.units == "m" and t.rate == 100.0
    assert t.positions[0, 0].tolist() == [0.011, -0.031, 0.021]
    assert t.occluded[:, 0].tolist() == [False, True, False]
    expected = read_motive_csv(path, marker_types=["Rigid Body Marker"])
    assert expected.positions[1, 0].tolist() == [0.012, -0.032, 0.022]
    with pytest.raises(DemonstrationError, match="'Cube:Marker1' is used by more than one"):
        read_motive_csv(path, marker_types=["Marker", "Rigid Body Marker"])
    with pytest.raises(DemonstrationError, match=r"no marker positions of type 'Bone Marker'"):
        read_motive_csv(path, marker_types="Bone Marker")


def _sample_lines() -> list[str]:
    return SAMPLE.read_text().splitlines()


def _write(tmp_path: Path, lines: list[str]) -> Path:
    path = tmp_path / "edited.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_motive_extra_labelled_header_row_is_ignored(tmp_path: Path) -> None:
    # Motive 3.x (format 1.25) adds a labelled "Parent" row below "ID" for skeleton data
    lines = _sample_lines()
    lines.insert(5, ",Parent," + ",".join(["Root"] * 12))
    lines[0] = lines[0].replace("Format Version,1.23", "Format Version,1.25")
    assert read_motive_csv(_write(tmp_path, lines)) == read_motive_csv(SAMPLE)


def test_motive_centimetres_become_millimetres(tmp_path: Path) -> None:
    lines = _sample_lines()
    lines[0] = lines[0].replace("Millimeters", "Centimeters")
    t = read_motive_csv(_write(tmp_path, lines))
    assert t.units == "mm"
    assert t.marker("Hand:IndexTip")[5].tolist() == pytest.approx(
        [-584.43696, -130.24614, 327.44589]
    )


def test_motive_millisecond_truncated_times_are_accepted(tmp_path: Path) -> None:
    lines = _sample_lines()
    for i in range(7, len(lines)):
        frame, time, rest = lines[i].split(",", 2)
        lines[i] = f"{frame},{math.floor(float(time) * 1000) / 1000:.6f},{rest}"
    assert lines[8].startswith("1,0.008000,")
    assert read_motive_csv(_write(tmp_path, lines)) == read_motive_csv(SAMPLE)


def _edit(lines: list[str], row: int, col: int, value: str) -> list[str]:
    cells = lines[row - 1].split(",")
    cells[col - 1] = value
    lines[row - 1] = ",".join(cells)
    return lines


def _drop(lines: list[str], row: int) -> list[str]:
    del lines[row - 1]
    return lines


@pytest.mark.parametrize(
    ("edit", "culprit"),
    [
        (lambda ls: ["Frame,X,Y,Z", *ls[7:]], r"row 1 should be Motive's metadata row"),
        (lambda ls: [ls[0], "", "a,b", "c,d"], r"no header row starting 'Frame'"),
        (lambda ls: _edit(ls, 7, 2, "Seconds"), r"row 7, column 2 \(B\): expected 'Time"),
        (lambda ls: _drop(ls, 4), r"no 'Name' row"),
        (lambda ls: _drop(ls, 6), r"row 5: expected the row naming each column's data"),
        (lambda ls: _edit(ls, 7, 5, "Y"), r"row 7, column 5 \(E\): Marker 'Hand:IndexTip'"),
        (lambda ls: _edit(ls, 6, 5, "Rotation"), r"'Hand:IndexTip' has no Position Z column"),
        (lambda ls: [ls[0], ls[1], ls[2].replace("Marker", "Bone"), *ls[3:]], r"\['Bone'\]"),
        (
            lambda ls: _edit(ls, 13, 4, "3z.1"),
            r"row 13, column 4 \(D\) \(marker 'Hand:IndexTip', Y\)",
        ),
        (
            lambda ls: _edit(ls, 20, 14, "inf"),
            r"row 20, column 14 \(N\) \(marker 'Hand:ThumbKnuckle', Z\)",
        ),
        (lambda ls: _edit(ls, 9, 1, "1.5"), r"row 9, column 1 \(A\) \(Frame\)"),
        (lambda ls: _edit(ls, 9, 2, "--"), r"row 9, column 2 \(B\) \(Time\)"),
        (
            lambda ls: [ls[0].replace("Millimeters", "Inches"), *ls[1:]],
            r"unknown Length Units 'Inches'",
        ),
        (lambda ls: [ls[0].replace("Length Units", "Length"), *ls[1:]], r"no 'Length Units'"),
        (lambda ls: [ls[0].replace("Frame Rate", "Rate"), *ls[1:]], r"neither 'Export Frame Rate'"),
        (
            lambda ls: [
                ls[0].replace("Export Frame Rate,120.000000", "Export Frame Rate,fast"),
                *ls[1:],
            ],
            r"Export Frame Rate is 'fast'",
        ),
        (
            lambda ls: [
                ls[0].replace("Export Frame Rate,120.000000", "Export Frame Rate,0"),
                *ls[1:],
            ],
            r"Export Frame Rate is '0'; expected a number of Hz from 0.01 to 100000",
        ),
        (
            lambda ls: [
                ls[0].replace("Export Frame Rate,120.000000", "Export Frame Rate,1e-30"),
                *ls[1:8],  # one frame: no time to disagree with the rate
            ],
            r"Export Frame Rate is '1e-30'; expected a number of Hz from 0.01",
        ),
        (
            lambda ls: [
                ls[0].replace("Export Frame Rate,120.000000", "Export Frame Rate,100"),
                *ls[1:],
            ],
            r"row 10: time 0.016667 s of frame 2 does not match",
        ),
        (lambda ls: _drop(ls, 20), r"row 20: frame 13 follows frame 11"),
        (lambda ls: _edit(ls, 20, 2, "0.110000"), r"row 20: time 0.11 s of frame 12"),
        (lambda ls: [*ls[:-1], ls[-1].rsplit(",", 2)[0]], r"row 31 has 12 cells"),
        (lambda ls: ls[:7], r"no data rows"),
    ],
)
def test_motive_errors_name_file_and_culprit(tmp_path: Path, edit: object, culprit: str) -> None:
    path = _write(tmp_path, edit(_sample_lines()))  # type: ignore[operator]
    with pytest.raises(DemonstrationError, match=culprit) as info:
        read_motive_csv(path)
    assert str(path) in str(info.value)
    assert isinstance(info.value, InputError)


def test_motive_missing_file_and_bad_options(tmp_path: Path) -> None:
    with pytest.raises(DemonstrationError, match="no such Motive CSV file"):
        read_motive_csv(tmp_path / "absent.csv")
    with pytest.raises(DemonstrationError, match="up must be"):
        read_motive_csv(SAMPLE, up="x")  # type: ignore[arg-type]
    with pytest.raises(DemonstrationError, match="decimals"):
        write_motive_csv(_traj(), tmp_path / "o.csv", decimals=-1)
    with pytest.raises(DemonstrationError, match="cannot write"):
        write_motive_csv(_traj(), tmp_path / "no" / "such" / "dir.csv")
