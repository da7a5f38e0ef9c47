"""Offscreen pictures of a simulation (MuJoCo's renderer; ``MUJOCO_GL=egl`` headless).

Rendering needs an OpenGL context; physics does not. :func:`render_trace` returns None with
the reason when no context can be made, so that a report can say so and carry on.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from numpy.typing import NDArray

from nonprehensile.sim.run import Simulator

__all__ = ["render_trace", "render_traces"]

UInt8Array = NDArray[np.uint8]


def _small_renderer(m: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A renderer whose GL buffers are only as large as these frames need.

    MuJoCo sizes the context's buffers from the model's visual settings when the context is
    made: a 4096 x 4096 shadow map (64 MB, cleared and paged in, although these frames draw
    no shadow) and a 640 x 480 multisampled offscreen buffer. The settings are lowered for
    the context's creation only and then put back, so the model is left as it came (issue
    16: about 0.04 s CPU and 60 MB less for the report's filmstrip).
    """
    quality, glob = m.vis.quality, m.vis.global_
    saved = quality.shadowsize, glob.offwidth, glob.offheight
    quality.shadowsize, glob.offwidth, glob.offheight = 1, width, height
    try:
        return mujoco.Renderer(m, height, width, max_geom=4 * m.ngeom + 100)
    finally:
        quality.shadowsize, glob.offwidth, glob.offheight = saved


def render_trace(
    sim: Simulator,
    trace: NDArray[np.float64],
    times: Sequence[float],
    *,
    width: int = 320,
    height: int = 240,
    distance: float | None = None,
) -> tuple[list[UInt8Array] | None, str]:
    """Frames of a recorded simulation trace at the given times.

    Parameters
    ----------
    sim : Simulator
        The simulator that made the trace (``SimResult.trace``).
    trace : array, shape (n, 8 + 3 * n_fingers)
        Rows ``[t, object qpos (7), finger positions ...]``.
    times : sequence of float
        When to draw (nearest trace rows).

    Returns
    -------
    (frames or None, note)
        RGB images (height, width, 3), or None and why there are none.
    """
    return render_traces(sim, [(trace, times)], width=width, height=height, distance=distance)


def render_traces(
    sim: Simulator,
    traces: Sequence[tuple[NDArray[np.float64], Sequence[float]]],
    *,
    width: int = 320,
    height: int = 240,
    distance: float | None = None,
) -> tuple[list[UInt8Array] | None, str]:
    """Frames of several traces (``(trace, times)`` pairs, as :func:`render_trace`), in order.

    One OpenGL context serves them all (making one costs more than drawing a dozen frames),
    and the scene is drawn without shadows and reflections: with a software OpenGL (Mesa's
    llvmpipe, what a headless machine has) those passes cost 90 % of a frame (issue 16).
    """
    m, d = sim.model, sim.data
    try:
        renderer = _small_renderer(m, height, width)
    except Exception as exc:
        return None, f"no OpenGL context for offscreen rendering ({type(exc).__name__}: {exc})"
    try:
        cam = mujoco.MjvCamera()
        cam.azimuth, cam.elevation = 135.0, -30.0
        cam.distance = distance if distance is not None else max(
            0.15, 3.0 * sim.scale * sim.poly.diameter)
        frames: list[UInt8Array] = []
        qadr = sim._qadr
        fadr = sim._finger_qadr
        for trace, times in traces:
            for t in times:
                i = int(np.clip(np.searchsorted(trace[:, 0], t), 0, len(trace) - 1))
                row = trace[i]
                d.qpos[qadr:qadr + 7] = row[1:8]
                d.qpos[fadr] = row[8:8 + len(fadr)]
                mujoco.mj_forward(m, d)
                cam.lookat[:] = d.xpos[sim._body] + np.array([0.0, 0.0, 0.02])
                renderer.update_scene(d, cam)
                renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
                renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
                frames.append(np.asarray(renderer.render()).copy())
        return frames, ""
    except Exception as exc:
        return None, f"offscreen rendering failed ({type(exc).__name__}: {exc})"
    finally:
        renderer.close()
