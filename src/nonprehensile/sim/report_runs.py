"""The main job's two physics runs too slow to repeat at every report, kept by what they ran.

* :func:`plan_sweep`: the plan's robustness sweep (closed and open loop across the physics
  distribution, by :func:`~nonprehensile.sim.robustness.run_sweep`, the executor
  ``simulate robustness`` runs). A few hundred executions cost minutes of CPU, more than the
  whole ``make demo`` may spend (15 s), so the package ships one the project computed
  (``data/demo_sweep.json``, written by ``nonprehensile demo --write-sweep FILE``, with its
  command, commit, seed and sample count), and it is used only when it is for the same
  sweep: the same plan (steps, references), skills, motion clusters, distribution, seed,
  samples, loops and tolerances, the states' ``--angle-tol`` among them (:func:`sweep_key`).
  Otherwise the sweep is run and kept in the cache folder
  (:func:`nonprehensile.pipeline.cache_dir`), as the motion library is.
* :func:`robot_execution`: the plan executed closed loop by the bundled Panda (the base
  searched, one continuous simulation with transits, as ``simulate plan --robot panda``),
  with the robot's per-control-step records and the arm's joint positions at a few
  instants for the filmstrip; a few seconds of CPU, kept in the cache folder.

Both keys say nothing of the executor's code: a sweep computed at another commit is the
right sweep run by other code. Its provenance names the commit, and the digest of the
executor's source files (:func:`executor_digest`) tells whether this installation's differs;
the report says so.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import os
import pickle
import re
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Callable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import Plan
from nonprehensile.states import DEFAULT_ANGLE_TOL

__all__ = [
    "DEMO_SWEEP_LOOPS",
    "DEMO_SWEEP_SAMPLES",
    "DEMO_SWEEP_SEED",
    "SHIPPED_SWEEP",
    "check_writable",
    "executor_digest",
    "plan_sweep",
    "robot_execution",
    "sweep_key",
]

#: The report's sweep: samples of the distribution, its seed, the loops side by side (the
#: benchmark of the main plan's bar runs the same 200 samples, docs/benchmarks.md).
DEMO_SWEEP_SAMPLES = 200
DEMO_SWEEP_SEED = 0
DEMO_SWEEP_LOOPS = ("closed", "open")
#: Bins of each parameter's range in the report's figure.
DEMO_SWEEP_BINS = 7
#: The sweep the package ships, in its data folder.
SHIPPED_SWEEP = "demo_sweep.json"

#: Bumped when what the keys cover or the kept documents hold changes (the sweep's, the
#: robot execution's).
_FORMAT = "report-runs/1"
_ROBOT_FORMAT = "robot/3"

#: The executor's source files (package-relative): the closed loop's decisions and the
#: simulation (what a sweep's numbers depend on besides its inputs).
# what decides an execution: the controller, its transits and observations, the planner and
# what it plans with (references, step paths, inference, states), and the simulator
_EXECUTOR_FILES = ("control.py", "transit.py", "observation.py", "planning.py", "references.py",
                   "step_paths.py", "inference.py", "states.py", "equivalence.py", "checks.py",
                   "geometry", "sim")
# the robot arms' modules and the renderer run none of the free-fingertip executions these runs
# keep (no module above imports them at load; the sweep's robot path imports them inside its own
# branch), so a change to a robot's IK or gains does not make the shipped sweep stale; the robot
# run's own key (robot_key) digests them
_ROBOT_FILES = frozenset({"ik.py", "panda.py", "placement.py", "robot.py", "robot_driver.py",
                          "robot_run.py", "robot_scene.py"})
_NOT_EXECUTOR = frozenset({"report_runs.py", "render.py"}) | _ROBOT_FILES


def _digest(parts: Any) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def _array_digest(a: Any) -> str:
    # rounded to a micrometre (model units of a 5 cm cube, metres): a last-bit difference of
    # another BLAS must not make a shipped sweep look like another sweep's
    x = np.round(np.asarray(a, dtype=float), 6) + 0.0  # + 0.0: no negative zeros
    return hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()


def _plan_identity(plan: Plan) -> dict[str, Any]:
    """The plan as JSON, with every reference motion's positions digested."""
    refs = []
    for step in plan.steps:
        for source, target, label, ref in step.motions:
            refs.append([str(source), str(target), str(label),
                         None if ref is None else _array_digest(ref.positions)])
    return {"plan": plan.to_dict(), "references": refs}


