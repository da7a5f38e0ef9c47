"""The ``nonprehensile`` command line: parse, call the library, format.

Every command that prints a result takes ``--json`` and then prints exactly one JSON document
on stdout; messages go to stderr. Exit codes: 0 success, 2 bad input (the message names the
file and the culprit), 1 anything else (docs/files.md).

This package's ``__init__`` imports only :mod:`click`: ``nonprehensile --version`` and
``--help`` must not pay for numpy, scipy, networkx, scikit-learn or matplotlib. Each command
group lives in its own module of this package (``cli/object.py``, ``cli/plan.py``, ...),
imported only when that command runs (or its own ``--help`` is asked for).

How to register a command
-------------------------
Write it in your own module, say ``src/nonprehensile/cli/sim.py``, as a plain click command
or group (``@click.command("simulate")`` / ``@click.group("sim")``; import heavy libraries at
the top of that module or inside the command, as you like). Then add ONE line to
:data:`COMMANDS` below::

    "simulate": ("nonprehensile.cli.sim:simulate_cmd", "Run a plan in the physics simulator."),

The key is the command's name on the command line (it must equal the click command's name),
the first string is ``"module:attribute"``, the second the one-line help that
``nonprehensile --help`` lists without importing the module: the first sentence of the
command's docstring (``tests/test_cli_lazy.py`` checks that both agree). A subcommand of an
existing group (``dataset annotate``) is added in that group's module as usual
(``@dataset_group.command("annotate")``), or registered from another module with
``dataset_group.add_command(...)`` at the end of the group's module.
"""

from __future__ import annotations

import atexit
import functools
import importlib
import inspect
import os
import re
import sys
import threading
from collections.abc import Sequence
from typing import Any, NoReturn

import click

__all__ = ["COMMANDS", "HelpGroup", "LazyGroup", "first_sentence", "main", "one_line", "run"]

#: Command name -> ("module:attribute" of the click command, its one-line help).
COMMANDS: dict[str, tuple[str, str]] = {
    "cluster": ("nonprehensile.cli.cluster:cluster_group",
                "Cluster demonstrated trajectories on a Hilbert-curve index, in a store."),
    "dataset": ("nonprehensile.cli.dataset:dataset_group",
                "Demonstration datasets: check and show one, annotate recordings, draw "
                "trajectories, generate a synthetic one."),
    "demo": ("nonprehensile.cli.demo:demo",
             "The main job: the whole pipeline on a dataset, ending in an HTML report."),
    "infer": ("nonprehensile.cli.infer:infer_cmd",
              "Infer undemonstrated transitions of SKILLS_FILE over a state set (paper "
              "Section V)."),
    "maneuvers": ("nonprehensile.cli.maneuvers:maneuvers_cmd",
                  "Every roll, rotation and tumble of MODEL from a state: what stays on the "
                  "ground (edge or vertex), the direction the object travels, and the final "
                  "state to write in a skill."),
    "object": ("nonprehensile.cli.object:object_group",
               "Object models: show one, or make one from a mesh."),
    "plan": ("nonprehensile.cli.plan:plan_cmd",
             "Plan transitions, contact events and finger motions from --from to --to."),
    "serve": ("nonprehensile.cli.serve:serve_group",
              "Run the demonstration service: mentors upload demonstrations into a PostgreSQL "
              "or SQLite store."),
    "simulate": ("nonprehensile.cli.sim:simulate_group",
                 "Execute demonstrations, inferred transitions and plans in the MuJoCo "
                 "simulation."),
    "skills": ("nonprehensile.cli.skills:skills_group",
               "Demonstrated skills: contact events, motions and skill graphs."),
    "states": ("nonprehensile.cli.states:states_cmd",
               "The stable states of MODEL and their geometric-equivalence classes."),
}


def load_command(name: str) -> click.Command:
    """Import the command registered as ``name`` in :data:`COMMANDS`."""
    target = COMMANDS[name][0]
    module, _, attr = target.partition(":")
    cmd = getattr(importlib.import_module(module), attr)
    if not isinstance(cmd, click.Command):  # pragma: no cover - a registration mistake
        raise TypeError(f"{target} is not a click command")
    return cmd


def unusable_text(text: str) -> bool:
    """Whether ``text`` holds what no file name or value may: a NUL, or a lone surrogate that
    no encoding can write (either fails deep inside a system call with an unrelated error)."""
    if "\x00" in text:
        return True
    try:
        text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:
        return True
    return False


def check_arguments(args: list[str]) -> None:
    """Refuse, before any parsing, an argument no file name or value may hold
    (:func:`unusable_text`)."""
    for i, arg in enumerate(args):
        if unusable_text(arg):
            prev = args[i - 1] if i and args[i - 1].startswith("-") else None
            where = f"the value of {prev}" if prev else f"argument {i + 1}"
            raise click.UsageError(
                f"{where}, {arg!r}, holds a NUL character or a lone surrogate, which no file "
                "name or value may hold"
            )


#: Words ending in a full stop that do not end a sentence ("the paper's Fig. 12").
ABBREVIATIONS = frozenset({"Fig", "Figs", "e.g", "i.e", "cf", "vs", "etc", "Sec", "Eq", "No",
                           "approx"})


