"""The report's physics section: the plan executed in MuJoCo, step by step.

Each plan step is simulated (open loop, one continuous simulation: :mod:`nonprehensile.sim`),
shown as a filmstrip from offscreen rendering where an OpenGL context can be made (a note
otherwise: the report never fails for want of GL), with the table of predicted vs simulated
transitions. Without the ``sim`` extra the section says how to get it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import Plan
from nonprehensile.viz._figures import new_figure
from nonprehensile.viz.report import Section, figure_to_png

__all__ = ["filmstrip_figure", "physics_section"]


def filmstrip_figure(frames: Sequence[Any], captions: Sequence[str], *, per_row: int = 6
                     ) -> Any:
    """Frames side by side, with captions, as one matplotlib figure."""
    n = len(frames)
    rows = (n + per_row - 1) // per_row
    cols = min(n, per_row)
    fig = new_figure(figsize=(2.2 * cols, 1.8 * rows))
    for i, (img, cap) in enumerate(zip(frames, captions, strict=True)):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.imshow(img)
        ax.set_title(cap, fontsize=7)
        ax.axis("off")
    fig.tight_layout()
    return fig


def physics_section(
    poly: Polyhedron, plan: Plan, *, scale: float, fingers: Mapping[str, str],
) -> tuple[Section, list[dict[str, Any]]]:
    """Simulate the plan and describe it; also returns the per-step records (JSON)."""
    title = "Physics: the plan executed in MuJoCo"
    try:
        from nonprehensile.sim import Simulator
        from nonprehensile.sim.execute import fingers_of, simulate_step
        from nonprehensile.sim.render import render_trace
    except ImportError:
        return Section(title, ["The simulation needs the `sim` extra (MuJoCo): "
                               "pip install 'nonprehensile[sim]'. Not simulated here."]), []
    if not plan.steps:
        return Section(title, ["The plan has no step to simulate."]), []
    n = max(max(fingers_of(s.transition.skill), default=1) for s in plan.steps)
    sim = Simulator(poly, scale=scale, n_fingers=n)
    outcomes = []
    traces = []
    # one continuous simulation, open loop; each step keeps its trace for the pictures
    for i, step in enumerate(plan.steps):
        o = simulate_step(sim, step, fingers=fingers, continue_from_current=i > 0,
                          label={"step": i + 1}, keep_trace=10)
        outcomes.append(o)
        traces.append(o.result.trace)
    records = [o.to_dict() for o in outcomes]
    ok = sum(o.success for o in outcomes)
    paras = [
        f"Each of the {len(plan.steps)} steps was executed in one continuous MuJoCo "
        "simulation, open loop: the fingertips (compliant spheres) follow each step's "
        "reference motion, placed where the plan predicts the object to be; the object "
        "carries on from wherever physics left it. A step succeeds when the object rests on "
        "the predicted face, theta within 5 degrees, centre of mass within 10 mm of the "
        f"plan's prediction. {ok} of {len(outcomes)} steps ended as predicted. "
        f"Physics: {sim.params.mass:g} kg object, friction {sim.params.friction_table:g} "
        f"(table) / {sim.params.friction_finger:g} (finger), fingertip radius "
        f"{1000 * sim.params.finger_radius:g} mm, {1000 * sim.params.timestep:g} ms steps.",
    ]
    rows = []
    for r in records:
        s = r["simulated"]
        rows.append([
            str(r["step"]), r["skill"],
            f"{r['from']['face']}:{r['from']['theta']:g} -> {r['predicted']['face']}:"
            f"{r['predicted']['theta']:g}",
            "-" if s is None else f"{s['face']}:{s['theta']:.1f}",
            "-" if r["position_error_m"] is None else f"{1000 * r['position_error_m']:.1f}",
            "yes" if r["chain_ok"] else "missing " + ", ".join(r["missing_events"]),
            " -> ".join(" ∧ ".join(e["contacts"]) for e in r["simulation"]["events"]),
            "yes" if r["success"] else "NO",
        ])
    section = Section(title, paras, [], [(
        ["step", "skill", "predicted", "simulated", "position error (mm)",
         "skill's events in order", "simulated contact events", "as predicted"], rows)])
    frames: list[Any] = []
    captions: list[str] = []
    note = ""
    for i, tr in enumerate(traces):
        if tr is None:
            continue
        times = [float(t) for t in np.linspace(0.0, float(tr[-1, 0]), 6)]
        got, note = render_trace(sim, tr, times)
        if got is None:
            frames = []
            break
        frames += got
        captions += [f"step {i + 1}, t = {t:.2f} s" for t in times]
    if frames:
        section.figures.append((figure_to_png(filmstrip_figure(frames, captions)),
                                "Filmstrip of the simulated plan (offscreen MuJoCo rendering)."))
    else:
        section.paragraphs.append(f"No pictures: {note or 'nothing to draw'}; the physics "
                                  "above does not need them.")
    return section, records
