"""``nonprehensile dataset``: generate, inspect and draw demonstration datasets.

Registered on the main group by :mod:`nonprehensile.cli`. Progress bars and messages go to
stderr; ``--json`` prints one JSON document on stdout (docs/files.md).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import click
from rich.table import Table

from nonprehensile.cli import HelpGroup
from nonprehensile.cli.common import emit_json, err, handle_errors, out, progress_bar
from nonprehensile.cli.options import count, number
from nonprehensile.demonstrations.dataset import (
    DEFAULT_GAP_LIMIT,
    SCALE_RANGE,
    Dataset,
    check_dataset,
    dataset_path,
    dataset_summary,
)
from nonprehensile.demonstrations.segment import segment_dataset, segments_by_arc
from nonprehensile.demonstrations.synth import (
    DEFAULT_SEED,
    MAX_DROPOUTS,
    MAX_GAP_LIMIT,
    MAX_MENTORS,
    MAX_N_PER_SKILL,
    MAX_NOISE_MM,
    MAX_RATE,
    MAX_SEED,
    MIN_RATE,
    synthesize,
)
from nonprehensile.errors import DemonstrationError

__all__ = ["dataset_group"]


@click.group("dataset", cls=HelpGroup)
def dataset_group() -> None:
    """Demonstration datasets: check and show one, annotate recordings, draw trajectories,
    generate a synthetic one."""


@dataset_group.command("synth")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--seed", type=count(0, MAX_SEED), default=DEFAULT_SEED,
              show_default=True, help="Random seed (the bundled dataset uses the default).")
@click.option("--skills", "skills_file", type=click.Path(dir_okay=False), default=None,
              help="Skills file to demonstrate (default: the bundled cube skills).")
@click.option("--n-per-skill", type=count(1, MAX_N_PER_SKILL), default=30,
              show_default=True,
              help="Demonstrations per skill, shared round-robin among the mentors.")
@click.option("--mentors", type=count(1, MAX_MENTORS), default=3, show_default=True,
              help="Number of mentors (the first three have the documented styles).")
@click.option("--rate", type=number(MIN_RATE, MAX_RATE), default=120.0,
              show_default=True, help="Sampling rate, Hz.")
@click.option("--scale", type=number(*SCALE_RANGE), default=0.05, show_default=True,
              help="Metres per model unit (0.05: a 5 cm cube).")
@click.option("--noise", "noise_mm", type=number(0.0, MAX_NOISE_MM), default=0.5,
              show_default=True, help="Measurement noise (standard deviation), mm.")
@click.option("--dropouts", type=number(0.0, MAX_DROPOUTS), default=0.5,
              show_default=True,
              help="Mean number of marker dropouts per marker and demonstration.")
@click.option("--gap-limit", type=count(0, MAX_GAP_LIMIT), default=DEFAULT_GAP_LIMIT,
              show_default=True,
              help="Longest dropout a loader accepts, frames (dropouts are at most half).")
@click.option("--format", "trajectory_format", type=click.Choice(["c3d", "csv"]),
              default="c3d", show_default=True, help="Trajectory files: C3D or Motive CSV.")
@click.option("--track-object", is_flag=True,
              help="Also track the object: markers on it (and its rigid body in CSV).")
@click.option("--force", is_flag=True,
              help="Replace the dataset already in OUT_DIR (its annotations and recordings).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@handle_errors
def synth_cmd(
    out_dir: str, seed: int, skills_file: str | None, n_per_skill: int, mentors: int,
    rate: float, scale: float, noise_mm: float, dropouts: float, gap_limit: int,
    trajectory_format: str, track_object: bool, force: bool, as_json: bool,
) -> None:
    """Generate a seeded synthetic dataset in OUT_DIR (see docs/dataset.md)."""
    start = time.perf_counter()
    with progress_bar("generating", as_json) as update:
        ds = synthesize(
            out_dir, seed=seed, skills_file=skills_file, n_per_skill=n_per_skill,
            mentors=mentors, rate=rate, scale=scale, noise_mm=noise_mm, dropouts=dropouts,
            gap_limit=gap_limit, trajectory_format=trajectory_format,
            track_object=track_object, progress=update, overwrite=force,
        )
    elapsed = time.perf_counter() - start
    if as_json:
        emit_json({"output": str(Path(out_dir)), "seconds": round(elapsed, 3),
                   **dataset_summary(ds)})
        return
    err.print(f"wrote {_n(len(ds.demonstrations), 'demonstration')} of "
              f"{_n(len(ds.skills), 'skill')} by {_n(len(ds.mentors), 'mentor')} to {out_dir} "
              f"in {elapsed:.2f} s")


def _n(count: int, word: str) -> str:
    """``1 demonstration``, ``2 demonstrations``."""
    return f"{count} {word}{'' if count == 1 else 's'}"


def _show_problems(problems: list[Any], as_json: bool, root: str) -> None:
    if as_json:
        emit_json({"root": root, "problems": [p.to_dict() for p in problems]})
    if len(problems) == 1:  # one line naming the culprit
        from nonprehensile.demonstrations.dataset import headed

        raise DemonstrationError(f"{headed(root, problems[0])}; nothing was loaded")
    lines = "\n".join(f"  - {p}" for p in problems)
    raise DemonstrationError(
        f"{root}: {len(problems)} problem(s) in the dataset, nothing was loaded:\n{lines}"
    )


def _arc_rows(ds: Dataset) -> list[dict[str, Any]]:
    graphs, segments = segment_dataset(ds)
    rows = []
    for arc, segs in segments_by_arc(segments).items():
        step = segs[0].motion
        durations = [s.t_end - s.t_start for s in segs]
        rows.append({
            "maneuver": graphs.graphs[arc.group].graph["maneuver"],
            "group": arc.group,
            "skill": arc.key,
            "from": step.source,
            "to": step.target,
            "label": step.label,
            "segments": len(segs),
            "mean_duration_s": round(sum(durations) / len(durations), 4),
        })
    return rows


@dataset_group.command("show")
@click.argument("directory")
@click.option("--arcs", is_flag=True,
              help="Also segment every demonstration and list the skill-graph arcs.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@handle_errors
def show_cmd(directory: str, arcs: bool, as_json: bool) -> None:
    """Show DIRECTORY (a dataset folder, or `cube` for the bundled one): skills, mentors,
    counts, durations and problems. A dataset with problems lists them all and exits 2."""
    root = dataset_path(directory)
    start = time.perf_counter()
    with progress_bar("loading", as_json) as update:
        ds, problems = check_dataset(root, progress=update)
    if ds is None:
        _show_problems(problems, as_json, str(root))
        return
    summary = dataset_summary(ds)
    for note in ds.notes:
        err.print(f"note: {note}", markup=False)
    summary["load_seconds"] = round(time.perf_counter() - start, 3)
    arc_rows = _arc_rows(ds) if arcs else None
    if arc_rows is not None:
        summary["arcs"] = arc_rows
    if as_json:
        emit_json(summary)
        return
    if not ds.demonstrations:
        out.print(f"[bold]{root}[/]: no demonstrations of its {len(ds.skills)} skills; "
                  "nothing to check")
        return
    out.print(
        f"[bold]{root}[/]: {_n(summary['n_demonstrations'], 'demonstration')} of "
        f"{_n(len(ds.skills), 'skill')} on {summary['object']} (scale {ds.scale:g} m per unit), "
        f"{summary['rate_hz']:g} Hz, markers {', '.join(summary['markers'])} "
        f"({summary['units']}), {100 * summary['occluded_fraction']:.2f} % of samples "
        f"occluded; loaded in {summary['load_seconds']:.2f} s; no problems found; not "
        f"checked: {'; '.join(summary['not_checked'])}"
    )
    t = Table(title="Skills")
    for col in ("skill", "maneuver", "demos", "mentors", "duration s (mean, min-max)"):
        t.add_column(col)
    for s in summary["skills"]:
        d = s.get("duration_s")
        t.add_row(s["name"], s["maneuver"], str(s["count"]),
                  ", ".join(f"{m} {n}" for m, n in s["mentors"].items()),
                  f"{d['mean']:.2f} ({d['min']:.2f}-{d['max']:.2f})" if d else "-")
    out.print(t)
    m = Table(title="Mentors")
    for col in ("mentor", "demos", "duration s (mean, min-max)"):
        m.add_column(col)
    for row in summary["mentors"]:
        d = row["duration_s"]
        m.add_row(row["name"], str(row["count"]),
                  f"{d['mean']:.2f} ({d['min']:.2f}-{d['max']:.2f})")
    out.print(m)
    if arc_rows is not None:
        a = Table(title="Skill-graph arcs and their registered segments")
        for col in ("maneuver", "arc (skill: from -> to)", "label", "segments", "mean s"):
            a.add_column(col)
        for r in arc_rows:
            a.add_row(f"{r['group']} {r['maneuver']}", f"{r['skill']}: {r['from']} -> {r['to']}",
                      r["label"], str(r["segments"]), f"{r['mean_duration_s']:.2f}")
        out.print(a)


@dataset_group.command("figure")
@click.argument("directory")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Image file to write (PNG, SVG or PDF, by suffix).")
@click.option("--skill", "skills", multiple=True,
              help="Skill to draw (repeat; default: the tumbling pair of Fig. 12 where "
                   "demonstrated, else the first demonstrated skill).")
@click.option("--marker", default=None, help="Marker to draw (default: the R1 tip marker).")
@click.option("--color-by", type=click.Choice(["skill", "mentor"]), default="skill",
              show_default=True, help="Colour each trajectory by its skill or its mentor.")
@handle_errors
def figure_cmd(
    directory: str, output: str, skills: tuple[str, ...], marker: str | None, color_by: str
) -> None:
    """Draw the trajectories of skills in 3-D (the paper's Fig. 12(a))."""
    from nonprehensile.demonstrations.dataset import load_dataset
    from nonprehensile.viz.trajectories import trajectory_figure

    ds = load_dataset(dataset_path(directory))
    fig = trajectory_figure(ds, skills or None, marker=marker, color_by=color_by)
    from nonprehensile.viz import save_figure

    save_figure(fig, output)
    err.print(f"wrote {output}")


from nonprehensile.cli.annotate import annotate_cmd  # noqa: E402  (it imports this module's deps)
from nonprehensile.cli.export import export_cmd  # noqa: E402

dataset_group.add_command(annotate_cmd)
dataset_group.add_command(export_cmd)
