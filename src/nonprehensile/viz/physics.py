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
from nonprehensile.viz.report import Section, figure_pixels, png_bytes

__all__ = ["FRAME_SIZE", "filmstrip_figure", "filmstrip_png", "physics_section"]


#: Pixels of one filmstrip frame: six to a row fill the report's page at its 80 dpi.
FRAME_SIZE = (176, 132)


def _filmstrip_layout(frames: Sequence[Any], captions: Sequence[str], *, per_row: int,
                      dpi: float) -> tuple[Any, Any, list[tuple[int, int]]]:
    """A figure the mosaic's size holding the captions, the mosaic (RGB, white between the
    tiles) and each frame's top left corner in it (pixels, rows down)."""
    n = len(frames)
    rows = (n + per_row - 1) // per_row
    cols = min(n, per_row)
    h, w = np.asarray(frames[0]).shape[:2]
    gap, band = max(2, w // 40), max(16, h // 8)  # between tiles; above each for its caption
    cell_h, cell_w = band + h + gap, w + gap
    mosaic = np.full((rows * cell_h, cols * cell_w, 3), 255, dtype=np.uint8)
    height, width = mosaic.shape[:2]
    fig = new_figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    corners = []
    for i, (img, cap) in enumerate(zip(frames, captions, strict=True)):
        r, c = divmod(i, per_row)
        y, x = r * cell_h + band, c * cell_w
        mosaic[y:y + h, x:x + w] = np.asarray(img)[..., :3]
        corners.append((y, x))
        # figure fractions from the top left (the mosaic's rows run downwards)
        fig.text((x + w / 2) / width, 1.0 - (y - 2) / height, cap, ha="center", va="bottom",
                 fontsize=7)
    return fig, mosaic, corners


def filmstrip_figure(frames: Sequence[Any], captions: Sequence[str], *, per_row: int = 6,
                     dpi: float = 80.0) -> Any:
    """Frames side by side, with captions, as one matplotlib figure.

    The frames (RGB arrays of one size) are tiled into one image placed on the figure pixel
    for pixel (``figimage``: no axes, nothing resampled), captions above each tile: no
    per-frame axes and no layout engine to run (a dozen axes and ``tight_layout`` cost 0.3 s,
    one axes and ``imshow`` 30 ms: issue 16). Saved at ``dpi``, the figure is the tiled
    image. The report writes the same pixels with :func:`filmstrip_png`.
    """
    fig, mosaic, _ = _filmstrip_layout(frames, captions, per_row=per_row, dpi=dpi)
    # interpolation "none": Agg draws the pixels as they are (any other resamples at 1:1)
    fig.figimage(mosaic, origin="upper", interpolation="none")
    return fig


def filmstrip_png(frames: Sequence[Any], captions: Sequence[str], *, per_row: int = 6,
                  dpi: int = 80) -> bytes:
    """:func:`filmstrip_figure` as the report's PNG (:func:`figure_to_png`), the same pixels.

    Matplotlib draws the captions alone; the frames are then copied into its pixels as they
    are, which is what ``figimage`` without resampling draws, less Agg's compositing of a
    1080 x 300 image (issue 16).
    """
    fig, _, corners = _filmstrip_layout(frames, captions, per_row=per_row, dpi=dpi)
    pixels = figure_pixels(fig, dpi)
    for img, (y, x) in zip(frames, corners, strict=True):
        rgb = np.asarray(img)[..., :3]
        pixels[y:y + rgb.shape[0], x:x + rgb.shape[1], :3] = rgb
    return png_bytes(pixels)


def physics_section(
    poly: Polyhedron, plan: Plan, *, scale: float, fingers: Mapping[str, str],
) -> tuple[Section, list[dict[str, Any]]]:
    """Simulate the plan and describe it; also returns the per-step records (JSON)."""
    title = "Physics: the plan executed in MuJoCo"
    try:
        from nonprehensile.sim import Simulator
        from nonprehensile.sim.execute import fingers_of, simulate_step
        from nonprehensile.sim.render import render_traces
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
    shown = [(i, tr, [float(t) for t in np.linspace(0.0, float(tr[-1, 0]), 6)])
             for i, tr in enumerate(traces) if tr is not None]
    got, note = (render_traces(sim, [(tr, times) for _, tr, times in shown],
                               width=FRAME_SIZE[0], height=FRAME_SIZE[1]) if shown
                 else (None, ""))
    frames: list[Any] = got or []
    captions = [f"step {i + 1}, t = {t:.2f} s" for i, _, times in shown for t in times]
    if frames:
        section.figures.append((filmstrip_png(frames, captions),
                                "Filmstrip of the simulated plan (offscreen MuJoCo rendering)."))
    else:
        section.paragraphs.append(f"No pictures: {note or 'nothing to draw'}; the physics "
                                  "above does not need them.")
    return section, records
