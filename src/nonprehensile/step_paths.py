"""The reference finger paths of a plan step (paper Section VII, step 4), as a controller
tracks them.

A step's reference is its arcs' reference motions one after the other
(:func:`step_targets`): each arc starts where the previous one ended and blends into its own
path (consecutive arcs' medoids may come from different demonstrations), and the whole is
filtered as a tracking controller filters measured paths (:func:`smooth_markers`).

Pure core: numpy only.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from nonprehensile.demonstrations.dataset import DEFAULT_FINGERS
from nonprehensile.errors import InputError
from nonprehensile.planning import PlanStep
from nonprehensile.skills.contacts import Finger
from nonprehensile.skills.skill import Skill

__all__ = ["ease", "fingers_of", "knuckle_marker", "marker_index", "resample", "smooth_markers",
           "step_directions", "step_targets", "with_stop"]

FloatArray = NDArray[np.float64]


def fingers_of(skill: Skill) -> list[int]:
    """The finger numbers a skill names."""
    return sorted({el.index for e in skill.events for p in e.pairs
                   for el in (p.x, p.y) if isinstance(el, Finger)})


def marker_index(fingers: Mapping[str, str], k: int,
                 names: tuple[str, ...] | list[str]) -> int:
    """Column of finger ``Rk``'s tip marker among ``names``."""
    name = fingers.get(f"R{k}")
    if name is None or name not in names:
        raise InputError(f"finger R{k} has no tip marker among {list(names)} (the dataset's "
                         f"fingers map {dict(fingers)})")
    return list(names).index(name)


def ease(s: FloatArray) -> FloatArray:
    """Minimum-jerk profile from 0 to 1 (``s`` in [0, 1])."""
    return np.asarray(s**3 * (10.0 - 15.0 * s + 6.0 * s**2))


