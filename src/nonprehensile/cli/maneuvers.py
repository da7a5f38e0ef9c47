"""``nonprehensile maneuvers``: where every maneuver from a state goes.

Registered in :data:`nonprehensile.cli.COMMANDS`.
"""

from __future__ import annotations

import click
from rich.table import Table

from nonprehensile.cli.common import bounded, emit_json, fmt_num, handle_errors, out
from nonprehensile.cli.options import (
    angle_tol_option,
    json_option,
    load_cli_model,
    parse_state,
    rtol_option,
)
from nonprehensile.errors import InputError, ManeuverError
from nonprehensile.states import State

__all__ = ["maneuvers_cmd"]


@click.command("maneuvers")
@click.argument("model")
@click.option("--from", "start", required=True, callback=parse_state,
              help="The initial state FACE:THETA (e.g. a:0).")
@click.option("--step", type=bounded(float, 1e-3, 360.0), default=90.0, show_default=True,
              help="Rotations by every multiple of this many degrees, and tumbles onto final "
                   "thetas on this grid.")
@rtol_option
@angle_tol_option
@json_option
@handle_errors
def maneuvers_cmd(model: str, start: State, step: float, rtol: float | None, angle_tol: float,
                  as_json: bool) -> None:
    """Every roll, rotation and tumble of MODEL from a state: what stays on the ground (edge
    or vertex), the direction the object travels, and the final state to write in a skill.

    Rolls go over each edge of the bottom face; rotations turn by multiples of --step;
    tumbles go over each vertex of the bottom face onto the faces through it, to final
    thetas on the --step grid (and by the shortest motion onto a face that shares no edge
    with the bottom face). Directions are degrees from +x, counterclockwise seen from above,
    of the centre of mass's travel. "stable" says whether the object rests on the final face.
    """
    from nonprehensile.maneuvers import maneuvers_from

    poly = load_cli_model(model, rtol)
    if start.face not in poly.faces:
        raise InputError(f"--from {start}: {poly.name!r} has no face {start.face!r}; its faces "
                         f"are {list(poly.faces)}")
    try:
        opts = maneuvers_from(poly, start, step=step, angle_tol=angle_tol)
    except ManeuverError as exc:
        raise InputError(f"{model}: {exc}") from None
    if as_json:
        emit_json({"object": poly.name, "from": start.to_dict(), "step": step,
                   "maneuvers": [o.to_dict() for o in opts]})
        return
    t = Table(title=f"{len(opts)} maneuvers of {poly.name} from {start}")
    for col in ("maneuver", "over", "edge / vertex", "direction (deg)", "turn (deg)",
                "final state", "stable"):
        t.add_column(col)
    for o in opts:
        m = o.maneuver
        where = (f"edge {o.edge}" if o.edge is not None else
                 f"vertex {o.vertex}" if o.vertex is not None else "face")
        t.add_row(m.kind, o.element, where,
                  "-" if o.direction is None else fmt_num(round(o.direction, 4) % 360.0),
                  fmt_num(round(m.angle, 4)), m.end.exact(), "yes" if o.stable else "no")
    out.print(t)
