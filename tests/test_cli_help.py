"""The command line explains itself (issue 24 point 7): every command and option described,
group listings not cut, tables whole when piped, docs naming only what ships."""

from __future__ import annotations

import re
from pathlib import Path

import click
from click.testing import CliRunner

import nonprehensile as nph
from nonprehensile.cli import COMMANDS, first_sentence, load_command, main

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _walk(cmd: click.Command, path: list[str]):  # type: ignore[no-untyped-def]
    yield path, cmd
    if isinstance(cmd, click.Group):
        for name, sub in cmd.commands.items():
            yield from _walk(sub, [*path, name])


def test_every_command_and_option_is_described() -> None:
    missing = []
    for name in COMMANDS:
        for path, cmd in _walk(load_command(name), [name]):
            if not (cmd.help or "").strip():
                missing.append(" ".join(path))
            missing += [f"{' '.join(path)} {p.opts[0]}" for p in cmd.params
                        if isinstance(p, click.Option) and not p.hidden
                        and not (p.help or "").strip()]
    assert missing == []


def test_group_help_lists_whole_first_sentences() -> None:
    assert first_sentence("Draw it (the paper's Fig. 12(a)). More.") == \
        "Draw it (the paper's Fig. 12(a))."
    runner = CliRunner()
    for name in COMMANDS:
        group = load_command(name)
        if not isinstance(group, click.Group):
            continue
        text = " ".join(runner.invoke(main, [name, "--help"]).output.split())
        for sub, cmd in group.commands.items():
            want = " ".join(first_sentence(cmd.help or "").split())
            assert f"{sub} {want}" in text, (name, sub)
            assert not want.endswith(("Fig.", "..."))


def test_tables_are_whole_when_piped() -> None:
    # CliRunner's output is not a terminal, as a pipe is not: no column is squeezed or cut
    r = CliRunner().invoke(main, ["maneuvers", "cube", "--from", "a:0"])
    assert r.exit_code == 0, r.output
    head = next(line for line in r.output.splitlines() if "direction (deg)" in line)
    assert len(head) > 80 and "final state" in head and "edge / vertex" in head


def test_docs_name_only_what_ships() -> None:
    for doc in DOCS:
        text = doc.read_text()
        assert "shared/spec" not in text and "files-and-cli.md" not in text, doc.name
        for name in set(re.findall(r"\bnph\.([A-Za-z_][A-Za-z0-9_]*)", text)):
            assert hasattr(nph, name), f"{doc.name} names nph.{name}, which does not exist"
    # the function table of docs/maneuvers.md names the package's own functions
    table = (ROOT / "docs" / "maneuvers.md").read_text().split("## ")[1]
    for name in re.findall(r"^\| `([a-z_]+)\(", table, flags=re.M):
        assert hasattr(nph, name), name
    for src in (ROOT / "src").rglob("*.py"):
        assert "shared/spec" not in src.read_text(), src
