"""What the simulator records for the report's per-step plots: tracking error, contact force,
slip (``Simulator.run(..., signals=True)``), each checked against an independent measure."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco", reason="the sim extra (MuJoCo) is not installed")

from nonprehensile.geometry import cube
from nonprehensile.sim.run import Simulator, pose_of_state, signal_columns
from nonprehensile.states import State

SIZE = 0.05  # m: a 5 cm cube


@pytest.fixture(scope="module")
def sim() -> Simulator:
    return Simulator(cube(), scale=SIZE, n_fingers=1)


def test_pressing_down_force_is_the_actuators_and_error_its_spring(sim: Simulator) -> None:
    """A fingertip pressed 2 mm into the top face of a resting cube, held: in equilibrium
    the contact's normal force equals the finger's actuator force, and the tracking error is
    that force over the actuator's stiffness (Hooke's law); the resting cube does not slip."""
    start = pose_of_state(sim.poly, State("a", 0.0), (0.0, 0.0), SIZE)
    top = SIZE + sim.params.finger_radius
    target = np.tile([0.0, 0.0, top - 0.002], (100, 1))
    target[:20, 2] = np.linspace(top + 0.01, top - 0.002, 20)
    res = sim.run(start, {1: target}, 200.0, keep_trace=1, signals=True, settle=0.2)
    cols = signal_columns(1)
    # then the actuators' set points (control_columns)
    assert res.trace is not None and res.trace.shape[1] == cols["slip"].stop + sim.model.nu
    last = res.trace[-1]
    actuator = abs(float(sim.data.actuator_force[2]))  # the z axis of finger 1
    force = float(last[cols["force"]][0])
    error = float(last[cols["error"]][0])
    assert actuator > 0.1
    assert force == pytest.approx(actuator, rel=0.02)
    assert error == pytest.approx(actuator / sim.params.stiffness, rel=0.02)
    assert float(last[cols["slip"]][0]) < 1e-4
    # before the finger arrives: no force
    assert float(res.trace[5, cols["force"]][0]) == 0.0


def test_sliding_cube_slips_at_the_speed_of_its_centre(sim: Simulator) -> None:
    """Pushed low on a side face (below the height at which it would tip), the cube slides
    without turning: its points on the table move as its centre of mass does."""
    start = pose_of_state(sim.poly, State("a", 0.0), (0.0, 0.0), SIZE)
    x0 = -SIZE / 2 - sim.params.finger_radius - 0.01
    target = np.zeros((200, 3))
    target[:, 0] = np.linspace(x0, x0 + 0.06, 200)
    target[:, 2] = 0.012
    res = sim.run(start, {1: target}, 200.0, keep_trace=1, signals=True, settle=0.1)
    assert res.trace is not None and res.final_state is not None
    assert res.final_state.face == "a"  # slid, not tipped
    t, x = res.trace[:, 0], res.trace[:, 1]
    slip = res.trace[:, signal_columns(1)["slip"]][:, 0]
    moving = (t > 0.5) & (t < 0.9)
    speed = np.gradient(x, t)[moving]
    assert speed.mean() > 0.03
    # NaN where a contact point lifts off for a step (the cube chatters as it slides)
    on_table = np.isfinite(slip[moving])
    assert on_table.mean() > 0.8
    assert np.median(np.abs(slip[moving][on_table] - speed[on_table])) < 0.1 * speed.mean()


def test_signals_are_off_by_default(sim: Simulator) -> None:
    start = pose_of_state(sim.poly, State("a", 0.0), (0.0, 0.0), SIZE)
    target = np.tile([0.2, 0.2, 0.2], (10, 1))
    res = sim.run(start, {1: target}, 100.0, keep_trace=1, settle=0.01)
    # pose and fingertip, then the set points (control_columns)
    assert res.trace is not None and res.trace.shape[1] == 8 + 3 + sim.model.nu
