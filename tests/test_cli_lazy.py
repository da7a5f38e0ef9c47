"""The command line imports a command's module only when that command runs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import nonprehensile
from nonprehensile.cli import COMMANDS, load_command, main

HEAVY = ("numpy", "scipy", "networkx", "sklearn", "matplotlib", "yaml", "rich",
         "nonprehensile.geometry", "nonprehensile.planning", "nonprehensile.pipeline")

_PROBE = """
import json, sys
from nonprehensile.cli import main
try:
    main({args!r}, standalone_mode=False)
finally:
    sys.stdout.flush()
    print("\\nMODULES=" + json.dumps(sorted(sys.modules)))
"""


def _modules_after(args: list[str]) -> tuple[str, set[str]]:
    proc = subprocess.run([sys.executable, "-c", _PROBE.format(args=args)],
                          capture_output=True, text=True, timeout=60, check=True)
    text, _, mods = proc.stdout.rpartition("\nMODULES=")
    return text, set(json.loads(mods))


@pytest.mark.parametrize("args", [["--help"], ["--version"]])
def test_help_and_version_import_no_heavy_module(args: list[str]) -> None:
    text, mods = _modules_after(args)
    loaded = sorted(m for m in mods if m.split(".")[0] in HEAVY or m in HEAVY
                    or any(m.startswith(h + ".") for h in HEAVY))
    assert loaded == [], f"{args} imported {loaded[:10]}"
    if args == ["--help"]:
        for name in COMMANDS:
            assert f"  {name} " in text


def test_one_command_imports_only_its_module() -> None:
    _, mods = _modules_after(["object", "--help"])
    assert "nonprehensile.cli.object" in mods
    assert "nonprehensile.cli.plan" not in mods and "sklearn" not in mods
    assert "matplotlib" not in mods


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_registered_commands_match_their_registration(name: str) -> None:
    cmd = load_command(name)
    assert isinstance(cmd, click.Command)
    assert cmd.name == name
    # the help that --help lists without importing is the command's own first sentence
    assert COMMANDS[name][1] == cmd.get_short_help_str(limit=1000)


def test_lazy_group_runs_commands_and_rejects_unknown_ones() -> None:
    runner = CliRunner()
    res = runner.invoke(main, ["states", "cube", "--step", "90", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["n_classes"] >= 1
    res = runner.invoke(main, ["no-such-command"])
    assert res.exit_code == 2 and "No such command" in res.output


def test_package_names_resolve_on_first_use() -> None:
    assert nonprehensile.State.parse("a:90").theta == 90.0
    assert callable(nonprehensile.plan)
    assert "Polyhedron" in dir(nonprehensile)
    with pytest.raises(AttributeError):
        _ = nonprehensile.no_such_name
    for name in nonprehensile.__all__:
        assert getattr(nonprehensile, name) is not None


def test_long_state_tables_are_streamed_with_the_same_content() -> None:
    runner = CliRunner()
    doc = json.loads(runner.invoke(main, ["states", "cube", "--step", "1", "--json"]).output)
    res = runner.invoke(main, ["states", "cube", "--step", "1"])
    assert res.exit_code == 0
    lines = res.output.splitlines()
    assert lines[0] == f"2160 states of cube, {doc['n_classes']} equivalence classes"
    rows = [line.split() for line in lines[2:]]
    assert len(rows) == len(doc["states"]) == 2160
    for (state, face, theta, cls), want in zip(rows, doc["states"], strict=True):
        assert state == f"{want['face']}:{theta}" and face == want["face"]
        assert float(theta) == want["theta"] and int(cls) == want["class"]


def test_demo_help_imports_no_library_module() -> None:
    """``nonprehensile demo --help`` shows its options without importing numpy, scipy or
    the geometry (0.9 s CPU when it did: issue 16), and the defaults it shows are the
    pipeline's task."""
    text, mods = _modules_after(["demo", "--help"])
    heavy = [h for h in HEAVY if h != "rich"]  # rich draws the command's progress bars
    loaded = sorted(m for m in mods if any(m == h or m.startswith(h + ".") for h in heavy))
    assert loaded == [], f"demo --help imported {loaded[:10]}"
    from nonprehensile.cli.demo import DEMO_GOAL, DEMO_START
    from nonprehensile.pipeline import DEFAULT_GOAL, DEFAULT_START

    assert (str(DEFAULT_START), str(DEFAULT_GOAL)) == (DEMO_START, DEMO_GOAL)
    assert f"[default: {DEMO_START}]" in text and f"[default: {DEMO_GOAL}]" in text


