"""Axis conventions of motion-capture recordings: named presets and explicit mappings.

Our world frame has ``z`` up (the table is ``z = 0``). Trackers disagree: Vicon, Qualisys and
most biomechanics labs record ``z`` up; OptiTrack Motive's global frame is ``y`` up (its
exports can be switched to ``z`` up). A dataset's annotations say which convention its files
use, by a preset name or explicitly, as where each of OUR axes comes from in the file::

    "axes": "motive-yup"
    "axes": {"x": "x", "y": "-z", "z": "y"}      # the same thing, spelled out

The mapping must be a proper rotation (a permutation of the file's axes with signs, of
determinant +1): a mirror image would turn every demonstrated rotation the other way.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError

__all__ = ["AXES_PRESETS", "DEFAULT_AXES", "axes_matrix", "axes_to_dict", "parse_axes"]

FloatArray = NDArray[np.float64]

#: Named conventions: our (x, y, z) as signed axes of the file.
AXES_PRESETS: Mapping[str, tuple[str, str, str]] = {
    "zup": ("x", "y", "z"),
    "vicon-zup": ("x", "y", "z"),
    "qualisys-zup": ("x", "y", "z"),
    "motive-zup": ("x", "y", "z"),
    "yup": ("x", "-z", "y"),
    "motive-yup": ("x", "-z", "y"),
}

#: The convention assumed when the annotations name none, by file suffix: C3D files are
#: usually z-up (biomechanics), Motive CSV exports y-up (Motive's global frame).
DEFAULT_AXES: Mapping[str, str] = {".c3d": "zup", ".csv": "motive-yup"}

_SIGNED = {"x": (0, 1.0), "y": (1, 1.0), "z": (2, 1.0),
           "-x": (0, -1.0), "-y": (1, -1.0), "-z": (2, -1.0),
           "+x": (0, 1.0), "+y": (1, 1.0), "+z": (2, 1.0)}


def axes_matrix(spec: tuple[str, str, str]) -> FloatArray:
    """The rotation, shape (3, 3), that takes file coordinates to ours: ``ours = M @ file``."""
    m = np.zeros((3, 3))
    for row, name in enumerate(spec):
        col, sign = _SIGNED[name]
        m[row, col] = sign
    return m


def parse_axes(value: object) -> tuple[str, str, str]:
    """A preset name or an explicit ``{"x": ..., "y": ..., "z": ...}`` as our axes' sources.

    Raises
    ------
    InputError
        An unknown preset, a malformed mapping, or one that is not a proper rotation.
    """
    if isinstance(value, str):
        if value in AXES_PRESETS:
            return AXES_PRESETS[value]
        raise InputError(f"'axes': unknown preset {value!r}; the presets are "
                         f"{sorted(AXES_PRESETS)}, or give {{\"x\": \"x\", \"y\": \"-z\", "
                         "\"z\": \"y\"}: where each of our axes (z up) is in the file")
    if not isinstance(value, Mapping) or set(value) != {"x", "y", "z"}:
        raise InputError(f"'axes' must be a preset name ({', '.join(sorted(AXES_PRESETS))}) or "
                         f"a mapping with keys x, y, z, got {value!r}")
    spec = tuple(str(value[k]).strip().lower() for k in ("x", "y", "z"))
    bad = [s for s in spec if s not in _SIGNED]
    if bad:
        raise InputError(f"'axes': {bad[0]!r} is not a file axis; use x, y, z, -x, -y or -z")
    used = sorted(_SIGNED[s][0] for s in spec)
    if used != [0, 1, 2]:
        raise InputError(f"'axes' {dict(value)!r} names a file axis twice; each of x, y, z must "
                         "appear once (with a sign)")
    out = (spec[0], spec[1], spec[2])
    if np.linalg.det(axes_matrix(out)) < 0:
        raise InputError(f"'axes' {dict(value)!r} is a mirror image (left-handed); flip the "
                         "sign of one axis so that demonstrated rotations keep their sense")
    return out


def axes_to_dict(spec: tuple[str, str, str]) -> dict[str, str]:
    """The explicit JSON form of a convention."""
    return {"x": spec[0].lstrip("+"), "y": spec[1].lstrip("+"), "z": spec[2].lstrip("+")}