def sweep_key(poly: Polyhedron, scale: float, plan: Plan, skills: Sequence[Any],
              motions: Any, distribution: Any, *, seed: int, samples: int,
              loops: Sequence[str], angle_tol: float, position_tol: float,
              states_angle_tol: float = DEFAULT_ANGLE_TOL) -> str:
    """What a plan's sweep is for, as a digest: the object, the plan (its steps and
    reference motions), the skills, the motion library's clusters (the re-planner's
    references), the distribution, seed, samples, loops and tolerances.

    ``angle_tol`` and ``position_tol`` are the executor's (when a step counts as done);
    ``states_angle_tol`` is the tolerance the states were matched at (``--angle-tol``: the
    dataset's skills and states, the expansion the closed loop re-plans over). It joins the
    key only when it is not the default, so that sweeps kept or shipped at the default (the
    package's ``data/demo_sweep.json``) keep their keys.
    """
    labels = np.asarray(getattr(motions, "labels", ()), dtype=np.int64)
    parts: dict[str, Any] = {
        "format": _FORMAT, "object": [poly.name, _array_digest(poly.vertices),
                                      sorted(poly.faces)], "scale": round(float(scale), 9),
        "plan": _plan_identity(plan), "skills": [repr(s) for s in skills],
        "clusters": hashlib.sha256(labels.tobytes()).hexdigest(),
        "segments": len(labels), "distribution": distribution.to_dict(), "seed": int(seed),
        "samples": int(samples), "loops": list(loops), "angle_tol": float(angle_tol),
        "position_tol": float(position_tol)}
    if states_angle_tol != DEFAULT_ANGLE_TOL:
        parts["states_angle_tol"] = float(states_angle_tol)
    return _digest(parts)[:32]


def executor_digest(root: Path | None = None, *, robot: bool = False) -> str:
    """A digest of the executor's source files in this installation (16 hex digits).

    Parameters
    ----------
    root : Path, optional
        The package folder to digest (default: this installation's ``nonprehensile``).
    robot : bool
        Also the robot arms' modules (IK, driver, scene, placement, the bundled Panda): what a
        robot execution runs beside the free fingertips' executor.
    """
    root = Path(__file__).resolve().parent.parent if root is None else root
    left_out = _NOT_EXECUTOR - _ROBOT_FILES if robot else _NOT_EXECUTOR
    h = hashlib.sha256()
    for name in _EXECUTOR_FILES:
        p = root / name
        files = sorted(p.glob("*.py")) if p.is_dir() else [p]
        # this module keeps the runs; it is not what runs them
        for f in (f for f in files if f.name not in left_out):
            with contextlib.suppress(OSError):
                h.update(f.relative_to(root).as_posix().encode())
                h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _commit(git: str = "git", timeout: float = 5.0, root: Path | None = None) -> str:
    """The git commit of this source tree (``+dirty`` with uncommitted changes to the
    executor), for a sweep's provenance.

    Never raises and never waits more than about ``timeout`` seconds per git call: without a
    ``git`` program, outside a checkout, in an installed copy that a checkout around it does
    not track (a virtual environment inside someone's repository), or when git fails or
    hangs, it returns ``"unknown (<why>)"``. git's environment is cleared of ``GIT_*``
    variables (a hook's ``GIT_DIR`` would name another repository), it may not prompt, and
    ``git status`` takes no index lock (it runs beside the user's own git commands).
    ``root`` is the package's folder (default: this installation's).
    """
    root = Path(__file__).resolve().parent.parent if root is None else root
    exe = shutil.which(git)
    if exe is None:
        return f"unknown (no {git!r} program on PATH)"
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")}
    env.update(GIT_TERMINAL_PROMPT="0", GIT_OPTIONAL_LOCKS="0", LC_ALL="C")

    def run(*args: str) -> str:
        # a session of its own: on a timeout the whole group is killed, so that a child git
        # started (a hook, an fsmonitor) cannot keep the pipes open and hang the read
        with subprocess.Popen([exe, "-C", str(root), *args], stdin=subprocess.DEVNULL,
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                              env=env, start_new_session=True) as proc:
            try:
                out, _ = proc.communicate(timeout=timeout)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(OSError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.communicate()
                raise
        if proc.returncode:
            raise subprocess.CalledProcessError(proc.returncode, args)
        return out.strip()

    try:
        # this very file tracked: the checkout is this source tree, not one around a copy
        run("ls-files", "--error-unmatch", "--", "sim/report_runs.py")
    except subprocess.TimeoutExpired:
        return f"unknown (git did not answer in {timeout:g} s)"
    except (OSError, subprocess.SubprocessError, UnicodeDecodeError):
        return "unknown (not a git checkout of nonprehensile's source)"
    try:
        head = run("rev-parse", "--verify", "HEAD")
        dirty = run("status", "--porcelain", "--", ".")
    except subprocess.TimeoutExpired:
        return f"unknown (git did not answer in {timeout:g} s)"
    except (OSError, subprocess.SubprocessError, UnicodeDecodeError):
        return "unknown (git could not read this checkout's commit)"
    if not re.fullmatch(r"[0-9a-f]{40}|[0-9a-f]{64}", head):
        return "unknown (git could not read this checkout's commit)"
    return head + ("+dirty" if dirty else "")


def _shipped_path() -> Path:
    return Path(str(resources.files("nonprehensile") / "data" / SHIPPED_SWEEP))


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):  # missing or damaged: computed again
        return None
    return doc if isinstance(doc, dict) else None


