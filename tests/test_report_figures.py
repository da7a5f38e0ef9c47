"""The report's figures of issue 24: the per-skill transition panels, the plan filmstrip's
ticks and bottom face, what the physics filmstrip says the object stands on."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from nonprehensile.geometry import cube
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.states import State, states_by_step
from nonprehensile.viz.graphs import skill_components, transitions_figure, transitions_svg

SKILLS = Path(__file__).parents[1] / "examples" / "cube_skills.json"


@pytest.fixture(scope="module")
def expansion() -> Any:
    poly, skills = read_skills(SKILLS)
    return poly, skills, expand(poly, skills, states_by_step(poly, 90))


def test_each_skill_falls_into_cycles_of_its_maneuvers_order(expansion: Any) -> None:
    """A skill is one world-fixed maneuver: on the cube's 24 states, a quarter roll or a
    quarter turn comes back after 4 steps (6 cycles), a tumble over a vertex, a third of a
    turn about a body diagonal, after 3 (8 cycles). Every arc of the skill is on exactly
    one chain, in order."""
    _, _, exp = expansion
    for name in {t.skill.name for t in exp.transitions}:
        arcs = {(t.start, t.end) for t in exp.transitions if t.skill.name == name}
        maneuver = next(t.skill.maneuver for t in exp.transitions if t.skill.name == name)
        chains = skill_components(exp, name)
        k = 3 if maneuver == "tumbling" else 4
        assert all(closed and len(states) == k for states, closed in chains), name
        assert len(chains) == 24 // k
        walked = {(s[i], s[(i + 1) % len(s)]) for s, _ in chains for i in range(len(s))}
        assert walked == arcs


def test_a_state_set_the_maneuver_leaves_gives_open_chains(expansion: Any) -> None:
    poly, skills, _ = expansion
    subset = [State("a", 0.0), State("d", 0.0), State("f", 0.0)]
    exp = expand(poly, skills, subset)
    chains = skill_components(exp, "push-roll")
    inside = set(subset)
    assert chains and not any(closed for _, closed in chains)
    for states, _ in chains:
        # each chain runs inside the set and may end on a state outside it
        assert all(s in inside for s in states[:-1])
    svg = transitions_svg(exp, skills=["push-roll"])
    assert 'stroke-dasharray="3,2"' in svg  # the state outside the set, dashed


def test_svg_panels_name_every_state_and_arc(expansion: Any) -> None:
    _, _, exp = expansion
    svg = transitions_svg(exp)
    for name in {t.skill.name for t in exp.transitions}:
        panel = svg[svg.index(f'<g data-skill="{name}">'):]
        panel = panel[:panel.index("</g>")]
        texts = re.findall(r'font-size="13">([^<]+)</text>', panel)
        assert sorted(texts) == sorted(str(s) for s in exp.graph.states)
        assert panel.count("<path ") == 24
    with pytest.raises(Exception, match="no skill 'nope'"):
        transitions_svg(exp, skills=["nope"])


def test_matplotlib_panels_draw_a_label_per_state_and_skill(expansion: Any) -> None:
    _, _, exp = expansion
    fig = transitions_figure(exp)
    names = {t.skill.name for t in exp.transitions}
    assert len(fig.axes) == len(names)
    for ax in fig.axes:
        assert sorted(t.get_text() for t in ax.texts) == sorted(str(s) for s in exp.graph.states)


def test_plan_filmstrip_has_tick_values_and_the_bottom_face_in_red() -> None:
    from matplotlib.colors import to_hex

    from nonprehensile.planning import plan
    from nonprehensile.viz.plan_figure import plan_filmstrip_figure
    from nonprehensile.viz.report import figure_to_png

    poly, skills = read_skills(SKILLS)
    exp = expand(poly, skills, states_by_step(poly, 90))
    result = plan(poly, exp, State("b", 200.0), State("e", 110.0), position=(0.3, 0.1))
    fig = plan_filmstrip_figure(poly, result)
    bottoms = [s.start_world.face for s in result.steps] + [result.goal.face]
    poses = [s.start_pose for s in result.steps] + [result.steps[-1].end_pose]
    assert len(fig.axes) == len(bottoms)
    for ax, bottom, pose in zip(fig.axes, bottoms, poses, strict=True):
        assert f"bottom face {bottom}" in ax.get_title()
        # one face is drawn red, and it is the one that lies on the table in that pose
        red = [c for c in ax.collections
               if {to_hex(x, keep_alpha=False) for x in c.get_facecolor()} == {"#d62728"}]
        assert len(red) == 1 and red[0].get_gid() == f"bottom:{bottom}"
        assert pose is not None
        z = pose.to_world(poly.vertices[list(poly.faces[bottom])])[:, 2]
        assert np.abs(z).max() < 1e-9
    figure_to_png(fig)  # drawn: the tick labels exist
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            labels = [t.get_text() for t in axis.get_ticklabels()]
            assert len([lab for lab in labels if lab]) >= 2
            assert all(re.fullmatch(r"[−-]?\d+(\.\d+)?", lab) for lab in labels if lab)


def _rot_x(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_down_element_reads_face_edge_and_vertex() -> None:
    """The physics filmstrip's captions: which face, edge or vertex is lowest, against the
    cube's own normals (its bottom face a points to -z; rotating about x by 45 degrees
    brings down the edge between a and the face whose normal is +-y)."""
    from nonprehensile.viz.physics import down_element

    poly = cube()
    down = next(f for f in poly.faces if poly.normals[f][2] < -0.99)
    assert down_element(poly, np.eye(3)) == down
    tilted = _rot_x(45.0)
    side = next(f for f in poly.faces
                if (tilted @ poly.normals[f])[2] < -0.5 and f != down)
    assert down_element(poly, tilted) == f"E({','.join(sorted((down, side)))})"
    # a body diagonal straight down: a vertex, shared by three faces
    axis = np.array([1.0, 1.0, 1.0]) / math.sqrt(3)
    target = np.array([0.0, 0.0, 1.0])
    v = np.cross(axis, target)
    c = float(axis @ target)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    rot = np.eye(3) + vx + vx @ vx / (1 + c)  # takes (1, 1, 1) to +z: vertex (0,0,0) lowest
    element = down_element(poly, rot)
    assert element.startswith("V(") and len(element.split(",")) == 3
    # within the tolerance of resting, the face itself
    assert down_element(poly, _rot_x(2.0)) == down


def test_a_turn_between_steps_is_not_reported_at_the_end() -> None:
    """The physics table said "at the end" for every correction push, but the closed loop
    also turns the object back onto a step's predicted state between steps (an angle
    block's roll landed 6.4 degrees short, was turned, then step 2 ran): each push follows
    one transit (``turn`` or ``correction``), so the transits say when it ran. The
    transits below are such an execution's, as `simulate plan --json` printed them."""
    from nonprehensile.viz.physics import correction_times

    transits = [{"before": "step 1"}, {"before": "turn"}, {"before": "step 2"},
                {"before": "turn"}, {"before": "correction"}, {"before": "end"}]
    corrections = [{"kind": "turn"}, {"kind": "turn"}, {"kind": "slide"}]
    assert correction_times(transits, corrections) == [
        "before step 2", "at the end", "at the end"]
    # an execution whose transits do not pair with its pushes says nothing it cannot know
    assert correction_times(transits[:1], corrections[:1]) == ["-"]
