"""Observations of the simulated scene through a sensor model.

:class:`SimObserver` samples the simulator's true object pose and fingertip centres at the
sensor's rate and hands them to an :class:`~nonprehensile.observation.ObservationStream`,
which adds the configured noise and latency. A tracker (rigid body or object markers from
motion capture) would feed the same stream with its own samples; the controller sees only
:class:`~nonprehensile.observation.Observation` values either way.
"""

from __future__ import annotations

import numpy as np

from nonprehensile.observation import Observation, ObservationModel, ObservationStream
from nonprehensile.sim.run import Simulator

__all__ = ["SimObserver"]


class SimObserver:
    """The simulator seen through a sensor.

    Parameters
    ----------
    sim : Simulator
    model : ObservationModel
    rng : numpy.random.Generator
    """

    def __init__(self, sim: Simulator, model: ObservationModel,
                 rng: np.random.Generator) -> None:
        self.sim = sim
        self.stream = ObservationStream(model, rng)
        self._last: Observation | None = None

    def sample(self, now: float) -> Observation | None:
        """Take a sample if the sensor is due at ``now``; return the newest observation that
        has arrived if it is new since the last call, else None."""
        s = self.stream
        if s.due(now):
            sim = self.sim
            s.push(now, sim.judge.pose(sim.data), sim.driver.tips(sim.data))
        got = s.latest(now)
        if got is None or got is self._last:
            return None
        self._last = got
        return got

    def next_time(self) -> float:
        """When :meth:`sample` next has something to do (s): calling it earlier is a
        no-op."""
        return self.stream.next_time()

    def wait(self, now: float) -> Observation | None:
        """The newest observation that has arrived by ``now`` (new or not)."""
        self.sample(now)
        return self.stream.latest(now)
