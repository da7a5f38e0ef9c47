"""The base placement search drawn as a reachability map.

Drawn from :meth:`nonprehensile.sim.placement.Placement.candidates_dict` (plain numbers:
needs neither MuJoCo nor mink): every candidate base the search tried, seen from above, those
that reach the whole plan (transits included) coloured by their least joint margin over it,
those that do not as crosses, the chosen base with its heading, and the plan's fingertip path.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from nonprehensile.errors import InputError
from nonprehensile.viz._figures import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["reachability_figure"]


def reachability_figure(candidates: Sequence[Mapping[str, Any]], chosen: Mapping[str, Any],
                        targets_xy: Any = None) -> Figure:
    """A top view of the base placement search.

    Parameters
    ----------
    candidates : sequence of dict
        Each ``{"base": {"x", "y", "yaw_deg"}, "reach_error_m", "joint_margin_rad",
        "feasible"}`` (:meth:`~nonprehensile.sim.placement.Placement.candidates_dict`).
    chosen : dict
        The chosen base, ``{"x", "y", "yaw_deg"}`` (m, m, degrees).
    targets_xy : array_like, shape (n, 2), optional
        The plan's fingertip targets seen from above (m), drawn as a line.

    Raises
    ------
    InputError
        No candidates (nothing was searched: a base given with ``--base``).
    """
    if not candidates:
        raise InputError("no candidate bases to draw: the base was given, not searched "
                         "(drop --base to search it)")
    xy = np.array([[c["base"]["x"], c["base"]["y"]] for c in candidates], dtype=float)
    ok = np.array([bool(c["feasible"]) for c in candidates])
    margin = np.array([float(c["joint_margin_rad"]) for c in candidates])
    fig = new_figure(figsize=(6.4, 6.2), dpi=80)
    ax = fig.add_axes((0.12, 0.2, 0.66, 0.72))
    if targets_xy is not None:
        t = np.asarray(targets_xy, dtype=float).reshape(-1, 2)
        ax.plot(t[:, 0], t[:, 1], color="tab:orange", lw=1.2, label="fingertip path")
    if (~ok).any():
        ax.scatter(xy[~ok, 0], xy[~ok, 1], marker="x", color="0.55", s=28,
                   label="does not reach the whole plan")
    if ok.any():
        sc = ax.scatter(xy[ok, 0], xy[ok, 1], c=margin[ok], cmap="viridis", s=46,
                        edgecolors="k", linewidths=0.4, label="reaches it")
        cax = fig.add_axes((0.82, 0.2, 0.03, 0.72))
        cb = fig.colorbar(sc, cax=cax)
        cb.set_label("least joint margin over the plan (rad)", fontsize=9)
    bx, by, yaw = float(chosen["x"]), float(chosen["y"]), math.radians(float(chosen["yaw_deg"]))
    span = float(np.ptp(xy, axis=0).max()) if len(xy) > 1 else 0.5
    arrow = 0.12 * max(span, 0.2)
    ax.scatter([bx], [by], marker="*", s=260, facecolors="none", edgecolors="#d62728",
               linewidths=1.6, label="chosen base", zorder=5)
    ax.annotate("", xy=(bx + arrow * math.cos(yaw), by + arrow * math.sin(yaw)), xytext=(bx, by),
                arrowprops={"arrowstyle": "->", "color": "#d62728", "lw": 1.6}, zorder=6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{int(ok.sum())} of {len(candidates)} candidate bases reach the whole plan "
                 "(transits included)", fontsize=10)
    # below the map: the candidates' rings fill the axes
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8,
              frameon=False)
    ax.tick_params(labelsize=8)
    return fig
