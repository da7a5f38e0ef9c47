"""``nonprehensile skills``, ``infer`` and ``plan``: from skills to a plan (``demo`` is in
:mod:`nonprehensile.cli.demo`).

Registered in :data:`nonprehensile.cli.COMMANDS`.
"""

from __future__ import annotations

from typing import Any

import click
from rich.table import Table

from nonprehensile.cli.common import emit_json, err, fmt_num, handle_errors, out, stage_bars
from nonprehensile.cli.options import (
    angle_tol_option,
    atol_option,
    json_option,
    parse_state,
    rtol_option,
    state_set,
    states_option,
    step_option,
)
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.inference import METHODS, Expansion, cross_check, expand
from nonprehensile.io import read_skills
from nonprehensile.pipeline import motions_from_dataset, write_plan_motions
from nonprehensile.planning import DEFAULT_RELOCATION_COST, plan
from nonprehensile.skills.contacts import format_event
from nonprehensile.skills.skill import Skill, group_by_maneuver, skill_graph, skill_to_dict
from nonprehensile.states import State

__all__ = ["infer_cmd", "plan_cmd", "print_plan", "skills_group"]


@click.group("skills")
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


def _expansion_table(exp: Expansion) -> Table:
    t = Table(title=f"{len(exp.transitions)} transitions ({exp.method} inference)")
    for col in ("from", "to", "skill", "maneuver", "shown", "faces mapped"):
        t.add_column(col)
    for tr in exp.transitions:
        changed = ", ".join(f"{k}->{v}" for k, v in sorted(tr.mapping.items()) if k != v)
        t.add_row(str(tr.start), str(tr.end), tr.skill.name, tr.skill.maneuver,
                  "demonstrated" if tr.demonstrated else "inferred", changed or "-")
    return t


@click.command("infer")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@step_option
@states_option
@click.option("--method", type=click.Choice(METHODS), default="exact", show_default=True,
              help="exact: through the symmetry group; paper: the paper's edge-index method.")
@click.option("--compare", is_flag=True,
              help="Also run the other method and report where the two disagree.")
@click.option("--figure", type=click.Path(dir_okay=False), default=None,
              help="Also draw the expanded graph and its transition matrix to this image.")
@rtol_option
@atol_option
@angle_tol_option
@json_option
@handle_errors
def infer_cmd(
    skills_file: str, step: float | None, states_file: str | None, method: str, compare: bool,
    figure: str | None, rtol: float | None, atol: float | None, angle_tol: float, as_json: bool,
) -> None:
    """Infer undemonstrated transitions of SKILLS_FILE over a state set (paper Section V)."""
    poly, skills = read_skills(skills_file, rtol=rtol, angle_tol=angle_tol)
    states = state_set(poly, step, states_file, angle_tol)
    exp = expand(poly, skills, states, method=method, atol=atol,  # type: ignore[arg-type]
                 angle_tol=angle_tol)
    applied = {t.source.name for t in exp.transitions}
    for s in skills:
        if s.name not in applied:
            err.print(f"note: skill {s.name!r} (from {s.initial}) applies to no state of the "
                      "set: no state is equivalent to its initial state")
    doc = exp.to_dict(poly.name)
    if figure:
        from nonprehensile.viz import save_figure, state_graph_figure

        save_figure(state_graph_figure(exp), figure, dpi=80)
        err.print(f"wrote {figure}")
    if compare:
        doc["disagreements"] = [d.to_dict() for d in cross_check(
            poly, skills, states, atol=atol, angle_tol=angle_tol)]
    if as_json:
        emit_json(doc)
        return
    out.print(_expansion_table(exp))
    n_demo = sum(t.demonstrated for t in exp.transitions)
    out.print(
        f"expanded graph: {len(exp.graph.states)} states, {len(exp.transitions)} transitions "
        f"({n_demo} demonstrated, {len(exp.transitions) - n_demo} inferred)"
    )
    if compare:
        dis = doc["disagreements"]
        if not dis:
            out.print("the paper's method and the exact one agree on every transition")
        for d in dis:
            out.print(f"disagree [{d['kind']}] {d['skill']} from {State.from_dict(d['from'])}: "
                      f"exact {d['exact'] or '(none)'}, paper {d['paper'] or '(none)'}")


