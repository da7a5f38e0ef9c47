"""``nonprehensile states``: the stable states of a model and their equivalence classes.

Registered in :data:`nonprehensile.cli.COMMANDS`.
"""

from __future__ import annotations

import click
from rich.table import Table

from nonprehensile.cli.common import emit_json, fmt_num, handle_errors, out
from nonprehensile.cli.object import STREAM_ROWS
from nonprehensile.cli.options import (
    angle_tol_option,
    atol_option,
    json_option,
    load_cli_model,
    rtol_option,
    state_set,
    states_option,
    step_option,
)
from nonprehensile.equivalence import equivalence_classes

__all__ = ["states_cmd"]


@click.command("states")
@click.argument("model")
@step_option
@states_option
@rtol_option
@atol_option
@angle_tol_option
@json_option
@handle_errors
def states_cmd(
    model: str, step: float | None, states_file: str | None, rtol: float | None, atol: float | None,
    angle_tol: float, as_json: bool,
) -> None:
    """The stable states of MODEL and their geometric-equivalence classes."""
    poly = load_cli_model(model, rtol)
    states = state_set(poly, step, states_file, angle_tol)
    classes = equivalence_classes(poly, states, atol=atol, angle_tol=angle_tol)
    n_classes = max(classes) + 1 if classes else 0
    if as_json:
        emit_json({
            "states": [{**s.to_dict(), "class": c} for s, c in zip(states, classes, strict=True)],
            "n_classes": n_classes,
        })
        return
    title = f"{len(states)} states of {poly.name}, {n_classes} equivalence classes"
    if len(states) > STREAM_ROWS:
        # a table of thousands of rows is printed as it goes, in plain aligned columns: a
        # rich Table measures every cell first (minutes and a GB at 360,000 rows)
        width = max(len(str(s)) for s in states)
        lines = [title, f"{'state':<{width}}  face  {'theta (deg)':>11}  class"]
        click.echo("\n".join(lines))
        for i in range(0, len(states), 4096):
            click.echo("\n".join(
                f"{s!s:<{width}}  {s.face:<4}  {fmt_num(s.theta):>11}  {c:>5}"
                for s, c in zip(states[i:i + 4096], classes[i:i + 4096], strict=True)))
        return
    t = Table(title=title)
    t.add_column("state")
    t.add_column("face")
    t.add_column("theta (deg)", justify="right")
    t.add_column("class", justify="right")
    for s, c in zip(states, classes, strict=True):
        t.add_row(str(s), s.face, fmt_num(s.theta), str(c))
    out.print(t)
