"""Segmentation at event times and registration to skill-graph arcs.

Truths used: a hand-made recording whose positions are the frame numbers (so each cut can be
read off), the skills file's own event chains and labels (which arc each motion must land
on), and the contact pairs of the events (what each graph node must hold).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nonprehensile.demonstrations.dataset import Dataset, Demonstration, EventTime, load_dataset
from nonprehensile.demonstrations.record import MarkerTrajectory
from nonprehensile.demonstrations.segment import (
    segment_dataset,
    segment_demonstration,
    segments_by_arc,
    skill_graphs,
)
from nonprehensile.demonstrations.synth import synthesize_dataset
from nonprehensile.errors import InputError
from nonprehensile.io import read_skills

SKILLS = Path(__file__).parents[1] / "src" / "nonprehensile" / "data" / "cube_skills.json"


@pytest.fixture(scope="module")
def cube() -> Dataset:
    return load_dataset("cube")


def _counting_demo(times: list[float], n_frames: int = 60, rate: float = 10.0) -> Demonstration:
    _, skills = read_skills(SKILLS)
    skill = next(s for s in skills if s.name == "push-roll")
    pos = np.repeat(np.arange(n_frames, dtype=float)[:, None, None], 4, axis=1)
    pos = np.repeat(pos, 3, axis=2)
    traj = MarkerTrajectory(pos, ("a", "b", "c", "d"), rate, "mm")
    events = tuple(EventTime(e.id, t) for e, t in zip(skill.events, times, strict=True))
    return Demonstration("count.c3d", skill, "me", skill.initial, skill.final, events, traj)


def test_cuts_are_the_frames_between_event_times() -> None:
    poly, skills = read_skills(SKILLS)
    graphs = skill_graphs(poly, skills)
    # frames are 0.1 s apart; 0.3 is 3, 1.25 falls between 12 and 13, 2.0000001 is 20
    demo = _counting_demo([0.3, 1.25, 2.0000001, 3.5, 5.9])
    segs = segment_demonstration(demo, graphs)
    frames = [s.trajectory.positions[:, 0, 0].tolist() for s in segs]
    assert frames[0] == list(range(3, 13))
    assert frames[1] == list(range(13, 21))
    assert frames[2] == list(range(20, 36))
    assert frames[3] == list(range(35, 60))
    assert [s.step for s in segs] == [0, 1, 2, 3]
    assert [(s.t_start, s.t_end) for s in segs][1] == (1.25, 2.0000001)
    assert [s.motion.label for s in segs] == ["approach", "push", "follow", "retreat"]


def test_events_too_close_to_cut_between() -> None:
    poly, skills = read_skills(SKILLS)
    demo = _counting_demo([0.3, 1.21, 1.29, 3.5, 5.9])  # no two frames between 1.21 and 1.29
    with pytest.raises(InputError, match="less than two frames apart"):
        segment_demonstration(demo, skill_graphs(poly, skills))


def test_gaps_are_filled_before_cutting_or_kept() -> None:
    ds = synthesize_dataset(seed=4, n_per_skill=2, dropouts=3.0)
    _, filled = segment_dataset(ds, fill=True)
    _, raw = segment_dataset(ds, fill=False)
    assert not any(np.isnan(s.trajectory.positions).any() for s in filled)
    assert any(np.isnan(s.trajectory.positions).any() for s in raw)
    for f, r in zip(filled, raw, strict=True):
        seen = ~np.isnan(r.trajectory.positions)
        np.testing.assert_array_equal(f.trajectory.positions[seen], r.trajectory.positions[seen])


def test_every_bundled_segment_is_registered_to_its_arc(cube: Dataset) -> None:
    graphs, segments = segment_dataset(cube)
    assert len(segments) == sum(len(d.skill.motions) for d in cube.demonstrations) == 660
    for s in segments:
        g = graphs.graphs[s.arc.group]
        assert g.has_edge(s.arc.source, s.arc.target, s.arc.key)
        assert s.arc.key == s.skill
        data = g.edges[s.arc.source, s.arc.target, s.arc.key]
        assert data["motion"] == s.demonstration.skill.motions[s.step]
        # the nodes hold the contacts of the events that bound the segment
        skill = s.demonstration.skill
        assert g.nodes[s.arc.source]["event"].pairs == skill.events[s.step].pairs
        assert g.nodes[s.arc.target]["event"].pairs == skill.events[s.step + 1].pairs
        assert s.trajectory.n_frames == round((s.t_end - s.t_start) * 120) + 1


def test_same_events_land_on_parallel_arcs(cube: Dataset) -> None:
    graphs, segments = segment_dataset(cube)
    arcs = segments_by_arc(segments)
    assert all(len(v) == 30 for v in arcs.values())
    assert len(graphs.graphs) == 3  # rolling, tumbling, rotating
    for one, other in (("roll-arc", "roll-pull"), ("tumble-lift", "tumble-twist")):
        a = sorted({s.arc for s in segments if s.skill == one}, key=lambda r: str(r))
        b = sorted({s.arc for s in segments if s.skill == other}, key=lambda r: str(r))
        assert a[0].group == b[0].group
        # same nodes for every step: the arcs of the two skills are parallel
        ends_a = {(x.source, x.target) for x in a}
        ends_b = {(x.source, x.target) for x in b}
        assert ends_a == ends_b and len(ends_a) == 4
    # push-roll shares the rolling graph but branches: its touch node is not roll-arc's hook
    push = {s.arc.target for s in segments if s.skill == "push-roll" and s.step == 0}
    hook = {s.arc.target for s in segments if s.skill == "roll-arc" and s.step == 0}
    assert len(push) == len(hook) == 1 and push != hook


def test_segments_keep_their_demonstration(cube: Dataset) -> None:
    _, segments = segment_dataset(cube)
    s = segments[5]
    d = s.demonstration
    assert s.mentor == d.mentor and s.skill == d.skill.name
    assert s.t_start == d.events[s.step].time and s.t_end == d.events[s.step + 1].time


def test_arc_of_bad_step() -> None:
    poly, skills = read_skills(SKILLS)
    graphs = skill_graphs(poly, skills)
    with pytest.raises(InputError, match=r"motions 0\.\.3"):
        graphs.arc_of(skills[0], 4)
    with pytest.raises(InputError, match="no skill graph"):
        graphs.group_of("moonwalk")
