"""Options and helpers that several commands share: tolerances, state sets, ``--json``.

Imported by the command modules (``cli.object``, ``cli.plan``, ...), never by
:mod:`nonprehensile.cli` itself, which stays free of the library's imports. This module
imports click and no numpy: a command's ``--help`` (``nonprehensile demo --help``) must not
pay for the geometry (0.4 s of imports: issue 16); the helpers import what they use when
they run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import click

from nonprehensile.checks import DEFAULT_ANGLE_TOL, DEFAULT_RTOL
from nonprehensile.errors import InputError

if TYPE_CHECKING:
    from nonprehensile.geometry.polyhedron import Polyhedron
    from nonprehensile.states import State

__all__ = [
    "angle_tol_option",
    "atol_option",
    "json_option",
    "load_cli_model",
    "parse_state",
    "rtol_option",
    "state_set",
    "states_option",
    "step_option",
]


def load_cli_model(path: str, rtol: float | None) -> Polyhedron:
    """The model a command names (a file, or a bundled name such as ``cube``)."""
    from nonprehensile.io import load_model

    return load_model(path, rtol=rtol)


rtol_option = click.option(
    "--rtol",
    type=float,
    default=None,
    help="Length tolerance relative to the object's diameter (raise it for measured models; "
    f"default: the model file's own rtol, else {DEFAULT_RTOL:g}).",
)
json_option = click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
angle_tol_option = click.option(
    "--angle-tol", type=float, default=DEFAULT_ANGLE_TOL, show_default=True,
    help="Angle tolerance in degrees for matching states (raise it for measured models).",
)
atol_option = click.option(
    "--atol", type=float, default=None,
    help="Length tolerance of the symmetry group (default: the model's own, rtol x diameter).",
)


def state_set(
    poly: Polyhedron, step: float | None, states_file: str | None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[State]:
    """The state set chosen on the command line (``--step`` or ``--states``)."""
    from nonprehensile.io import read_states
    from nonprehensile.states import check_states, states_by_step

    if (step is None) == (states_file is None):
        raise InputError("give exactly one of --step DEG or --states FILE")
    if step is not None:
        return states_by_step(poly, step)
    assert states_file is not None
    return check_states(poly, read_states(states_file), angle_tol=angle_tol)


step_option = click.option("--step", type=float, default=None,
                           help="Orientation step in degrees (e.g. 90).")
states_option = click.option("--states", "states_file", type=click.Path(dir_okay=False),
                             default=None, help="JSON list of {face, theta} states.")


def parse_state(ctx: click.Context, param: click.Parameter, value: str) -> State:
    from nonprehensile.states import State

    try:
        return State.parse(value)
    except InputError as exc:
        raise click.BadParameter(str(exc)) from None

