"""``nonprehensile skills``: demonstrated skills, their contact events, motions, skill graphs.

Registered in :data:`nonprehensile.cli.COMMANDS`.
"""

from __future__ import annotations

from typing import Any

import click
from rich.table import Table

from nonprehensile.cli import HelpGroup
from nonprehensile.cli.common import emit_json, err, handle_errors, out
from nonprehensile.cli.options import (
    angle_tol_option,
    json_option,
    rtol_option,
)
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.io import read_skills
from nonprehensile.skills.contacts import format_event
from nonprehensile.skills.skill import Skill, group_by_maneuver, skill_graph, skill_to_dict
from nonprehensile.states import State

__all__ = ["skill_graphs_summary", "skills_group"]


@click.group("skills", cls=HelpGroup)
def skills_group() -> None:
    """Demonstrated skills: contact events, motions and skill graphs."""


def skill_graphs_summary(poly: Polyhedron, skills: list[Skill]) -> list[dict[str, Any]]:
    """Each maneuver's skill graph (paper Fig. 5(b)) as nodes and arcs."""
    out = []
    for grp in group_by_maneuver(poly, skills):
        g = skill_graph(poly, grp)
        names = {key: f"n{i}" for i, key in enumerate(g.nodes)}
        out.append({
            "skills": [s.name for s in grp],
            "maneuver": grp[0].maneuver,
            "from": grp[0].initial.to_dict(),
            "to": grp[0].final.to_dict(),
            "nodes": [{"node": names[k], "ids": sorted(d["ids"]),
                       "contacts": format_event(d["event"])} for k, d in g.nodes(data=True)],
            "arcs": [{"from": names[a], "to": names[b], "skill": d["skill"],
                      "label": d["motion"].label} for a, b, d in g.edges(data=True)],
        })
    return out


@skills_group.command("show")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@click.option("--figure", type=click.Path(dir_okay=False), default=None,
              help="Also draw the skill graph of each maneuver to this image.")
@rtol_option
@angle_tol_option
@json_option
@handle_errors
def skills_show(
    skills_file: str, figure: str | None, rtol: float | None, angle_tol: float, as_json: bool
) -> None:
    """Show the skills of SKILLS_FILE and the skill graph of each maneuver."""
    poly, skills = read_skills(skills_file, rtol=rtol, angle_tol=angle_tol)
    graphs = skill_graphs_summary(poly, skills)
    if figure:
        from nonprehensile.viz import save_figure, skill_graphs_figure

        groups = group_by_maneuver(poly, skills)
        save_figure(skill_graphs_figure([skill_graph(poly, g) for g in groups]), figure, dpi=80)
        err.print(f"wrote {figure}")
    if as_json:
        emit_json({"object": poly.name, "skills": [skill_to_dict(s) for s in skills],
                   "graphs": graphs})
        return
    for s in skills:
        t = Table(title=f"{s.name}: {s.initial} -> {s.final} ({s.maneuver}"
                        f"{', invertible' if s.invertible else ''})")
        t.add_column("event")
        t.add_column("contacts")
        t.add_column("motion to next")
        for i, e in enumerate(s.events):
            motion = s.motions[i].label or "-" if i < len(s.motions) else ""
            t.add_row(e.id, format_event(e, "paper"), motion)
        out.print(t)
    for gsum in graphs:
        out.print(
            f"skill graph of {State.from_dict(gsum['from'])} -> {State.from_dict(gsum['to'])} "
            f"({gsum['maneuver']}): skills {', '.join(gsum['skills'])}; "
            f"{len(gsum['nodes'])} contact events, {len(gsum['arcs'])} motion arcs"
        )
