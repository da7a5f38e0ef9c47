"""Measured success rates of transitions: the physics' verdict as data the planner reads.

A robustness sweep (``nonprehensile simulate robustness``, :mod:`nonprehensile.sim.robustness`)
executes every transition of the expanded state-transition graph across a physics
distribution and counts how many samples end as predicted. :class:`SuccessRates` holds those
counts per transition (skill, model start state, model end state) and per loop (open or
closed); it is written and read as JSON (``-o FILE``; ``plan --robustness FILE``).

The 95 % interval of a rate is Wilson's score interval (:func:`wilson_interval`): exact enough
at 20 samples, never outside [0, 1], and not empty at 0/n or n/n as the normal
approximation's is.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nonprehensile.errors import InputError
from nonprehensile.states import State

__all__ = [
    "FORMAT",
    "LOOPS",
    "Rate",
    "SuccessRates",
    "TransitionKey",
    "read_success_rates",
    "wilson_interval",
]

#: The rates file's ``format`` tag.
FORMAT = "nonprehensile-success-rates/1"
#: Execution loops a rate can be measured under.
LOOPS = ("closed", "open")
#: z for a two-sided 95 % interval.
Z95 = 1.959963984540054


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson's score interval of a success rate ``k / n``.

    Returns
    -------
    (float, float)
        Lower and upper bounds in [0, 1]; ``(0, 1)`` when ``n == 0``.
    """
    if n < 0 or not 0 <= k <= n:
        raise InputError(f"a success count must satisfy 0 <= k <= n, got k={k!r}, n={n!r}")
    if n == 0:
        return 0.0, 1.0
    p = k / n
    z2 = z * z
    den = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / den
    half = z / den * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    # exact at the ends: 0/n has lower bound 0, n/n upper bound 1 (rounding aside)
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return lo, hi


@dataclass(frozen=True)
class Rate:
    """``k`` successes of ``n`` executions."""

    k: int
    n: int

    def __post_init__(self) -> None:
        wilson_interval(self.k, self.n)  # validates

    @property
    def rate(self) -> float:
        """``k / n`` (NaN when nothing ran)."""
        return self.k / self.n if self.n else math.nan

    @property
    def interval(self) -> tuple[float, float]:
        """The 95 % Wilson interval."""
        return wilson_interval(self.k, self.n)

    @property
    def smoothed(self) -> float:
        """Laplace's rule of succession ``(k + 1) / (n + 2)``: never 0 or 1 from a finite
        count, so ``-log`` of it is a finite cost that still grows with every failure."""
        return (self.k + 1) / (self.n + 2)

    def __add__(self, other: Rate) -> Rate:
        return Rate(self.k + other.k, self.n + other.n)

    def to_dict(self) -> dict[str, Any]:
        """JSON form: counts, rate and interval."""
        lo, hi = self.interval
        return {"k": self.k, "n": self.n,
                "rate": None if not self.n else round(self.rate, 6),
                "ci95": [round(lo, 6), round(hi, 6)]}

    def __str__(self) -> str:
        if not self.n:
            return "not run"
        lo, hi = self.interval
        return f"{self.k}/{self.n} = {100 * self.rate:.0f} % (95 % CI {100 * lo:.0f}-" \
               f"{100 * hi:.0f} %)"


def _theta_key(theta: float) -> float:
    a = round(float(theta) % 360.0, 6)
    return 0.0 if a >= 360.0 else a + 0.0


@dataclass(frozen=True)
class TransitionKey:
    """A transition of the expanded graph: its skill and model start and end states."""

    skill: str
    start: State
    end: State

    @staticmethod
    def of(skill: str, start: State, end: State) -> TransitionKey:
        """The key with angles normalised (equal transitions give equal keys)."""
        return TransitionKey(skill, State(start.face, _theta_key(start.theta)),
                             State(end.face, _theta_key(end.theta)))

    def __str__(self) -> str:
        return f"{self.skill} {self.start} -> {self.end}"


