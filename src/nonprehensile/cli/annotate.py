"""``nonprehensile dataset annotate``: contact events found from the tracked object and fingers.

Registered on the ``dataset`` group by :mod:`nonprehensile.cli.dataset`. Messages and the
review list go to stderr; ``--json`` prints one JSON document on stdout.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import click
from rich.table import Table

from nonprehensile.cli.common import emit_json, err, handle_errors, out, progress_bar
from nonprehensile.cli.options import number
from nonprehensile.demonstrations.annotate import DetectionParams, annotate_dataset
from nonprehensile.demonstrations.dataset import ANNOTATION_FILES, _annotations_file
from nonprehensile.errors import InputError
from nonprehensile.io import load_document, save_document

__all__ = ["annotate_cmd"]


#: A distance threshold, mm.
_MM = number(0.0, 1000.0, low_open=True, unit="mm")


def _with_kept_recordings(data: Any, kept: Any, root: Path
                          ) -> tuple[Any, list[str], list[str]]:
    """The annotations ``data`` (an earlier run's output) with the recordings of the kept
    list ``kept`` that it does not name added back, and the files added back and those left
    out because they are no longer in the folder ``root``; ``data`` itself when either is not
    an annotations document (the annotator then says what is wrong with it)."""
    if not (isinstance(data, dict) and isinstance(data.get("demonstrations"), list)
            and isinstance(kept, dict) and isinstance(kept.get("demonstrations"), list)):
        return data, [], []
    named = {d.get("file") for d in data["demonstrations"] if isinstance(d, dict)}
    extra, gone = [], []
    for d in kept["demonstrations"]:
        if not isinstance(d, dict) or d.get("file") in named:
            continue
        f = d.get("file")
        if isinstance(f, str) and not (root / f).is_file():
            gone.append(f)  # (deleted since: not a recording to annotate any more)
        else:
            extra.append(d)
    return ({**data, "demonstrations": [*data["demonstrations"], *extra]},
            [str(d.get("file")) for d in extra], gone)


@click.command("annotate")
@click.argument("directory", type=click.Path(file_okay=False))
@click.option("-o", "--output", "output", type=click.Path(dir_okay=False), required=True,
              help="Where to write the complete annotations (in DIRECTORY or a folder holding "
                   "it; name it annotations.json for `dataset show`).")
@click.option("--pad-radius", type=number(0.0, 100.0, unit="mm"), default=0.0, show_default=True,
              help="Distance from a tip marker to the finger's contact surface, mm.")
@click.option("--contact", "contact_mm", type=(_MM, _MM), default=(4.0, 7.0),
              show_default=True, help="Finger contact thresholds ON OFF, mm (hysteresis).")
@click.option("--ground", "ground_mm", type=(_MM, _MM), default=(1.5, 3.0),
              show_default=True, help="Vertex-on-table thresholds ON OFF, mm (hysteresis).")
@click.option("--min-duration", type=number(0.0, 10.0, unit="s"), default=0.05, show_default=True,
              help="Shortest contact state kept, s; shorter ones are flickers.")
@click.option("--state-tol", type=number(0.0, 90.0, low_open=True, unit="degrees"), default=5.0,
              show_default=True,
              help="Tolerance of resting poses against the skills' states, degrees.")
@click.option("--no-fit", is_flag=True,
              help="Time events at the threshold crossings, not by the smooth-onset fit.")
@click.option("--motions", default=None,
              help="A motion library (a dataset folder, or `cube`) whose clusters name the "
                   "skill where skills share their events and states (default: the folder's "
                   "own recordings that name their skill).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@handle_errors
def annotate_cmd(
    directory: str, output: str, pad_radius: float, contact_mm: tuple[float, float],
    ground_mm: tuple[float, float], min_duration: float, state_tol: float, no_fit: bool,
    motions: str | None, as_json: bool,
) -> None:
    """Find the contact events, states and skill of every recording in DIRECTORY.

    DIRECTORY's annotations list the recordings (file, mentor) and the set-up: fingers,
    markers and how the object is tracked ("object": a rigid body or object markers). The
    complete annotations (skill, initial, final, events with times) go to OUTPUT, ready for
    `dataset show` and `demo --dataset`; recordings whose events fit no skill are left out
    and a new skill is proposed for them. Skills with the same events and states are told
    apart by their motion (--motions, or the recordings that name their skill). Every
    doubtful call is listed.
    """
    root = Path(directory)
    dest = Path(output)
    source = _annotations_file(root) if root.is_dir() else None
    gap = 12
    if source is not None:
        data = load_document(source)
        if isinstance(data, dict) and isinstance(data.get("gap_limit"), int):
            gap = data["gap_limit"]
    for opt, (on, off), usual in (("--contact", contact_mm, "4 7"),
                                  ("--ground", ground_mm, "1.5 3")):
        if not off > on:
            raise InputError(f"{opt}: ON must be below OFF (hysteresis: a contact is made below "
                             f"ON mm and broken above OFF mm), got ON {on:g} and OFF {off:g}; "
                             f"for instance {opt} {usual}")
    try:
        params = DetectionParams(
            pad_radius=pad_radius / 1000, contact_on=contact_mm[0] / 1000,
            contact_off=contact_mm[1] / 1000, ground_on=ground_mm[0] / 1000,
            ground_off=ground_mm[1] / 1000, min_duration=min_duration, state_tol=state_tol,
            gap_limit=gap if gap >= 0 else 12, refine=not no_fit,
        )
    except InputError as exc:
        raise InputError(f"bad option: {exc}") from None
    from nonprehensile.naming import MotionNamer

    namer = None
    if motions is not None:
        from nonprehensile.demonstrations.dataset import dataset_path, load_dataset

        with progress_bar("motion library", as_json) as update:
            namer = MotionNamer(load_dataset(dataset_path(motions), progress=update))
    over_input = source is not None and dest.resolve() == source.resolve()
    keep = source.with_name(f"{source.stem}.recordings{source.suffix}") if source else None
    recordings = None
    if over_input and source is not None and keep is not None and keep.is_file():
        # an earlier run wrote over the input and kept the recordings list beside it: the
        # recordings that run left out (they fit no skill then) are annotated again, and the
        # kept list is never replaced by one that lacks them
        recordings, added, gone = _with_kept_recordings(load_document(source),
                                                        load_document(keep), source.parent)
        if added:  # said: a recording removed from the input alone comes back from here
            err.print(f"re-annotating {len(added)} recording(s) of {keep} that {source.name} "
                      f"does not list: {', '.join(added[:10])}"
                      + (" ..." if len(added) > 10 else "")
                      + " (to drop one for good, remove it from both files)", markup=False,
                      highlight=False)
        if gone:
            err.print(f"note: {len(gone)} recording(s) of {keep} are no longer in the folder "
                      f"and are left out: {', '.join(gone[:10])}"
                      + (" ..." if len(gone) > 10 else ""), markup=False, highlight=False)
    with progress_bar("annotating", as_json) as update:
        report = annotate_dataset(root, relative_to=dest.parent, params=params,
                                  progress=update, namer=namer,
                                  namer_from=None if namer is not None else MotionNamer,
                                  annotations=recordings)
    if over_input and keep is not None and source is not None:
        # the input lists recordings the output may leave out: keep it beside
        if recordings is None:
            shutil.copyfile(source, keep)
        else:
            save_document(recordings, keep)
        err.print(f"kept the recordings list as {keep}")
    if dest.name not in ANNOTATION_FILES:
        err.print(f"note: `dataset show` looks for {ANNOTATION_FILES[0]}; {dest.name} is "
                  "read only under that name")
    dest.parent.mkdir(parents=True, exist_ok=True)
    save_document(report.annotations, dest)
    if as_json:
        emit_json({"output": str(dest), **report.to_dict()})
        return
    t = Table(title=f"{root}: {len(report.recordings)} recordings")
    for col in ("file", "mentor", "skill", "states", "events (s)", "doubts"):
        t.add_column(col)
    for r in report.recordings:
        res = r.result
        states = f"{res.initial} -> {res.final}" if res.initial and res.final else "?"
        t.add_row(r.file, r.mentor, res.skill or "[red]none[/]", states,
                  " ".join(f"{e.id}@{e.time:.3f}" for e in res.events),
                  str(len(res.doubts)))
    out.print(t)
    for line in report.doubts:
        err.print(f"doubt: {line}", markup=False)
    for prop in report.proposals:
        err.print(f"proposed skill for {', '.join(prop['recordings'])}:", markup=False)
        err.print_json(data=prop["skill"])
    n_ok = len(report.recordings) - len(report.unmatched)
    err.print(f"wrote {dest}: {n_ok} of {len(report.recordings)} recordings annotated, "
              f"{len(report.unmatched)} fit no skill, {len(report.doubts)} doubtful calls")
