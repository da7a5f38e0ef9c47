"""Validators of the numbers users pass: tolerances, counts (``check_*``, as pytransform3d),
and the default tolerances.

A NaN or negative tolerance would silently switch checks off (every comparison with NaN is
false), so every entry point that takes one validates it here.
"""

from __future__ import annotations

import math

from nonprehensile.errors import InputError

__all__ = ["DEFAULT_ANGLE_TOL", "DEFAULT_RTOL", "check_tolerance"]

# Defined here, in a module that imports no numpy, so that the command line's options can
# show them without importing the geometry (``nonprehensile demo --help``: issue 16); the
# geometry and the states re-export them.
#: Default length tolerance, relative to the object's diameter.
DEFAULT_RTOL = 1e-7
#: Default tolerance on angles, in degrees, for exact models (the spec's default).
DEFAULT_ANGLE_TOL = 1e-6


def check_tolerance(value: object, name: str, *, allow_zero: bool = False) -> float:
    """A tolerance as a float: finite and positive (or zero when ``allow_zero``).

    Raises
    ------
    InputError
        Naming the parameter and the value.
    """
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        need = "a finite number >= 0" if allow_zero else "a positive finite number"
        raise InputError(f"{name} must be {need}, got {value!r}")
    return v