@dataclass(frozen=True)
class SuccessRates:
    """Success counts per transition and loop, measured across a physics distribution.

    Attributes
    ----------
    rates : mapping of (TransitionKey, str) to Rate
        Per transition and loop (``"closed"`` or ``"open"``).
    object : str
        The object model's name (a file for another object is refused).
    meta : mapping
        How they were measured (distribution, seed, samples, dataset): carried through.
    """

    rates: Mapping[tuple[TransitionKey, str], Rate]
    object: str
    meta: Mapping[str, Any]

    def loops(self) -> list[str]:
        """The loops measured, closed first."""
        have = {loop for _, loop in self.rates}
        return [lp for lp in LOOPS if lp in have]

    def get(self, key: TransitionKey, loop: str) -> Rate | None:
        """The rate of one transition under ``loop``, or None if not measured."""
        return self.rates.get((key, loop))

    def to_dict(self) -> dict[str, Any]:
        """The rates file's JSON document."""
        rows: dict[TransitionKey, dict[str, Any]] = {}
        for (key, loop), r in sorted(self.rates.items(), key=lambda kv: (
                kv[0][0].skill, kv[0][0].start, kv[0][0].end, kv[0][1])):
            row = rows.setdefault(key, {"skill": key.skill, "from": key.start.to_dict(),
                                        "to": key.end.to_dict()})
            row[loop] = r.to_dict()
        return {"format": FORMAT, "object": self.object, **dict(self.meta),
                "transitions": list(rows.values())}

    def write(self, path: str | Path) -> Path:
        """Write the rates file (JSON, through a temporary name and a rename)."""
        from nonprehensile.io import write_text_file

        return write_text_file(path, json.dumps(self.to_dict(), indent=1) + "\n")

    @staticmethod
    def from_dict(doc: Any, source: str = "the rates file") -> SuccessRates:
        """Parse a rates document; every problem is an :class:`InputError` naming it."""
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
            raise InputError(f"{source}: not a success-rates file (format {FORMAT!r} "
                             f"expected, got {got!r}); write one with `nonprehensile simulate "
                             "robustness ... -o FILE`")
        obj = doc.get("object")
        rows = doc.get("transitions")
        if not isinstance(obj, str) or not isinstance(rows, list):
            raise InputError(f"{source}: needs 'object' (a name) and 'transitions' (a list)")
        rates: dict[tuple[TransitionKey, str], Rate] = {}
        for i, row in enumerate(rows):
            where = f"{source}: transition {i}"
            if not isinstance(row, dict) or not isinstance(row.get("skill"), str):
                raise InputError(f"{where}: needs 'skill', 'from', 'to' and a count per loop")
            try:
                key = TransitionKey.of(row["skill"], State.from_dict(row["from"]),
                                       State.from_dict(row["to"]))
            except (KeyError, TypeError, ValueError) as exc:  # StateError is a ValueError
                raise InputError(f"{where}: bad 'from' or 'to' ({exc})") from None
            for loop in LOOPS:
                if loop not in row:
                    continue
                c = row[loop]
                k, n = (c.get("k"), c.get("n")) if isinstance(c, dict) else (None, None)
                if not all(isinstance(v, int) and not isinstance(v, bool) for v in (k, n)):
                    raise InputError(f"{where} ({loop}): counts 'k' and 'n' must be whole "
                                     f"numbers, got {c!r}")
                assert isinstance(k, int) and isinstance(n, int)
                try:
                    rates[(key, loop)] = Rate(k, n)
                except InputError as exc:
                    raise InputError(f"{where} ({loop}): {exc}") from None
        meta = {k: v for k, v in doc.items() if k not in ("format", "object", "transitions")}
        return SuccessRates(rates, obj, meta)

    @staticmethod
    def from_counts(counts: Iterable[tuple[TransitionKey, str, bool]], object_name: str,
                    meta: Mapping[str, Any] | None = None) -> SuccessRates:
        """Rates from individual outcomes ``(key, loop, success)``."""
        acc: dict[tuple[TransitionKey, str], list[int]] = {}
        for key, loop, ok in counts:
            if loop not in LOOPS:
                raise InputError(f"unknown loop {loop!r}; expected one of {list(LOOPS)}")
            c = acc.setdefault((key, loop), [0, 0])
            c[0] += bool(ok)
            c[1] += 1
        return SuccessRates({k: Rate(*v) for k, v in acc.items()}, object_name, meta or {})


def read_success_rates(path: str | Path) -> SuccessRates:
    """Read a rates file (JSON)."""
    from nonprehensile.io import load_document

    return SuccessRates.from_dict(load_document(path), str(path))
