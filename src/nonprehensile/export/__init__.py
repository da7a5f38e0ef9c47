"""Data out to the robot-learning ecosystem: episodes (:mod:`~nonprehensile.export.episodes`)
from demonstrations (:mod:`~nonprehensile.export.demonstrations`) and simulated executions
(:mod:`nonprehensile.sim.episodes`), written as LeRobot v3.0 datasets
(:mod:`~nonprehensile.export.lerobot`, needs pyarrow: the ``scale`` extra, imported lazily).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from nonprehensile.errors import InputError
from nonprehensile.export.demonstrations import dataset_episodes, demonstration_episode
from nonprehensile.export.episodes import Episode, check_fps, check_new_folder

__all__ = ["FORMATS", "Episode", "dataset_episodes", "demonstration_episode", "export_dataset",
           "write_episodes"]

#: The formats :func:`export_dataset` writes.
FORMATS = ("lerobot",)


def write_episodes(episodes: list[Episode], out_dir: str | Path, *, format: str = "lerobot",
                   **kw: Any) -> Path:
    """Write episodes in a learning-dataset format (``"lerobot"``: LeRobot v3.0).

    Raises
    ------
    InputError
        An unknown format, pyarrow missing, or what the writer refuses (an existing folder).
    """
    if format not in FORMATS:
        raise InputError(f"unknown export format {format!r}; the formats are {list(FORMATS)}")
    try:
        from nonprehensile.export.lerobot import write_lerobot
    except ImportError as exc:  # the extra is missing
        raise InputError(f"the LeRobot export needs pyarrow: pip install 'nonprehensile[scale]' "
                         f"({exc})") from None
    return write_lerobot(episodes, out_dir, **kw)


def export_dataset(
    dataset: str | Path,
    out_dir: str | Path,
    *,
    format: str = "lerobot",
    fps: float | None = None,
    with_object: bool | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[Path, list[Episode]]:
    """Load a dataset folder (or ``"cube"``) and write its demonstrations as a learning
    dataset.

    Parameters
    ----------
    dataset : str or Path
    out_dir : str or Path
        A new folder.
    format : {"lerobot"}
    fps : float, optional
        Frame rate (default: the recordings'); LeRobot needs a whole number.
    with_object : bool, optional
        The object's pose in ``observation.state``: True requires it, False leaves it out,
        None includes it when the dataset tracks the object.

    Returns
    -------
    path : Path
    episodes : list of Episode

    Raises
    ------
    InputError
        A dataset with problems (all listed), an existing ``out_dir``, the object asked for
        and not tracked.
    """
    from nonprehensile.demonstrations.dataset import dataset_path, load_dataset

    fps = check_fps(fps)
    root = Path(out_dir)
    if format not in FORMATS:
        raise InputError(f"unknown export format {format!r}; the formats are {list(FORMATS)}")
    check_new_folder(root)  # before the slow part
    ds = load_dataset(dataset_path(dataset), progress=progress)
    episodes = dataset_episodes(ds, fps=fps, with_object=with_object)
    info = {"source": "dataset", "dataset": str(dataset), "object": ds.poly.name,
            "scale_m_per_unit": ds.scale, "fingers": dict(ds.fingers),
            "skills": [s.name for s in ds.skills]}
    return write_episodes(episodes, root, format=format, extra_info=info), episodes