def _write_json(path: Path, doc: Mapping[str, Any], mode: int = 0o600) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".sweep-", suffix=".tmp")
    try:
        os.chmod(tmp, mode)
        with os.fdopen(fd, "w") as fh:
            json.dump(doc, fh, separators=(",", ":"))
            fh.write("\n")
        os.replace(tmp, path)  # atomic: a reader sees all or nothing
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def check_writable(path: Path) -> None:
    """Refuse a sweep file that cannot be written, before minutes of sweeping.

    Raises
    ------
    InputError
        Its folder cannot be made or written, or it is a folder.
    """
    if path.is_dir():
        raise InputError(f"--write-sweep {path}: is a folder; give a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as exc:
        raise InputError(f"--write-sweep {path}: cannot write there ({exc}); give a file in "
                         "a folder you can write") from None


def plan_sweep(
    poly: Polyhedron, expansion: Any, plan: Plan, motions: Any, *, scale: float,
    fingers: Mapping[str, str], skills: Sequence[Any], samples: int = DEMO_SWEEP_SAMPLES,
    seed: int = DEMO_SWEEP_SEED, cache: Path | None = None, shipped: Path | bool | None = True,
    write: Path | None = None, command: str = "", workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """The plan's robustness sweep, closed and open loop: shipped, kept, or run now.

    Parameters
    ----------
    poly, expansion, plan, motions
        The object, the expanded graph (the closed loop's re-plans), the plan and the motion
        library it was planned with.
    scale : float
        Metres per model unit.
    fingers : mapping
        Finger name -> tip marker.
    skills : sequence of Skill
        The skills planned with (part of the key).
    samples, seed : int
        Of the distribution (``DEFAULT_DISTRIBUTION``, for this object).
    cache : Path, optional
        Folder where a sweep run here is kept (and looked for); None: not kept.
    shipped : Path, True or None
        A sweep document to use when its key matches (True: the package's
        ``data/demo_sweep.json``; None or False: none).
    write : Path, optional
        Run the sweep afresh (neither shipped nor kept one is used) and write it here with
        its provenance: the file to ship.
    command : str
        The command that asked for it (the provenance of a written sweep).
    workers : int, optional
        Processes of the sweep's pool (default: every core).
    progress : callable, optional
        ``progress(done, total)`` in executions.

    Returns
    -------
    dict
        :meth:`SweepResult.to_dict` (records included, ``DEMO_SWEEP_BINS`` bins) with
        ``key``, ``provenance`` (``command``, ``commit``, ``created``, ``executor_digest``)
        and ``source``: ``"shipped"``, ``"cache"`` or ``"computed"``; and
        ``executor_current``: whether this installation's executor code is the one that
        computed it.
    """
    from nonprehensile.sim import robustness as rob
    from nonprehensile.sim.compare import DEFAULT_ANGLE_TOL_DEG, DEFAULT_POSITION_TOL
    from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION

    distribution = DEFAULT_DISTRIBUTION.for_object(poly, scale)
    key = sweep_key(poly, scale, plan, skills, motions, distribution, seed=seed,
                    samples=samples, loops=DEMO_SWEEP_LOOPS, angle_tol=DEFAULT_ANGLE_TOL_DEG,
                    position_tol=DEFAULT_POSITION_TOL,
                    states_angle_tol=expansion.angle_tol)
    current = executor_digest()
    candidates: list[tuple[str, Path]] = []
    if write is None:
        if shipped is True:
            candidates.append(("shipped", _shipped_path()))
        elif isinstance(shipped, Path):
            candidates.append(("shipped", shipped))
        if cache is not None:
            candidates.append(("cache", cache / f"sweep-{key}.json"))
    for source, path in candidates:
        doc = _read_json(path)
        if doc is not None and doc.get("key") == key and doc.get("records"):
            doc["source"] = source
            doc["executor_current"] = (doc.get("provenance", {}).get("executor_digest")
                                       == current)
            return doc
    if write is not None:
        check_writable(write)
    spec = rob.SweepSpec(poly, scale, (rob.plan_unit(plan),), distribution, seed, samples,
                         DEMO_SWEEP_LOOPS, dict(fingers), DEFAULT_ANGLE_TOL_DEG,
                         DEFAULT_POSITION_TOL, expansion=expansion,
                         library=rob.frozen_library(expansion, motions))
    result = rob.run_sweep(spec, workers=workers, progress=progress)
    doc = result.to_dict(records=True, n_bins=DEMO_SWEEP_BINS)
    doc["key"] = key
    doc["provenance"] = {
        "command": command, "commit": _commit(), "executor_digest": current,
        "created": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "what": "the main job's plan, closed and open loop, across DEFAULT_DISTRIBUTION "
                "(sim.robustness.run_sweep: the executor of `simulate robustness`)"}
    if write is not None:  # a file to ship: readable by everyone, as the package's data
        _write_json(write, doc, 0o644)
    if cache is not None:
        with contextlib.suppress(OSError):  # a read-only cache only costs the next run
            _write_json(cache / f"sweep-{key}.json", doc)
    doc["source"] = "computed"
    doc["executor_current"] = True
    return doc


# --------------------------------------------------------------------- robot execution
def arm_frames(sim: Any, log: Mapping[str, Any], trace: Any,
               steps: Sequence[tuple[int, float, float]],
               per_step: int | None = None) -> list[dict[str, Any]]:
    """The arm and the object at a few instants of a robot execution, as drawable shapes.

    At the start, ``per_step`` instants across each executed step (``steps``: ``(number, t0,
    t1)``, each step's end the last) and the run's end (``step`` 0),
    the recorded joint positions (``log["q"]`` at the nearest ``log["time"]``) and the
    object's pose (the execution's ``trace`` row nearest in time) are put into the robot
    model and its forward kinematics read: every capsule, cylinder and sphere of the arms
    (collision shapes: the links, the rod, the fingertip) as a segment ``(p0, p1)`` with its
    radius, the object's vertices, the fingertip site, whether the fingertip touched the
    object then (the robot's log), and the trace's own joint positions at that instant (the
    execution's record, beside the robot's log: the two agree when they are of the same
    instant).

    Returns
    -------
    list of dict
        ``step``, ``time`` (s), ``q`` (n_joints,), ``segments`` (m, 2, 3), ``radii`` (m,),
        ``object`` (n_vertices, 3), ``tip`` (3,) (metres), ``touch`` (bool), ``q_trace``
        (n_joints,) or None.
    """
    import mujoco

    n_per = per_step or ROBOT_FRAMES_PER_STEP
    m = sim.model
    d = mujoco.MjData(m)
    sc = sim.scene
    times = np.asarray(log["time"], dtype=float)
    qs = np.asarray(log["q"], dtype=float)
    if not len(times):
        return []
    kinds = {int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_CYLINDER),
             int(mujoco.mjtGeom.mjGEOM_SPHERE)}
    arm_bodies = {b for b in range(m.nbody)
                  if (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or "").startswith("arm")}
    geoms = [g for g in range(m.ngeom)
             if int(m.geom_bodyid[g]) in arm_bodies and int(m.geom_type[g]) in kinds]
    qadr = sim.judge.qadr
    verts = sim.scale * np.asarray(sim.poly.vertices, dtype=float)  # the mesh, body frame
    tr = None if trace is None or not len(trace) else np.asarray(trace, dtype=float)
    out = []
    touch = np.asarray(log["touch"], dtype=bool)
    n_joints = qs.shape[1]
    # the start, n_per instants across each step (its end the last), and the run's end (after
    # any correction push): step 0 there
    instants = [(int(steps[0][0]), float(steps[0][1]))] if steps else []
    for number, t0, t1 in steps:
        instants += [(int(number), float(t)) for t in np.linspace(t0, t1, n_per + 1)[1:]]
    instants.append((0, float(times[-1])))
    for number, t in instants:
        q_trace = None
        if tr is not None:  # the trace's row nearest t, and the log at the row's time
            row = tr[int(np.clip(np.searchsorted(tr[:, 0], t), 0, len(tr) - 1))]
            d.qpos[qadr:qadr + 7] = row[1:8]
            q_trace = np.array(row[8:8 + n_joints])
            t = float(row[0])
        i = int(np.clip(np.searchsorted(times, t - 1e-9), 0, len(times) - 1))
        d.qpos[sc.qadr] = qs[i]
        mujoco.mj_kinematics(m, d)
        segs, radii = [], []
        for g in geoms:
            c, axis = d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3)[:, 2]
            half = 0.0 if int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_SPHERE) \
                else float(m.geom_size[g, 1])
            segs.append([c - half * axis, c + half * axis])
            radii.append(float(m.geom_size[g, 0]))
        body = sim.judge.body
        rot = d.xmat[body].reshape(3, 3)
        out.append({
            "step": int(number), "time": float(times[i]), "q": qs[i].copy(),
            "segments": np.array(segs), "radii": np.array(radii),
            "object": verts @ rot.T + d.xpos[body],
            "tip": np.array(d.site_xpos[int(sc.tip_sites[0])]),
            "touch": bool(touch[i]), "q_trace": q_trace})
    return out



