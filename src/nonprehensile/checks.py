"""Validators of the numbers users pass: tolerances, counts, angles (``check_*``, as
pytransform3d), the ranges they must lie in, and the default tolerances.

A NaN or negative tolerance would silently switch checks off (every comparison with NaN is
false), a count of 2^32 would run for days, so every entry point that takes a number checks
it here: the library's functions through :func:`check_number` (or :func:`check_tolerance`),
the command line's options through the option types of ``nonprehensile.cli.options``, which
apply the same :class:`Range` objects. This module imports no numpy (the command line's
``--help`` must not pay for it: issue 16).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from nonprehensile.errors import InputError

__all__ = [
    "ANGLE_TOL_RANGE",
    "DEFAULT_ANGLE_TOL",
    "DEFAULT_RTOL",
    "DRIFT_DEG",
    "LENGTH_RANGE",
    "MARGIN_RANGE",
    "MAX_ARMS",
    "MAX_RTOL",
    "RTOL_RANGE",
    "STEP_RANGE",
    "Range",
    "check_number",
    "check_tolerance",
    "suggest_angle_tol",
]

# Defined here, in a module that imports no numpy, so that the command line's options can
# show them without importing the geometry (``nonprehensile demo --help``: issue 16); the
# geometry and the states re-export them.
#: Default length tolerance, relative to the object's diameter.
DEFAULT_RTOL = 1e-7
#: Default tolerance on angles, in degrees, for exact models (the spec's default).
DEFAULT_ANGLE_TOL = 1e-6
#: A transition that lands closer than this (degrees) to a state of the set, but not within
#: the angle tolerance, is one a model's rounding split from it (a model from a mesh carries
#: its file's: a float32 STL's rolls land about 1e-5 degrees off a state set): the planner
#: and the skill checks then name the angle tolerance as the fix. Small, so that a
#: transition landing near a state of a fine set by chance is rarely taken for it (1 in
#: 1,000 of a 1-degree set's).
DRIFT_DEG = 1e-3

#: Largest relative length tolerance: at a tenth of the object's size, faces a tenth apart
#: would be one plane; measured models need 1e-3 at most.
MAX_RTOL = 0.1
#: The most arms a robot scene takes (``--arms``): copies of one robot around the object.
MAX_ARMS = 4


def suggest_angle_tol(miss: float) -> float:
    """An angle tolerance (degrees) that takes in a miss of ``miss`` degrees by a model's
    rounding with room for a few steps of it: ten times it, rounded up to a power of ten,
    at least 1e-3."""
    return max(1e-3, 10.0 ** math.ceil(math.log10(10.0 * miss)))


@dataclass(frozen=True)
class Range:
    """The values a number may take: finite, between ``low`` and ``high`` (each bound
    included unless ``low_open`` / ``high_open``), and whole when ``integer``.

    Parameters
    ----------
    low, high : float
        Bounds; ``-inf`` / ``inf`` for none (the value must be finite anyway).
    low_open, high_open : bool
        Exclude the bound itself (a tolerance ``> 0``).
    integer : bool
        Only whole numbers (counts, seeds); a float such as ``3.0`` is not one.
    unit : str
        Unit named in messages (``"degrees"``, ``"m"``).
    """

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    unit: str = ""

    def describe(self) -> str:
        """What is expected, as a message says it: ``a number above 0 and at most 360
        (degrees)``, ``a whole number from 1 to 1000``."""
        kind = "a whole number" if self.integer else "a finite number"
        lo, hi = math.isfinite(self.low), math.isfinite(self.high)
        if lo and hi and not (self.low_open or self.high_open):
            text = f"{kind} from {_num(self.low)} to {_num(self.high)}"
        else:
            parts = []
            if lo:
                parts.append(f"{'above' if self.low_open else 'at least'} {_num(self.low)}")
            if hi:
                parts.append(f"{'below' if self.high_open else 'at most'} {_num(self.high)}")
            text = kind + (" " + " and ".join(parts) if parts else "")
        return text + (f" ({self.unit})" if self.unit else "")

    def problem(self, value: object) -> tuple[float | int | None, str | None]:
        """``(value as a number, None)`` if ``value`` is in the range, else ``(None, why)``:
        ``expected a number ..., got 'nan'`` (a string is parsed as the command line does)."""
        # (the message is written only for a value out of range: this runs on every
        # checked call, many at the observation rate)
        v: float | int
        if type(value) is float and not self.integer:  # the common case, checked below
            v = value
        elif isinstance(value, bool):
            return None, f"expected {self.describe()}, got {_shown(value)} (a truth value)"
        elif isinstance(value, str):
            text = value.strip()
            try:
                v = int(text) if self.integer else float(text)
            except ValueError:  # also a 5,000-digit integer, beyond int()'s limit
                return None, f"expected {self.describe()}, got {_shown(value)}"
        elif isinstance(value, numbers.Integral):
            v = int(value)
        elif isinstance(value, numbers.Real):
            v = float(value)
            if self.integer:
                if not (math.isfinite(v) and v.is_integer()):
                    return None, f"expected {self.describe()}, got {_shown(value)}"
                v = int(v)
        else:
            kind = "" if value is None else f" (a {type(value).__name__})"
            return None, f"expected {self.describe()}, got {_shown(value)}{kind}"
        if not self.integer:
            try:
                v = float(v)
            except OverflowError:  # an integer beyond any float
                return None, f"expected {self.describe()}, got {_shown(value)}"
            if not math.isfinite(v):
                return None, f"expected {self.describe()}, got {_shown(value)}"
        if (v < self.low or v > self.high or (self.low_open and v == self.low)
                or (self.high_open and v == self.high)):
            return None, f"expected {self.describe()}, got {_shown(value)}"
        return (v if self.integer else v + 0.0), None  # -0.0 -> 0.0

    def check(self, value: object, name: str,
              error: type[InputError] = InputError) -> float | int:
        """``value`` as a number (int when ``integer``), or ``error`` naming ``name``."""
        v, why = self.problem(value)
        if why is not None:
            raise error(f"{name}: {why}")
        assert v is not None
        return v


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


#: An angle step of a state set, degrees (it must also divide 360: ``states_by_step``).
STEP_RANGE = Range(0.0, 360.0, low_open=True, unit="degrees")
#: A tolerance on angles, degrees: beyond a right angle every state would match its
#: neighbours.
ANGLE_TOL_RANGE = Range(0.0, 90.0, unit="degrees")
#: A length tolerance relative to the object's diameter (from about float64's resolution).
RTOL_RANGE = Range(1e-15, MAX_RTOL)
#: A length in a model's or a recording's own units (as ``bounds.MAX_COORDINATE``).
LENGTH_RANGE = Range(0.0, 1e9, low_open=True)
#: A distance in a model's own units that may be zero (a stability margin).
MARGIN_RANGE = Range(0.0, 1e9)


def check_number(value: object, name: str, rng: Range,
                 error: type[InputError] = InputError) -> float | int:
    """``value`` checked against ``rng`` (see :meth:`Range.check`).

    Raises
    ------
    InputError
        (or ``error``) naming ``name``, what was expected and what came.
    """
    return rng.check(value, name, error)


def check_tolerance(value: object, name: str, *, allow_zero: bool = False,
                    high: float = math.inf) -> float:
    """A tolerance as a float: finite and positive (or zero when ``allow_zero``), at most
    ``high``.

    Raises
    ------
    InputError
        Naming the parameter and the value.
    """
    return float(Range(0.0, high, low_open=not allow_zero).check(value, name))
