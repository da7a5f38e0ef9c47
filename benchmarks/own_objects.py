"""Skills written from ``nonprehensile maneuvers --json`` output, by rule (shared by the
own-objects benchmark and its CI-sized test).

A roll is pushed by one finger on the side face at its back; a rotation is turned by two
fingers on two opposite side faces; a tumble is pinched on the third face through its pivot
vertex and the face opposite it. These are the bundled cube's skill shapes (push-roll,
twist, tumble-lift), written for any object.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.states import State, state_pose


def _world_normals(poly: Polyhedron, state: State) -> dict[str, np.ndarray]:
    r, _ = state_pose(poly, state)
    return {f: r @ np.asarray(poly.normals[f]) for f in poly.faces}


def _sides(poly: Polyhedron, state: State, exclude: set[str]) -> dict[str, np.ndarray]:
    """Faces whose world normal is near horizontal (within 60 degrees), but ``exclude``."""
    n = _world_normals(poly, state)
    flat = math.cos(math.radians(30))
    return {f: v for f, v in n.items() if f not in exclude and abs(v[2]) < flat}


def skill_from_option(poly: Polyhedron, opt: dict[str, Any], name: str) -> dict[str, Any] | None:
    """A skill (the skills file's form) carrying out one entry of ``maneuvers --json``, or
    None when the object offers no faces for the rule's fingers."""
    start = State.from_dict(opt["from"])
    end = State.from_dict(opt["to"])
    f0, g = start.face, end.face
    rest = {"id": "rest", "contacts": [f"(G,{f0})"]}
    done = {"id": "done", "contacts": [f"(G,{g})"]}
    if opt["kind"] == "rolling":
        d = math.radians(opt["direction"])
        travel = np.array([math.cos(d), math.sin(d), 0.0])
        sides = _sides(poly, start, {f0, g})
        if not sides:
            return None
        back = min(sides, key=lambda f: float(sides[f] @ travel))
        if float(sides[back] @ travel) > -0.3:
            return None
        p = f"(R1,{back})"
        events = [rest, {"id": "touch", "contacts": [p, f"(G,{f0})"]},
                  {"id": "pivot", "contacts": [p, f"(G,{opt['element']})"]},
                  {"id": "landed", "contacts": [p, f"(G,{g})"]}, done]
        labels = ["approach", "push", "follow", "retreat"]
    elif opt["kind"] == "rotating":
        sides = _sides(poly, start, {f0})
        pairs = [(float(sides[a] @ sides[b]), a, b) for a in sides for b in sides if a < b]
        if not pairs:
            return None
        dot, a, b = min(pairs)
        if dot > -0.8:
            return None
        events = [rest, {"id": "grip", "contacts": [f"(R1,{a})", f"(R2,{b})", f"(G,{f0})"]},
                  done]
        labels = ["approach", "turn"]
    else:
        faces = [f for f in opt["element"][2:-1].split(",") if f not in (f0, g)]
        n = _world_normals(poly, start)
        if not faces:
            return None
        a = faces[0]
        b = min((f for f in poly.faces if f not in (f0, g, a)),
                key=lambda f: float(n[f] @ n[a]))
        if float(n[a] @ n[b]) > -0.8:
            return None
        pinch = [f"(R1,{a})", f"(R2,{b})"]
        events = [rest, {"id": "pinch", "contacts": [*pinch, f"(G,{f0})"]},
                  {"id": "tilt", "contacts": [*pinch, f"(G,{opt['element']})"]},
                  {"id": "landed", "contacts": [*pinch, f"(G,{g})"]}, done]
        labels = ["approach", "lift", "lift-over", "release"]
    motions = [{"from": events[i]["id"], "to": events[i + 1]["id"], "label": lab}
               for i, lab in enumerate(labels)]
    return {"name": name, "initial": opt["from"], "final": opt["to"], "maneuver": opt["kind"],
            "events": events, "motions": motions}
