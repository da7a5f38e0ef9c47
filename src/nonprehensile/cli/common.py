"""What every command module of the command line shares: consoles, errors, JSON output.

Exit codes (docs/files.md): 0 success, 2 bad input (the message names the
file and the culprit), 1 anything else.
"""

from __future__ import annotations

import functools
import json
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, TypeVar

import click
from rich.console import Console, ConsoleDimensions
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)
from rich.text import Text

from nonprehensile.cli import unusable_text
from nonprehensile.cli.options import Number, number
from nonprehensile.errors import InputError, NonprehensileError

__all__ = [
    "Bounded",
    "bounded",
    "emit_json",
    "err",
    "fmt_num",
    "handle_errors",
    "out",
    "progress_bar",
    "record_options",
    "stage_bars",
]

F = TypeVar("F", bound=Callable[..., Any])

if TYPE_CHECKING:
    _ParamBase = click.ParamType[Any, Any]
else:  # click < 8.2 has no type parameters at run time
    _ParamBase = click.ParamType

#: Width of output that goes to a file or a pipe (no terminal to fit): tables are printed
#: whole, never squeezed to 80 columns and cut ("nonprehensile states cube | less").
PIPED_WIDTH = 10_000


class _Console(Console):
    """A console as wide as the terminal, or :data:`PIPED_WIDTH` when the output is not a
    terminal (``COLUMNS`` still decides when it is set)."""

    @property
    def size(self) -> ConsoleDimensions:
        dims = super().size
        if self.is_terminal or self._width is not None or "COLUMNS" in os.environ:
            return dims
        return ConsoleDimensions(PIPED_WIDTH, dims.height)

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        self._width, self._height = new_size


out = _Console(soft_wrap=True, emoji=False, highlight=False)
err = _Console(stderr=True, soft_wrap=True, emoji=False, highlight=False)


def fmt_num(x: float) -> str:
    """A number as a person reads it (6 significant digits)."""
    return f"{x:.6g}"


def bounded(kind: type[int] | type[float], low: float, high: float) -> Number:
    """A :class:`~nonprehensile.cli.options.Number` option type from ``low`` to ``high``."""
    return number(low, high, integer=kind is int)


#: The former name of the option type (every numeric option is a ``Number`` now).
Bounded = Number


def record_options(what: str) -> Callable[[F], F]:
    """``--record OUT`` and ``--record-fps``: write ``what`` to a new folder as a LeRobot v3.0
    dataset (``simulate plan`` and ``simulate robustness`` share them)."""
    record = click.option(
        "--record", "record", type=click.Path(file_okay=False), default=None,
        help=f"Also write {what} to this new folder as a LeRobot v3.0 dataset "
             "(docs/dataset.md#executions-as-datasets).")
    fps = click.option(
        "--record-fps", type=bounded(float, 1.0, 1e4), default=100.0, show_default=True,
        help="Frame rate of --record (a divisor of the physics rate keeps its values).")

    def apply(f: F) -> F:
        return record(fps(f))

    return apply


def _check_text_arguments(kwargs: dict[str, Any]) -> None:
    """Every text argument must be encodable: a NUL or a lone surrogate in a file name would
    fail deep inside a system call with an unrelated error."""
    ctx = click.get_current_context(silent=True)
    opts = {p.name: (p.opts[0] if p.opts else p.name) for p in ctx.command.params} if ctx else {}
    for name, value in kwargs.items():
        values = value if isinstance(value, tuple) else (value,)
        for v in values:
            if isinstance(v, str) and unusable_text(v):
                where = opts.get(name) or name
                raise InputError(
                    f"{str(where).upper() if not str(where).startswith('-') else where}: "
                    f"{v!r} holds a NUL character or a lone surrogate, which no file name or "
                    "value may hold"
                )


def _printable(exc: BaseException) -> str:
    """A message any terminal can take: a lone surrogate quoted from the input is escaped
    (written raw, it would fail in the console and leave it unusable)."""
    return str(exc).encode("utf-8", "backslashreplace").decode("utf-8")


def handle_errors(fn: F) -> F:
    """Check text arguments, then turn library errors into one-line messages and the spec's
    exit codes."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            _check_text_arguments(kwargs)
            return fn(*args, **kwargs)
        except InputError as exc:
            # the message may hold brackets (lists of faces): never read it as markup
            err.print(Text.assemble(("error: ", "bold red"), _printable(exc)))
            sys.exit(2)
        except NonprehensileError as exc:
            err.print(Text.assemble(("error: ", "bold red"), _printable(exc)))
            sys.exit(1)
        except OSError as exc:
            # a file the user named cannot be read or written: bad input, not a crash
            where = f"{exc.filename}: " if exc.filename else ""
            err.print(Text.assemble(("error: ", "bold red"), f"{where}{exc.strerror or exc}"))
            sys.exit(2)

    return wrapper  # type: ignore[return-value]


def emit_json(data: Any) -> None:
    """Print one JSON document on stdout."""
    try:
        # strict JSON: a NaN or an infinity would make the document unreadable to others
        text = json.dumps(data, indent=2, allow_nan=False)
    except ValueError as exc:
        raise NonprehensileError(f"the result holds a non-finite number ({exc})") from None
    click.echo(text)


def _bars(transient: bool) -> Progress:
    return Progress(TextColumn("{task.description:<12}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), console=err, transient=transient)


@contextmanager
def progress_bar(label: str, quiet: bool = False) -> Iterator[Callable[[int, int], None]]:
    """One progress bar on stderr, fed by a ``(done, total)`` callback (none when quiet)."""
    if quiet:
        yield lambda done, total: None
        return
    with _bars(transient=True) as bar:
        task = bar.add_task(label, total=None)
        yield lambda done, total: bar.update(task, completed=done, total=total)


@contextmanager
def stage_bars(quiet: bool = False) -> Iterator[Callable[[str, int, int], None]]:
    """A progress bar per stage of a long job, fed by a ``(stage, done, total)`` callback."""
    if quiet:
        yield lambda stage, done, total: None
        return
    with _bars(transient=False) as bar:
        tasks: dict[str, TaskID] = {}

        def update(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        yield update
