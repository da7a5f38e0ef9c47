"""The main job: the whole pipeline on a dataset, ending in a report (``nonprehensile demo``).

Object model and stable states, skills, inference to the expanded state-transition graph,
incremental clustering of every demonstrated motion segment, and a plan between two states that
were never demonstrated, with reference finger motions; written as a self-contained HTML report
(``index.html``, images embedded) and a JSON summary (``summary.json``).

This module runs the job; the report's composition (its sections, drawn from what the job
computed) is :mod:`nonprehensile.viz.demo_report`. It sits at the edge of the package (it
writes files); the CLI calls it and shows its progress.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pickle
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nonprehensile.demonstrations.dataset import Dataset, load_dataset
from nonprehensile.demonstrations.segment import Segment, segment_dataset
from nonprehensile.equivalence import equivalence_classes
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.geometry.symmetry import rotation_group
from nonprehensile.inference import cross_check, expand
from nonprehensile.io import write_text_file
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.microcluster import one_thread
from nonprehensile.planning import Plan, plan
from nonprehensile.references import ClusteredMotions, flatten_segments
from nonprehensile.skills.skill import Skill
from nonprehensile.states import DEFAULT_ANGLE_TOL, State, stable_faces, states_by_step

__all__ = [
    "DemoResult",
    "adjusted_rand_index",
    "cluster_segments",
    "motions_from_dataset",
    "run_demo",
    "write_plan_motions",
]

#: Fewest segments on an arc for it to be clustered (fewer make one cluster).
MIN_CLUSTERED = 6

#: ``progress(stage, done, total)``: the CLI turns it into progress bars.
StageProgress = Callable[[str, int, int], None]

#: The default task: neither state was demonstrated; the start lies 20 degrees off the model's
#: orientations and away from the origin, so the agent must be relocated (Section VII, step 1).
DEFAULT_START = State("b", 200.0)
DEFAULT_GOAL = State("e", 110.0)
DEFAULT_POSITION = (0.30, 0.10)


def adjusted_rand_index(a: Sequence[Any] | np.ndarray[Any, Any],
                        b: Sequence[Any] | np.ndarray[Any, Any]) -> float:
    """Adjusted Rand index of two labelings of the same samples (1: the same partition).

    scikit-learn's ``adjusted_rand_score`` by its pair-confusion formula, in exact integers,
    without importing scikit-learn (0.9 s, a fifth of the demo's budget: issue 16).
    """
    if len(a) != len(b):
        raise ValueError(f"labelings of {len(a)} and {len(b)} samples")
    _, ia = np.unique(np.asarray(a).ravel(), return_inverse=True)
    _, ib = np.unique(np.asarray(b).ravel(), return_inverse=True)
    table = np.zeros((int(ia.max(initial=-1)) + 1, int(ib.max(initial=-1)) + 1), dtype=np.int64)
    np.add.at(table, (ia.ravel(), ib.ravel()), 1)
    n = len(a)
    squares = int((table * table).sum())
    fp = int((table @ table.sum(axis=0)).sum()) - squares
    fn = int((table.T @ table.sum(axis=1)).sum()) - squares
    tp = squares - n
    tn = n * n - fp - fn - squares
    if fn == 0 and fp == 0:
        return 1.0
    return 2.0 * (tp * tn - fn * fp) / ((tp + fn) * (fn + tn) + (tp + fp) * (fp + tn))


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("nonprehensile")
    except PackageNotFoundError:  # pragma: no cover - run from a source tree
        from nonprehensile import __version__

        return __version__


def _quiet(stage: str, done: int, total: int) -> None:
    del stage, done, total


@dataclass(frozen=True)
class DemoResult:
    """What the main job produced: its summary, and where the report and summary are."""

    summary: dict[str, Any]
    report: Path
    summary_path: Path


def cluster_segments(
    segments: list[Segment],
    *,
    batch: int = 10,
    seed: int = 0,
    progress: StageProgress = _quiet,
) -> tuple[ClusteredMotions, list[dict[str, Any]]]:
    """Cluster the segments of every arc (pair of contact events) incrementally.

    Segments between the same two contact events are clustered together, whatever skill made
    them: parallel arcs of a skill graph (the paper's skills 2 and 3, or the two tumbling
    skills of Fig. 9) are told apart by their motion alone, as in the paper's Fig. 12: where
    several skills share an arc, the clusterer is asked for as many clusters as skills; where
    one skill has the arc to itself, it chooses the number (the mentors' styles). Each arc's
    segments are streamed into a :class:`HilbertClusterer` ``batch`` at a time, in the
    dataset's order (skill after skill: a new skill arrives as new data would).

    Every segment must have the same markers (the vectors of all arcs form one array).

    Cost: on the bundled cube (660 segments, 14 arcs) about 1 s of CPU: the clusterer's
    207 macro steps, 65 of them searches (the others refit the chosen mixture), the
    projection's 58 recalibrations, and the resampling of every segment (all at once:
    segments of one length share a spline). The pipeline takes the clusterer's defaults;
    the macro step's schedule is the motion model's to tune (``docs/motion-model.md``).

    Returns
    -------
    motions : ClusteredMotions
        Every segment with its cluster (clusters numbered per arc).
    arcs : list of dict
        Per arc: the segments' rows and the fitted clusterer (``rows``, ``clusterer``: not
        JSON), the skills on it, the number of segments and clusters, and, when several skills
        share the arc, the adjusted Rand index of the clusters against the skills.
    """
    by_pair: dict[tuple[int, Any, Any], list[int]] = {}
    for i, s in enumerate(segments):
        by_pair.setdefault((s.arc.group, s.arc.source, s.arc.target), []).append(i)
    labels = np.zeros(len(segments), dtype=np.int64)
    # every segment at once: segments of the same length share one spline
    vectors = flatten_segments(segments) if segments else np.zeros((0, 0))
    arcs = []
    total = sum(len(v) for v in by_pair.values())
    done = 0
    for (group, _, _), rows in by_pair.items():
        x = vectors[rows]
        n_skills = len({segments[i].skill for i in rows})
        clusterer = None
        if len(rows) >= max(n_skills + 1, MIN_CLUSTERED):
            clusterer = HilbertClusterer(n_skills if n_skills > 1 else None, random_state=seed)
        if clusterer is None:
            # too few demonstrations on this arc to cluster: one cluster, still a medoid
            streamed = found = np.zeros(len(rows), dtype=np.int64)
            done += len(rows)
            progress("clustering", done, total)
        else:
            for start in range(0, len(rows), batch):
                clusterer.partial_fit(x[start:start + batch])
                done += min(batch, len(rows) - start)
                progress("clustering", done, total)
            # no closing recalibration: the clusters as the stream left them (current
            # labels), and the ids each segment got when it arrived (scored too)
            streamed = np.asarray(clusterer.labels_registered_, dtype=np.int64)
            found = np.asarray(clusterer.labels_, dtype=np.int64)
        # clusters numbered 1, 2, ... on each arc in the order of their first segment: the
        # numbers the report's histograms and the plan show (the clusterer's own ids are
        # arbitrary, and differ from arc to arc)
        first_seen = {c: k for k, c in enumerate(dict.fromkeys(found.tolist()), start=1)}
        found = np.array([first_seen[c] for c in found.tolist()], dtype=np.int64)
        labels[rows] = found
        skills = [segments[i].skill for i in rows]
        first = segments[rows[0]]
        entry: dict[str, Any] = {
            "rows": rows,
            "clusterer": clusterer,
            "group": group,
            "from": first.motion.source,
            "to": first.motion.target,
            "skills": sorted(set(skills)),
            "segments": len(rows),
            "clusters": len(set(found.tolist())),
            "labels": sorted({s.motion.label for s in (segments[i] for i in rows)}),
        }
        styles = [f"{segments[i].skill}/{segments[i].mentor}" for i in rows]
        if len(set(skills)) > 1:
            entry["ari_vs_skill"] = float(adjusted_rand_index(skills, found))
            entry["ari_vs_skill_as_streamed"] = float(adjusted_rand_index(skills, streamed))
        # mentors move in their own styles: clusters that split a skill by mentor are right
        entry["ari_vs_skill_and_mentor"] = float(adjusted_rand_index(styles, found))
        arcs.append(entry)
    return ClusteredMotions(segments, labels, vectors), arcs


def motions_from_dataset(
    dataset: str | Path,
    *,
    skills: Sequence[Skill] | None = None,
    poly: Polyhedron | None = None,
    seed: int = 0,
    progress: StageProgress = _quiet,
    cache: str | Path | bool | None = True,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> tuple[Dataset, ClusteredMotions]:
    """Load a dataset, segment it and cluster its motions: the planner's reference motions.

    When ``skills`` (and ``poly``) are given, the dataset's demonstrations must be of that
    object, and a skill it shares with them by name must be the same skill: a reference motion
    is only meaningful for the skill it shows. (Skills it does not demonstrate simply get no
    reference motion.)

    The result is built once per dataset and kept in a cache folder (``cache``: a folder,
    True for :func:`cache_dir`, False for none). It is keyed by the size and modification
    time of every file in the dataset folder, the seed, the package version and ``angle_tol``
    (the dataset's skills and states are read at it), so a changed, added or removed file, or
    another tolerance, rebuilds it.

    Raises
    ------
    InputError
        Another object, or a skill of the same name demonstrated differently.
    """
    folder = cache_dir() if cache is True else (Path(cache) if cache else None)
    cached = _cached_motions(dataset, seed, folder, angle_tol)
    if cached is not None:
        ds, motions = cached
        progress("loading", 1, 1)
        _check_same_model(dataset, ds, skills, poly)
        return ds, motions
    ds = load_dataset(dataset, progress=lambda d, n: progress("loading", d, n),
                      angle_tol=angle_tol)
    _check_same_model(dataset, ds, skills, poly)
    _, segments = segment_dataset(ds)
    with one_thread():
        motions, _ = cluster_segments(segments, seed=seed, progress=progress)
    _store_motions(dataset, seed, folder, (ds, motions), angle_tol)
    return ds, motions


#: Bumped when what the cache holds changes shape, or when the clusterer's defaults change the
#: clusters it builds (2: issue 14's macro-step schedule and components), so that a library
#: cached by an older clustering is rebuilt even though the dataset's files did not change
#: (3: macro steps between searches refit the chosen mixture; 4: every recording's markers in
#: the dataset's one order, so a library built from files of mixed orders is rebuilt; 5: the
#: library's class moved to nonprehensile.references, which old pickles do not name).
_CACHE_FORMAT = "motions/5"


def cache_dir() -> Path:
    """Where built motion libraries are kept: ``$NONPREHENSILE_CACHE``, else
    ``$XDG_CACHE_HOME/nonprehensile``, else ``~/.cache/nonprehensile``."""
    env = os.environ.get("NONPREHENSILE_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "nonprehensile"


def _dataset_key(dataset: str | Path, seed: int,
                 angle_tol: float = DEFAULT_ANGLE_TOL) -> str | None:
    """A digest of every file of the dataset folder (path, size, mtime), the seed, the
    versions and the angle tolerance it is read at; None when the folder cannot be listed."""
    from nonprehensile.demonstrations.dataset import dataset_path

    try:
        root = dataset_path(dataset).resolve()
        entries = sorted(
            (str(p.relative_to(root)), p.stat().st_size, p.stat().st_mtime_ns)
            for p in root.rglob("*") if p.is_file()
        )
    except (OSError, InputError):
        return None
    parts: tuple[Any, ...] = (_CACHE_FORMAT, _version(), str(root), seed, MIN_CLUSTERED,
                              entries)
    # the dataset's skills and states are checked (and a skill's maneuver classified) at this
    # tolerance: a library read at another must not stand in for this one. Only a tolerance
    # other than the default joins the key, so libraries kept at the default stay valid
    if angle_tol != DEFAULT_ANGLE_TOL:
        parts += (("angle_tol", float(angle_tol)),)
    h = hashlib.sha256(repr(parts).encode())
    return h.hexdigest()[:32]


def _cached_motions(dataset: str | Path, seed: int, folder: Path | None,
                    angle_tol: float = DEFAULT_ANGLE_TOL
                    ) -> tuple[Dataset, ClusteredMotions] | None:
    if folder is None:
        return None
    key = _dataset_key(dataset, seed, angle_tol)
    path = folder / f"motions-{key}.pickle"
    if key is None or not path.is_file():
        return None
    try:
        with path.open("rb") as fh:
            # our own cache file, written by _store_motions below (a folder the user owns)
            value = pickle.load(fh)
    except Exception:  # a damaged or stale cache (any unpickling error) is rebuilt
        return None
    if (not isinstance(value, tuple) or len(value) != 2
            or not isinstance(value[0], Dataset) or not isinstance(value[1], ClusteredMotions)):
        return None
    return value


def _store_motions(dataset: str | Path, seed: int, folder: Path | None,
                   value: tuple[Dataset, ClusteredMotions],
                   angle_tol: float = DEFAULT_ANGLE_TOL) -> None:
    key = _dataset_key(dataset, seed, angle_tol) if folder is not None else None
    if folder is None or key is None:
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".motions-", suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, folder / f"motions-{key}.pickle")  # atomic: readers see all or none
    except OSError:
        # a read-only or full cache folder only costs the next call its time
        with contextlib.suppress(OSError, UnboundLocalError):
            os.unlink(tmp)


def _check_same_model(dataset: str | Path, ds: Dataset, skills: Sequence[Skill] | None,
                      poly: Polyhedron | None) -> None:
    if poly is not None and (poly.faces != ds.poly.faces
                             or poly.vertices.shape != ds.poly.vertices.shape
                             or not np.allclose(poly.vertices, ds.poly.vertices)):
        raise InputError(
            f"{dataset}: its demonstrations are of object {ds.poly.name!r}, not of the skills "
            f"file's {poly.name!r} (their models differ)"
        )
    known = {s.name: s for s in ds.skills}
    for s in skills or ():
        theirs = known.get(s.name)
        if theirs is not None and (theirs.initial, theirs.final, theirs.events) != (
                s.initial, s.final, s.events):
            raise InputError(
                f"{dataset}: skill {s.name!r} is demonstrated there differently (its states "
                "or contact events differ from the skills file's)"
            )


def write_plan_motions(result: Plan, out_dir: str | Path) -> list[Path]:
    """Write each step's reference trajectories as C3D and CSV files (world frame, metres),
    and ``plan.json`` (the plan with the object's pose before and after each step).

    Files are named ``stepNN-ARC.c3d`` / ``.csv`` with ``ARC`` the motion's two events. Each
    is written in its format's usual convention, the one our readers assume by default, so it
    reads back to the same positions: C3D ``z`` up, and the CSV Motive's layout with Motive's
    ``y`` up, so that Motive and any tool that reads Motive exports read it as Motive would.

    Returns
    -------
    list of Path
        The files written.
    """
    from nonprehensile.demonstrations.formats import write_c3d, write_motive_csv
    from nonprehensile.demonstrations.record import MarkerTrajectory

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for i, step in enumerate(result.steps, start=1):
        for source, target, _, ref in step.motions:
            if ref is None:
                continue
            traj = MarkerTrajectory.from_arrays(ref.positions, ref.marker_names, ref.rate, "m")
            stem = out / f"step{i:02d}-{source}-{target}"
            write_c3d(traj, stem.with_suffix(".c3d"))
            write_motive_csv(traj, stem.with_suffix(".csv"),
                             take_name=f"step {i} {step.transition.skill.name} {source}->{target}")
            written += [stem.with_suffix(".c3d"), stem.with_suffix(".csv")]
    # the plan itself, with the object's tracked pose before and after every step, so that a
    # controller knows where each step's reference motion expects the object
    doc = out / "plan.json"
    write_text_file(doc, json.dumps(result.to_dict(), indent=1) + "\n")
    written.append(doc)
    return written


#: The report's robot section when the job was asked to skip it (``demo --no-robot``).
ROBOT_SKIPPED = "skipped (--no-robot)"


def _physics_runs(ds: Dataset, exp: Any, result: Plan, motions: ClusteredMotions,
                  states: Sequence[State], *, seed: int, folder: Path | None,
                  samples: int | None, write_sweep: str | Path | None,
                  progress: StageProgress, command: str, robot: bool = True
                  ) -> dict[str, Any]:
    """The report's robustness sweep and robot execution (:mod:`nonprehensile.sim.report_runs`),
    each as its document or ``{"error": why}`` (no ``sim`` or ``robot`` extra, no plan)."""
    runs: dict[str, Any] = {}
    if not result.steps:
        return {"sweep": {"error": "the plan has no step"},
                "robot": {"error": "the plan has no step"}}
    try:
        from nonprehensile.sim import report_runs
    except ImportError as exc:
        why = f"the simulation needs the `sim` extra: pip install 'nonprehensile[sim]' ({exc})"
        return {"sweep": {"error": why}, "robot": {"error": why}}
    from nonprehensile.errors import NonprehensileError

    del seed  # the clustering's seed: the sweep has its own (DEMO_SWEEP_SEED)
    try:
        runs["sweep"] = report_runs.plan_sweep(
            ds.poly, exp, result, motions, scale=ds.scale, fingers=ds.fingers,
            skills=list(ds.skills), samples=samples or report_runs.DEMO_SWEEP_SAMPLES,
            cache=folder, write=Path(write_sweep) if write_sweep else None,
            command=command, progress=lambda d, n: progress("robustness sweep", d, n))
    except NonprehensileError as exc:
        if write_sweep:  # asked for the file: its failure is the command's
            raise
        runs["sweep"] = {"error": str(exc)}
    if not robot:
        runs["robot"] = {"error": ROBOT_SKIPPED}
        return runs
    progress("robot", 0, 1)
    try:  # an ImportError past mink's own check: a part of the extra missing

        runs["robot"] = report_runs.robot_execution(
            ds.poly, result, motions, scale=ds.scale, fingers=ds.fingers,
            skills=list(ds.skills), states=states, cache=folder, angle_tol=exp.angle_tol)
    except NonprehensileError as exc:
        runs["robot"] = {"error": str(exc)}
    except ImportError as exc:
        runs["robot"] = {"error": f"robot arms need mink: pip install 'nonprehensile[robot]' "
                                  f"({exc})"}
    progress("robot", 1, 1)
    return runs


@one_thread()  # BLAS on one thread for the whole job: steady on a busy machine (issue 16)
def run_demo(
    out_dir: str | Path = "report",
    *,
    dataset: str | Path = "cube",
    start: State = DEFAULT_START,
    goal: State = DEFAULT_GOAL,
    position: tuple[float, float] = DEFAULT_POSITION,
    step: float = 90.0,
    seed: int = 0,
    progress: StageProgress = _quiet,
    command: str | None = None,
    cache: str | Path | bool | None = True,
    sweep_samples: int | None = None,
    write_sweep: str | Path | None = None,
    robot: bool = True,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> DemoResult:
    """Run the whole pipeline on a dataset and write the report.

    Parameters
    ----------
    out_dir : str or Path
        Folder of the report (``index.html``) and the JSON summary (``summary.json``).
    dataset : str or Path
        A dataset folder, or ``"cube"`` for the bundled one.
    start, goal : State
        The task; neither needs to be a demonstrated state.
    position : (float, float)
        Where the object is on the table, in metres.
    step : float
        Orientation step of the state set (the paper's example: 90).
    seed : int
        Seed of the clustering's random choices.
    progress : callable
        ``progress(stage, done, total)``.
    command : str, optional
        The command line that ran the job, written on the report (default: the equivalent
        ``nonprehensile demo`` command).
    cache : str, Path or bool
        Where the physics runs too slow to repeat are kept (the plan's robustness sweep, its
        execution by the Panda: :mod:`nonprehensile.sim.report_runs`): a folder, True for
        :func:`cache_dir`, False for none.
    sweep_samples : int, optional
        Samples of the report's robustness sweep (default
        :data:`~nonprehensile.sim.report_runs.DEMO_SWEEP_SAMPLES`; the package ships that
        sweep for the default task).
    write_sweep : str or Path, optional
        Run the robustness sweep afresh and write it here with its provenance (the file the
        package ships is ``src/nonprehensile/data/demo_sweep.json``).
    robot : bool
        Execute the plan by the bundled Panda for the report's robot section (False: the
        section says it was skipped; the rest of the job is the same).
    angle_tol : float
        Angle tolerance in degrees for matching states (``--angle-tol``): the dataset's
        skills and states, the expansion, the plan and its re-plans. A model from a mesh
        carries its file's rounding and needs more than the default (``docs/planning.md``).

    Returns
    -------
    DemoResult

    Raises
    ------
    InputError
        A dataset that does not load, or holds no demonstration; a task or option out of
        range.
    """
    if write_sweep is not None:  # before any work: the sweep is written at the end
        try:
            from nonprehensile.sim.report_runs import check_writable
        except ImportError as exc:
            raise InputError(f"--write-sweep runs the sweep in MuJoCo: pip install "
                             f"'nonprehensile[sim]' ({exc})") from None
        check_writable(Path(write_sweep))
    times: dict[str, float] = {}
    t0 = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal t0
        now = time.perf_counter()
        times[name] = round(now - t0, 3)
        t0 = now

    ds: Dataset = load_dataset(dataset, progress=lambda d, n: progress("loading", d, n),
                               angle_tol=angle_tol)
    if not ds.demonstrations:  # refused before the physics runs, not at the report's figures
        raise InputError(f"{dataset}: the dataset has no demonstration, and the main job "
                         "learns its motions from demonstrations; add recordings to its "
                         "annotations (`nonprehensile dataset annotate` finds their events)")
    poly, skills = ds.poly, list(ds.skills)
    lap("load")
    states = states_by_step(poly, step)
    classes = equivalence_classes(poly, states, angle_tol=angle_tol)
    exp = expand(poly, skills, states, angle_tol=angle_tol)
    disagreements = cross_check(poly, skills, states, angle_tol=angle_tol)
    lap("inference")
    graphs, segments = segment_dataset(ds)
    lap("segmentation")
    motions, arcs = cluster_segments(segments, seed=seed, progress=progress)
    lap("clustering")
    result: Plan = plan(poly, exp, start, goal, position=position, motions=motions,
                        scale=ds.scale, angle_tol=angle_tol)
    lap("planning")
    folder = cache_dir() if cache is True else (Path(cache) if cache else None)
    runs = _physics_runs(ds, exp, result, motions, states, seed=seed, folder=folder,
                         samples=sweep_samples, write_sweep=write_sweep, progress=progress,
                         command=command or f"nonprehensile demo --dataset {dataset} "
                                            f"--from {start} --to {goal}", robot=robot)
    lap("physics runs")

    summary: dict[str, Any] = {
        "object": {"name": poly.name, "faces": len(poly.faces),
                   "stable_faces": stable_faces(poly),
                   "symmetry_order": len(rotation_group(poly))},
        "states": {"step": step, "count": len(states), "classes": max(classes) + 1},
        "skills": [s.name for s in skills],
        "inference": {
            "transitions": len(exp.transitions),
            "demonstrated": sum(t.demonstrated for t in exp.transitions),
            "paper_method_disagreements": len(disagreements),
        },
        "dataset": {"demonstrations": len(ds.demonstrations), "mentors": list(ds.mentors),
                    "segments": len(segments)},
        "clustering": [{k: v for k, v in a.items() if k not in ("rows", "clusterer")}
                       for a in arcs],
        "plan": result.to_dict(),
        "seconds": times,
    }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meta = [("nonprehensile", _version()), ("seed", str(seed)),
            ("command", command or f"nonprehensile demo --dataset {dataset} --from {start} "
                                   f"--to {goal} --seed {seed}"),
            ("dataset", str(ds.root or dataset))]
    summary["meta"] = dict(meta)
    from nonprehensile.viz.demo_report import ReportContext, write_demo_report

    ctx = ReportContext(ds, exp, graphs, segments, motions, arcs, result, summary, runs)
    report = write_demo_report(out, ctx, progress, meta)
    lap("report")
    summary["seconds"] = times
    summary_path = out / "summary.json"
    write_text_file(summary_path, json.dumps(summary, indent=2) + "\n")
    return DemoResult(summary, report, summary_path)
