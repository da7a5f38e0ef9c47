"""LeRobot datasets (codebase version v3.0) written and read with pyarrow alone.

LeRobot (Hugging Face's robot-learning library) reads a dataset folder laid out as its own
``LeRobotDataset`` writes it (``lerobot/datasets``: ``utils.py``, ``dataset_metadata.py``,
``dataset_writer.py``, ``compute_stats.py``; ``CODEBASE_VERSION = "v3.0"``)::

    meta/info.json                         codebase_version, fps, features, paths, totals, splits
    meta/stats.json                        per feature: min, max, mean, std, count, q01 ... q99
    meta/tasks.parquet                     task (the pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet   one row per episode: length, tasks, where its
                                           frames are (data/chunk_index, data/file_index,
                                           dataset_from_index, dataset_to_index), stats/...
    data/chunk-000/file-000.parquet        one row per frame, one row group per episode

Frames hold LeRobot's five default features (``timestamp`` float32, ``frame_index``,
``episode_index``, ``index``, ``task_index`` int64), ``observation.state`` (object pose, then
fingertips; float32, components named in ``info.json``), ``observation.markers`` (every
marker that matters, demonstrations only), ``action`` (the fingertip targets) and this
project's labels ``skill_index``, ``event_index`` and ``arc_index`` (int64; -1 for none),
whose label names are the feature's ``labels`` list in ``info.json``. Each episode's row in
``meta/episodes`` also carries its skill, mentor, initial and final states, success and source.

LeRobot is not needed to write or read these files (it pulls torch); pyarrow is, from the
``scale`` extra. ``benchmarks/lerobot_check.py`` opens them with the real ``LeRobotDataset``.
We write by hand only the pandas metadata of ``tasks.parquet`` (so that pandas restores the
task strings as the index, as LeRobot's loader expects) since pandas is not a dependency.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import secrets
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.export.episodes import Episode, check_new_folder

__all__ = [
    "CODEBASE_VERSION",
    "DATA_PATH",
    "EPISODES_PATH",
    "LABEL_FEATURES",
    "LeRobotExport",
    "read_lerobot",
    "write_lerobot",
]

#: The LeRobot dataset format version written (``lerobot.datasets`` ``CODEBASE_VERSION``).
CODEBASE_VERSION = "v3.0"
#: File-path templates of info.json (LeRobot's ``DEFAULT_DATA_PATH`` and episodes path).
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
TASKS_PATH = "meta/tasks.parquet"
#: LeRobot's defaults for its chunking settings (``DEFAULT_CHUNK_SIZE`` and file sizes, MB).
CHUNKS_SIZE, DATA_FILE_MB, VIDEO_FILE_MB = 1000, 100, 200
#: The quantiles LeRobot's stats carry (``DEFAULT_QUANTILES``).
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
#: The label features this project adds, and the Episode attributes they come from.
LABEL_FEATURES = {"skill_index": "skill", "event_index": "event", "arc_index": "arc"}
_DEFAULT_FEATURES = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
_POSE_NAMES = ("object.x", "object.y", "object.z", "object.qx", "object.qy", "object.qz",
               "object.qw")

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LeRobotExport:
    """A LeRobot dataset read back (:func:`read_lerobot`).

    Attributes
    ----------
    root : Path
    info : dict
        ``meta/info.json``.
    stats : dict
        ``meta/stats.json``.
    tasks : list of str
        Indexed by ``task_index``.
    episodes : list of dict
        The rows of ``meta/episodes`` (without their ``stats/`` columns), in episode order.
    frames : dict of str to array
        Every column of the frames, shape (n_frames,) or (n_frames, dim).
    """

    root: Path
    info: dict[str, Any]
    stats: dict[str, Any]
    tasks: list[str]
    episodes: list[dict[str, Any]]
    frames: dict[str, NDArray[Any]]

    def labels(self, feature: str) -> list[str]:
        """The label names of a label feature (``"skill_index"``, ...)."""
        return list(self.info["features"][feature]["labels"])


def _xyz(prefix: str) -> list[str]:
    return [f"{prefix}.{a}" for a in "xyz"]


def _features(episodes: Sequence[Episode], labels: Mapping[str, list[str]]) -> dict[str, Any]:
    first = episodes[0]
    with_object = all(e.object_pose is not None for e in episodes)
    state_names = ([*_POSE_NAMES] if with_object else []) + [
        n for f in first.finger_names for n in _xyz(f)]
    features: dict[str, Any] = {
        "observation.state": {"dtype": "float32", "shape": [len(state_names)],
                              "names": state_names},
    }
    if all(e.markers is not None and e.marker_names == first.marker_names for e in episodes):
        names = [n for m in first.marker_names for n in _xyz(m)]
        features["observation.markers"] = {"dtype": "float32", "shape": [len(names)],
                                           "names": names}
    features["action"] = {"dtype": "float32", "shape": [3 * len(first.finger_names)],
                          "names": [n for f in first.finger_names for n in _xyz(f)]}
    for key in LABEL_FEATURES:
        features[key] = {"dtype": "int64", "shape": [1], "names": None,
                         "labels": list(labels[key])}
    return {**features, **_DEFAULT_FEATURES}


def _stats(values: NDArray[Any]) -> dict[str, list[Any]]:
    """LeRobot's per-feature statistics over frames (``compute_stats.get_feature_stats``);
    quantiles exact (LeRobot estimates them from histograms)."""
    v = np.asarray(values, dtype=np.float64)
    v = v.reshape(len(v), -1)
    out: dict[str, list[Any]] = {
        "min": v.min(axis=0).tolist(), "max": v.max(axis=0).tolist(),
        "mean": v.mean(axis=0).tolist(), "std": v.std(axis=0).tolist(), "count": [len(v)],
    }
    for q in QUANTILES:
        out[f"q{round(q * 100):02d}"] = np.quantile(v, q, axis=0).tolist()
    return out


def _tasks_table(tasks: list[str]) -> pa.Table:
    """``meta/tasks.parquet``: ``task_index`` with the task strings as the pandas index."""
    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()),
                      "task": pa.array(tasks, pa.string())})
    # the pandas metadata (written by pyarrow's from_pandas) that makes pandas restore "task"
    # as the frame's index: LeRobot reads the tasks with pd.read_parquet and takes a task's
    # string as its row's name
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode",
                            "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": None},
            {"name": "task", "field_name": "task", "pandas_type": "unicode",
             "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0",
    }
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


def _fixed(values: NDArray[Any], dtype: pa.DataType) -> pa.Array:
    """A (n, d) array as a fixed-size list column (the Arrow type of LeRobot's vector
    features)."""
    arr = np.ascontiguousarray(values)
    flat = pa.array(arr.reshape(-1), type=dtype)
    return pa.FixedSizeListArray.from_arrays(flat, arr.shape[1])


def write_lerobot(
    episodes: Sequence[Episode],
    out_dir: str | Path,
    *,
    robot_type: str | None = "free_fingertips",
    extra_info: Mapping[str, Any] | None = None,
) -> Path:
    """Write episodes as a LeRobot v3.0 dataset in a new folder.

    Parameters
    ----------
    episodes : sequence of Episode
        At least one, all at one integer frame rate, with the same fingers (and, for
        ``observation.markers``, the same markers); ``observation.state`` holds the object's
        pose only when every episode has it.
    out_dir : str or Path
        The dataset folder to create: it must not exist (as LeRobot's ``create`` refuses an
        existing root), so that nothing is overwritten or mixed.
    robot_type : str or None
        ``info.json``'s ``robot_type``.
    extra_info : mapping, optional
        Facts about the whole export (object, scale, where it came from), written to
        ``meta/nonprehensile.json``: LeRobot drops unknown top-level keys of ``info.json``
        with a warning at every load.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    InputError
        No episodes, the folder exists, frame rates that differ or are not whole numbers
        (LeRobot's ``fps`` is an integer), fingers that differ between episodes.
    """
    root = Path(out_dir)
    if not episodes:
        raise InputError(f"{root}: no episodes to export")
    check_new_folder(root)
    rates = sorted({float(e.fps) for e in episodes})
    fps = rates[0]
    if len(rates) > 1 or fps < 1 or not math.isclose(fps, round(fps), abs_tol=1e-9):
        # (a rate of 1e-30 Hz is within 1e-9 of the whole number 0, which LeRobot divides by)
        raise InputError(f"{root}: LeRobot needs one whole number of frames per second, at "
                         f"least 1; the episodes have {rates} Hz: give --fps N")
    fingers = episodes[0].finger_names
    for e in episodes:
        if e.finger_names != fingers:
            raise InputError(f"{root}: every episode must have the fingers {list(fingers)}; "
                             f"{e.task!r} has {list(e.finger_names)}")
    # the labels of all episodes, in first-seen order; each episode's indices mapped to them
    labels: dict[str, list[str]] = {k: [] for k in LABEL_FEATURES}
    for e in episodes:
        for key, attr in LABEL_FEATURES.items():
            for name in getattr(e, f"{attr}_names"):
                if name not in labels[key]:
                    labels[key].append(name)
    tasks = list(dict.fromkeys(e.task for e in episodes))
    features = _features(episodes, labels)
    with_object = features["observation.state"]["names"][:1] == ["object.x"]
    with_markers = "observation.markers" in features

    columns: dict[str, list[NDArray[Any]]] = {k: [] for k in features}
    ep_rows: list[dict[str, Any]] = []
    start = 0
    for i, e in enumerate(episodes):
        n = e.n_frames
        state = e.fingertips.reshape(n, -1)
        if with_object:
            assert e.object_pose is not None
            state = np.concatenate([e.object_pose, state], axis=1)
        cols: dict[str, NDArray[Any]] = {
            "observation.state": state.astype(np.float32),
            "action": e.action.reshape(n, -1).astype(np.float32),
            "timestamp": e.timestamps.astype(np.float32),
            "frame_index": np.arange(n, dtype=np.int64),
            "episode_index": np.full(n, i, np.int64),
            "index": np.arange(start, start + n, dtype=np.int64),
            "task_index": np.full(n, tasks.index(e.task), np.int64),
        }
        if with_markers:
            assert e.markers is not None
            cols["observation.markers"] = e.markers.reshape(n, -1).astype(np.float32)
        for key, attr in LABEL_FEATURES.items():
            local = getattr(e, attr)
            names = getattr(e, f"{attr}_names")
            lut = np.array([labels[key].index(x) for x in names] + [-1], dtype=np.int64)
            cols[key] = lut[local]  # -1 indexes the appended -1
        for k in features:
            columns[k].append(cols[k])
        row: dict[str, Any] = {
            "episode_index": i, "tasks": [e.task], "length": n,
            "data/chunk_index": 0, "data/file_index": 0,
            "dataset_from_index": start, "dataset_to_index": start + n,
            "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
        }
        for k, v in e.meta.items():
            row[k] = v
        for k in features:
            for stat, value in _stats(cols[k]).items():
                row[f"stats/{k}/{stat}"] = value
        ep_rows.append(row)
        start += n

    # written beside the folder, then renamed: the export appears whole or not at all (a full
    # disk left a cut data file in the folder, which the next export refused as existing)
    # (a fresh name per export, never one another export may be writing: a name made from
    # the process id was shared by two threads, or by two containers' PID 1 on one volume,
    # and one published the other's frames under its own info.json)
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
        tmp = _scratch(root)
    except OSError as exc:
        raise InputError(f"{root}: cannot create the export folder ({exc.filename}: "
                         f"{exc.strerror or exc}); give a new folder inside a folder you can "
                         "write to") from None
    try:
        (tmp / "meta").mkdir()
        # frames: one row group per episode (LeRobot's layout: an episode reads as one group)
        data_path = tmp / DATA_PATH.format(chunk_index=0, file_index=0)
        data_path.parent.mkdir(parents=True)
        arrays = {}
        for k, ft in features.items():
            dtype = pa.float32() if ft["dtype"] == "float32" else pa.int64()
            stacked = np.concatenate(columns[k])
            arrays[k] = _fixed(stacked, dtype) if ft["shape"] != [1] else pa.array(stacked, dtype)
        table = pa.table(arrays)
        with pq.ParquetWriter(data_path, table.schema, compression="snappy") as writer:
            for row in ep_rows:
                writer.write_table(table.slice(row["dataset_from_index"], row["length"]))
        # episodes: every key of every row (null where an episode lacks it)
        keys = list(dict.fromkeys(k for r in ep_rows for k in r))
        ep_table = pa.table({k: [r.get(k) for r in ep_rows] for k in keys})
        ep_path = tmp / EPISODES_PATH.format(chunk_index=0, file_index=0)
        ep_path.parent.mkdir(parents=True)
        pq.write_table(ep_table, ep_path, compression="snappy")
        pq.write_table(_tasks_table(tasks), tmp / TASKS_PATH)
        total = np.concatenate
        stats = {k: _stats(total(columns[k])) for k in features}
        info = {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": robot_type,
            "total_episodes": len(episodes),
            "total_frames": start,
            "total_tasks": len(tasks),
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": DATA_FILE_MB,
            "video_files_size_in_mb": VIDEO_FILE_MB,
            "fps": round(fps),
            "splits": {"train": f"0:{len(episodes)}"},
            "data_path": DATA_PATH,
            "video_path": None,
            "features": features,
        }
        _write_json(tmp / "meta" / "info.json", info)
        _write_json(tmp / "meta" / "stats.json", stats)
        if extra_info:
            _write_json(tmp / "meta" / "nonprehensile.json", dict(extra_info))
        _publish(tmp, root)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):
            raise OSError(exc.errno, f"cannot write the export ({exc.strerror or exc}); nothing "
                          "was written: free space, or give a folder you can write to",
                          str(root)) from None
        raise
    return root


def _scratch(root: Path) -> Path:
    """A new, empty folder beside ``root``, named ``.NAME.partial-`` and 8 random hex digits
    (``.out.partial-3f9a0c12``), made with the user's umask (``tempfile.mkdtemp``'s mode 0700
    became the published dataset's: another user or a training job under another account
    could not read it)."""
    for _ in range(100):
        tmp = root.parent / f".{root.name}.partial-{secrets.token_hex(4)}"
        try:
            tmp.mkdir()
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(errno.EEXIST, "no free scratch folder name", str(root.parent))


def _publish(tmp: Path, root: Path) -> None:
    """Rename the written folder ``tmp`` to ``root``, never onto a folder that appeared there
    meanwhile (an :class:`InputError`; ``tmp`` is left to the caller).

    POSIX ``rename`` replaces an empty folder silently, so ``root`` is claimed first with
    ``mkdir``, which fails if anything is there; the rename then replaces only the empty
    folder this call made."""
    try:
        root.mkdir()
    except FileExistsError:
        raise InputError(f"{root}: a file or folder appeared there while the export was "
                         "written; nothing was written: give another folder, or move that one "
                         "away and export again") from None
    try:
        tmp.rename(root)
    except BaseException as exc:  # (Ctrl-C too: the claimed folder is not left behind)
        with contextlib.suppress(OSError):
            root.rmdir()  # (only ours, and only empty: a folder with anything in it stays)
        if isinstance(exc, OSError) and exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
            # (filled in between: not ours)
            raise InputError(f"{root}: files appeared there while the export was written; "
                             "nothing was written: give another folder") from None
        raise


def _write_json(path: Path, doc: Any) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=2, ensure_ascii=False)
        fh.write("\n")


def read_lerobot(path: str | Path) -> LeRobotExport:
    """Read a LeRobot v3.0 dataset folder (as written by :func:`write_lerobot`, or by LeRobot
    itself without videos or images).

    Raises
    ------
    InputError
        Not a v3.0 dataset folder, or files that disagree with ``info.json``.
    """
    root = Path(path)
    info_path = root / "meta" / "info.json"
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{root}: not a LeRobot dataset folder ({info_path.name}: {exc})"
                         ) from None
    if not isinstance(info, dict) or info.get("codebase_version") != CODEBASE_VERSION:
        got = info.get("codebase_version") if isinstance(info, dict) else None
        raise InputError(f"{root}: codebase_version {got!r}; this reader reads "
                         f"{CODEBASE_VERSION!r}")
    stats_path = root / "meta" / "stats.json"
    stats = json.loads(stats_path.read_text(encoding="utf-8")) if stats_path.is_file() else {}
    try:
        tasks_t = pq.read_table(root / TASKS_PATH)
        ep_t = pq.read_table(sorted((root / "meta" / "episodes").glob("*/*.parquet")))
        data_t = pq.read_table(sorted((root / "data").glob("*/*.parquet")))
    except (OSError, pa.ArrowException) as exc:
        raise InputError(f"{root}: cannot read the dataset's parquet files: {exc}") from None
    order = np.argsort(tasks_t.column("task_index").to_numpy())
    tasks = [tasks_t.column("task").to_pylist()[i] for i in order]
    episodes = [{k: v for k, v in r.items() if not k.startswith("stats/")}
                for r in ep_t.to_pylist()]
    frames: dict[str, NDArray[Any]] = {}
    for name in data_t.column_names:
        col = data_t.column(name).combine_chunks()
        if pa.types.is_fixed_size_list(col.type):
            frames[name] = col.flatten().to_numpy().reshape(len(col), col.type.list_size)
        else:
            frames[name] = col.to_numpy()
    missing = sorted(set(info.get("features", {})) - set(frames))
    if missing:
        raise InputError(f"{root}: info.json's features {missing} are not in the data files")
    if len(data_t) != info.get("total_frames"):
        raise InputError(f"{root}: {len(data_t)} frames in the data files, info.json says "
                         f"{info.get('total_frames')}")
    return LeRobotExport(root, info, stats, tasks, episodes, frames)
