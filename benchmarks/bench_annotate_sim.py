"""Automatic annotation against physics: demonstrations replayed in MuJoCo.

The bundled demonstrations' fingertip paths drive the simulator's fingertips (open loop,
:mod:`nonprehensile.sim`); MuJoCo's contacts are the truth, independent of our kinematic
generator. The simulated object pose and fingertip centres are sampled at 120 Hz and
measured as a lab would: four markers on the object with 0.5 mm noise, the pose fitted to
them by Kabsch, the fingertip markers (at the centres of the 6 mm fingertip spheres: the pad
radius) with 0.5 mm noise. :func:`annotate_recording` then works from that alone.

Compared with physics:

* finger contacts: MuJoCo's own contacts (distance <= 0.1 mm), debounced by the simulator;
  the time each finger makes or breaks contact;
* the chain: physics' contact states with the same rule for flickers applied (states shorter
  than ``min_duration`` dropped), against the detected chain;
* the final state: where physics left the object.

Physics' ground element is itself read from vertex heights with a tolerance, so its
lift-off times are those of a threshold; they are reported apart.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from nonprehensile.demonstrations.annotate import DetectionParams, annotate_recording
from nonprehensile.demonstrations.dataset import load_dataset
from nonprehensile.demonstrations.record import MarkerTrajectory, PoseTrajectory, kabsch_poses
from nonprehensile.demonstrations.synth import default_object_markers
from nonprehensile.motion.trajectory import fill_gaps
from nonprehensile.sim.execute import fingers_of
from nonprehensile.sim.run import Simulator, pose_of_state
from nonprehensile.skills.contacts import Finger, Ground, normalize_event

RATE = 120.0
NOISE = 5e-4  # m


def _physics_chain(events, poly, min_frames):  # type: ignore[no-untyped-def]
    """Physics' states (time, pairs) with flickers dropped as the detector drops them."""
    runs = [(e.time * RATE, normalize_event(e.event, poly).pairs) for e in events]
    changed = True
    while changed and len(runs) > 2:
        changed = False
        for j in range(1, len(runs) - 1):
            if runs[j + 1][0] - runs[j][0] < min_frames:
                del runs[j]
                if runs[j - 1][1] == runs[j][1]:
                    del runs[j]
                changed = True
                break
    return runs


def main() -> None:
    step = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    ds = load_dataset("cube")
    demos = ds.demonstrations[::step]
    sim = Simulator(ds.poly, scale=ds.scale, n_fingers=2)
    rng = np.random.default_rng(0)
    layout = np.array(list(default_object_markers(ds.poly, ds.skills, ds.scale).values()))
    lay_m = layout * ds.scale
    # the marker is the sphere centre, the pad radius exactly known: tighter contact thresholds
    params = DetectionParams(pad_radius=sim.params.finger_radius, contact_on=0.0015,
                             contact_off=0.003)
    min_frames = round(params.min_duration * RATE)
    n = chain_ok = final_ok = 0
    finger_err: list[float] = []
    ground_err: list[float] = []
    t0 = time.perf_counter()
    for d in demos:
        traj = d.trajectory.to_units("m")
        pos = np.asarray(fill_gaps(traj.positions, 48))
        ks = fingers_of(d.skill)
        targets = {k: pos[:, traj.marker_names.index(ds.fingers[f"R{k}"])] for k in ks}
        start = pose_of_state(ds.poly, d.initial, (0.0, 0.0), sim.scale)
        res = sim.run(start, targets, traj.rate, keep_trace=1)
        tr = res.trace
        if tr is None:
            continue
        t = tr[:, 0]
        tt = np.arange(np.ceil(t[0] * RATE) / RATE, t[-1], 1 / RATE)
        p = np.stack([np.interp(tt, t, tr[:, 1 + i]) for i in range(3)], 1)
        rot = Slerp(t, Rotation.from_quat(tr[:, [5, 6, 7, 4]]))(tt).as_matrix()
        m = len(tt)
        obj = (np.einsum("nij,mj->nmi", rot, lay_m) + p[:, None]
               + rng.normal(0, NOISE, (m, len(lay_m), 3)))
        bp, bq, _ = kabsch_poses(obj, lay_m)
        pose = PoseTrajectory("cube", bp, bq, RATE, "m")
        tips = np.stack([np.stack([np.interp(tt, t, tr[:, 8 + 3 * k + i]) for i in range(3)], 1)
                         for k in range(2)], 1) + rng.normal(0, NOISE, (m, 2, 3))
        rec = MarkerTrajectory(tips, ("R1", "R2"), RATE, "m")
        a = annotate_recording(ds.poly, ds.skills, rec, pose, {f"R{k}": f"R{k}" for k in ks},
                               ds.scale, params)
        # physics times are on the simulation clock; the samples start at tt[0]
        shift = tt[0] * RATE
        phys = _physics_chain(res.events, ds.poly, min_frames)
        det = [(x * RATE + shift, e.pairs) for x, e in zip(a.times, a.chain, strict=True)]
        n += 1
        chain_ok += [q for _, q in phys] == [q for _, q in det]
        final_ok += res.final_state is not None and a.final is not None and (
            res.final_state.face == a.final.face
            and abs((res.final_state.theta - a.final.theta + 180) % 360 - 180) < 5)
        if [q for _, q in phys] == [q for _, q in det]:
            for (tp, qp), (td, _), (_, qprev) in zip(phys[1:], det[1:], phys[:-1],
                                                     strict=True):
                fingers_changed = ({x for x in qp if isinstance(x.x, Finger)}
                                   != {x for x in qprev if isinstance(x.x, Finger)})
                ground_changed = ({x for x in qp if isinstance(x.x, Ground)}
                                  != {x for x in qprev if isinstance(x.x, Ground)})
                if fingers_changed and not ground_changed:
                    finger_err.append(td - tp)
                elif ground_changed and not fingers_changed:
                    ground_err.append(td - tp)
    fe, ge = np.abs(finger_err), np.abs(ground_err)
    print(f"   {n} bundled demonstrations replayed in MuJoCo ({time.perf_counter() - t0:.1f} s)")
    print(f"   chain equal to physics' (flickers dropped alike): {100 * chain_ok / n:.1f} %")
    print(f"   final state equal to physics' (5 degrees): {100 * final_ok / n:.1f} %")
    if len(fe):
        print(f"   finger make/break vs MuJoCo contacts: median |error| {np.median(fe):.2f} "
              f"frames, p90 {np.percentile(fe, 90):.2f}, mean signed "
              f"{np.mean(finger_err):+.2f} ({len(fe)} events)")
    if len(ge):
        print(f"   ground changes vs physics' thresholded ground element: median |error| "
              f"{np.median(ge):.2f} frames, mean signed {np.mean(ground_err):+.2f} "
              f"({len(ge)} events)")


if __name__ == "__main__":
    main()
