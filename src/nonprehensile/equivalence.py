"""Geometric equivalence of states: the object's rotation symmetry group acting on states.

Two states are geometrically equivalent (paper Section V) when the object occupies the same
space in both, up to a horizontal translation: their poses differ by a proper rotation symmetry
``g`` of the object (:func:`~nonprehensile.geometry.symmetry.rotation_group`), ``R_1 = R_2 g``.
The group belongs to the object model; its action on states sits here, above
:mod:`nonprehensile.states`, so that the object model does not know states.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from nonprehensile.geometry.polyhedron import Polyhedron, wrap_index
from nonprehensile.geometry.symmetry import Symmetry, rotation_group
from nonprehensile.states import DEFAULT_ANGLE_TOL, State

__all__ = ["apply_to_state", "equivalence_classes", "equivalent"]


def apply_to_state(poly: Polyhedron, g: Symmetry, state: State) -> State:
    """The state equivalent to ``state`` through symmetry ``g``.

    With ``R`` the pose of ``state``, the result has pose ``R g^-1``: the object occupies the
    same space, with face ``g(F_b)`` on the ground.

    Returns
    -------
    State
        ``{g(F_b), theta + Delta_F_b[j]}`` where ``g`` takes edge ``j`` of ``F_b`` to edge 1.
    """
    f = state.face
    n = poly.n_edges(f)
    j = wrap_index(1 - g.edge_shift[f], n)
    return State(g.face_map[f], state.theta + poly.delta[f][j - 1])


def equivalent(
    poly: Polyhedron,
    a: State,
    b: State,
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> Symmetry | None:
    """The symmetry taking state ``a`` to state ``b``, or None if they are not equivalent."""
    for g in rotation_group(poly, atol):
        if apply_to_state(poly, g, a).isclose(b, angle_tol):
            return g
    return None


def equivalence_classes(
    poly: Polyhedron,
    states: Sequence[State],
    *,
    atol: float | None = None,
    angle_tol: float = DEFAULT_ANGLE_TOL,
) -> list[int]:
    """Number the geometric-equivalence classes of a state set.

    Parameters
    ----------
    poly : Polyhedron
    states : sequence of State
    atol : float, optional
        Length tolerance of the symmetry group.
    angle_tol : float
        Angle tolerance in degrees.

    Returns
    -------
    list of int
        ``classes[i]`` is the class of ``states[i]``; classes are numbered 0, 1, ... in order
        of first appearance.
    """
    group = rotation_group(poly, atol)
    angle_tol = float(angle_tol)
    n = len(states)
    if n == 0:
        return []
    # states by face: sorted angles and their positions in ``states``
    faces = np.array([s.face for s in states])
    thetas = np.array([s.theta for s in states], dtype=np.float64)
    by_face: dict[str, tuple[NDArray[np.float64], NDArray[np.int64]]] = {}
    for f in np.unique(faces).tolist():
        pos = np.flatnonzero(faces == f)
        order = np.argsort(thetas[pos], kind="stable")
        by_face[f] = (thetas[pos][order], pos[order])
    # images[g][i]: the first state equal to g . states[i] within the tolerance, or -1. The
    # identity is in the group, so copies of one state (equal within the tolerance) merge.
    images = []
    for g in group:
        img = np.full(n, -1, dtype=np.int64)
        for f, (th, pos) in by_face.items():
            if f not in g.face_map or g.face_map[f] not in by_face:
                continue
            h = g.face_map[f]
            j = wrap_index(1 - g.edge_shift[f], poly.n_edges(f))
            target = (th + poly.delta[f][j - 1]) % 360.0
            img[pos] = _match(target, *by_face[h], angle_tol)
        images.append(img)
    # a class is an orbit of the group: label each state by the smallest position in its
    # orbit, repeating until stable (chains of near-copies within the tolerance)
    label = np.arange(n, dtype=np.int64)
    for _ in range(n):
        new = label.copy()
        for img in images:
            ok = img >= 0
            np.minimum.at(new, np.flatnonzero(ok), label[img[ok]])
            np.minimum.at(new, img[ok], label[ok])
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    # classes numbered in order of first appearance
    _, first, inverse = np.unique(label, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return [int(c) for c in rank[inverse]]


def _match(
    target: NDArray[np.float64], thetas: NDArray[np.float64], pos: NDArray[np.int64],
    tol: float,
) -> NDArray[np.int64]:
    """For each angle of ``target``, the smallest position among the sorted ``thetas`` within
    ``tol`` degrees (modulo 360), or -1."""
    out = np.full(len(target), np.iinfo(np.int64).max, dtype=np.int64)
    for shift in (-360.0, 0.0, 360.0):
        lo = np.searchsorted(thetas, target - tol + shift, side="left")
        hi = np.searchsorted(thetas, target + tol + shift, side="right")
        one = hi - lo == 1
        out[one] = np.minimum(out[one], pos[lo[one]])
        for k in np.flatnonzero(hi - lo > 1).tolist():  # near-copies: rare
            out[k] = min(int(out[k]), int(pos[lo[k] : hi[k]].min()))
    out[out == np.iinfo(np.int64).max] = -1
    return out