def _parse_costs(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> dict[
        str, float] | None:
    if not value:
        return None
    out = {}
    for item in value:
        name, sep, num = item.partition("=")
        try:
            out[name] = float(num)
        except ValueError:
            raise click.BadParameter(
                f"expected SKILL=COST (e.g. push-roll=2.5), got {item!r}") from None
        if not sep or not name:
            raise click.BadParameter(f"expected SKILL=COST (e.g. push-roll=2.5), got {item!r}")
    return out


def print_plan(plan_doc: dict[str, Any]) -> None:
    """A plan as a person reads it: offset, then each step's events and motions."""
    off = plan_doc["offset"]
    out.print(
        f"plan {State.from_dict(plan_doc['start'])} -> {State.from_dict(plan_doc['goal'])}: "
        f"{len(plan_doc['steps'])} step(s), cost {fmt_num(plan_doc['cost'])}; relocate the "
        f"agent by {fmt_num(off['rotate_deg'])} degrees and ({fmt_num(off['translate'][0])}, "
        f"{fmt_num(off['translate'][1])})"
        + (f"; it relocates {plan_doc.get('relocations')} more time(s) between steps"
           if plan_doc.get("relocations") else "")
    )
    for i, step in enumerate(plan_doc["steps"], start=1):
        agent = step.get("agent")
        where = ""
        if agent is not None:
            moved = "relocated: " if step.get("relocated") and i > 1 else ""
            where = (f"; {moved}agent at {fmt_num(agent['rotate_deg'])} deg, "
                     f"({fmt_num(agent['translate'][0])}, {fmt_num(agent['translate'][1])})")
        t = Table(title=f"step {i}: {State.from_dict(step['from'])} -> "
                        f"{State.from_dict(step['to'])} by {step['skill']} ({step['maneuver']}, "
                        f"{'demonstrated' if step['demonstrated'] else 'inferred'}){where}")
        t.add_column("event")
        t.add_column("contacts")
        t.add_column("then")
        t.add_column("reference motion")
        for j, ev in enumerate(step["events"]):
            m = step["motions"][j] if j < len(step["motions"]) else None
            ref = m["reference"] if m else None
            n_demos = ref["n_demonstrations"] if ref else 0
            ref_text = (f"cluster {ref['cluster']} medoid of {n_demos} "
                        f"demonstration{'' if n_demos == 1 else 's'}, {ref['n_frames']} frames"
                        if ref else ("-" if m else ""))
            t.add_row(ev["id"], " ∧ ".join(ev["contacts"]), m["label"] if m else "", ref_text)
        out.print(t)


@click.command("plan")
@click.argument("skills_file", type=click.Path(dir_okay=False))
@click.option("--from", "start", required=True, callback=parse_state,
              help="Start state FACE:THETA as the object lies (any orientation).")
@click.option("--to", "goal", required=True, callback=parse_state,
              help="Goal state FACE:THETA in the same (world) frame.")
@step_option
@states_option
@click.option("--at", "position", type=(float, float), default=(0.0, 0.0), show_default=True,
              help="Where the object is on the table (x y), for the agent's offset.")
@click.option("--cost", "costs", multiple=True, callback=_parse_costs,
              help="Cost of a skill, SKILL=COST (repeatable); default 1 per transition.")
@click.option("--relocation-cost", type=float, default=DEFAULT_RELOCATION_COST,
              show_default=True,
              help="Cost of relocating the agent between steps (its first placement is free).")
@click.option("--dataset", default=None,
              help="Demonstrations (a dataset folder, or `cube`) to attach reference motions.")
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="Write each step's reference trajectories here (C3D and CSV).")
@rtol_option
@atol_option
@angle_tol_option
@json_option
@handle_errors
def plan_cmd(
    skills_file: str, start: State, goal: State, step: float | None, states_file: str | None,
    position: tuple[float, float], costs: dict[str, float] | None, relocation_cost: float,
    dataset: str | None, out_dir: str | None, rtol: float | None, atol: float | None,
    angle_tol: float, as_json: bool,
) -> None:
    """Plan transitions, contact events and finger motions from --from to --to."""
    poly, skills = read_skills(skills_file, rtol=rtol, angle_tol=angle_tol)
    states = state_set(poly, step, states_file, angle_tol)
    exp = expand(poly, skills, states, atol=atol, angle_tol=angle_tol)
    if out_dir is not None and dataset is None:
        raise InputError("--out writes reference trajectories: give --dataset too")
    motions = None
    scale = 1.0
    if dataset is not None:
        with stage_bars(as_json) as bars:
            ds, motions = motions_from_dataset(dataset, skills=skills, poly=poly,
                                               progress=bars)
        scale = ds.scale
    result = plan(poly, exp, start, goal, position=position, costs=costs, motions=motions,
                  angle_tol=angle_tol, scale=scale, relocation_cost=relocation_cost)
    doc = result.to_dict()
    if out_dir is not None:
        written = write_plan_motions(result, out_dir)
        doc["files"] = [str(p) for p in written]
        err.print(f"wrote {len(written)} files to {out_dir}")
    if as_json:
        emit_json(doc)
        return
    print_plan(doc)
