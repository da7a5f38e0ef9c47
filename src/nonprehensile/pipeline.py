"""The main job: the whole pipeline on a dataset, ending in a report (``nonprehensile demo``).

Object model and stable states, skills, inference to the expanded state-transition graph,
incremental clustering of every demonstrated motion segment, and a plan between two states that
were never demonstrated, with reference finger motions; written as a self-contained HTML report
(``index.html``, images embedded) and a JSON summary (``summary.json``).

This module sits at the edge of the package (it writes files and draws figures); the CLI calls
it and shows its progress.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nonprehensile.demonstrations.dataset import Dataset, load_dataset
from nonprehensile.demonstrations.segment import Segment, segment_dataset
from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.geometry.symmetry import equivalence_classes, rotation_group
from nonprehensile.inference import Expansion, cross_check, expand
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.library import ClusteredMotions, flatten_segments
from nonprehensile.planning import Plan, plan
from nonprehensile.skills.contacts import format_event
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State, stable_faces, states_by_step
from nonprehensile.viz.report import Section, figure_to_png, write_report

__all__ = [
    "DemoResult",
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

    Returns
    -------
    motions : ClusteredMotions
        Every segment with its cluster (clusters numbered per arc).
    arcs : list of dict
        Per arc: the segments' rows and the fitted clusterer (``rows``, ``clusterer``: not
        JSON), the skills on it, the number of segments and clusters, and, when several skills
        share the arc, the adjusted Rand index of the clusters against the skills.
    """
    from sklearn.metrics import adjusted_rand_score

    by_pair: dict[tuple[int, Any, Any], list[int]] = {}
    for i, s in enumerate(segments):
        by_pair.setdefault((s.arc.group, s.arc.source, s.arc.target), []).append(i)
    labels = np.zeros(len(segments), dtype=np.int64)
    vectors: list[np.ndarray] = [np.empty(0)] * len(segments)
    arcs = []
    total = sum(len(v) for v in by_pair.values())
    done = 0
    for (group, _, _), rows in by_pair.items():
        x = flatten_segments([segments[i] for i in rows])
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
            streamed = np.asarray(clusterer.labels_, dtype=np.int64)
            # the periodic recalibration, due at the end of the stream: the report shows the
            # clusters as a recalibrated store holds them (the streamed ids are scored too)
            clusterer.recalibrate()
            found = np.asarray(clusterer.labels_, dtype=np.int64)
        labels[rows] = found
        for r, v in zip(rows, x, strict=True):
            vectors[r] = v
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
            entry["ari_vs_skill"] = float(adjusted_rand_score(skills, found))
            entry["ari_vs_skill_as_streamed"] = float(adjusted_rand_score(skills, streamed))
        # mentors move in their own styles: clusters that split a skill by mentor are right
        entry["ari_vs_skill_and_mentor"] = float(adjusted_rand_score(styles, found))
        arcs.append(entry)
    return ClusteredMotions(segments, labels, np.vstack(vectors)), arcs


