"""The main job's report: its sections, drawn from what :func:`nonprehensile.pipeline.run_demo`
computed, and the page that holds them (``nonprehensile demo``).

Each section is a function of a :class:`ReportContext` returning a
:class:`~nonprehensile.viz.report.Section`; :data:`REPORT_SECTIONS` lists them in order.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nonprehensile.demonstrations.dataset import Dataset
from nonprehensile.demonstrations.segment import Segment
from nonprehensile.inference import Expansion
from nonprehensile.planning import Plan
from nonprehensile.references import ClusteredMotions
from nonprehensile.skills.contacts import format_event
from nonprehensile.viz.report import Cell, HtmlFigure, Section, figure_to_png, write_report

__all__ = ["REPORT_SECTIONS", "ReportContext", "collector_spared", "write_demo_report"]


@contextlib.contextmanager
def collector_spared() -> Iterator[None]:
    """Leave the objects alive now out of the cyclic garbage collector's walks in the block.

    Matplotlib's figures are webs of reference cycles, so drawing the report sets off the
    collector, and each full collection walks every object the job holds (its modules,
    dataset and models: 150,000 objects, about 0.05 s a walk; issue 16). Frozen
    (:func:`gc.freeze`), they are skipped; garbage made in the block is collected as usual,
    and the frozen objects are handed back to the collector when the block ends. Where
    something else has already frozen objects, nothing is changed (unfreezing would hand
    back theirs too).
    """
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@dataclass(frozen=True)
class ReportContext:
    """Everything the main job computed, for the report's sections to draw from."""

    ds: Dataset
    exp: Expansion
    graphs: Any
    segments: list[Segment]
    motions: ClusteredMotions
    arcs: list[dict[str, Any]]
    result: Plan
    summary: dict[str, Any]
    #: The physics runs kept between reports (:mod:`nonprehensile.sim.report_runs`):
    #: ``sweep`` and ``robot``, each its document or ``{"error": why}``.
    runs: dict[str, Any] = field(default_factory=dict)


#: The report's sections, in order: ``"module:function"``, each function taking a
#: :class:`ReportContext` and returning a :class:`~nonprehensile.viz.report.Section` (or None
#: to leave itself out). A new section is one line here; its module imports what it draws
#: with, inside the function.
REPORT_SECTIONS: list[str] = [
    "nonprehensile.viz.demo_report:object_section",
    "nonprehensile.viz.demo_report:inference_section",
    "nonprehensile.viz.demo_report:motion_section",
    "nonprehensile.viz.demo_report:plan_section",
    "nonprehensile.viz.demo_report:physics_section",
    "nonprehensile.viz.demo_report:robustness_section",
    "nonprehensile.viz.demo_report:robot_section",
]


def write_demo_report(
    out: Path, ctx: ReportContext, progress: Callable[[str, int, int], None],
    meta: Sequence[tuple[str, str]] = (),
) -> Path:
    """Draw every section of :data:`REPORT_SECTIONS` from ``ctx`` and write ``out/index.html``.

    Parameters
    ----------
    out : Path
        The report's folder.
    ctx : ReportContext
        What the main job computed.
    progress : callable
        ``progress("figures", done, total)``.
    meta : sequence of (str, str)
        Name and value rows written at the top of the report.

    Returns
    -------
    Path
        The report's ``index.html``.
    """
    import importlib

    ds = ctx.ds
    sections = []
    progress("figures", 0, len(REPORT_SECTIONS))
    with collector_spared():
        for i, target in enumerate(REPORT_SECTIONS, start=1):
            module, _, attr = target.partition(":")
            section = getattr(importlib.import_module(module), attr)(ctx)
            if section is not None:
                sections.append(section)
            progress("figures", i, len(REPORT_SECTIONS))
    return write_report(
        out, f"nonprehensile: {ds.poly.name}",
        "The whole pipeline of the paper (Integrated Object, Skill, and Motion Models for "
        f"Nonprehensile Manipulation) on {_whose(ctx)}: the object model, the "
        "state-transition graph expanded by inference, the skill graphs, the clustered finger "
        "motions, and a plan between two states that were never demonstrated.",
        sections, meta=meta,
    )


