"""Options and helpers that several commands share: tolerances, state sets, ``--json``.

Imported by the command modules (``cli.object``, ``cli.plan``, ...), never by
:mod:`nonprehensile.cli` itself, which stays free of the library's imports. This module
imports click and no numpy: a command's ``--help`` (``nonprehensile demo --help``) must not
pay for the geometry (0.4 s of imports: issue 16); the helpers import what they use when
they run.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import click

from nonprehensile.checks import (
    ANGLE_TOL_RANGE,
    DEFAULT_ANGLE_TOL,
    DEFAULT_RTOL,
    LENGTH_RANGE,
    RTOL_RANGE,
    STEP_RANGE,
    Range,
)
from nonprehensile.errors import InputError

if TYPE_CHECKING:
    from nonprehensile.geometry.polyhedron import Polyhedron
    from nonprehensile.states import State

__all__ = [
    "ANGLE",
    "ANGLE_TOL",
    "COORDINATE",
    "LENGTH",
    "NON_NEGATIVE",
    "POSITIVE",
    "RTOL",
    "SEED",
    "STEP",
    "Number",
    "OptionError",
    "angle_tol_option",
    "atol_option",
    "count",
    "json_option",
    "load_cli_model",
    "note_drift",
    "number",
    "parse_state",
    "rtol_option",
    "state_set",
    "states_option",
    "step_option",
]

if TYPE_CHECKING:
    _ParamBase = click.ParamType[Any, Any]
else:  # click < 8.2 has no type parameters at run time
    _ParamBase = click.ParamType


class OptionError(click.BadParameter):
    """A bad option value, shown as the library's errors are: one line on stderr,
    ``error: --step: expected a finite number above 0 and at most 360 (degrees), got 'nan'``
    (click's usual usage text around it would make four), exit 2."""

    def format_message(self) -> str:
        p = self.param
        name = (p.opts[0] if isinstance(p, click.Option) and p.opts
                else (p.human_readable_name if p is not None else "value"))
        return f"{name}: {self.message}"

    def show(self, file: Any = None) -> None:
        click.echo(click.style("error: ", fg="red", bold=True) + self.format_message(),
                   err=True)


class Number(_ParamBase):
    """The type of every numeric option: a finite number in a :class:`~nonprehensile.checks.
    Range`, checked when the command line is parsed, before any work.

    click's ``float`` takes ``nan`` and ``inf``, and its ranges let NaN through; this type
    refuses them, and anything outside the range, with one line naming the option, what was
    expected and what came (exit 2). ``tests/test_cli_options.py`` walks every command and
    fails on a numeric option of another type, so a new option cannot skip the check.
    """

    def __init__(self, rng: Range) -> None:
        self.range = rng
        self.name = "integer" if rng.integer else "float"

    @property
    def low(self) -> float:
        return self.range.low

    @property
    def high(self) -> float:
        return self.range.high

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None
                ) -> Any:
        v, why = self.range.problem(value)
        if why is not None:
            raise OptionError(why, ctx=ctx, param=param)
        return v

    def __repr__(self) -> str:
        return f"Number({self.range.describe()})"


def number(low: float = -math.inf, high: float = math.inf, *, integer: bool = False,
           low_open: bool = False, high_open: bool = False, unit: str = "") -> Number:
    """A :class:`Number` option type: ``number(0, 360, low_open=True, unit="degrees")``."""
    return Number(Range(low, high, low_open=low_open, high_open=high_open, integer=integer,
                        unit=unit))


def count(low: int, high: int) -> Number:
    """A whole number from ``low`` to ``high`` (a count, a seed)."""
    return number(low, high, integer=True)


#: An angle step of a state set (``--step``), degrees.
STEP = Number(STEP_RANGE)
#: A tolerance on angles (``--angle-tol``), degrees.
ANGLE_TOL = Number(ANGLE_TOL_RANGE)
#: A length tolerance relative to the object's diameter (``--rtol``).
RTOL = Number(RTOL_RANGE)
#: A length tolerance or size in a model's own units (``--atol``).
LENGTH = Number(LENGTH_RANGE)
#: A tolerance on a final angle, degrees (above 0, at most half a turn).
ANGLE = number(0.0, 180.0, low_open=True, unit="degrees")
#: A position on the table, metres.
COORDINATE = number(-1e3, 1e3, unit="m")
#: Any positive finite number (the library checks the physical range: SimParams).
POSITIVE = number(0.0, low_open=True)
#: Any finite number >= 0.
NON_NEGATIVE = number(0.0)
#: A random seed numpy's generators take (and scikit-learn's ``random_state``).
SEED = count(0, 2**32 - 1)


def load_cli_model(path: str, rtol: float | None) -> Polyhedron:
    """The model a command names (a file, or a bundled name such as ``cube``)."""
    from nonprehensile.io import load_model

    return load_model(path, rtol=rtol)


rtol_option = click.option(
    "--rtol",
    type=RTOL,
    default=None,
    help="Length tolerance relative to the object's diameter (raise it for measured models; "
    f"default: the model file's own rtol, else {DEFAULT_RTOL:g}).",
)
json_option = click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
angle_tol_option = click.option(
    "--angle-tol", type=ANGLE_TOL, default=DEFAULT_ANGLE_TOL, show_default=True,
    help="Angle tolerance in degrees for matching states (raise it for measured models).",
)
atol_option = click.option(
    "--atol", type=LENGTH, default=None,
    help="Length tolerance of the symmetry group (default: the model's own, rtol x diameter).",
)


def note_drift(expansion: Any, angle_tol: float) -> None:
    """One note on stderr when the expansion's transitions land off its state set by a
    model's rounding (:func:`~nonprehensile.planning.landing_drift`): its plans may be
    missed, and a search for them run to its limit, until ``--angle-tol`` takes it in."""
    from nonprehensile.checks import suggest_angle_tol
    from nonprehensile.cli.common import err
    from nonprehensile.planning import landing_drift

    drift = landing_drift(expansion, angle_tol)
    if drift is not None:
        err.print(f"note: the transitions land {drift:.2g} degrees off the state set, more "
                  f"than --angle-tol {angle_tol:g} (a model from a mesh carries its file's "
                  f"rounding): plans may be missed, or searched long; --angle-tol "
                  f"{suggest_angle_tol(drift):g} takes it in")


def state_set(
    poly: Polyhedron, step: float | None, states_file: str | None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[State]:
    """The state set chosen on the command line (``--step`` or ``--states``)."""
    from nonprehensile.io import read_state_set
    from nonprehensile.states import states_by_step

    if (step is None) == (states_file is None):
        raise InputError("give exactly one of --step DEG or --states FILE")
    if step is not None:
        return states_by_step(poly, step)
    assert states_file is not None
    return read_state_set(poly, states_file, angle_tol=angle_tol)


step_option = click.option("--step", type=STEP, default=None,
                           help="Orientation step in degrees (e.g. 90).")
states_option = click.option("--states", "states_file", type=click.Path(dir_okay=False),
                             default=None, help="JSON list of {face, theta} states (or what "
                             "`states --json` prints).")


def parse_state(ctx: click.Context, param: click.Parameter, value: str) -> State:
    from nonprehensile.states import State

    try:
        return State.parse(value)
    except InputError as exc:
        raise click.BadParameter(str(exc)) from None