#: Instants of the robot's filmstrip: this many per executed step, across it.
ROBOT_FRAMES_PER_STEP = 3


def robot_key(poly: Polyhedron, scale: float, plan: Plan, skills: Sequence[Any],
              motions: Any, angle_tol: float = DEFAULT_ANGLE_TOL) -> str:
    """What a robot execution is for: the object, plan, skills and motion clusters, the
    bundled robot, the angle tolerance its re-plans match states with (named only when it
    is not the default, so the default's keys stay as they were) and this installation's
    executor code (a few seconds to redo)."""
    from nonprehensile import __version__

    labels = np.asarray(getattr(motions, "labels", ()), dtype=np.int64)
    parts = {
        "format": _ROBOT_FORMAT, "robot": "panda", "version": __version__,
        "executor": executor_digest(robot=True),
        "object": [poly.name, _array_digest(poly.vertices)],
        "scale": round(float(scale), 9), "plan": _plan_identity(plan),
        "skills": [repr(s) for s in skills],
        "clusters": hashlib.sha256(labels.tobytes()).hexdigest()}
    if angle_tol != DEFAULT_ANGLE_TOL:
        parts["angle_tol"] = float(angle_tol)
    return _digest(parts)[:32]


def robot_execution(
    poly: Polyhedron, plan: Plan, motions: Any, *, scale: float, fingers: Mapping[str, str],
    skills: Sequence[Any], states: Sequence[Any], cache: Path | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> dict[str, Any]:
    """The plan executed closed loop by the bundled Panda, as ``simulate plan --robot
    panda`` runs it (base searched, one continuous simulation, transits included; re-plans
    with the skills the arm has fingers for, expanded over ``states``).

    Returns
    -------
    dict
        ``execution`` (:meth:`Execution.to_dict`, each step with its ``robot`` metrics),
        ``robot`` (:meth:`RobotSimulator.describe`), ``placement``, ``metrics`` (the whole
        run's :class:`RobotMetrics`), ``log`` (per control step: ``time`` (n,), ``error``
        (n,), ``touch`` (n,), ``q``, ``qd``, ``tau`` (n, n_joints)), ``limits`` (``lower``,
        ``upper``, ``velocity``, ``torque``, each (n_joints,), and ``joint_names``),
        ``steps`` (per executed step ``(number, t0, t1)``), ``trace`` (the execution's
        trace, rows ``[t, object qpos (7), fingertip positions ...]``) and ``cached``.

    Raises
    ------
    InputError
        Without the ``robot`` extra (mink), saying how to install it.
    """
    key = robot_key(poly, scale, plan, skills, motions, angle_tol)
    path = cache / f"robot-{key}.pickle" if cache is not None else None
    if path is not None and path.is_file():
        try:
            with path.open("rb") as fh:
                # our own cache file, written below (a folder the user owns)
                got = pickle.load(fh)
        except Exception:  # a damaged or stale cache (any unpickling error) is redone
            got = None
        if isinstance(got, dict) and got.get("key") == key:
            return {**got, "cached": True}
    from nonprehensile.sim.ik import import_mink

    import_mink()  # InputError with the install line when the extra is absent
    from nonprehensile.control import replanner
    from nonprehensile.inference import expand
    from nonprehensile.sim.closed_loop import execute_plan, scene_fingers
    from nonprehensile.sim.placement import place_base, plan_targets
    from nonprehensile.sim.robot import Robot
    from nonprehensile.sim.robot_run import RobotSimulator, robot_control
    from nonprehensile.sim.robot_scene import Arm
    from nonprehensile.sim.scene import DEFAULT_PARAMS
    from nonprehensile.step_paths import fingers_of

    robot = Robot.builtin("panda")
    n_tips = len(robot.tip_sites)
    if any(max(fingers_of(s.transition.skill), default=1) > n_tips for s in plan.steps):
        raise InputError(f"the plan has a step for more fingers than the Panda's {n_tips}")
    params = DEFAULT_PARAMS
    paths = plan_targets(plan, fingers, n_tips)
    placement = place_base(robot, poly, scale, paths, params=params)
    sim = RobotSimulator(poly, [Arm(robot, placement.base)], scale=scale, params=params)
    if sim.n_fingers < scene_fingers(plan):
        raise InputError(f"the plan needs {scene_fingers(plan)} fingers; the Panda has "
                         f"{sim.n_fingers}")

    # re-plans only with skills the arm has fingers for, as `simulate plan --robot` does
    exp = expand(poly, [s for s in skills if max(fingers_of(s), default=1) <= n_tips],
                 list(states), angle_tol=angle_tol)
    cfg = robot_control(n_fingers=sim.n_fingers)
    ex = execute_plan(sim, plan, fingers=fingers, loop="closed",
                      replan=replanner(poly, exp, plan.goal, motions=motions, scale=scale),
                      config=cfg, keep_trace=10)
    log = sim.robot_log
    doc = ex.to_dict()
    for (_, t0, t1), r in zip(ex.step_traces, doc["steps"], strict=False):
        r["robot"] = log.metrics(*log.window(t0, t1)).to_dict()
    sc = sim.scene
    got = {
        "key": key, "execution": doc, "robot": sim.describe(),
        "placement": {"base": placement.base.to_dict(),
                      "reach_error_m": placement.reach_error_m,
                      "joint_margin_rad": placement.joint_margin_rad,
                      "feasible": placement.feasible, "candidates": placement.tried,
                      # the reachability map's numbers: every candidate, and the fingertip
                      # path seen from above (every 10th target)
                      "tried": placement.candidates_dict(),
                      "targets_xy": np.concatenate([arr[::10, 0, :2] for arr, _ in paths])},
        "metrics": log.metrics().to_dict(),
        "log": {"time": np.array(log.time), "error": np.array(log.error),
                "touch": np.array(log.touch, dtype=bool), "q": np.array(log.q),
                "qd": np.array(log.qd), "tau": np.array(log.tau)},
        "limits": {"lower": np.array(sc.lower), "upper": np.array(sc.upper),
                   "velocity": np.array(sc.velocity), "torque": np.array(sc.torque),
                   "joint_names": list(sc.joint_names)},
        "steps": [(int(n), float(t0), float(t1)) for n, t0, t1 in ex.step_traces],
        "trace": None if ex.trace is None else np.array(ex.trace),
    }
    got["frames"] = arm_frames(sim, got["log"], got["trace"], got["steps"])
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".robot-", suffix=".tmp")
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(got, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except OSError:
            with contextlib.suppress(OSError, UnboundLocalError):
                os.unlink(tmp)
    return {**got, "cached": False}
