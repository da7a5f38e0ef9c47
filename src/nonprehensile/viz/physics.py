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
from nonprehensile.viz.report import Section, figure_pixels, figure_to_png, png_bytes

__all__ = ["FRAME_SIZE", "down_element", "filmstrip_figure", "filmstrip_png",
           "physics_section", "signals_figure"]


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


def down_element(poly: Polyhedron, rotation: Any, *, tilt_deg: float = 3.0) -> str:
    """What the object stands on under ``rotation``: its bottom face (``"a"``), or, tipped
    over more than ``tilt_deg``, the edge (``"E(a,b)"``) or vertex (``"V(a,b,c)"``) lowest.

    The edge or vertex is the one whose vertices lie within 1 % of the object's diameter of
    the lowest vertex (the object pivots on it).
    """
    import math

    rot = np.asarray(rotation, dtype=float)
    faces = poly.face_ids
    normals_z = np.array([(rot @ poly.normals[f])[2] for f in faces])
    i = int(np.argmin(normals_z))
    if math.degrees(math.acos(float(np.clip(-normals_z[i], -1.0, 1.0)))) <= tilt_deg:
        return faces[i]
    z = poly.vertices @ rot[2]
    low = np.flatnonzero(z <= z.min() + 0.01 * poly.diameter)
    common = frozenset.intersection(*(poly.vertex_faces[int(v)] for v in low))
    if len(low) == 2 and len(common) == 2:
        return f"E({','.join(sorted(common))})"
    if len(low) == 1:
        return f"V({','.join(sorted(poly.vertex_faces[int(low[0])]))})"
    return faces[i]  # several low vertices without one edge: nearest face down