def _whose(ctx: ReportContext) -> str:
    """Whose demonstrations the report is of: the bundled ones, or the dataset's folder."""
    from nonprehensile.demonstrations.dataset import BUNDLED_DATASETS, bundled_path

    root = ctx.ds.root
    if root is None:
        return "the bundled demonstrations"
    bundled = {bundled_path(name).resolve() for name in BUNDLED_DATASETS}
    return ("the bundled demonstrations" if Path(root).resolve() in bundled
            else f"the demonstrations of {Path(root).name}")


def physics_section(ctx: ReportContext) -> Section:
    """The plan executed in MuJoCo (issue 9); a note instead where that cannot be done."""
    from nonprehensile.errors import NonprehensileError
    from nonprehensile.viz.physics import physics_section as draw

    ds, result, summary = ctx.ds, ctx.result, ctx.summary
    try:
        from nonprehensile.control import replanner

        rp = replanner(ds.poly, ctx.exp, result.goal, motions=ctx.motions, scale=ds.scale)
        section, records = draw(ds.poly, result, scale=ds.scale, fingers=ds.fingers,
                                replan=rp)
    except NonprehensileError as exc:
        summary["physics"] = {"error": str(exc)}
        return Section("Physics: the plan executed in MuJoCo", [f"Not simulated: {exc}"])
    summary["physics"] = {"steps": records,
                          "all_as_predicted": all(r["success"] for r in records)}
    return section


def plural(n: int, word: str, many: str | None = None) -> str:
    """``1 demonstration``, ``2 demonstrations``."""
    return f"{n} {word if n == 1 else many or word + 's'}"


def object_section(ctx: ReportContext) -> Section:
    """The object model: two labeled views, and ``A`` and ``Delta`` as HTML tables."""
    from nonprehensile.viz import object_figure

    poly, summary = ctx.ds.poly, ctx.summary
    png = figure_to_png(object_figure(poly, tables=False))
    labels, a = poly.adjacency_matrix()
    tables: list[tuple[Sequence[str | Cell], Sequence[Sequence[str | Cell]]]] = []
    if len(labels) <= 40:
        tables.append((["A", *labels], [[f, *[str(k) if k else "-" for k in a[i]]]
                                         for i, f in enumerate(labels)]))
    tables.append((["face", "Delta (deg)", "edges"],
                   [[f, ", ".join(f"{d:g}" for d in poly.delta[f]), str(poly.n_edges(f))]
                    for f in list(poly.faces)[:200]]))
    return Section(
        "Object model (paper Section III, Fig. 3)",
        [f"{poly.name}: {plural(len(poly.faces), 'face')} labeled "
         f"{', '.join(list(poly.faces)[:40])}{' ...' if len(poly.faces) > 40 else ''}; edge "
         "numbers run clockwise seen from outside; the adjacency matrix A holds, for each pair "
         "of adjacent faces, the number of their shared edge on the row face. Rotation "
         f"symmetry group of order {summary['object']['symmetry_order']}; "
         f"{plural(summary['states']['count'], 'state')} at a "
         f"{summary['states']['step']:g}-degree step form "
         f"{plural(summary['states']['classes'], 'geometric-equivalence class', 'geometric-equivalence classes')}."],  # noqa: E501
        [(png, "The labeled object from two opposite sides; `nonprehensile object figure MODEL "
               "--html FILE` draws it as a view you can rotate")],
        tables,
    )


