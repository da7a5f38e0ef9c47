"""``nonprehensile plan``: from skills to a plan (``skills`` is in :mod:`nonprehensile.cli.skills`,
``infer`` in :mod:`nonprehensile.cli.infer`, ``demo`` in :mod:`nonprehensile.cli.demo`).

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
from nonprehensile.geometry.units import metres_per_unit
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.pipeline import motions_from_dataset, write_plan_motions
from nonprehensile.planning import DEFAULT_RELOCATION_COST, plan
from nonprehensile.states import State

__all__ = ["plan_cmd", "print_plan"]


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
@click.option("--html", "html_out", default=None, type=click.Path(dir_okay=False),
              help="Write a rotatable 3-D view of the plan: one self-contained HTML file "
              "(plotly.js embedded, opens offline) with the object's pose at each step, the "
              "reference finger paths (with --dataset) and the agent; needs the view3d extra.")
@rtol_option
@atol_option
@angle_tol_option
@json_option
@handle_errors
def plan_cmd(
    skills_file: str, start: State, goal: State, step: float | None, states_file: str | None,
    position: tuple[float, float], costs: dict[str, float] | None, relocation_cost: float,
    dataset: str | None, out_dir: str | None, html_out: str | None, rtol: float | None,
    atol: float | None, angle_tol: float, as_json: bool,
) -> None:
    """Plan transitions, contact events and finger motions from --from to --to."""
    poly, skills = read_skills(skills_file, rtol=rtol, angle_tol=angle_tol)
    states = state_set(poly, step, states_file, angle_tol)
    exp = expand(poly, skills, states, atol=atol, angle_tol=angle_tol)
    if out_dir is not None and dataset is None:
        raise InputError("--out writes reference trajectories: give --dataset too")
    if html_out is not None and not html_out.lower().endswith((".html", ".htm")):
        raise InputError(f"--html {html_out}: the 3-D view is an HTML file; name it .html")
    motions = None
    # world positions in metres: from the model's units, or the dataset's recorded scale
    scale = metres_per_unit(poly.units)
    markers: list[str] | None = None
    if dataset is not None:
        with stage_bars(as_json) as bars:
            ds, motions = motions_from_dataset(dataset, skills=skills, poly=poly,
                                               progress=bars)
        scale = ds.scale
        markers = list(ds.fingers.values())
    result = plan(poly, exp, start, goal, position=position, costs=costs, motions=motions,
                  angle_tol=angle_tol, scale=scale, relocation_cost=relocation_cost)
    doc = result.to_dict()
    if out_dir is not None:
        written = write_plan_motions(result, out_dir)
        doc["files"] = [str(p) for p in written]
        err.print(f"wrote {len(written)} files to {out_dir}")
    if html_out is not None:
        from nonprehensile.viz.view3d import plan_view, write_html

        write_html(plan_view(poly, result, scale=scale, markers=markers,
                             units="m" if dataset is not None else poly.units), html_out)
        doc["html"] = str(html_out)
        err.print(f"wrote {html_out}")
    if as_json:
        emit_json(doc)
        return
    print_plan(doc)
