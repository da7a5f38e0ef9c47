"""CI-sized physics check (issue 9): a demonstrated and an inferred transition on two objects.

The cube's come from the bundled demonstrations (recorded from physics); the hexagonal prism's
from takes recorded here by the physics generator, so the generator itself is exercised. Each
inferred transition is executed with its demonstrated skill's reference motion, placed on the
object by the planner's own placement (`planning.step_for`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

# headless offscreen rendering (as nonprehensile.sim sets it when it is imported first)
if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")

from nonprehensile.demonstrations.dataset import Dataset, load_dataset
from nonprehensile.demonstrations.segment import segment_dataset
from nonprehensile.inference import expand
from nonprehensile.planning import step_for
from nonprehensile.references import ClusteredMotions, flatten_segments
from nonprehensile.sim import Simulator
from nonprehensile.sim.execute import DemonstrationLibrary, replay_demonstration, simulate_step
from nonprehensile.sim.record import record_dataset
from nonprehensile.states import states_by_step

HEX_SKILLS = Path(__file__).resolve().parents[1] / "examples" / "hexprism_skills.json"


def _library(ds: Dataset) -> ClusteredMotions:
    _, segments = segment_dataset(ds)
    return ClusteredMotions(segments, np.zeros(len(segments), dtype=np.int64),
                            flatten_segments(segments, n_points=50))


def _check(ds: Dataset, skill: str, whole: bool = False) -> None:
    sim = Simulator(ds.poly, scale=ds.scale)
    demo = next(d for d in ds.demonstrations if d.skill.name == skill)
    got = replay_demonstration(sim, ds, demo)
    assert got.success, got.to_dict()
    exp = expand(ds.poly, list(ds.skills), states_by_step(ds.poly, 90))
    inferred = next(t for t in exp.transitions
                    if t.source.name == skill and not t.demonstrated)
    # a cluster library (as the planner's) or each skill's medoid demonstration whole
    library = DemonstrationLibrary(segment_dataset(ds)[1]) if whole else _library(ds)
    step = step_for(ds.poly, inferred, position=(0.2, -0.1), motions=library, scale=ds.scale)
    out = simulate_step(sim, step, fingers=ds.fingers)
    assert out.success, out.to_dict()
    assert out.comparison.chain_ok, out.to_dict()
    # it ended where the exact maneuver says, on the table too
    assert out.comparison.position_error is not None
    assert out.comparison.position_error < 0.010


def test_bundled_tumbling_pinch_replays_in_physics() -> None:
    # the tumbling skills pinch the opposite faces e and b (a pinch on the adjacent faces f and
    # b slid the cube off its pivot: 8 and 1 of 30 replays ended in d:90); one take per mentor
    # and skill replayed from its recorded markers ends in d:90, the pinch holding the cube on
    # its pivot vertex (the pads' light touch at the landing is not always read: the landed
    # event is missing in 7 of the 60 bundled tumbling replays, docs/physics.md)
    ds = load_dataset("cube")
    sim = Simulator(ds.poly, scale=ds.scale)
    for skill in ("tumble-lift", "tumble-twist"):
        for mentor in ("ana", "ben", "chen"):
            demo = next(d for d in ds.of_skill(skill) if d.mentor == mentor)
            assert {str(p) for p in demo.skill.events[1].pairs} >= {"(R1,e)", "(R2,b)"}
            got = replay_demonstration(sim, ds, demo)
            assert got.success, got.to_dict()
            found = {eid for eid, t, _ in got.comparison.matched if t is not None}
            assert {"pinch", "tilt", "done"} <= found, got.to_dict()


def test_cube_push_roll_demonstrated_and_inferred() -> None:
    ds = load_dataset("cube")
    small = Dataset(ds.poly, ds.skills, tuple(d for d in ds.demonstrations
                                              if d.skill.name == "push-roll")[:6],
                    ds.scale, ds.gap_limit, ds.fingers)
    _check(small, "push-roll")


def test_hexprism_recorded_from_physics_demonstrated_and_inferred() -> None:
    ds, stats = record_dataset(HEX_SKILLS, n_per_skill=2, seed=5)
    assert all(s["kept"] == 2 for s in stats.values())
    assert ds.object_markers and ds.demonstrations[0].trajectory.rigid_bodies
    _check(ds, "push-roll", whole=True)


def test_report_physics_section_simulates_each_step() -> None:
    from nonprehensile.planning import plan
    from nonprehensile.states import State
    from nonprehensile.viz.physics import physics_section

    ds = load_dataset("cube")
    small = Dataset(ds.poly, ds.skills, tuple(d for d in ds.demonstrations
                                              if d.skill.name == "push-roll")[:6],
                    ds.scale, ds.gap_limit, ds.fingers)
    exp = expand(ds.poly, list(ds.skills), states_by_step(ds.poly, 90))
    pl = plan(ds.poly, exp, State("a", 0), State("d", 0), motions=_library(small),
              position=(0.1, 0.1), costs={"push-roll": 0.5}, scale=ds.scale)
    section, records = physics_section(ds.poly, pl, scale=ds.scale, fingers=ds.fingers)
    assert len(records) == len(pl.steps) == 1 and records[0]["success"]
    # executed closed loop: the steps' table, then (if any) the re-plans and corrections
    _, rows = section.tables[0]
    assert len(rows) == 1 and rows[0][-1] == "yes"
    assert "touch" in rows[0][5] and "done" in rows[0][5]  # the observed events
    assert "closed loop" in section.paragraphs[0] and "Open loop" in section.paragraphs[1]
    # a filmstrip where OpenGL works, a note saying why not elsewhere: never an error
    assert section.figures or any("No pictures" in p for p in section.paragraphs)


def test_filmstrip_renderer_is_small_and_draws_what_a_default_one_does() -> None:
    """The report's renderer makes its GL buffers only as large as its frames (no 4096^2
    shadow map: issue 16), leaves the model's settings as they were, and draws the very
    pixels a renderer with MuJoCo's default buffers draws."""
    import mujoco

    from nonprehensile.geometry import cube
    from nonprehensile.sim.render import _small_renderer, render_traces

    sim = Simulator(cube(), scale=0.05, n_fingers=1)
    m, d = sim.model, sim.data
    settings = (m.vis.quality.shadowsize, m.vis.global_.offwidth, m.vis.global_.offheight)
    try:
        small = _small_renderer(m, 66, 88)
    except Exception as exc:  # pragma: no cover - a machine without any OpenGL
        pytest.skip(f"no OpenGL context for offscreen rendering here: {exc}")
    try:
        # mujoco.Renderer keeps its MjrContext private; its sizes are what this is about
        ctx = small._mjr_context
        assert (ctx.offWidth, ctx.offHeight) == (88, 66) and ctx.shadowSize <= 1
    finally:
        small.close()
    assert (m.vis.quality.shadowsize, m.vis.global_.offwidth,
            m.vis.global_.offheight) == settings == (4096, 640, 480)
    trace = np.zeros((2, 8 + 3 * len(sim._finger_qadr)))
    trace[:, 0] = [0.0, 1.0]
    trace[:, 3] = 0.025  # the cube (5 cm) resting on the table
    trace[:, 4] = 1.0  # identity quaternion
    (frame,), note = render_traces(sim, [(trace, [0.5])], width=88, height=66)
    assert note == ""
    full = mujoco.Renderer(m, 66, 88)
    try:
        cam = mujoco.MjvCamera()
        cam.azimuth, cam.elevation = 135.0, -30.0
        cam.distance = max(0.15, 3.0 * sim.scale * sim.poly.diameter)
        mujoco.mj_forward(m, d)
        cam.lookat[:] = d.xpos[sim._body] + np.array([0.0, 0.0, 0.02])
        full.update_scene(d, cam)
        full.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        full.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        expected = full.render()
    finally:
        full.close()
    assert frame.shape == (66, 88, 3) and frame.std() > 1.0  # a picture, not a blank
    np.testing.assert_array_equal(frame, expected)
