"""Compare a simulated motion with what the skill model predicts.

The prediction is a final state (and, for a plan step, a final position) and an event chain.
The simulation succeeds when the object rests in the predicted state (same bottom face,
``theta`` within ``angle_tol``) and, when a position is predicted, within ``position_tol``
of it. Beside that verdict: whether the skill's events appear in the simulated chain as an
in-order subsequence, which are missing, and the timing offset of each one found.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from nonprehensile.errors import ContactError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose
from nonprehensile.sim.run import SimEvent, SimResult
from nonprehensile.skills.contacts import ContactEvent, normalize_event
from nonprehensile.skills.skill import Skill
from nonprehensile.states import State, angle_diff

__all__ = ["DEFAULT_ANGLE_TOL_DEG", "DEFAULT_POSITION_TOL", "Comparison", "compare"]

#: A simulated final state matches the prediction within this many degrees.
DEFAULT_ANGLE_TOL_DEG = 5.0
#: A simulated final position matches the prediction within this many metres.
DEFAULT_POSITION_TOL = 0.010


@dataclass(frozen=True)
class Comparison:
    """Predicted vs simulated.

    Attributes
    ----------
    success : bool
        The object ended in the predicted state (and position, when predicted).
    predicted, simulated : State, State or None
    theta_error : float or None
        Simulated minus predicted ``theta``, degrees (same face only).
    position_error : float or None
        Distance between the simulated and predicted centre of mass on the table, metres.
    matched : tuple of (str, float or None, float or None)
        Per skill event: its id, the simulated time it was found at (None if missing) and
        that time minus the expected one (None if unknown).
    missing : tuple of str
        Skill events not found in order in the simulated chain.
    chain_ok : bool
        Every skill event was found, in order.
    """

    success: bool
    predicted: State
    simulated: State | None
    theta_error: float | None
    position_error: float | None
    matched: tuple[tuple[str, float | None, float | None], ...]
    missing: tuple[str, ...]
    chain_ok: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "success": self.success,
            "predicted": self.predicted.to_dict(),
            "simulated": self.simulated.to_dict() if self.simulated is not None else None,
            "theta_error_deg": None if self.theta_error is None else round(self.theta_error, 3),
            "position_error_m": (None if self.position_error is None
                                 else round(self.position_error, 5)),
            "chain_ok": self.chain_ok,
            "missing_events": list(self.missing),
            "events": [{"id": i, "sim_time": None if t is None else round(t, 4),
                        "offset_s": None if o is None else round(o, 4)}
                       for i, t, o in self.matched],
        }


def _norm(event: ContactEvent, poly: Polyhedron) -> frozenset[Any]:
    try:
        return normalize_event(event, poly).pairs
    except ContactError:
        return event.pairs


def compare(
    poly: Polyhedron,
    skill: Skill,
    result: SimResult,
    *,
    predicted: State | None = None,
    predicted_pose: ObjectPose | None = None,
    event_times: Sequence[float] | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL_DEG,
    position_tol: float = DEFAULT_POSITION_TOL,
) -> Comparison:
    """Compare a simulation with the skill it executed.

    Parameters
    ----------
    poly : Polyhedron
    skill : Skill
        The (adapted) skill: its events and final state are the prediction.
    result : SimResult
    predicted : State, optional
        The predicted final state, if not the skill's (in the world frame of the simulation).
    predicted_pose : ObjectPose, optional
        The predicted final pose: its centre of mass on the table is checked too.
    event_times : sequence of float, optional
        Expected time of each skill event (s from the motion's start), for timing offsets.
    angle_tol : float
        Degrees.
    position_tol : float
        Metres.
    """
    want = predicted if predicted is not None else skill.final
    got = result.final_state
    theta_err = None
    ok = got is not None and got.face == want.face
    if ok and got is not None:
        theta_err = angle_diff(got.theta, want.theta)
        ok = abs(theta_err) <= angle_tol
    pos_err = None
    if predicted_pose is not None:
        pos_err = math.dist(result.final_pose.position, predicted_pose.position)
        ok = ok and pos_err <= position_tol
    sim: list[tuple[float, frozenset[Any]]] = [
        (e.time, _norm(e.event, poly)) for e in result.events]
    matched: list[tuple[str, float | None, float | None]] = []
    missing: list[str] = []
    j = 0
    for i, ev in enumerate(skill.events):
        target = _norm(ev, poly)
        k = next((k for k in range(j, len(sim)) if sim[k][1] == target), None)
        if k is None:
            matched.append((ev.id, None, None))
            missing.append(ev.id)
            continue
        t = sim[k][0]
        off = t - event_times[i] if event_times is not None and i < len(event_times) else None
        matched.append((ev.id, t, off))
        j = k + 1
    return Comparison(bool(ok), want, got, theta_err, pos_err, tuple(matched), tuple(missing),
                      not missing)


def events_text(events: Sequence[SimEvent]) -> str:
    """The simulated chain, one event per arrow, for people."""
    return " -> ".join(str(e.event) for e in events)