def test_option_module_imports_no_numpy() -> None:
    """The options every command shares import click only (their defaults come from
    :mod:`nonprehensile.checks`, the same values the geometry and states use)."""
    code = ("import sys, nonprehensile.cli.options as o, nonprehensile.checks as c; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numpy', 'scipy')))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, check=True)
    assert proc.stdout.strip() == "[]"
    from nonprehensile import checks
    from nonprehensile.geometry.polyhedron import DEFAULT_RTOL
    from nonprehensile.states import DEFAULT_ANGLE_TOL

    assert (DEFAULT_RTOL, DEFAULT_ANGLE_TOL) == (checks.DEFAULT_RTOL, checks.DEFAULT_ANGLE_TOL)


def test_demo_parses_its_task_in_a_fresh_process() -> None:
    """The demo parses --from/--to before anything else imports the library, so the states
    module is the first of it imported: it must not import itself back through the geometry
    (a circular import that failed `nonprehensile demo` outright)."""
    probe = ("from nonprehensile.cli import main\n"
             "main(['demo', '--from', 'a:x'], standalone_mode=True)\n")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "FACE:THETA" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run([sys.executable, "-c", "import nonprehensile.states"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


_RUN = """
import atexit, sys, threading, time
from pathlib import Path
from nonprehensile.cli import run
out = Path(sys.argv[1])
atexit.register(lambda: (out / "atexit").write_text("ran"))
if sys.argv[2] == "thread":
    def late() -> None:
        time.sleep(0.3)
        (out / "thread").write_text("ran")
    threading.Thread(target=late).start()
run(sys.argv[3:])
"""


def test_script_exit_keeps_code_output_exit_handlers_and_threads(tmp_path: Path) -> None:
    """The script's fast exit (no interpreter teardown: issue 16) keeps the exit code and
    every byte of the output, runs the exit handlers (the one that stops the C3D worker is
    registered the same way), and
    where another thread still runs it waits for it, as Python's own exit does."""
    def script(mode: str, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-c", _RUN, str(tmp_path), mode, *args],
                              capture_output=True, text=True, timeout=60)

    done = script("plain", "states", "cube", "--step", "5", "--json")
    assert done.returncode == 0, done.stderr
    expected = CliRunner().invoke(main, ["states", "cube", "--step", "5", "--json"]).output
    assert done.stdout == expected and len(json.loads(done.stdout)["states"]) > 400
    assert (tmp_path / "atexit").read_text() == "ran"
    (tmp_path / "atexit").unlink()
    bad = script("plain", "states", "no-such-model", "--step", "90")
    assert bad.returncode == 2 and bad.stderr.startswith("error:")
    assert (tmp_path / "atexit").read_text() == "ran"
    waited = script("thread", "--version")
    assert waited.returncode == 0 and "version" in waited.stdout
    assert (tmp_path / "thread").read_text() == "ran"


_BLAS = """
import json, os, sys
import nonprehensile.cli as cli

def probe(args=None):
    import numpy  # noqa: F401  (loads OpenBLAS as a command would)
    from threadpoolctl import threadpool_info
    print(json.dumps([p["num_threads"] for p in threadpool_info()
                      if p["internal_api"] == "openblas"]))

cli.main = probe
cli.run([])
"""


@pytest.mark.parametrize(("env", "threads"), [({}, {1}), ({"OMP_NUM_THREADS": "2"}, {2}),
                                              ({"OPENBLAS_NUM_THREADS": "2"}, {2})])
def test_script_starts_openblas_on_one_thread_unless_the_environment_chooses(
    env: dict[str, str], threads: set[int],
) -> None:
    """Idle OpenBLAS threads spin at start-up (0.2 s of CPU a command: issue 16); the user's
    own choice of thread count is kept."""
    clean = {k: v for k, v in os.environ.items()
             if k not in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")}
    proc = subprocess.run([sys.executable, "-c", _BLAS], capture_output=True, text=True,
                          timeout=60, env={**clean, **env}, check=True)
    assert set(json.loads(proc.stdout)) == threads


def test_script_started_without_stdout_exits_cleanly() -> None:
    """A closed standard output (``>&-``) leaves ``sys.stdout`` None: the script's fast exit
    takes the ordinary exit then, rather than a traceback on flushing it."""
    proc = subprocess.run(["sh", "-c", f'"{sys.executable}" -m nonprehensile.cli --version >&-'],
                          capture_output=False, stderr=subprocess.PIPE, text=True, timeout=60)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr
