"""The base placement search over the transits between steps, and its reachability map
(the command line's map: ``tests/test_robot.py``, the placement test)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")
pytest.importorskip("mink", reason="the robot extra (mink) is not installed: "
                    "pip install 'nonprehensile[robot]'")
pytest.importorskip("matplotlib", reason="the viz extra (matplotlib) is not installed")

from hypothesis import given, settings, strategies as st

from nonprehensile.errors import InputError
from nonprehensile.geometry.build import cube
from nonprehensile.sim.placement import place_base, transit_path
from nonprehensile.sim.robot import Robot
from nonprehensile.viz.reachability import reachability_figure

CUBE = cube()
SCALE = 0.05

coord = st.floats(-0.5, 0.5, allow_nan=False)
height = st.floats(0.0, 0.3, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 3).flatmap(lambda k: st.tuples(
    st.lists(st.tuples(coord, coord, height), min_size=k, max_size=k),
    st.lists(st.tuples(coord, coord, height), min_size=k, max_size=k))),
    st.floats(0.01, 0.1), st.floats(0.002, 0.02))
def test_transit_path_goes_up_across_and_down(ends: tuple, lift: float,
                                              spacing: float) -> None:
    a, b = (np.array(e, dtype=float) for e in ends)
    path = transit_path(a, b, lift=lift, spacing=spacing)
    assert path.shape[1:] == a.shape
    np.testing.assert_array_equal(path[0], a)
    np.testing.assert_allclose(path[-1], b, atol=1e-12)
    top = max(a[:, 2].max(), b[:, 2].max()) + lift
    assert path[..., 2].max() == pytest.approx(top)
    # every finger climbs at its start, crosses at the top, descends at its end: never
    # below the lower of its two ends, and no coordinate moves more than ``spacing`` at once
    assert (path[..., 2] >= np.minimum(a[:, 2], b[:, 2]) - 1e-12).all()
    assert np.abs(np.diff(path, axis=0)).max() <= spacing + 1e-12
    across = np.isclose(path[..., 2], top).all(axis=1)
    xy = path[across][..., :2]
    # the horizontal leg runs straight from above the start to above the end
    for f in range(len(a)):
        d = b[f, :2] - a[f, :2]
        rel = xy[:, f] - a[f, :2]
        assert np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0]).max() < 1e-9


def test_place_base_reaches_across_a_jump_between_steps() -> None:
    # two steps whose paths are 6 cm apart (as the main plan's): the transit between them is
    # followed, not jumped, so a base that reaches both is feasible, and the chosen base is
    # the candidate with the most joint margin among the feasible ones
    one = np.tile(np.array([[0.3, 0.1, 0.04]]), (20, 1, 1))
    one[:, 0, 0] += np.linspace(0.0, 0.03, 20)
    two = one.copy()
    two[:, 0, 1] += 0.06
    pl = place_base(Robot.builtin(), CUBE, SCALE, [(one, 20.0), (two, 20.0)], radii=(0.5,),
                    n_directions=4)
    assert pl.feasible and pl.reach_error_m < 0.005
    assert len(pl.candidates) == pl.tried == 4
    ok = [c for c in pl.candidates if c.feasible]
    assert ok and pl.joint_margin_rad == max(c.joint_margin_rad for c in ok)
    assert pl.base == max(ok, key=lambda c: c.joint_margin_rad).base
    doc = pl.candidates_dict()
    assert [d["feasible"] for d in doc] == [c.feasible for c in pl.candidates]
    fig = reachability_figure(doc, pl.base.to_dict(), one[:, 0, :2])
    ax = fig.axes[0]
    # one point per candidate (crosses and coloured dots) and the chosen base's star
    drawn = sum(len(c.get_offsets()) for c in ax.collections)
    assert drawn == len(doc) + 1


def test_reachability_figure_needs_candidates() -> None:
    with pytest.raises(InputError, match="--base"):
        reachability_figure([], {"x": 0.0, "y": 0.0, "yaw_deg": 0.0})