def motions_from_dataset(
    dataset: str | Path,
    *,
    skills: Sequence[Skill] | None = None,
    poly: Polyhedron | None = None,
    seed: int = 0,
    progress: StageProgress = _quiet,
) -> tuple[Dataset, ClusteredMotions]:
    """Load a dataset, segment it and cluster its motions: the planner's reference motions.

    When ``skills`` (and ``poly``) are given, the dataset's demonstrations must be of that
    object, and a skill it shares with them by name must be the same skill: a reference motion
    is only meaningful for the skill it shows. (Skills it does not demonstrate simply get no
    reference motion.)

    Raises
    ------
    InputError
        Another object, or a skill of the same name demonstrated differently.
    """
    ds = load_dataset(dataset, progress=lambda d, n: progress("loading", d, n))
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
    _, segments = segment_dataset(ds)
    motions, _ = cluster_segments(segments, seed=seed, progress=progress)
    return ds, motions


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
    doc.write_text(json.dumps(result.to_dict(), indent=1) + "\n", encoding="utf-8")
    written.append(doc)
    return written


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

    Returns
    -------
    DemoResult
    """
    times: dict[str, float] = {}
    t0 = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal t0
        now = time.perf_counter()
        times[name] = round(now - t0, 3)
        t0 = now

    ds: Dataset = load_dataset(dataset, progress=lambda d, n: progress("loading", d, n))
    poly, skills = ds.poly, list(ds.skills)
    lap("load")
    states = states_by_step(poly, step)
    classes = equivalence_classes(poly, states)
    exp = expand(poly, skills, states)
    disagreements = cross_check(poly, skills, states)
    lap("inference")
    graphs, segments = segment_dataset(ds)
    lap("segmentation")
    motions, arcs = cluster_segments(segments, seed=seed, progress=progress)
    lap("clustering")
    result: Plan = plan(poly, exp, start, goal, position=position, motions=motions,
                        scale=ds.scale)
    lap("planning")

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
    report = _write_report(out, ds, exp, graphs, segments, motions, arcs, result, summary,
                           progress)
    lap("report")
    summary["seconds"] = times
    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return DemoResult(summary, report, summary_path)


def _write_report(
    out: Path, ds: Dataset, exp: Expansion, graphs: Any, segments: list[Segment],
    motions: ClusteredMotions, arcs: list[dict[str, Any]], result: Plan,
    summary: dict[str, Any], progress: StageProgress,
) -> Path:
    from nonprehensile.viz import object_figure, skill_graphs_figure, state_graph_figure
    from nonprehensile.viz.clusters import cluster_histogram_figure
    from nonprehensile.viz.trajectories import trajectory_figure

    poly = ds.poly
    n_fig = 6
    progress("figures", 0, n_fig)
    sections = []

    fig_object = figure_to_png(object_figure(poly))
    progress("figures", 1, n_fig)
    sections.append(_object_section(poly, summary, fig_object))

    demo_skills = [s.name for s in ds.skills][:2]
    fig_graph = figure_to_png(state_graph_figure(exp, skills=demo_skills))
    progress("figures", 2, n_fig)
    fig_skills = figure_to_png(skill_graphs_figure(list(graphs.graphs)))
    progress("figures", 3, n_fig)
    sections.append(_inference_section(exp, summary, fig_graph, fig_skills))

    # the arcs where skills with the same contact events move differently: the paper's Fig. 12
    shared = [a for a in arcs
              if len(a["skills"]) > 1 and len(a["labels"]) > 1 and a["clusterer"] is not None]
    tumbling = next((a for a in shared if a["group"] == 1), shared[0] if shared else None)
    fig_traj = figure_to_png(trajectory_figure(ds, tumbling["skills"] if tumbling else None))
    progress("figures", 4, n_fig)
    hist_pngs = []
    for a in shared:
        rows = a["rows"]
        title = f"{a['from']} -> {a['to']} ({', '.join(a['skills'])})"
        hist_pngs.append((figure_to_png(cluster_histogram_figure(
            a["clusterer"], motions.vectors[rows], [segments[i].skill for i in rows],
            title=title)), title))
    progress("figures", 5, n_fig)
    sections.append(_motion_section(summary, arcs, fig_traj, hist_pngs))
    sections.append(_plan_section(result))
    sections.append(_physics(ds, result, summary))
    progress("figures", 6, n_fig)
    return write_report(
        out, f"nonprehensile: {poly.name}",
        "The whole pipeline of the paper (Integrated Object, Skill, and Motion Models for "
        "Nonprehensile Manipulation) on the bundled demonstrations: the object model, the "
        "state-transition graph expanded by inference, the skill graphs, the clustered finger "
        "motions, and a plan between two states that were never demonstrated.",
        sections,
    )


def _physics(ds: Dataset, result: Plan, summary: dict[str, Any]) -> Section:
    """The plan executed in MuJoCo (issue 9); a note instead where that cannot be done."""
    from nonprehensile.errors import NonprehensileError
    from nonprehensile.viz.physics import physics_section

    try:
        section, records = physics_section(ds.poly, result, scale=ds.scale,
                                           fingers=ds.fingers)
    except NonprehensileError as exc:
        summary["physics"] = {"error": str(exc)}
        return Section("Physics: the plan executed in MuJoCo", [f"Not simulated: {exc}"])
    summary["physics"] = {"steps": records,
                          "all_as_predicted": all(r["success"] for r in records)}
    return section


def _object_section(poly: Any, summary: dict[str, Any], png: bytes) -> Section:
    return Section(
        "Object model (paper Section III, Fig. 3)",
        [f"{poly.name}: {len(poly.faces)} faces labeled {', '.join(poly.faces)}; edge numbers "
         "run clockwise seen from outside; the adjacency matrix holds, for each pair of "
         "adjacent faces, the number of their shared edge on the row face. Rotation symmetry "
         f"group of order {summary['object']['symmetry_order']}; "
         f"{summary['states']['count']} states at a {summary['states']['step']:g}-degree step "
         f"form {summary['states']['classes']} geometric-equivalence class(es)."],
        [(png, "The labeled object, its adjacency matrix of edge numbers and face shapes")],
    )


def _inference_section(exp: Expansion, summary: dict[str, Any], graph_png: bytes,
                       skills_png: bytes) -> Section:
    inf = summary["inference"]
    rows = [[str(t.start), str(t.end), t.skill.name, t.skill.maneuver,
             "demonstrated" if t.demonstrated else "inferred"]
            for t in exp.transitions if t.demonstrated]
    return Section(
        "Skills and inference (Sections IV and V, Fig. 5, 7)",
        [f"{len(summary['skills'])} demonstrated skills expand to {inf['transitions']} "
         f"transitions over the state set, {inf['demonstrated']} of them demonstrated. The "
         "paper's edge-index method and the exact symmetry method disagree on "
         f"{inf['paper_method_disagreements']} of them."],
        [(graph_png, "State-transition graph: demonstrated arcs bold, inferred arcs thin "
                     "(two skills drawn), beside the full transition matrix"),
         (skills_png, "Skill graphs: contact events as nodes, finger motions as arcs")],
        [(["from", "to", "skill", "maneuver", "shown"], rows)],
    )


def _motion_section(summary: dict[str, Any], arcs: list[dict[str, Any]], traj_png: bytes,
                    hists: list[tuple[bytes, str]]) -> Section:
    ds = summary["dataset"]
    def score(a: dict[str, Any], key: str) -> str:
        return f"{a[key]:.2f}" if key in a else "-"

    rows = [[f"{a['from']} -> {a['to']}", ", ".join(a["skills"]), ", ".join(a["labels"]),
             str(a["segments"]), str(a["clusters"]), score(a, "ari_vs_skill"),
             score(a, "ari_vs_skill_as_streamed"), score(a, "ari_vs_skill_and_mentor")]
            for a in arcs]
    return Section(
        "Demonstrations and motion clusters (Section VI, Fig. 12)",
        [f"{ds['demonstrations']} demonstrations by {len(ds['mentors'])} mentors, cut at their "
         f"contact events into {ds['segments']} segments registered to the skill graphs' "
         "arcs, then streamed, 10 at a time and skill after skill, into an incremental "
         "clusterer on a Hilbert-curve index, arc by arc; a recalibration closes each stream. "
         "Where two skills share their contact events, the clusterer is asked for two clusters "
         "and the adjusted Rand index (ARI, 1 is perfect) says how well they separate the "
         "skills: on the arcs where the skills move differently (quarter circle or straight "
         "pull, lift-over or twist-over) they should, on the others (the same approach) they "
         "cannot. Where one skill has an arc, the clusterer picks the number of clusters: the "
         "mentors' styles (last column)."],
        [(traj_png, "Fingertip trajectories of two skills with the same contact events"),
         *[(png, f"Hilbert keys of {title}, coloured by cluster") for png, title in hists]],
        [(["arc", "skills", "motions", "segments", "clusters", "ARI vs skill",
           "ARI vs skill, as streamed", "ARI vs skill x mentor"], rows)],
    )


def _plan_section(result: Plan) -> Section:
    off = result.offset
    rows = []
    for i, step in enumerate(result.steps, start=1):
        t = step.transition
        for j, ev in enumerate(t.skill.events):
            motion = step.motions[j] if j < len(step.motions) else None
            ref = motion[3] if motion else None
            rows.append([
                str(i) if j == 0 else "",
                f"{step.start_world} -> {step.end_world} by {t.skill.name}" if j == 0 else "",
                ev.id, format_event(ev, "paper"), motion[2] if motion else "",
                (f"cluster {ref.cluster} medoid ({ref.n_demonstrations} demos, "
                 f"{ref.positions.shape[0]} frames)") if ref else "",
            ])
    return Section(
        "Plan (Section VII)",
        [f"From {result.start} to {result.goal}, neither of them demonstrated: relocate the "
         f"agent by {off.rotate_deg:g} degrees and ({off.translate[0]:g}, "
         f"{off.translate[1]:g}) m, then {len(result.steps)} transition(s). Each step lists "
         "its contact events and, for each motion, the reference finger trajectory: the "
         "medoid of the skill's main cluster, in the world frame."],
        [],
        [(["step", "transition", "event", "contacts", "then", "reference motion"], rows)],
    )
