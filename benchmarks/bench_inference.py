"""Expansion time against states x demonstrated skills: exact method vs the paper's method.

Both methods run on the same object, state set and skills in the same run; the ratio
``paper / exact`` is what to read (the machines are small and noisy). The exact method's time
includes computing the object's rotation group (its cache is cleared before each run).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from nonprehensile.geometry import Polyhedron, convex_hull, prism
from nonprehensile.geometry.symmetry import _rotation_group_cached
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.maneuvers import roll, rotate
from nonprehensile.skills.contacts import parse_event
from nonprehensile.skills.skill import Motion, Skill
from nonprehensile.states import State, is_stable, states_by_step


def _roll_skill(p: Polyhedron, s: State, k: int, name: str) -> Skill:
    m = roll(p, s, edge=k)
    f, g = m.pivot
    events = (parse_event([f"(G,{f})"], "rest"), parse_event([f"(G,E({f},{g}))"], "pivot"),
              parse_event([f"(G,{g})"], "done"))
    return Skill(name, s, m.end, events, (Motion("rest", "pivot"), Motion("pivot", "done")),
                 "rolling")


def _rotate_skill(p: Polyhedron, s: State, angle: float) -> Skill:
    m = rotate(p, s, angle)
    events = (parse_event([f"(G,{s.face})"], "rest"), parse_event([f"(G,{s.face})"], "done"))
    return Skill("rotate", s, m.end, events, (Motion("rest", "done"),), "rotating")


def fibonacci_hull(n_faces: int) -> Polyhedron:
    """A convex hull of points spread on a sphere, with about ``n_faces`` triangles."""
    n = n_faces // 2 + 2  # a triangulated sphere with n vertices has 2n - 4 faces
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = math.pi * (1 + 5**0.5) * i
    pts = np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])
    return convex_hull(pts, name=f"hull{n_faces}")


def best_of(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        _rotation_group_cached.cache_clear()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def case(name: str, p: Polyhedron, step: float, skills: list[Skill], repeat: int) -> None:
    states = states_by_step(p, step)
    n_exact = len(expand(p, skills, states, method="exact").transitions)
    n_paper = len(expand(p, skills, states, method="paper").transitions)
    t_exact = best_of(lambda: expand(p, skills, states, method="exact"), repeat)
    t_paper = best_of(lambda: expand(p, skills, states, method="paper"), repeat)
    size = len(states) * len(skills)
    print(f"{name:28s} {len(states):6d} states x {len(skills):2d} skills: "
          f"exact {t_exact * 1e3:9.2f} ms ({t_exact / size * 1e6:7.2f} us/pair, "
          f"{n_exact} transitions)  paper {t_paper * 1e3:9.2f} ms ({n_paper} transitions)  "
          f"paper/exact = {t_paper / t_exact:6.1f}x", flush=True)


def main() -> None:
    cube, cube_skills = read_skills(
        __import__("importlib.resources").resources.files("nonprehensile") / "data"
        / "cube_skills.json")
    case("cube, step 90", cube, 90, cube_skills, repeat=5)

    hexa = prism(6)
    side = next(f for f in hexa.faces if hexa.n_edges(f) == 4)
    s = State(side, 0)
    hex_skills = [_roll_skill(hexa, s, k, f"roll{k}") for k in range(1, 5)]
    hex_skills.append(_rotate_skill(hexa, s, 30))
    case("hexagonal prism, step 1", hexa, 1, hex_skills, repeat=3)

    hull = fibonacci_hull(100)
    f = next(f for f in hull.faces if is_stable(hull, f))
    hull_skills = [_roll_skill(hull, State(f, 0), k, f"roll{k}") for k in (1, 2, 3)]
    case(f"{len(hull.faces)}-face convex hull, step 15", hull, 15, hull_skills, repeat=3)


if __name__ == "__main__":
    main()