def smooth_markers(pos: FloatArray, n: int) -> FloatArray:
    """Centred moving average over ``n`` frames along axis 0 (ends padded by repetition)."""
    k = np.ones(n) / n
    pad = np.concatenate([np.repeat(pos[:1], n // 2, axis=0), pos,
                          np.repeat(pos[-1:], n - 1 - n // 2, axis=0)])
    flat = pad.reshape(len(pad), -1)
    out = np.column_stack([np.convolve(flat[:, j], k, mode="valid")
                           for j in range(flat.shape[1])])
    return out.reshape(pos.shape)


def step_targets(
    step: PlanStep, fingers: Mapping[str, str] = DEFAULT_FINGERS, smooth: int = 9,
) -> tuple[dict[int, FloatArray], float, list[float]]:
    """The fingertip targets of a step: its reference motions one after the other.

    Returns
    -------
    targets : dict of int to array, shape (n_frames, 3)
    rate : float
    event_times : list of float
        Expected time of each skill event (the arcs' boundaries).

    Raises
    ------
    InputError
        If an arc has no reference motion, or the arcs' rates differ.
    """
    skill = step.transition.skill
    wanted = fingers_of(skill)
    chunks: dict[int, list[FloatArray]] = {k: [] for k in wanted}
    rate = None
    times = [0.0]
    total = 0
    for source, target, _, ref in step.motions:
        if ref is None:
            raise InputError(f"skill {skill.name!r} has no reference motion for its arc "
                             f"{source} -> {target}: give demonstrations of it (--dataset)")
        if rate is not None and abs(ref.rate - rate) > 1e-9:
            raise InputError(f"the reference motions of {skill.name!r} differ in rate "
                             f"({rate:g} and {ref.rate:g} Hz)")
        rate = ref.rate
        skip = 0 if total == 0 else 1  # arcs share their boundary frame
        for k in wanted:
            p = np.array(ref.positions[:, marker_index(fingers, k, ref.marker_names)])
            if chunks[k]:
                # consecutive arcs' references may be medoids of different demonstrations,
                # whose fingers were at slightly different places at the shared event: start
                # where the previous arc ended and blend into this arc's own path, so the
                # fingertip never jumps
                gap = chunks[k][-1][-1] - p[0]
                w = 1.0 - ease(np.linspace(0.0, 1.0, len(p)))
                p = p + np.outer(w, gap)
            chunks[k].append(p[skip:])
        total += len(ref.positions) - skip
        times.append((total - 1) / ref.rate)
    if rate is None:
        raise InputError(f"skill {skill.name!r} has no motion arcs to execute")
    # the references are measured paths: filtered as a tracking controller would
    return ({k: smooth_markers(np.concatenate(v), smooth) if smooth > 1 else np.concatenate(v)
             for k, v in chunks.items()}, rate, times)


def knuckle_marker(tip: str, names: tuple[str, ...] | list[str]) -> str | None:
    """The knuckle marker of the finger whose tip marker is ``tip``.

    The rule is a naming convention (the dataset format maps fingers to tip markers only):
    the tip's name with its ``_tip`` ending turned into ``_knuckle`` (``index_tip`` ->
    ``index_knuckle``, the bundled recordings' and the paper's Fig. 11 markers).

    Parameters
    ----------
    tip : str
        The finger's tip marker (the dataset's ``fingers`` map).
    names : sequence of str
        The markers a recording has.

    Returns
    -------
    str or None
        The knuckle's name; None when ``tip`` does not end in ``_tip`` or no such marker
        is among ``names``.
    """
    if not tip.endswith("_tip"):
        return None
    name = tip.removesuffix("_tip") + "_knuckle"
    return name if name in names else None


def step_directions(
    step: PlanStep, fingers: Mapping[str, str] = DEFAULT_FINGERS, smooth: int = 9,
) -> dict[int, FloatArray]:
    """The recorded finger directions of a step, frame by frame as :func:`step_targets`
    gives its targets: the unit vector from each finger's knuckle marker to its tip marker
    (:func:`knuckle_marker`), the direction a finger tool's axis points from the flange to
    the tip, filtered as the targets are.

    Returns
    -------
    directions : dict of int to array, shape (n_frames, 3)
        Only the fingers whose knuckle is in every arc's reference (none if any arc has no
        reference motion: :func:`step_targets` says why).
    """
    wanted = fingers_of(step.transition.skill)
    chunks: dict[int, list[FloatArray]] = {k: [] for k in wanted}
    total = 0
    for _, _, _, ref in step.motions:
        if ref is None:
            return {}
        skip = 0 if total == 0 else 1  # arcs share their boundary frame (step_targets)
        for k in list(chunks):
            tip = fingers.get(f"R{k}")
            knuckle = None if tip is None else knuckle_marker(tip, ref.marker_names)
            if tip is None or knuckle is None or tip not in ref.marker_names:
                del chunks[k]  # a finger without its knuckle in one arc has no direction
                continue
            names = list(ref.marker_names)
            d = ref.positions[:, names.index(tip)] - ref.positions[:, names.index(knuckle)]
            chunks[k].append(np.asarray(d[skip:], dtype=np.float64))
        total += len(ref.positions) - skip
    out: dict[int, FloatArray] = {}
    for k, v in chunks.items():
        d = np.concatenate(v) if v else np.zeros((0, 3))
        if smooth > 1 and len(d):
            d = smooth_markers(d, smooth)
        norm = np.linalg.norm(d, axis=1)
        if len(d) == 0 or not np.all(norm > 1e-9):  # a marker on top of the other: no axis
            continue
        out[k] = d / norm[:, None]
    return out


def resample(path: FloatArray, rate: float, dt: float) -> FloatArray:
    """Rows of ``path`` (shape (n, ..., 3), sampled at ``rate`` Hz) every ``dt`` s, by a
    cubic spline: linear interpolation of a 120 Hz path to a 1 kHz physics step would make
    the commanded velocity a staircase, its acceleration spikes of tens of m/s^2 at every
    frame."""
    n = len(path)
    m = max(1, round((n - 1) / rate / dt))
    if n < 4:
        t_ref = np.arange(n) / rate
        flat = path.reshape(n, -1)
        t = np.arange(m + 1) * dt
        out = np.column_stack([np.interp(t, t_ref, flat[:, j]) for j in range(flat.shape[1])])
        return out.reshape((m + 1, *path.shape[1:]))
    spline = CubicSpline(np.arange(n) / rate, path, axis=0)
    t = np.minimum(np.arange(m + 1) * dt, (n - 1) / rate)
    return np.asarray(spline(t))


def with_stop(path: FloatArray, rate: float, tau: float = 0.1) -> FloatArray:
    """``path`` (shape (n, ..., 3) at ``rate`` Hz) extended by ``tau`` s in which it comes
    to rest from its final velocity (a cubic Hermite leg: the acceleration stays within
    ``2 |v| / tau``). A demonstration's segment is cut at an event, still moving: held
    there, a fingertip would be asked to stop within one physics step."""
    if len(path) < 2:
        return path
    v = (path[-1] - path[-2]) * rate
    k = max(2, round(tau * rate))
    s = np.arange(1, k + 1) / k
    # h(s) = p + v tau (s - s^2 + s^3 / 3): velocity v (1 - s)^2, at rest at s = 1
    shape = (s - s**2 + s**3 / 3.0).reshape((k,) + (1,) * (path.ndim - 1))
    return np.concatenate([path, path[-1][None] + tau * shape * v[None]])
