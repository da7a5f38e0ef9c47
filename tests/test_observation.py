"""The contact pairs an observation shows, with and without the caller's pair cache
(observation.py keeps no module-level cache: a controller passes its own)."""

from __future__ import annotations

import inspect

import numpy as np

from nonprehensile import observation
from nonprehensile.geometry.build import cube
from nonprehensile.observation import Observation, PairCache, observed_contacts
from nonprehensile.planning import ObjectPose
from nonprehensile.states import State, state_pose

CUBE = cube()
SCALE = 0.05
KW = {"finger_radius": 0.006, "tol": 0.0015, "ground_tol": 0.0015}


def _pose(state: State) -> ObjectPose:
    r, t = state_pose(CUBE, state)
    return ObjectPose(r, SCALE * t, SCALE * (r @ CUBE.com + t), SCALE)


def test_a_pair_cache_changes_no_answer_and_reuses_its_pairs() -> None:
    """Fingertips scattered over and around the cube (faces, edges, corners, apart): the
    cached answers equal fresh ones (the truth: pairs built anew on every call), and a pair
    seen again is the cached object, not a new one."""
    rng = np.random.default_rng(7)
    pose = _pose(State("a", 0.0))
    cache: PairCache = {}
    seen = 0
    for _ in range(300):
        # a point near the cube's surface: a random direction out of its centre, pushed out
        # to its surface and a few millimetres either side of the pad's reach
        d = rng.normal(size=(2, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        x = d / np.abs(d).max(axis=1, keepdims=True) * 0.5 + 0.5  # on the unit cube
        tips = pose.to_world(x) + d * rng.uniform(0.0, 0.01, size=(2, 1))
        obs = Observation(0.0, pose, tips)
        fresh = observed_contacts(CUBE, obs, **KW)
        cached = observed_contacts(CUBE, obs, cache=cache, **KW)
        assert cached == fresh
        again = observed_contacts(CUBE, obs, cache=cache, **KW)
        by_pair = {p: p for p in cached}
        assert all(by_pair[p] is p for p in again)  # the very objects built the first time
        seen += len(fresh)
    pairs = [k for k in cache if not isinstance(k[0], str)]
    assert seen > 300 and len(pairs) >= 10  # fingertips touched many elements, not one
    # only the elements of this cube's faces, edges and corners with the ground and 2 fingers
    assert len(pairs) <= 3 * (6 + 12 + 8)
    # and the elements kept by their sets of near planes (or low vertices): at most one per
    # face, edge and corner, and the two fingers
    assert len(cache) - len(pairs) <= 2 * (6 + 12 + 8) + 2


def test_observation_keeps_no_module_level_cache() -> None:
    """No global mutable state (house style): nothing in the module is an lru_cache."""
    for name, value in vars(observation).items():
        assert not hasattr(value, "cache_info"), name
    assert "cache" in inspect.signature(observed_contacts).parameters
