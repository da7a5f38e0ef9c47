"""``nonprehensile dataset export``: a dataset as a robot-learning dataset (LeRobot v3.0).

Registered on the ``dataset`` group by :mod:`nonprehensile.cli.dataset`.
"""

from __future__ import annotations

import click

from nonprehensile.cli.common import emit_json, err, handle_errors, progress_bar
from nonprehensile.cli.options import count
from nonprehensile.export import FORMATS, export_dataset
from nonprehensile.export.episodes import summarize

__all__ = ["export_cmd"]


@click.command("export")
@click.argument("directory")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--format", "fmt", type=click.Choice(list(FORMATS)), default="lerobot",
              show_default=True, help="Dataset format: LeRobot v3.0 (parquet).")
@click.option("--fps", type=count(1, 100_000), default=None,
              help="Frames per second, a whole number as LeRobot's (default: the recordings' "
                   "rate); resampled linearly (orientations spherically).")
@click.option("--object/--no-object", "with_object", default=None,
              help="Put the object's pose in observation.state (--object: required, an "
                   "untracked dataset is an error; --no-object: fingertips only). Default: "
                   "when the dataset tracks the object.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")
@handle_errors
def export_cmd(directory: str, out_dir: str, fmt: str, fps: float | None,
               with_object: bool | None, as_json: bool) -> None:
    """Export DIRECTORY (a dataset folder, or `cube`) to OUT_DIR (a new folder) as a
    LeRobot v3.0 dataset: one episode per demonstration, observation.state (object pose
    and fingertips), action (next fingertip targets), skill, contact event and arc labels
    per frame (docs/dataset.md#lerobot-export)."""
    with progress_bar("loading", as_json) as update:
        path, episodes = export_dataset(directory, out_dir, format=fmt, fps=fps,
                                        with_object=with_object, progress=update)
    with_pose = all(e.object_pose is not None for e in episodes)
    doc = {"output": str(path), "format": fmt, "fps": episodes[0].fps,
           "object_pose": with_pose, **summarize(episodes)}
    if as_json:
        emit_json(doc)
        return
    if not with_pose:
        err.print("note: the dataset does not track the object: observation.state holds the "
                  "fingertips only", markup=False)
    err.print(f"wrote {path}: {doc['n_episodes']} episodes, {doc['n_frames']} frames at "
              f"{doc['fps']:g} fps, {len(doc['tasks'])} tasks ({fmt})", markup=False)
