"""Every numeric option of every command is checked by one option type (issue 25).

The walk below visits the whole command tree (groups included) and fails on a numeric option
of any type other than :class:`nonprehensile.cli.options.Number`: a new option cannot skip
the check. Then every such option is given NaN, an infinity and a value past its range: each
must be refused at parsing, exit 2, on one line naming the option, what was expected and
what came.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import nonprehensile
from nonprehensile.checks import Range
from nonprehensile.cli import main
from nonprehensile.cli.options import Number


def _commands(cmd: click.Command, path: tuple[str, ...] = ()
              ) -> Iterator[tuple[tuple[str, ...], click.Command]]:
    yield path, cmd
    if isinstance(cmd, click.Group):
        ctx = click.Context(cmd)
        for name in cmd.list_commands(ctx):
            sub = cmd.get_command(ctx, name)
            assert sub is not None, name
            yield from _commands(sub, (*path, name))


def _types(param: click.Parameter) -> list[click.ParamType]:
    t = param.type
    return list(t.types) if isinstance(t, click.Tuple) else [t]


def _numeric(t: click.ParamType) -> bool:
    return isinstance(t, (click.types.IntParamType, click.types.FloatParamType, Number))


ALL = list(_commands(main))
OPTIONS = [(path, p) for path, cmd in ALL for p in cmd.params
           if isinstance(p, click.Option) and any(_numeric(t) for t in _types(p))]


def test_every_numeric_option_uses_the_checker() -> None:
    escaped = [f"{' '.join(path) or 'nonprehensile'} {p.opts[0]}: {type(t).__name__}"
               for path, cmd in ALL for p in cmd.params for t in _types(p)
               if _numeric(t) and not isinstance(t, Number)]
    assert not escaped, "numeric options without the checker (use cli.options.number):\n" \
        + "\n".join(escaped)
    # the walk reaches the commands the issue names (a walk that found nothing would pass)
    names = {(" ".join(path), p.opts[0]) for path, p in OPTIONS}
    for want in [("simulate plan", "--tol-deg"), ("simulate plan", "--position-tol"),
                 ("states", "--angle-tol"), ("plan", "--angle-tol"), ("infer", "--angle-tol"),
                 ("simulate record", "--n-per-skill"), ("dataset annotate", "--min-duration"),
                 ("dataset synth", "--n-per-skill"), ("serve", "--recalibrate-every")]:
        assert want in names, want
    assert len(OPTIONS) >= 80


def _bad_values(rng: Range) -> list[str]:
    out = ["nan", "inf", "-inf"]
    if math.isfinite(rng.high):
        out.append(repr(rng.high * 10 + 1) if not rng.integer else str(int(rng.high) + 1))
    if math.isfinite(rng.low):
        out.append(str(int(rng.low) - 1) if rng.integer else repr(rng.low - 1))
    if rng.low_open:
        out.append(repr(rng.low))
    return out


CASES = [(path, p, i, v) for path, p in OPTIONS for i, t in enumerate(_types(p))
         if isinstance(t, Number) for v in _bad_values(t.range)]


@pytest.mark.parametrize(("path", "param", "i", "value"), CASES,
                         ids=[f"{' '.join(c[0])}{c[1].opts[0]}[{c[2]}]={c[3]}" for c in CASES])
def test_absurd_values_are_refused_at_parsing(path: tuple[str, ...], param: click.Option,
                                              i: int, value: str) -> None:
    n = len(_types(param))
    good = [str(_good(t)) for t in _types(param)]
    given = [*good[:i], value, *good[i + 1:]]
    r = CliRunner().invoke(main, [*path, param.opts[0], *given][: len(path) + 1 + n])
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    line = r.stderr.strip()
    assert line.startswith(f"error: {param.opts[0]}: expected") and value in line, line
    assert r.exception is None or isinstance(r.exception, SystemExit)


def _good(t: click.ParamType) -> float | int:
    assert isinstance(t, Number)
    rng = t.range
    lo = rng.low if math.isfinite(rng.low) else 0
    v = lo + (1 if rng.integer else 1e-3) if rng.low_open else lo
    return int(v) if rng.integer else v


SKILLS = str(Path(nonprehensile.__file__).parent / "data" / "cube_skills.json")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("ds") / "d"
    r = CliRunner().invoke(main, ["dataset", "synth", str(d), "--n-per-skill", "1",
                                  "--format", "csv"])
    assert r.exit_code == 0, r.output
    return d


@pytest.mark.parametrize("argv", [
    ["simulate", "plan", SKILLS, "--from", "a:0", "--to", "d:0", "--step", "90", "--tol-deg",
     "nan"],
    ["simulate", "plan", SKILLS, "--from", "a:0", "--to", "d:0", "--step", "90", "--tol-deg",
     "-1"],
    ["simulate", "plan", SKILLS, "--from", "a:0", "--to", "d:0", "--step", "90",
     "--position-tol", "nan"],
    ["simulate", "plan", SKILLS, "--from", "a:0", "--to", "d:0", "--step", "90",
     "--position-tol", "-1"],
    ["states", "cube", "--step", "90", "--angle-tol", "nan"],
    ["plan", SKILLS, "--from", "a:0", "--to", "d:0", "--step", "90", "--angle-tol", "nan"],
    ["infer", SKILLS, "--step", "90", "--angle-tol", "nan"],
    ["simulate", "record", SKILLS, "{tmp}/out", "--n-per-skill", "4294967296"],
    ["dataset", "annotate", "{data}", "-o", "{tmp}/a.json", "--min-duration", "1e308"],
    ["serve", "--store", "{tmp}/s.db", "--recalibrate-every", "nan"],
])
def test_issue_25_options(argv: list[str], dataset: Path, tmp_path: Path) -> None:
    """The values issue 25 found running (or crashing): each is refused before any work."""
    argv = [a.replace("{tmp}", str(tmp_path)).replace("{data}", str(dataset)) for a in argv]
    r = CliRunner().invoke(main, argv)
    assert r.exit_code == 2, r.output
    line = r.stderr.strip()
    assert line.startswith(f"error: {argv[-2]}: expected ") and "\n" not in line \
        and line.endswith(f"got {argv[-1]!r}"), r.stderr


@pytest.mark.parametrize("args", [
    ["plan", "cube_skills.json", "--from", "a:0", "--to", "zz", "--step", "90"],  # a callback's
    ["plan", "--no-such-option"],
    ["no-such-command"],
    ["--no-such-option"],
    ["object", "show"],  # a missing argument
])
def test_usage_errors_are_one_line(args: list[str]) -> None:
    """click's usage errors (an unknown option or command, a value a callback refuses, a
    missing argument) are one line naming the culprit and the command's --help, exit 2, as
    every other bad input: click's usage text and hint around them made four lines."""
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, (r.exit_code, r.output)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "--help)" in lines[0] and "Traceback" not in r.stderr


