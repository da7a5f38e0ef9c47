"""Robustness figure: success rate against each physical parameter, open and closed loop.

Drawn from a sweep's JSON document (:meth:`nonprehensile.sim.robustness.SweepResult.to_dict`,
``simulate robustness --json``), so it needs neither MuJoCo nor the sweep's objects: one panel
per varied quantity, the success rate of each of its bins with the 95 % Wilson interval as
error bars, one line per loop.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from nonprehensile.viz._figures import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["PARAMETER_AXES", "robustness_figure"]

#: Axis label and factor from SI to the shown unit, per quantity.
PARAMETER_AXES: dict[str, tuple[str, float]] = {
    "friction_table": ("table friction", 1.0),
    "friction_finger": ("finger friction", 1.0),
    "mass": ("mass (kg)", 1.0),
    "finger_radius": ("fingertip radius (mm)", 1000.0),
    "stiffness": ("finger stiffness (N/m)", 1.0),
    "max_force": ("finger force limit (N)", 1.0),
    "contact_timeconst": ("contact time constant (ms)", 1000.0),
    "start_offset": ("start position error (mm)", 1000.0),
    "start_yaw": ("start yaw error (deg)", 1.0),
    "tracking_noise": ("tracking noise (mm)", 1000.0),
    "finger_noise": ("finger noise (mm)", 1000.0),
}
_STYLE = {"closed": ("tab:blue", "o", "closed loop"), "open": ("tab:orange", "s", "open loop")}


def robustness_figure(doc: Mapping[str, Any], *, title: str | None = None,
                      parameters: list[str] | None = None) -> Figure:
    """Success rate against each parameter's bins, per loop.

    Parameters
    ----------
    doc : mapping
        A sweep's JSON document: ``bins`` (per quantity, a list of ``{low, high, <loop>:
        {k, n, rate, ci95}}``) and ``loops``.
    title : str, optional
    parameters : list of str, optional
        Which quantities (default every binned one).
    """
    from matplotlib.ticker import MaxNLocator

    bins = doc["bins"]
    names = [p for p in (parameters or list(bins)) if p in bins]
    loops = list(doc.get("loops", ["closed", "open"]))
    cols = min(4, max(1, len(names)))
    rows = (len(names) + cols - 1) // cols
    fig = new_figure(figsize=(3.2 * cols, 2.5 * rows + 0.5), dpi=80)
    for i, name in enumerate(names):
        ax = fig.add_subplot(rows, cols, i + 1)
        label, k = PARAMETER_AXES.get(name, (name, 1.0))
        for loop in loops:
            xs, ys, lo, hi = [], [], [], []
            for b in bins[name]:
                c = b.get(loop)
                if not c or not c["n"]:
                    continue
                xs.append(k * (b["low"] + b["high"]) / 2)
                ys.append(c["rate"])
                lo.append(c["rate"] - c["ci95"][0])
                hi.append(c["ci95"][1] - c["rate"])
            colour, marker, text = _STYLE.get(loop, ("k", "x", loop))
            ax.errorbar(xs, ys, yerr=[lo, hi], color=colour, marker=marker, capsize=3,
                        label=text, lw=1.2, ms=4)
        ax.set_ylim(-0.03, 1.03)
        ax.set_xlabel(label, fontsize=8)
        if i % cols == 0:
            ax.set_ylabel("success rate", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(5))  # mass in kg: six labels would collide
        ax.grid(alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7, loc="lower left")
    n = doc.get("samples")
    units = len(doc.get("units", []))
    fig.suptitle(title or f"{doc.get('object', '')}: success across the physics "
                 f"distribution ({units} unit(s) x {n} samples, 95 % Wilson intervals)",
                 fontsize=9)
    fig.tight_layout()
    return fig