def inference_section(ctx: ReportContext) -> Section:
    """The expanded state-transition graph (every skill) and the skill graphs."""
    from nonprehensile.viz import skill_graphs_figure, state_graph_figure
    from nonprehensile.viz.graphs import (
        MAX_DRAWN_STATES,
        transition_matrix_html,
        transitions_svg,
    )

    exp, summary = ctx.exp, ctx.summary
    caption = ("State-transition graph, one panel per skill: each skill is one maneuver "
               "applied wherever it applies, so its arcs form cycles (rolling a cube around a "
               "belt: four states) or chains; the demonstrated arc is bold black, the others "
               "inferred. Rest the pointer on an arc for its transition")
    graph: list[tuple[bytes | HtmlFigure, str]]
    if len(exp.graph.states) <= MAX_DRAWN_STATES:
        # both drawn by the browser: the panels' 168 labeled states cost matplotlib 0.2 s,
        # the matrix's 48 tick labels and cells 0.09 s (issue 16)
        graph = [(HtmlFigure(transitions_svg(exp)), caption),
                 (HtmlFigure(transition_matrix_html(exp)),
                  "Transition matrix: rows the start states, columns the end states; a cell "
                  "holds a stripe per skill realising the transition, outlined where it was "
                  "demonstrated")]
    else:
        graph = [(figure_to_png(state_graph_figure(exp)),
                  "Transition matrix (too many states to draw the graph)")]
    skills_png = figure_to_png(skill_graphs_figure(list(ctx.graphs.graphs)))
    inf = summary["inference"]
    rows = [[str(t.start), str(t.end), t.skill.name, t.skill.maneuver,
             "demonstrated" if t.demonstrated else "inferred"]
            for t in exp.transitions if t.demonstrated]
    return Section(
        "Skills and inference (Sections IV and V, Fig. 5, 7)",
        [f"{plural(len(summary['skills']), 'demonstrated skill')} expand to "
         f"{plural(inf['transitions'], 'transition')} over the state set, "
         f"{inf['demonstrated']} of them demonstrated. The paper's edge-index method and the "
         f"exact symmetry method disagree on {inf['paper_method_disagreements']} of them."],
        [*graph,
         (skills_png, "Skill graphs: contact events as nodes, finger motions as arcs")],
        [(["from", "to", "skill", "maneuver", "shown"], rows)],
    )


def motion_section(ctx: ReportContext) -> Section:
    """Fingertip trajectories and the Hilbert-key histograms of the shared arcs."""
    from nonprehensile.viz.clusters import cluster_histogram_figure
    from nonprehensile.viz.trajectories import trajectory_figure

    arcs, motions, segments = ctx.arcs, ctx.motions, ctx.segments
    # the arcs where skills with the same contact events move differently: the paper's Fig. 12
    shared = [a for a in arcs
              if len(a["skills"]) > 1 and len(a["labels"]) > 1 and a["clusterer"] is not None]
    tumbling = next((a for a in shared if a["group"] == 1), shared[0] if shared else None)
    traj_png = figure_to_png(trajectory_figure(ctx.ds, tumbling["skills"] if tumbling else None))
    hists = []
    for a in shared:
        rows = a["rows"]
        title = f"{a['from']} -> {a['to']} ({', '.join(a['skills'])})"
        hists.append((figure_to_png(cluster_histogram_figure(
            a["clusterer"], motions.vectors[rows], [segments[i].skill for i in rows],
            title=title, labels=motions.labels[rows])), title))
    ds = ctx.summary["dataset"]

    rows = [[f"{a['from']} -> {a['to']}", ", ".join(a["skills"]), ", ".join(a["labels"]),
             str(a["segments"]), str(a["clusters"]), ari_cell(a)] for a in arcs]
    return Section(
        "Demonstrations and motion clusters (Section VI, Fig. 12)",
        [f"{plural(ds['demonstrations'], 'demonstration')} by "
         f"{plural(len(ds['mentors']), 'mentor')}, cut at their "
         f"contact events into {plural(ds['segments'], 'segment')} registered to the skill "
         "graphs' arcs, then streamed, 10 at a time and skill after skill, into an incremental "
         "clusterer on a Hilbert-curve index, arc by arc. Where skills share an arc (the same "
         "contact events), the clusterer is asked for one cluster per skill; where one skill "
         "has it, it picks the number (the mentors' styles). Clusters are numbered from 1 on "
         "each arc, in the order of their first segment, here, in the histograms and in the "
         "plan."],
        [(traj_png, "Fingertip trajectories of two skills with the same contact events"
          if tumbling else "Fingertip trajectories (no two skills of this dataset share their "
          "contact events)"),
         *[(png, f"Hilbert keys of {title}, coloured by cluster") for png, title in hists]],
        [(["arc", "skills", "motions", "segments", "clusters", ARI_HEADER], rows)],
        notes=[ARI_NOTE],
    )