def test_a_group_without_a_command_still_shows_its_help() -> None:
    # click's "no arguments: the help" shows itself, not as a one-line error
    r = CliRunner().invoke(main, ["simulate"])
    assert r.exit_code == 2 and r.stderr.startswith("Usage:") and "robustness" in r.stderr
    assert "error:" not in r.stderr


def test_a_usage_error_keeps_its_type_without_standalone_mode() -> None:
    # a program running the command tree without click's standalone mode still catches
    # click's own exception types (BadParameter, NoSuchOption)
    with pytest.raises(click.BadParameter) as got:
        main.main(["maneuvers", "cube", "--from", "zz"], standalone_mode=False)
    assert got.value.param is not None and got.value.param.name == "start"
    with pytest.raises(click.NoSuchOption):
        main.main(["plan", "--no-such-option"], standalone_mode=False)


@pytest.mark.parametrize("theta", ["1e300", "-1e7", "1000000"])
def test_a_state_angle_past_a_million_degrees_is_refused(theta: str) -> None:
    # reduced modulo 360, 1e300 degrees was read as a:0
    r = CliRunner().invoke(main, ["maneuvers", "cube", "--from", f"a:{theta}"])
    assert r.exit_code == 2, r.output
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and "--from" in line and theta in line, r.stderr
    assert CliRunner().invoke(main, ["maneuvers", "cube", "--from", "a:-450"]).exit_code == 0