def first_sentence(text: str) -> str:
    """The first sentence of a help text, whole (click's own cuts it at "Fig." and at 45
    characters, which left group listings saying "the paper's Fig.")."""
    para = " ".join(inspect.cleandoc(text).split("\n\n")[0].split())
    for m in re.finditer(r"\.(?=\s|$)", para):
        word = para[:m.start()].rsplit(" ", 1)[-1].lstrip("(")
        if word not in ABBREVIATIONS:
            return para[:m.end()]
    return para


class HelpGroup(click.Group):
    """A click group whose ``--help`` lists each command with its whole first sentence."""

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = []
        for name in self.list_commands(ctx):
            cmd = self.get_command(ctx, name)
            if cmd is None or cmd.hidden:
                continue
            rows.append((name, cmd.short_help or first_sentence(cmd.help or "")))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


HelpGroup.group_class = type  # subgroups are HelpGroups too


def _show_one_line(exc: click.UsageError, file: Any = None) -> None:
    """click's usage error (an unknown option, a path option given a folder, a value a
    callback refuses) shown as the library's errors are: one line on stderr, ``error:
    Invalid value for '--to': expected a state written FACE:THETA (e.g. a:90), got 'zz'
    (nonprehensile plan --help)``, exit 2; click's usual usage text and hint around it made
    four lines."""
    where = exc.ctx.command_path if exc.ctx is not None else "nonprehensile"
    click.echo(click.style("error: ", fg="red", bold=True)
               + f"{exc.format_message()} ({where} --help)", file=file, err=file is None)


def one_line(exc: click.UsageError) -> click.UsageError:
    """``exc`` itself (its type, ``param`` and cause kept, for a caller that runs click
    without its standalone mode), shown on one line (:func:`_show_one_line`); an error that
    shows itself its own way (an option value's, ``OptionError``, already one line; click's
    "no arguments: the help") as it was."""
    if type(exc).show is click.UsageError.show:
        exc.show = functools.partial(_show_one_line, exc)  # type: ignore[method-assign]
    return exc


class LazyGroup(HelpGroup):
    """A click group whose commands are imported the first time they are used.

    ``--help`` lists the commands with the one-line help of :data:`COMMANDS` and imports
    nothing; ``nonprehensile NAME ...`` imports NAME's module only. Usage errors anywhere in
    the tree are one line (:func:`one_line`).
    """

    def make_context(self, info_name: str | None, args: list[str],
                     parent: click.Context | None = None, **extra: Any) -> click.Context:
        try:
            return super().make_context(info_name, args, parent, **extra)
        except click.UsageError as exc:  # (this group's own options and arguments)
            one_line(exc)
            raise

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:  # (a command's parsing, and what its callback raises)
            one_line(exc)
            raise

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*COMMANDS, *super().list_commands(ctx)})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.commands or cmd_name not in COMMANDS:
            return super().get_command(ctx, cmd_name)
        cmd = load_command(cmd_name)
        self.add_command(cmd, cmd_name)
        return cmd

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        check_arguments(args)
        return super().parse_args(ctx, args)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = []
        for name in self.list_commands(ctx):
            if name in COMMANDS:
                rows.append((name, COMMANDS[name][1]))
            elif not self.commands[name].hidden:
                cmd = self.commands[name]
                rows.append((name, cmd.short_help or first_sentence(cmd.help or "")))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


@click.group(cls=LazyGroup)
@click.version_option(package_name="nonprehensile")
def main(**_: Any) -> None:
    """Learn nonprehensile manipulation of polyhedral objects from demonstration."""


def run(args: Sequence[str] | None = None) -> NoReturn:
    """The ``nonprehensile`` script (and ``python -m nonprehensile.cli``): :func:`main`, then a
    fast exit.

    When a command has finished, every file it wrote is closed; what is left is to run the
    exit handlers (``atexit``: the C3D reader's worker is stopped and waited for, logging is
    flushed), flush the standard streams, and end. This ends there, with ``os._exit``,
    instead of tearing the interpreter down: freeing every module and object of scipy,
    matplotlib and MuJoCo costs 0.15 to 0.2 s of CPU, about 4 % of ``nonprehensile demo``
    (issue 16; mypy exits the same way). Where a thread other than the main one still runs,
    or a stream cannot be flushed, or a command exits with a message, the exit is Python's
    ordinary one. :func:`main` itself (what tests and programs call) never ends the process.

    OpenBLAS starts with one thread unless the environment chooses (``OPENBLAS_NUM_THREADS``,
    ``GOTO_NUM_THREADS`` or ``OMP_NUM_THREADS`` set): its threads start when numpy and scipy
    load and spin a while waiting for work (0.2 s of CPU at every start on a 2-core machine),
    whereas the library runs its BLAS calls on one thread anyway (``one_thread``: faster for
    its small matrices, and results independent of the thread count).
    """
    if not any(v in os.environ
               for v in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")):
        os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy: the commands import it lazily
    try:
        main(args)
        code: str | int | None = 0
    except SystemExit as exc:
        code = exc.code
    if code is None:
        code = 0
    if not isinstance(code, int) or any(
            t.is_alive() and not t.daemon for t in threading.enumerate()
            if t is not threading.main_thread()):
        sys.exit(code)  # a message to print, or threads to wait for: the ordinary exit
    if sys.stdout is None or sys.stderr is None:
        sys.exit(code)  # started without a standard stream: nothing to flush, the ordinary exit
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed pipe or stream: let Python report it as usual
        sys.exit(code)
    atexit._run_exitfuncs()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):  # pragma: no cover - a handler closed one
        pass
    os._exit(code)