#: The motion table's one score column: its header, with what the score is as a tooltip.
ARI_HEADER = Cell(
    "clusters match the skills? (ARI: 1 exactly, 0 chance)",
    "Adjusted Rand index of the arc's clusters against the skills of its segments: 1 when "
    "the clusters are exactly the skills, about 0 when they are no better than chance. Only "
    "arcs shared by skills that move differently can reach 1.")
#: The note under the motion table.
ARI_NOTE = ("Rest the pointer on a score for the other two: the ARI of the ids each segment "
            "got when it arrived (the stream without hindsight), and the ARI against skill "
            "and mentor together (clusters that split a skill by mentor are right there).")


def ari_cell(arc: dict[str, Any]) -> Cell:
    """The motion table's score of one arc (see :data:`ARI_HEADER`): the ARI against the
    skills and what to expect of it, the other two scores in its tooltip."""
    mentor = f"ARI against skill x mentor: {arc['ari_vs_skill_and_mentor']:.2f}"
    if "ari_vs_skill" not in arc:
        return Cell(f"- (one skill; {plural(arc['clusters'], 'cluster')}: its mentors' styles)",
                    mentor)
    value = arc["ari_vs_skill"]
    # the words read the number: 1 is the same partition, 0 what chance gives
    reading = ("exactly the skills" if value >= 0.995 else "mostly the skills" if value >= 0.5
               else "partly" if value >= 0.15 else "no better than chance")
    return Cell(f"{value:.2f}: {reading}",
                f"as registered (each segment's id on arrival): "
                f"{arc['ari_vs_skill_as_streamed']:.2f}; {mentor}")


def plan_section(ctx: ReportContext) -> Section:
    """The plan: a filmstrip of the object's poses, and its steps as a table."""
    from nonprehensile.viz.plan_figure import plan_filmstrip_figure

    result = ctx.result
    off = result.offset
    rows = []
    for i, step in enumerate(result.steps, start=1):
        t = step.transition
        agent = step.agent or off
        for j, ev in enumerate(t.skill.events):
            motion = step.motions[j] if j < len(step.motions) else None
            ref = motion[3] if motion else None
            rows.append([
                str(i) if j == 0 else "",
                f"{step.start_world} -> {step.end_world} by {t.skill.name}" if j == 0 else "",
                (f"{agent.rotate_deg:g} deg at ({agent.translate[0]:.3g}, "
                 f"{agent.translate[1]:.3g})" + (" (relocated)" if step.relocated and i > 1
                                                 else "")) if j == 0 else "",
                ev.id, format_event(ev, "paper"), motion[2] if motion else "",
                (f"cluster {ref.cluster} medoid ({plural(ref.n_demonstrations, 'demo')}, "
                 f"{ref.positions.shape[0]} frames)") if ref else "",
            ])
    relocs = (f" and {plural(result.relocations, 'relocation')}" if result.relocations
              else "")
    film = figure_to_png(plan_filmstrip_figure(ctx.ds.poly, result, scale=ctx.ds.scale,
                                               markers=list(ctx.ds.fingers.values())))
    return Section(
        "Plan (Section VII)",
        [f"From {result.start} to {result.goal}, neither of them demonstrated: place the "
         f"agent turned by {off.rotate_deg:g} degrees at ({off.translate[0]:g}, "
         f"{off.translate[1]:g}) m, then {plural(len(result.steps), 'transition')}"
         f"{relocs}"
         ". Each step lists where the agent stands, its contact events and, for each motion, "
         "the reference finger trajectory: the medoid of the skill's main cluster, in the "
         "world frame."],
        [(film, "Plan filmstrip: the object where each step starts (its bottom face red, "
                "the IDs of the faces turned to you), the reference finger paths and the "
                "agent, on axes in metres. `nonprehensile plan ... --html FILE` draws the same "
                "as a view you can rotate.")],
        [(["step", "transition", "agent", "event", "contacts", "then", "reference motion"],
          rows)],
    )


