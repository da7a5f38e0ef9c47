"""``nonprehensile infer``: undemonstrated transitions over a state set (paper Section V).

Registered in :data:`nonprehensile.cli.COMMANDS`.
"""

from __future__ import annotations

import click
from rich.table import Table

from nonprehensile.cli.common import emit_json, err, handle_errors, out
from nonprehensile.cli.options import (
    angle_tol_option,
    atol_option,
    json_option,
    rtol_option,
    state_set,
    states_option,
    step_option,
)
from nonprehensile.inference import METHODS, Expansion, cross_check, expand
from nonprehensile.io import read_skills
from nonprehensile.states import State

__all__ = ["infer_cmd"]


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
