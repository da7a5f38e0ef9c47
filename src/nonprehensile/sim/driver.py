"""Finger drivers: the part of a simulation that moves the fingertips.

A driver turns fingertip target trajectories (world, metres) into the scene's actuator
commands; the judge (:mod:`nonprehensile.sim.judge`) reads what physics did, the same way for
every driver. :class:`FreeFingertips` is today's driver: each fingertip a sphere on three slide
joints with position actuators (a compliant finger under impedance control). A robot arm's
driver (its tool tip following the same targets through inverse kinematics) implements the same
:class:`FingerDriver` protocol.
"""

from __future__ import annotations

from typing import Any, Protocol

import mujoco
import numpy as np
from numpy.typing import NDArray

__all__ = ["FingerDriver", "FreeFingertips"]

FloatArray = NDArray[np.float64]


class FingerDriver(Protocol):
    """What moves the fingertips of a scene.

    Attributes
    ----------
    n_fingers : int
        Fingertips ``R1 .. Rn``, in that order in every ``(..., n_fingers, 3)`` array.
    """

    n_fingers: int

    def controls(self, targets: FloatArray) -> FloatArray:
        """Actuator commands, shape (n_samples, model.nu), that drive the fingertips' centres
        along ``targets`` (shape (n_samples, n_fingers, 3), one sample per physics step).
        The step loop writes row ``i`` to ``data.ctrl`` before step ``i``."""
        ...

    def place(self, data: Any, targets: FloatArray) -> None:
        """Put the fingertips at rest at ``targets`` (shape (n_fingers, 3)) before a run."""
        ...

    def tips(self, data: Any) -> FloatArray:
        """Where the fingertips' centres are now, shape (n_fingers, 3)."""
        ...

    def qpos_indices(self) -> NDArray[np.int64]:
        """The ``qpos`` entries of the fingers (kept in traces, for rendering)."""
        ...


class FreeFingertips:
    """Fingertips as spheres on x/y/z slide joints, each axis a position actuator.

    The actuator's set point is the sphere's centre, so :meth:`controls` is the targets
    themselves, flattened.

    Parameters
    ----------
    model : mujoco.MjModel
        A scene of :func:`~nonprehensile.sim.scene.scene_xml` (joints ``finger{k}_x|y|z``,
        actuators in the same order).
    n_fingers : int
    """

    def __init__(self, model: Any, n_fingers: int) -> None:
        self.n_fingers = n_fingers
        m = model

        def jid(k: int, a: str) -> int:
            return int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"finger{k}_{a}"))

        self.qadr = np.array([m.jnt_qposadr[jid(k, a)] for k in range(1, n_fingers + 1)
                              for a in "xyz"], dtype=np.int64)
        self.dadr = np.array([m.jnt_dofadr[jid(k, a)] for k in range(1, n_fingers + 1)
                              for a in "xyz"], dtype=np.int64)
        # the fingers' joint positions as one slice when they are consecutive (they are in
        # the scene's order): read faster than by index
        a = int(self.qadr[0])
        self._qslice = (slice(a, a + len(self.qadr))
                        if np.array_equal(self.qadr, np.arange(a, a + len(self.qadr)))
                        else None)
        # that slice as a view of the last data read, shaped (n_fingers, 3) (MuJoCo's arrays
        # stay where they are for the data's life): the observer reads it at its rate
        self._bound: Any = None
        self._tips_view: FloatArray | None = None

    def controls(self, targets: FloatArray) -> FloatArray:
        """The targets flattened: the position actuators' set points."""
        t = np.asarray(targets, dtype=np.float64)
        return np.ascontiguousarray(t.reshape(len(t), 3 * self.n_fingers))

    def place(self, data: Any, targets: FloatArray) -> None:
        """Joint positions at the targets, velocities zero, set points there."""
        flat = np.asarray(targets, dtype=np.float64).ravel()
        data.qpos[self.qadr] = flat
        data.qvel[self.dadr] = 0.0
        data.ctrl[:] = flat

    def tips(self, data: Any) -> FloatArray:
        """The spheres' centres (joint positions: the slide joints start at the origin)."""
        if self._qslice is not None:
            if data is not self._bound:
                self._tips_view = data.qpos[self._qslice].reshape(self.n_fingers, 3)
                self._bound = data
            assert self._tips_view is not None
            return np.array(self._tips_view, dtype=np.float64)
        q = data.qpos[self.qadr]
        return np.array(q, dtype=np.float64).reshape(self.n_fingers, 3)

    def qpos_indices(self) -> NDArray[np.int64]:
        """The fingers' joint positions in ``qpos``."""
        return self.qadr