def _rate_text(d: dict[str, Any]) -> str:
    """``181/200 = 90.5 % (85.6-93.8 %)`` from a rate's JSON."""
    if not d["n"]:
        return "-"
    lo, hi = d["ci95"]
    return f"{d['k']}/{d['n']} = {100 * d['rate']:.1f} % ({100 * lo:.1f}-{100 * hi:.1f} %)"


#: The quantities the report's robustness figure plots (the issue's "friction and mass").
ROBUSTNESS_PARAMETERS = ("friction_table", "mass")


def robustness_section(ctx: ReportContext) -> Section:
    """The plan's robustness across the physics distribution, open and closed loop: success
    against table friction and mass (:func:`nonprehensile.sim.report_runs.plan_sweep`)."""
    from nonprehensile.viz.robustness import PARAMETER_AXES, robustness_figure

    title = "Robustness: the plan across the physics distribution"
    doc = ctx.runs.get("sweep") or {"error": "not run"}
    if "error" in doc:
        ctx.summary["robustness"] = {"error": doc["error"]}
        return Section(title, [f"Not swept: {doc['error']}"])
    loops = list(doc["loops"])
    prov = doc.get("provenance", {})
    dist = doc["distribution"]
    ranges = "; ".join(
        f"{PARAMETER_AXES.get(k, (k, 1.0))[0]} {v}" for k, v in _ranges(dist).items())
    where = {
        "shipped": f"shipped with the package (src/nonprehensile/data/demo_sweep.json), "
                   f"computed by `{prov.get('command', '?')}` at commit "
                   f"{prov.get('commit', '?')} on {prov.get('created', '?')}",
        "cache": f"kept in the cache folder from an earlier run (computed by "
                 f"`{prov.get('command', '?')}` at commit {prov.get('commit', '?')} on "
                 f"{prov.get('created', '?')})",
        "computed": "computed by this run (and kept in the cache folder for the next)",
    }[doc["source"]]
    stale = "" if doc.get("executor_current", True) else (
        " The executor's code in this installation differs from the code that computed it "
        "(its source digest " f"{prov.get('executor_digest', '?')} is not this one's): the "
        "numbers are that commit's; `nonprehensile demo --write-sweep FILE` runs it afresh.")
    overall = doc["overall"]
    counts = ", ".join(f"{lp} loop {_rate_text(overall[lp])}" for lp in loops)
    paras = [
        f"The plan ({doc['units'][0]['skill']}) executed {doc['samples']} times, once per "
        f"sample of the documented physics distribution (seed {doc['seed']}; "
        "`sim.distribution.DEFAULT_DISTRIBUTION`, docs/physics.md), closed and open loop on "
        "the same samples, by the executor of `simulate robustness` (`sim.robustness."
        "run_sweep`). It succeeds when the object ends on the goal's face, theta within "
        f"{doc['angle_tol_deg']:g} degrees and its centre of mass within "
        f"{1000 * doc['position_tol_m']:g} mm of the goal position: {counts} (95 % Wilson "
        f"intervals). Distribution: {ranges}. This sweep was {where}.{stale}",
    ]
    reasons: dict[str, int] = {}
    for r in doc["records"]:
        if r["loop"] == "closed" and not r["success"]:
            why = str(r["reason"]).split(":")[0][:80] or "?"
            reasons[why] = reasons.get(why, 0) + 1
    if reasons:
        paras.append("Closed-loop failures: " + "; ".join(
            f"{n} {why}" for why, n in sorted(reasons.items(), key=lambda kv: -kv[1])) + ".")
    names = [p for p in ROBUSTNESS_PARAMETERS if p in doc["bins"]]
    png = figure_to_png(robustness_figure(doc, parameters=names))
    rows = []
    for name in names:
        label, k = PARAMETER_AXES.get(name, (name, 1.0))
        for b in doc["bins"][name]:
            rows.append([label, f"{k * b['low']:.3g}-{k * b['high']:.3g}",
                         *(_rate_text(b[lp]) for lp in loops)])
    ctx.summary["robustness"] = {
        "samples": doc["samples"], "seed": doc["seed"], "source": doc["source"],
        "key": doc.get("key"), "provenance": prov,
        "executor_current": doc.get("executor_current", True),
        "overall": overall}
    return Section(
        title, paras,
        [(png, "Success rate against table friction and object mass, closed loop (blue) and "
               "open loop (orange): each point one bin of the parameter's range, with its 95 % "
               "Wilson interval; every other quantity varies across its own range within "
               "each bin")],
        [(["parameter", "bin", *(f"{lp} loop" for lp in loops)], rows)],
    )


