"""Physics: execute skills and plans in MuJoCo (the only package that imports ``mujoco``).

Needs the ``sim`` extra (``pip install 'nonprehensile[sim]'``). See ``docs/physics.md``.
"""

import os

# offscreen rendering without a display: EGL (set before mujoco is imported; physics itself
# never needs OpenGL)
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"

from nonprehensile.sim.distribution import (
    DEFAULT_DISTRIBUTION,
    Perturbation,
    PhysicsDistribution,
    PhysicsSample,
)
from nonprehensile.sim.run import SimEvent, SimResult, Simulator, default_scale, pose_of_state
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams, scene_xml

__all__ = [
    "DEFAULT_DISTRIBUTION",
    "DEFAULT_PARAMS",
    "Perturbation",
    "PhysicsDistribution",
    "PhysicsSample",
    "SimEvent",
    "SimParams",
    "SimResult",
    "Simulator",
    "default_scale",
    "pose_of_state",
    "scene_xml",
]
