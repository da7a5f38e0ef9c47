"""Length units of object models, and a model's conversion to SI (metres).

A model's ``units`` (the spec's optional key, default metres) says what its numbers mean.
Physics and every physical quantity (finger radius, slip, press depth) are in SI: a model is
converted at the edge, once, by :func:`in_metres`, so that the same object written in metres
and in millimetres is the same object in the simulation.

Only the units below are known: a model (or ``from-mesh --units``) naming another one is
refused, since nothing could convert it.
"""

from __future__ import annotations

import dataclasses
from fractions import Fraction

import numpy as np

from nonprehensile.errors import ModelError
from nonprehensile.geometry.polyhedron import Polyhedron

__all__ = ["UNITS", "UNIT_METRES", "check_units", "in_metres", "metres_per_unit"]

#: Metres per unit, exact: a metric unit converts by one division by a power of ten (correctly
#: rounded), so that 40 mm and 0.04 m give the same double.
UNITS: dict[str, Fraction] = {
    "m": Fraction(1),
    "dm": Fraction(1, 10),
    "cm": Fraction(1, 100),
    "mm": Fraction(1, 1000),
    "um": Fraction(1, 1_000_000),
    "in": Fraction(254, 10_000),
    "ft": Fraction(3048, 10_000),
}
#: Length of one model unit in metres, by the model's ``units``.
UNIT_METRES: dict[str, float] = {k: float(v) for k, v in UNITS.items()}


def check_units(units: object, *, what: str = "units") -> str:
    """``units`` if it is a known length unit, else a :class:`ModelError` naming the known ones.
    """
    if not isinstance(units, str) or units not in UNITS:
        raise ModelError(
            f"{what} {units!r} is not a length unit this library knows; use one of "
            f"{', '.join(UNITS)} (metres per unit: "
            + ", ".join(f"{k} {float(v):g}" for k, v in UNITS.items()) + ")"
        )
    return units


def metres_per_unit(units: str) -> float:
    """Metres per model unit for a known unit name (:data:`UNITS`)."""
    return UNIT_METRES[check_units(units)]


def _convert(x: np.ndarray, factor: Fraction) -> np.ndarray:
    if factor.numerator == 1:
        return np.asarray(x, dtype=np.float64) / float(factor.denominator)
    return np.asarray(x, dtype=np.float64) * float(factor)


def in_metres(poly: Polyhedron, scale: float | None = None) -> Polyhedron:
    """The same object with its lengths in metres (``units="m"``).

    Parameters
    ----------
    poly : Polyhedron
        A model in any known units.
    scale : float, optional
        Metres per model unit, overriding the model's ``units`` (a recording's ``scale``, or
        ``--scale``).

    Returns
    -------
    Polyhedron
        Vertices and centre of mass times the scale; the same faces, labels, virtual faces and
        relative tolerance.
    """
    factor: Fraction | None = UNITS[check_units(poly.units)]
    if scale is not None:
        # a scale that is a unit's converts as that unit does (exactly), any other by product
        factor = next((v for v in UNITS.values() if float(v) == float(scale)), None)
    if factor is not None and factor == 1:
        return poly if poly.units == "m" else dataclasses.replace(poly, units="m")
    if factor is None:
        factor_f = float(scale)  # type: ignore[arg-type]
        verts = np.asarray(poly.vertices, dtype=np.float64) * factor_f
        com = np.asarray(poly.com, dtype=np.float64) * factor_f
    else:
        verts = _convert(poly.vertices, factor)
        com = _convert(poly.com, factor)
    return dataclasses.replace(poly, vertices=verts, center_of_mass=com, units="m")