def _ranges(dist: dict[str, Any]) -> dict[str, str]:
    """Each varied quantity's range as shown (``0.3-1``), from the distribution's JSON."""
    from nonprehensile.viz.robustness import PARAMETER_AXES

    out = {}
    for name, v in dist.items():
        if name not in PARAMETER_AXES:
            continue
        k = PARAMETER_AXES[name][1]
        if isinstance(v, (list, tuple)) and len(v) == 2:
            out[name] = f"{k * float(v[0]):g}-{k * float(v[1]):g}"
        elif isinstance(v, (int, float)):
            out[name] = ("up to " if name.startswith("start_") else "") + f"{k * float(v):g}"
    return out


def robot_section(ctx: ReportContext) -> Section:
    """The plan executed closed loop by the bundled Panda: a filmstrip of the arm, the
    tracking error and joint margins over time
    (:func:`nonprehensile.sim.report_runs.robot_execution`)."""
    from nonprehensile.viz.robot_execution import arm_filmstrip_figure, robot_signals_figure

    title = "Robot: the plan executed by the bundled Franka Panda"
    doc = ctx.runs.get("robot") or {"error": "not run"}
    if "error" in doc:
        ctx.summary["robot"] = {"error": doc["error"]}
        if doc["error"].startswith("skipped"):  # asked for (demo --no-robot): no extra missing
            return Section(title, [f"Not executed: {doc['error']}."])
        return Section(title, [f"Not executed: {doc['error']}. With the `robot` extra "
                               "(pip install 'nonprehensile[robot]': mink and daqp) the "
                               "bundled Panda executes the plan here."])
    ex, m, pl = doc["execution"], doc["metrics"], doc["placement"]
    base = pl["base"]
    fs = ex["final_state"]
    at = m["longest_at_limit_s"]
    worst = max(at, key=lambda k: at[k]) if at else None
    contact = m["tracking_error_contact_max_m"]
    verdict = ("reached the goal" if ex["success"] else f"did NOT reach the goal "
               f"({ex['reason']})")
    paras = [
        "The bundled Panda (a mesh-free MJCF the project writes from Franka's published "
        "kinematics and limits, a finger rod with a spherical tip at the flange; docs/robot.md)"
        f" stands at the base the placement search chose, ({base['x']:.3f}, {base['y']:.3f}) m "
        f"heading {base['yaw_deg']:g} degrees ({pl['candidates']} candidates, reach error "
        f"{1000 * pl['reach_error_m']:.1f} mm, joint margin {pl['joint_margin_rad']:.2f} rad). "
        "It executes the plan closed loop in one continuous simulation, transits included "
        "(`simulate plan --robot panda`): mink's differential IK at "
        f"{doc['robot']['rates']['control_hz']:g} Hz, joint position servos with velocity "
        f"feed-forward and gravity compensation. It {verdict}: resting on "
        f"{'no face' if fs is None else str(fs['face']) + ':' + format(fs['theta'], '.1f')}, "
        f"{1000 * (ex['position_error_m'] or 0.0):.1f} mm from the goal position. "
        "Fingertip tracking error in contact at most "
        + ("-" if contact is None else f"{1000 * contact:.1f} mm")
        + f" ({1000 * m['tracking_error_max_m']:.1f} mm over the whole run); longest time "
        f"at a joint limit {1000 * (at[worst] if worst else 0.0):.0f} ms"
        + (f" ({worst})" if worst and at[worst] > 0 else "")
        + f"; contact of a link or the rod with the cube or the table "
        f"{1000 * m['other_contact_s']:.0f} ms; joint margin at least "
        f"{m['position_margin_min_rad']:.2f} rad; IK {m['ik_median_ms']:.3f} ms a solve "
        f"(median of {m['ik_solves']}). "
        + ("Kept in the cache folder from an earlier run." if doc.get("cached")
           else "Computed by this run (kept in the cache folder for the next)."),
    ]
    rows = []
    for r in ex["steps"]:
        rm = r.get("robot") or {}
        c = rm.get("tracking_error_contact_max_m")
        rows.append([str(r["step"]), r["skill"],
                     "-" if c is None else f"{1000 * c:.1f}",
                     f"{1000 * rm.get('tracking_error_max_m', float('nan')):.1f}",
                     f"{rm.get('position_margin_min_rad', float('nan')):.2f}",
                     f"{1000 * rm.get('time_at_limit_s', 0.0):.0f}",
                     f"{1000 * rm.get('other_contact_s', 0.0):.0f}",
                     "yes" if r["success"] else "NO"])
    figures: list[tuple[bytes | HtmlFigure, str]] = []
    if pl.get("tried"):
        from nonprehensile.viz.reachability import reachability_figure

        n_ok = sum(bool(c["feasible"]) for c in pl["tried"])
        figures.append((figure_to_png(reachability_figure(pl["tried"], base,
                                                          pl.get("targets_xy"))), (
            f"Where the arm may stand: the {len(pl['tried'])} candidate bases of the placement "
            f"search, seen from above, each facing the plan's fingertip path (orange). "
            f"{n_ok} reach every target of the plan, the transits between steps included "
            "(coloured by their least joint margin over it; crosses: out of reach); the star "
            "and arrow: the chosen base and its heading (the most joint margin among those "
            "that reach).")))
    if doc.get("frames"):
        figures.append((figure_to_png(arm_filmstrip_figure(doc["frames"])), (
            "Filmstrip of the arm, seen from the side (across the line from its base to the "
            "cube): its collision capsules, rod and fingertip (red while touching the cube) "
            "and the cube, drawn from the recorded joint positions and object pose at the "
            "start, across each executed step and at the end (after any correction).")))
    figures.append((figure_to_png(robot_signals_figure(doc["log"], doc["limits"],
                                                       doc["steps"])), (
        "The robot's records over the whole execution: the fingertip's distance from its "
        "target (shaded: touching the cube), each joint's distance to the nearer end of its "
        "range, and the largest share of a joint's velocity or torque limit in use. Dotted: "
        "where each executed step starts and ends; before, between and after them, transits "
        "and corrections.")))
    ctx.summary["robot"] = {"success": ex["success"], "final_state": fs,
                            "position_error_m": ex["position_error_m"], "base": base,
                            "metrics": m, "cached": bool(doc.get("cached"))}
    return Section(title, paras, figures, [(
        ["step", "skill", "tracking in contact, max (mm)", "tracking, max (mm)",
         "joint margin (rad)", "at a limit (ms)", "link/rod contact (ms)",
         "in the predicted state"], rows)])
