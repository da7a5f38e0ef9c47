"""The report's robot section: the plan executed by the bundled Panda, drawn from its records.

Drawn from :func:`nonprehensile.sim.report_runs.robot_execution`'s document (needs neither
MuJoCo nor an OpenGL context): a filmstrip of the arm (its collision capsules, the rod and the
fingertip, and the object, from the recorded joint positions and object pose at a few
instants, seen from the side), and the robot's records over time: fingertip tracking error
with the time in contact shaded, each joint's distance to the ends of its range, and the
largest share of a joint's velocity and torque limit in use.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from nonprehensile.viz._figures import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["arm_filmstrip_figure", "robot_signals", "robot_signals_figure", "side_view"]


def side_view(frames: Sequence[Mapping[str, Any]]) -> tuple[Any, Any]:
    """The horizontal axis of the side view and its origin: from the arm's base (the first
    segment's start) toward the object, so that the arm's reach lies across the picture.

    Returns
    -------
    (u, origin) : arrays, shape (3,)
    """
    base = np.asarray(frames[0]["segments"], dtype=float)[0, 0]
    target = np.asarray(frames[0]["object"], dtype=float).mean(axis=0)
    u = np.array([target[0] - base[0], target[1] - base[1], 0.0])
    norm = float(np.linalg.norm(u))
    u = u / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    return u, np.array([base[0], base[1], 0.0])


def _hull(points: Any) -> Any:
    """Convex hull of 2-D points, counterclockwise (Andrew's monotone chain: a handful of
    points, no scipy.spatial import for it)."""
    pts = sorted({(round(float(x), 9), round(float(y), 9)) for x, y in points})
    if len(pts) <= 2:
        return np.array(pts)

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def arm_filmstrip_figure(frames: Sequence[Mapping[str, Any]], *, per_row: int = 4,
                         captions: Sequence[str] | None = None) -> Figure:
    """The arm and the object at the recorded instants, side by side, seen from the side.

    Parameters
    ----------
    frames : sequence of mapping
        :func:`~nonprehensile.sim.report_runs.arm_frames`: per instant ``segments`` (m, 2, 3)
        and ``radii`` (m,) of the arm's shapes, ``object`` (n, 3) vertices, ``tip`` (3,),
        ``touch``, ``step``, ``time``; metres, world frame.
    per_row : int
        Panels per row.
    captions : sequence of str, optional
        Per frame (default: step and time, and "touching" while the fingertip touches).

    Each shape is drawn as a line as thick as its diameter (the axes have equal scales in
    metres, so a capsule's width is to scale), the object as the outline of its vertices'
    projection, filled; the table's surface is the line ``z = 0``. The view looks along the
    horizontal perpendicular of the base-to-object direction (:func:`side_view`).
    """
    from matplotlib.collections import LineCollection

    n = len(frames)
    if n == 0:
        raise ValueError("no frame to draw")
    u, origin = side_view(frames)
    cols = min(per_row, n)
    rows = (n + cols - 1) // cols

    def proj(p: Any) -> Any:
        p = np.asarray(p, dtype=float) - origin
        return np.stack([p[..., :] @ u, p[..., 2]], axis=-1)

    # one frame for every panel: the arm's and the object's extent over all instants
    every = np.concatenate([proj(np.asarray(f["segments"]).reshape(-1, 3)) for f in frames]
                           + [proj(f["object"]) for f in frames])
    pad = 0.06
    x0, x1 = float(every[:, 0].min()) - pad, float(every[:, 0].max()) + pad
    y0, y1 = -0.05, float(every[:, 1].max()) + pad
    panel_w = 2.6
    panel_h = panel_w * (y1 - y0) / (x1 - x0)
    fig = new_figure(figsize=(panel_w * cols, (panel_h + 0.3) * rows), dpi=80)
    points_per_m = 72.0 * panel_w / (x1 - x0)  # line widths are in points
    for k, f in enumerate(frames):
        r, c = divmod(k, cols)
        ax = fig.add_axes((c / cols, 1 - (r + 1) / rows, 1 / cols,
                           (panel_h / (panel_h + 0.3)) / rows))
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.axhspan(y0, 0.0, color="0.85", lw=0)
        ax.axhline(0.0, color="0.4", lw=0.8)
        obj = _hull(proj(f["object"]))
        ax.fill(obj[:, 0], obj[:, 1], color="#e6a23c", ec="#8a5a00", lw=0.8, zorder=2)
        segs = proj(np.asarray(f["segments"]))
        radii = np.asarray(f["radii"], dtype=float)
        # the largest shapes first, so the rod and the tip stay visible in front
        order = np.argsort(-radii)
        ax.add_collection(LineCollection(
            segs[order], linewidths=2 * radii[order] * points_per_m, colors="#6b7b8c",
            capstyle="round", zorder=3, alpha=0.9))
        tip = proj(f["tip"])
        ax.plot([tip[0]], [tip[1]], "o", ms=3, color="#d62728" if f.get("touch") else "k",
                zorder=4)
        text = (captions[k] if captions is not None else
                ("end" if f["step"] == 0 else f"step {f['step']}")
                + f", {f['time']:.2f} s" + (", touching" if f.get("touch") else ""))
        ax.set_title(text, fontsize=7, pad=2)
    return fig


def robot_signals(log: Mapping[str, Any], limits: Mapping[str, Any]) -> dict[str, Any]:
    """What the signals figure plots, from the robot's per-control-step log.

    Returns
    -------
    dict
        ``time`` (n,), ``error_mm`` (n,), ``touch`` (n,), ``margin_rad`` (n, n_joints): each
        joint's distance to the nearer end of its range, ``velocity_use`` and
        ``torque_use`` (n,): the largest ``|qd| / limit`` and ``|tau| / limit`` over the
        joints (joints without a torque limit left out).
    """
    q = np.asarray(log["q"], dtype=float)
    lower, upper = np.asarray(limits["lower"], float), np.asarray(limits["upper"], float)
    torque = np.asarray(limits["torque"], dtype=float)
    finite = np.isfinite(torque)
    tau = np.abs(np.asarray(log["tau"], dtype=float))
    return {
        "time": np.asarray(log["time"], dtype=float),
        "error_mm": 1000.0 * np.asarray(log["error"], dtype=float),
        "touch": np.asarray(log["touch"], dtype=bool),
        "margin_rad": np.minimum(q - lower, upper - q),
        "velocity_use": (np.abs(np.asarray(log["qd"], dtype=float))
                         / np.asarray(limits["velocity"], dtype=float)).max(axis=1),
        "torque_use": (tau[:, finite] / torque[finite]).max(axis=1) if finite.any()
        else np.zeros(len(q)),
    }


def _spans(flags: Any) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of True."""
    f = np.concatenate(([False], np.asarray(flags, dtype=bool), [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(f))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def robot_signals_figure(log: Mapping[str, Any], limits: Mapping[str, Any],
                         steps: Sequence[tuple[int, float, float]] = ()) -> Figure:
    """The robot's records over the whole execution, three rows on one time axis.

    Rows: the fingertip's distance from its target (mm; shaded where it touches the
    object), each joint's distance to the nearer end of its range (rad, one line per joint),
    and the largest share of a velocity and of a torque limit in use (1: at the limit).
    Dotted lines: where each executed step starts and ends (``steps``: ``(number, t0,
    t1)``).
    """
    sig = robot_signals(log, limits)
    t = sig["time"]
    names = [str(n).split("/")[-1] for n in limits.get("joint_names", [])]
    fig = new_figure(figsize=(9.6, 6.0), dpi=80)
    axes = [fig.add_axes((0.09, 0.70 - 0.3 * r, 0.74, 0.26)) for r in range(3)]
    for ax in axes:
        for a, b in _spans(sig["touch"]):
            ax.axvspan(t[a], t[min(b, len(t) - 1)], color="#fde2c8", lw=0)
        marks = sorted({v for _, t0, t1 in steps for v in (t0, t1)})
        if marks:
            ax.vlines(marks, 0.0, 1.0, transform=ax.get_xaxis_transform(), colors="0.45",
                      lw=0.8, linestyles=":")
        ax.set_xlim(float(t[0]), float(t[-1]))
        ax.tick_params(labelsize=8)
    axes[0].plot(t, sig["error_mm"], color="#d62728", lw=1.0)
    axes[0].set_ylabel("tracking error (mm)", fontsize=9)
    axes[0].set_ylim(0.0, max(1.0, float(sig["error_mm"].max()) * 1.1))
    for number, t0, t1 in steps:
        axes[0].text((t0 + t1) / 2, 1.02, f"step {number}", ha="center", va="bottom",
                     transform=axes[0].get_xaxis_transform(), fontsize=8, color="0.3")
    margin = sig["margin_rad"]
    for j in range(margin.shape[1]):
        axes[1].plot(t, margin[:, j], lw=1.0, label=names[j] if j < len(names) else f"q{j + 1}")
    axes[1].set_ylabel("joint margin (rad)", fontsize=9)
    axes[1].set_ylim(0.0, max(0.1, float(margin.max()) * 1.05))
    axes[1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0), frameon=False)
    axes[2].plot(t, sig["velocity_use"], color="#1f77b4", lw=1.0, label="velocity")
    axes[2].plot(t, sig["torque_use"], color="#9467bd", lw=1.0, label="torque")
    axes[2].set_ylim(0.0, 1.05)
    axes[2].set_ylabel("share of the limit", fontsize=9)
    axes[2].set_xlabel("simulated time (s)", fontsize=9)
    axes[2].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0), frameon=False)
    for ax in axes[:2]:
        ax.set_xticklabels([])
    return fig