def _quat_matrix(q: Any) -> Any:
    """A rotation matrix from MuJoCo's unit quaternion ``[w, x, y, z]``."""
    w, x, y, z = (float(v) for v in q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def signals_figure(traces: Sequence[Any], *, n_fingers: int, motion_end: Sequence[float],
                   titles: Sequence[str],
                   events: Sequence[Sequence[tuple[float, str]]] = ()) -> Any:
    """Per-step plots of what the execution did: one column per step, three rows.

    Rows: each finger's tracking error (mm, its distance from the commanded target), its
    normal contact force on the object (N), and the object's slip on the table (mm/s, the
    largest horizontal speed of its points on the table; gaps where it is off the table).
    Each row shares one scale across the steps; the settling after the motion is shaded,
    and the times at which the reference motion expects the skill's contact events are
    dotted lines, named at the top. A fixed layout (issue 16).

    Parameters
    ----------
    traces : sequence of array
        Per step, a trace kept with ``signals=True`` (:meth:`Simulator.run`).
    n_fingers : int
        Fingers in the scene (the trace's columns).
    motion_end : sequence of float
        Per step, when the reference motion ends (s).
    titles : sequence of str
        Per step, its panel title.
    events : sequence of sequence of (float, str)
        Per step, its skill's contact events: when the reference motion expects each, and
        its id.
    """
    from matplotlib.ticker import MaxNLocator

    from nonprehensile.sim.run import signal_columns

    cols = signal_columns(n_fingers)
    n = len(traces)
    xticks, yticks = MaxNLocator(4), MaxNLocator(3)
    rows = (("error", "tracking error (mm)", 1000.0), ("force", "contact force (N)", 1.0),
            ("slip", "object slip (mm/s)", 1000.0))
    width, height = min(14.2, 1.2 + 4.2 * n), 6.2
    fig = new_figure(figsize=(width, height))
    left, right, bottom, top = 0.9 / width, 0.2 / width, 0.55 / height, 0.62 / height
    gap_x, gap_y = 0.35 / width, 0.3 / height
    w = (1 - left - right - gap_x * (n - 1)) / n
    h = (1 - bottom - top - gap_y * 2) / 3
    colors = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e")
    limits = {}
    for key, _, unit in rows:
        values = np.concatenate([np.asarray(tr)[:, cols[key]].ravel() * unit for tr in traces])
        values = values[np.isfinite(values)]
        limits[key] = float(values.max()) * 1.1 if values.size and values.max() > 0 else 1.0
    for c, tr in enumerate(traces):
        tr = np.asarray(tr)
        t = tr[:, 0]
        for r, (key, label, unit) in enumerate(rows):
            ax = fig.add_axes((left + c * (w + gap_x), 1 - top - (r + 1) * h - r * gap_y, w, h))
            ax.axvspan(motion_end[c], t[-1], color="0.92", lw=0)
            marks = list(events[c]) if c < len(events) else []
            if marks:  # one collection for the column's event lines (a line each: ticks' cost)
                ax.vlines([e for e, _ in marks], 0.0, 1.0, transform=ax.get_xaxis_transform(),
                          colors="0.45", lw=0.8, linestyles=":")
            for k, (e, name) in enumerate(marks if r == 0 else ()):
                # named once, above the column, staggered where close
                ax.text(e, 1.02 + 0.13 * (k % 2), name, transform=ax.get_xaxis_transform(),
                        ha="center", va="bottom", fontsize=8, color="0.3")
            data = tr[:, cols[key]] * unit
            for k in range(data.shape[1]):
                ax.plot(t, data[:, k], color=colors[k % len(colors)], lw=1.3,
                        label=f"R{k + 1}" if key != "slip" else None)
            # a few ticks, set once: a tick costs about a millisecond (issue 16)
            ax.set_xticks(xticks.tick_values(0.0, t[-1]),
                          None if r == 2 else [])
            ax.set_yticks(yticks.tick_values(0.0, limits[key]), None if c == 0 else [])
            ax.set_xlim(0.0, t[-1])
            ax.set_ylim(0.0, limits[key])
            ax.tick_params(labelsize=9)
            if c == 0:
                ax.set_ylabel(label, fontsize=9)
            if r == 2:
                ax.set_xlabel("time in the step (s)", fontsize=9)
            if r == 0:
                ax.set_title(titles[c], fontsize=10, y=1.3)
                if c == 0 and data.shape[1] > 1:
                    ax.legend(fontsize=8, loc="upper right", frameon=False)
    return fig


def correction_times(transits: Sequence[Mapping[str, Any]],
                     corrections: Sequence[Any]) -> list[str]:
    """When each correction push of an execution ran: ``"before step N"`` for a turn back
    onto a step's predicted state (or onto the re-planner's frame) between steps, ``"at the
    end"`` for the turns and slides onto the goal after the last step. Read from the
    transits (each push is preceded by one, labelled ``turn`` or ``correction``, in the
    order of ``corrections``); ``"-"`` for each when they do not pair up."""
    labels = [str(t.get("before", "")) for t in transits]
    when = []
    for i, label in enumerate(labels):
        if label in ("turn", "correction"):
            nxt = next((x for x in labels[i + 1:] if x.startswith("step ")), None)
            when.append(f"before {nxt}" if nxt else "at the end")
    return when if len(when) == len(corrections) else ["-"] * len(corrections)


def physics_section(
    poly: Polyhedron, plan: Plan, *, scale: float, fingers: Mapping[str, str],
    replan: Any = None,
) -> tuple[Section, list[dict[str, Any]]]:
    """Execute the plan closed loop (and open loop beside) and describe it; also returns the
    closed loop's per-step records (JSON). ``replan``: the executor's re-planner
    (:func:`nonprehensile.control.replanner`), so a step that ends elsewhere is re-planned."""
    title = "Physics: the plan executed in MuJoCo"
    try:
        from nonprehensile.sim import Simulator
        from nonprehensile.sim.closed_loop import execute_plan, scene_fingers
        from nonprehensile.sim.render import render_traces
        from nonprehensile.sim.run import signal_columns
    except ImportError:
        return Section(title, ["The simulation needs the `sim` extra (MuJoCo): "
                               "pip install 'nonprehensile[sim]'. Not simulated here."]), []
    if not plan.steps:
        return Section(title, ["The plan has no step to simulate."]), []
    n = scene_fingers(plan)
    sim = Simulator(poly, scale=scale, n_fingers=n)
    # closed loop, one continuous simulation with transits; every executed step keeps its
    # trace (with the signals) for the pictures
    ex = execute_plan(sim, plan, fingers=fingers, loop="closed", replan=replan,
                      keep_trace=10, signals=True)
    opened = execute_plan(Simulator(poly, scale=scale, n_fingers=n), plan, fingers=fingers,
                          loop="open")
    cols = signal_columns(n)
    records = []
    traces = []
    for (_step, outcome), rec in zip(ex.executed, ex.steps, strict=True):
        # a step succeeds when the object rests in its predicted state; its position is
        # shown (the goal's position is judged at the end, after any correction)
        r = {**outcome.to_dict(), "success": rec["success"], "outcome": rec["outcome"],
             "reason": rec["reason"], "observed": rec["observed"],
             "next": rec.get("next", "")}
        tr = outcome.result.trace
        traces.append(tr)
        if tr is not None and tr.shape[1] > cols["slip"].start:
            slip = tr[:, cols["slip"]]
            # the largest of each signal over the step, for programs (the figure shows all)
            r["signals"] = {
                "max_tracking_error_m": round(float(tr[:, cols["error"]].max()), 6),
                "max_contact_force_n": round(float(tr[:, cols["force"]].max()), 4),
                "max_slip_m_per_s": (round(float(np.nanmax(slip)), 6)
                                     if np.isfinite(slip).any() else None),
            }
        records.append(r)
    doc = ex.to_dict()
    lim = doc["limits"]
    fs = ex.final_state
    verdict = (f"It reached the goal {plan.goal}" if ex.success else
               f"It did NOT reach the goal {plan.goal} ({ex.reason})")
    paras = [
        f"The plan was executed in one continuous MuJoCo simulation, closed loop "
        f"(`simulate plan --loop closed`, docs/physics.md): before each step the fingertip "
        "moves clear of the object and approaches it (a transit); each arc of the skill's "
        "graph runs its reference motion placed on the object where it is observed, until "
        "the arc's end event is observed; the state is read from the observed pose at the "
        "end of the step, and a step that ends elsewhere is re-planned from there. "
        f"{verdict}: it rests on {fs if fs is not None else 'no face'}"
        + (f", theta {ex.theta_error:+.1f} degrees and" if ex.theta_error is not None
           else ",")
        + f" {1000 * (ex.position_error or 0.0):.1f} mm from the goal position (the plan's "
        "prediction; the bar is 5 degrees and 10 mm). "
        f"{plural(len([r for r in ex.replans if not r.get('retry')]), 're-plan')}, "
        f"{plural(len([r for r in ex.replans if r.get('retry')]), 'retry', 'retries')}, "
        f"{plural(len(ex.corrections), 'correction push', 'correction pushes')}. "
        f"Fingertips: at most {lim['commanded_max_speed']:.2f} m/s and "
        f"{lim['commanded_max_accel']:.1f} m/s^2 commanded, "
        f"{lim['transit_finger_object_contact_s']:.3f} s of fingertip contact with the "
        f"object in the {len(ex.transits)} transits.",
        "Open loop beside (each step's reference where the plan predicts the object, run "
        "for its duration): it "
        + ("reached" if opened.success else "did NOT reach")
        + f" the goal, resting on {opened.final_state}, "
        f"{1000 * (opened.position_error or 0.0):.1f} mm from the goal position. "
        f"Physics: {sim.params.mass:g} kg object, friction {sim.params.friction_table:g} "
        f"(table) / {sim.params.friction_finger:g} (finger), fingertip radius "
        f"{1000 * sim.params.finger_radius:g} mm, {1000 * sim.params.timestep:g} ms steps; "
        "the robustness of both across the physics distribution is measured in "
        "docs/benchmarks.md.",
    ]
    rows = []
    for r in records:
        sim_state = r["simulated"]
        seen = [f"{e['event']} {e['time']:.2f} s" for e in r["observed"] if "event" in e]
        odd = [e["anomaly"] for e in r["observed"] if "anomaly" in e]
        rows.append([
            str(r["step"]), r["skill"],
            f"{r['from']['face']}:{r['from']['theta']:g} -> {r['predicted']['face']}:"
            f"{r['predicted']['theta']:g}",
            "-" if sim_state is None else f"{sim_state['face']}:{sim_state['theta']:.1f}",
            "-" if r["position_error_m"] is None else f"{1000 * r['position_error_m']:.1f}",
            " -> ".join(seen) or "-",
            "; ".join(odd) or "-",
            "yes" if r["success"] else "NO",
        ])
    tables: list[Any] = [(["step", "skill", "predicted", "simulated", "position error (mm)",
                "observed events (time from the step's start)", "anomaly",
                "in the predicted state"], rows)]
    extra = []
    for rp in ex.replans:
        extra.append([f"after step {rp['after_step']}",
                      "retry" + (" (higher, slower)" if rp.get("higher") else "")
                      if rp.get("retry") else "re-plan", rp["reason"],
                      "; ".join(rp.get("steps", [])) or rp.get("error", "")])
    for c, when in zip(ex.corrections, correction_times(ex.transits, ex.corrections),
                       strict=True):
        what = (f"theta {c['theta_error_before_deg']:+.1f} -> "
                f"{c['theta_error_after_deg']:+.1f} deg" if c["kind"] == "turn"
                and c["theta_error_after_deg"] is not None else
                f"moved {1000 * c.get('moved_m', 0.0):.1f} mm, "
                f"{1000 * c.get('error_after_m', 0.0):.1f} mm from the goal")
        extra.append([when, f"{c['kind']} push on face {c['face']}", what, ""])
    if extra:
        tables.append((["when", "what", "why / result", "new steps"], extra))
    section = Section(title, paras, [], tables)
    shown = [(i, tr, [float(t) for t in np.linspace(0.0, float(tr[-1, 0]), 6)])
             for i, tr in enumerate(traces) if tr is not None and len(tr)]
    got, note = (render_traces(sim, [(tr, times) for _, tr, times in shown],
                               width=FRAME_SIZE[0], height=FRAME_SIZE[1]) if shown
                 else (None, ""))
    frames: list[Any] = got or []
    captions = []
    for i, tr, times in shown:
        for t in times:
            row = tr[int(np.clip(np.searchsorted(tr[:, 0], t), 0, len(tr) - 1))]
            captions.append(f"step {i + 1}, {t:.2f} s, down: "
                            f"{down_element(poly, _quat_matrix(row[4:8]))}")
    if frames:
        section.figures.append((filmstrip_png(frames, captions),
                                "Filmstrip of the executed plan, closed loop (offscreen MuJoCo "
                                "rendering); each frame names what the object stands on: its "
                                "bottom face, or the edge E(f,g) or vertex V(...) it pivots "
                                "on."))
    else:
        section.paragraphs.append(f"No pictures: {note or 'nothing to draw'}; the physics "
                                  "above does not need them.")
    if shown:
        observed = [[(float(e["time"]), str(e["event"])) for e in records[i]["observed"]
                     if "event" in e] for i, _, _ in shown]
        ends = [ev[-1][0] if ev else float(tr[-1, 0]) for ev, (_, tr, _) in
                zip(observed, shown, strict=True)]
        titles = [f"step {i + 1}: {records[i]['skill']} "
                  f"({'as predicted' if records[i]['success'] else 'NOT as predicted'})"
                  for i, _, _ in shown]
        fig = signals_figure([tr for _, tr, _ in shown], n_fingers=n, motion_end=ends,
                             titles=titles, events=observed)
        section.figures.append((figure_to_png(fig), (
            "What the execution did, step by step: each fingertip's distance from its "
            "commanded target (tracking error), its normal force on the object, and how fast "
            "the object's points on the table slide (slip; a roll pivots on an edge, which "
            "should not slide). Dotted: when the controller observed each of the skill's "
            "contact events; grey: after the last one, the object coming to rest.")))
    return section, records


def plural(n: int, word: str, many: str | None = None) -> str:
    """``1 re-plan``, ``2 re-plans``."""
    return f"{n} {word if n == 1 else many or word + 's'}"
