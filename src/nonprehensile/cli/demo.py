"""``nonprehensile demo``: the main job, from the command line.

Registered in :data:`nonprehensile.cli.COMMANDS`. This module imports only click, rich and
the light option helpers: ``nonprehensile demo --help`` shows the options without importing
the library (numpy, scipy, networkx: 0.8 s CPU before, issue 16); the job imports it when it
runs.
"""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click

from nonprehensile.cli.common import emit_json, handle_errors, out, stage_bars
from nonprehensile.cli.options import SEED, angle_tol_option, count, json_option, parse_state

if TYPE_CHECKING:
    from nonprehensile.states import State

__all__ = ["DEMO_GOAL", "DEMO_START", "demo"]

#: The default task as typed: :data:`nonprehensile.pipeline.DEFAULT_START` and
#: ``DEFAULT_GOAL`` (the same states; a test keeps them equal), as text so that the help
#: needs no import of the library.
DEMO_START = "b:200"
DEMO_GOAL = "e:110"


def _command_line() -> str | None:
    """The command as typed, when the job runs from the ``nonprehensile`` script."""
    if Path(sys.argv[0]).name != "nonprehensile":
        return None
    return shlex.join(["nonprehensile", *sys.argv[1:]])


@click.command("demo")
@click.option("--out", "out_dir", default="report", show_default=True,
              type=click.Path(file_okay=False), help="Folder of the report and summary.")
@click.option("--dataset", default="cube", show_default=True,
              help="Dataset folder, or the bundled `cube`.")
@click.option("--from", "start", default=DEMO_START, show_default=True,
              callback=parse_state, help="Start state of the task.")
@click.option("--to", "goal", default=DEMO_GOAL, show_default=True,
              callback=parse_state, help="Goal state of the task.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the clustering.")
@click.option("--sweep-samples", type=count(1, 100_000), default=None,
              help="Samples of the physics distribution in the report's robustness sweep "
                   "[default: 200, the sweep the package ships for the default task].")
@click.option("--write-sweep", type=click.Path(dir_okay=False), default=None,
              help="Run the report's robustness sweep afresh and write it to this file with "
                   "its provenance (command, commit, seed); the package ships "
                   "src/nonprehensile/data/demo_sweep.json.")
@click.option("--no-robot", "no_robot", is_flag=True, default=False,
              help="Skip the report's robot section (the plan executed by the bundled Panda: "
                   "its base search and run take a few seconds).")
@angle_tol_option
@json_option
@handle_errors
def demo(out_dir: str, dataset: str, start: State, goal: State, seed: int,
         sweep_samples: int | None, write_sweep: str | None, no_robot: bool,
         angle_tol: float, as_json: bool) -> None:
    """The main job: the whole pipeline on a dataset, ending in an HTML report."""
    from nonprehensile.cli.plan import print_plan
    from nonprehensile.pipeline import run_demo

    t0 = time.perf_counter()
    with stage_bars(as_json) as bars:
        result = run_demo(out_dir, dataset=dataset, start=start, goal=goal, seed=seed,
                          progress=bars, command=_command_line(),
                          sweep_samples=sweep_samples, write_sweep=write_sweep,
                          robot=not no_robot, angle_tol=angle_tol)
    elapsed = time.perf_counter() - t0
    summary = result.summary
    if as_json:
        emit_json({**summary, "report": str(result.report), "summary": str(result.summary_path),
                   "wall_seconds": round(elapsed, 2)})
        return
    inf = summary["inference"]
    out.print(f"object {summary['object']['name']}: {summary['states']['count']} states, "
              f"{inf['transitions']} transitions ({inf['demonstrated']} demonstrated); "
              f"{summary['dataset']['demonstrations']} demonstrations, "
              f"{summary['dataset']['segments']} segments clustered")
    print_plan(summary["plan"])
    out.print(f"report: {result.report.resolve()}")
    out.print(f"summary: {result.summary_path.resolve()}  ({elapsed:.1f} s)")
