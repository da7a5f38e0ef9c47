"""The physics distribution that judges skills and plans: seeded samples of the world.

One simulator configuration is not physics. A skill, a reference motion or a plan is judged
across a documented distribution of what nobody has measured for the user's table, object and
robot (``docs/physics.md`` says why each range):

=====================  ==================  =================================================
parameter              range (uniform)     what it is
=====================  ==================  =================================================
``friction_table``     0.3 - 1.0           object-table Coulomb friction
``friction_finger``    0.5 - 1.2           object-fingertip Coulomb friction
``mass``               0.05 - 0.4 kg       for a 5 cm cube; other objects: the same density
                                           range, 400 - 3200 kg/m^3, times their volume
``finger_radius``      5 - 12 mm           fingertip sphere radius
``stiffness``          600 - 3000 N/m      finger position gain per axis
``max_force``          8 - 15 N            finger force limit per axis
``contact_timeconst``  0.004 - 0.02 s      MuJoCo ``solref`` time constant (softness)
start-pose error       <= 3 mm, <= 3 deg   where the object really is against where the plan
                                           believes it is (uniform in the disc; yaw uniform)
tracking noise         0.5 mm              standard deviation of the object tracker's error
                                           (what a closed-loop executor observes)
finger noise           1 mm                standard deviation of the fingertip's position
                                           error (a Gauss-Markov process, 50 ms correlation)
=====================  ==================  =================================================

A sample is a frozen :class:`PhysicsSample`: the :class:`~nonprehensile.sim.scene.SimParams`
of its scene and the :class:`Perturbation` of its execution. Sample ``i`` of seed ``s`` is
drawn from its own generator, ``numpy.random.SeedSequence([s, i])``, so it is the same
whichever worker draws it and in whatever order (:meth:`PhysicsDistribution.samples`).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.geometry.polyhedron import Polyhedron
from nonprehensile.planning import ObjectPose
from nonprehensile.sim.scene import DEFAULT_PARAMS, SimParams

__all__ = [
    "CUBE_VOLUME",
    "DEFAULT_DISTRIBUTION",
    "NO_PERTURBATION",
    "Perturbation",
    "PhysicsDistribution",
    "PhysicsSample",
    "finger_noise",
]

FloatArray = NDArray[np.float64]

#: Volume of the 5 cm cube the mass range is stated for, m^3.
CUBE_VOLUME = 0.05**3
#: Correlation time of the fingertip's position error, s: a robot finger's tracking error
#: wanders with the controller's bandwidth (a few Hz), it is not white per physics step.
FINGER_NOISE_TIME = 0.05
#: Largest start-pose error and noise accepted: beyond these a "perturbation" is a different
#: task (the object is elsewhere), and a typo such as millimetres given for metres is caught.
MAX_START_OFFSET = 0.05
MAX_START_YAW_DEG = 45.0
MAX_NOISE = 0.01


def _number(value: object, name: str, lo: float, hi: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(float(value)) or not lo <= float(value) <= hi:
        raise InputError(f"{name} must be a number in [{lo:g}, {hi:g}]"
                         f"{' ' + unit if unit else ''}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Perturbation:
    """How one execution differs from the plan's belief, besides the scene's parameters.

    Attributes
    ----------
    start_error : (float, float, float)
        ``(dx, dy, dyaw)``: the object really starts this far (m, m) from where it is
        believed to be, turned ``dyaw`` degrees about the vertical through its centre of mass.
    tracking_noise : float
        Standard deviation (m) of the object tracker's position error per marker. Only a
        closed-loop executor observes the object; open loop it changes nothing.
    finger_noise : float
        Standard deviation (m) of each fingertip's position error per axis, a Gauss-Markov
        process of correlation time ``FINGER_NOISE_TIME`` (see :func:`finger_noise`).
    noise_seed : int
        Seeds the noise streams (the finger's and the tracker's).
    """

    start_error: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tracking_noise: float = 0.0
    finger_noise: float = 0.0
    noise_seed: int = 0

    def __post_init__(self) -> None:
        se = tuple(self.start_error)
        if len(se) != 3:
            raise InputError(f"the start error must be (dx, dy, dyaw), got {self.start_error!r}")
        dx = _number(se[0], "the start error dx", -MAX_START_OFFSET, MAX_START_OFFSET, "m")
        dy = _number(se[1], "the start error dy", -MAX_START_OFFSET, MAX_START_OFFSET, "m")
        dyaw = _number(se[2], "the start error dyaw", -MAX_START_YAW_DEG, MAX_START_YAW_DEG,
                       "degrees")
        object.__setattr__(self, "start_error", (dx, dy, dyaw))
        for name in ("tracking_noise", "finger_noise"):
            object.__setattr__(self, name, _number(getattr(self, name),
                                                   f"the {name.replace('_', ' ')}", 0.0,
                                                   MAX_NOISE, "m"))
        s = self.noise_seed
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or not 0 <= s < 2**63:
            raise InputError(f"the noise seed must be a whole number in [0, 2^63), got {s!r}")
        object.__setattr__(self, "noise_seed", int(s))

    @property
    def is_null(self) -> bool:
        """Nothing perturbed."""
        return self.start_error == (0.0, 0.0, 0.0) and self.tracking_noise == 0.0 \
            and self.finger_noise == 0.0

    def rng(self, stream: str) -> np.random.Generator:
        """The generator of one noise stream (``"finger"``, ``"tracker"``, ...): each stream
        is its own, so drawing more of one never shifts another."""
        tag = int.from_bytes(hashlib.blake2b(stream.encode(), digest_size=8).digest(), "little")
        return np.random.default_rng(np.random.SeedSequence([self.noise_seed, tag]))

    def start_pose(self, pose: ObjectPose) -> ObjectPose:
        """Where the object really is when it is believed to be at ``pose``."""
        dx, dy, dyaw = self.start_error
        if (dx, dy, dyaw) == (0.0, 0.0, 0.0):
            return pose
        a = math.radians(dyaw)
        rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0],
                       [0.0, 0.0, 1.0]])
        com = np.asarray(pose.com, dtype=float) + np.array([dx, dy, 0.0])
        rot = rz @ pose.rotation
        # turn about the vertical through the centre of mass, then shift
        trans = com - rz @ (np.asarray(pose.com) - np.asarray(pose.translation))
        return ObjectPose(rot, trans, com, pose.scale)

    def finger_targets(self, targets: Mapping[int, FloatArray], rate: float,
                       stream: str = "finger") -> dict[int, FloatArray]:
        """The fingertip targets as the finger really moves: each plus its own noise (from
        the noise stream ``stream``: give each motion of one execution its own)."""
        if self.finger_noise == 0.0:
            return {k: np.asarray(v, dtype=float) for k, v in targets.items()}
        rng = self.rng(stream)
        return {k: np.asarray(v, dtype=float)
                + finger_noise(rng, len(v), rate, self.finger_noise)
                for k, v in sorted(targets.items())}

    def to_dict(self) -> dict[str, Any]:
        """JSON form (``start_error`` as ``[dx_m, dy_m, dyaw_deg]``)."""
        return {"start_error": list(self.start_error), "tracking_noise": self.tracking_noise,
                "finger_noise": self.finger_noise, "noise_seed": self.noise_seed}


#: No perturbation: the object where it is believed to be, no noise.
NO_PERTURBATION = Perturbation()


def finger_noise(rng: np.random.Generator, n_frames: int, rate: float, sigma: float,
                 tau: float = FINGER_NOISE_TIME) -> FloatArray:
    """A fingertip's position error: a stationary Gauss-Markov (first-order autoregressive)
    process per axis, standard deviation ``sigma`` (m), correlation time ``tau`` (s).

    Returns
    -------
    array, shape (n_frames, 3)
        Offsets at ``rate`` Hz.
    """
    if n_frames <= 0:
        return np.zeros((0, 3))
    a = math.exp(-1.0 / (rate * tau))
    w = rng.standard_normal((n_frames, 3)) * sigma
    out = np.empty((n_frames, 3))
    out[0] = w[0]  # started in the stationary distribution
    b = math.sqrt(1.0 - a * a)
    for i in range(1, n_frames):
        out[i] = a * out[i - 1] + b * w[i]
    return out


@dataclass(frozen=True)
class PhysicsSample:
    """One draw of the world: the scene's parameters and the execution's perturbation.

    Attributes
    ----------
    index : int
        The sample's number in its sweep (with the seed, what drew it).
    seed : int
    params : SimParams
    perturbation : Perturbation
    """

    index: int
    seed: int
    params: SimParams
    perturbation: Perturbation

    def values(self) -> dict[str, float]:
        """The varied quantities by name (the distribution's parameter names)."""
        p = self.params
        dx, dy, dyaw = self.perturbation.start_error
        return {
            "friction_table": p.friction_table, "friction_finger": p.friction_finger,
            "mass": p.mass, "finger_radius": p.finger_radius, "stiffness": p.stiffness,
            "max_force": p.max_force, "contact_timeconst": p.contact_timeconst,
            "start_offset": math.hypot(dx, dy), "start_yaw": dyaw,
            "tracking_noise": self.perturbation.tracking_noise,
            "finger_noise": self.perturbation.finger_noise,
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON form: index, seed, the varied values, and the full parameters."""
        return {"index": self.index, "seed": self.seed,
                **{k: round(v, 9) for k, v in self.values().items()},
                "params": self.params.to_dict(), "perturbation": self.perturbation.to_dict()}


Range = tuple[float, float]


@dataclass(frozen=True)
class PhysicsDistribution:
    """The documented distribution of physical parameters (module docstring).

    Every range is ``(low, high)``, drawn uniformly; ``low == high`` fixes a parameter.
    Parameters of :class:`SimParams` not named here (timestep, finger mass, settling,
    torsional friction, ...) stay at ``base``'s values.

    Attributes
    ----------
    friction_table, friction_finger, mass, finger_radius, stiffness, max_force, \
contact_timeconst : (float, float)
        Ranges (SI units). ``mass`` is for an object of volume ``volume``.
    start_offset : float
        Largest start position error, m (uniform in the disc of this radius).
    start_yaw : float
        Largest start yaw error, degrees (uniform in [-start_yaw, start_yaw]).
    tracking_noise, finger_noise : float
        Standard deviations, m.
    volume : float
        Volume (m^3) of the object the mass range is for: a 5 cm cube's.
    base : SimParams
        Everything not varied.
    """

    friction_table: Range = (0.3, 1.0)
    friction_finger: Range = (0.5, 1.2)
    mass: Range = (0.05, 0.4)
    finger_radius: Range = (0.005, 0.012)
    stiffness: Range = (600.0, 3000.0)
    max_force: Range = (8.0, 15.0)
    contact_timeconst: Range = (0.004, 0.02)
    start_offset: float = 0.003
    start_yaw: float = 3.0
    tracking_noise: float = 0.0005
    finger_noise: float = 0.001
    volume: float = CUBE_VOLUME
    base: SimParams = field(default=DEFAULT_PARAMS)

    #: The ranged parameters, in drawing order (part of what a seed means: never reorder).
    RANGED = ("friction_table", "friction_finger", "mass", "finger_radius", "stiffness",
              "max_force", "contact_timeconst")

    def __post_init__(self) -> None:
        for name in self.RANGED:
            r = getattr(self, name)
            try:
                lo, hi = (float(v) for v in r)
            except (TypeError, ValueError):
                raise InputError(f"the distribution's {name} must be a range (low, high), "
                                 f"got {r!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise InputError(f"the distribution's {name} must be a range low <= high, "
                                 f"got {r!r}")
            object.__setattr__(self, name, (lo, hi))
        _number(self.volume, "the distribution's object volume", 1e-12, 1e3, "m^3")
        # the extremes must make valid scenes (SimParams checks bounds and units) and
        # valid perturbations
        for pick in (0, 1):
            replace(self.base, **{n: getattr(self, n)[pick] for n in self.RANGED})
        Perturbation((self.start_offset, 0.0, self.start_yaw), self.tracking_noise,
                     self.finger_noise)
        if self.start_offset < 0 or self.start_yaw < 0:
            raise InputError("the distribution's start errors are largest magnitudes: give "
                             f"numbers >= 0, got {self.start_offset!r}, {self.start_yaw!r}")

    def for_object(self, poly: Polyhedron, scale: float) -> PhysicsDistribution:
        """The distribution for another object: its mass range scaled by its volume (the
        same densities, 400 - 3200 kg/m^3 for the default range)."""
        v = float(poly.volume) * float(scale) ** 3
        k = v / self.volume
        return replace(self, mass=(self.mass[0] * k, self.mass[1] * k), volume=v)

    def ranges(self) -> dict[str, Range]:
        """Each varied quantity's range, by the names of :meth:`PhysicsSample.values`."""
        out = {n: getattr(self, n) for n in self.RANGED}
        out["start_offset"] = (0.0, self.start_offset)
        out["start_yaw"] = (-self.start_yaw, self.start_yaw)
        out["tracking_noise"] = (self.tracking_noise, self.tracking_noise)
        out["finger_noise"] = (self.finger_noise, self.finger_noise)
        return out

    def sample(self, rng: np.random.Generator | int, *, index: int = 0,
               stream: int | None = None) -> PhysicsSample:
        """One draw.

        Parameters
        ----------
        rng : numpy.random.Generator or int
            A generator to draw from, or a seed: sample ``index`` of that seed then comes from
            ``SeedSequence([seed, index])`` (what :meth:`samples` does), or with a
            ``stream``, from ``SeedSequence([seed, stream, index])``.
        index : int
            The sample's number (recorded; with an int seed, it selects the draw).
        stream : int, optional
            Independent streams of one seed (a sweep gives each transition its own).
        """
        for name, v in (("sample index", index), ("sample stream", stream)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer))
                                  or not 0 <= v < 2**63):
                raise InputError(f"a {name} must be a whole number >= 0, got {v!r}")
        seed = -1
        if not isinstance(rng, np.random.Generator):
            if isinstance(rng, bool) or not isinstance(rng, (int, np.integer)) or \
                    not 0 <= rng < 2**63:
                raise InputError(f"the seed must be a whole number in [0, 2^63), got {rng!r}")
            seed = int(rng)
            entropy = [seed, int(index)] if stream is None else [seed, int(stream), int(index)]
            rng = np.random.default_rng(np.random.SeedSequence(entropy))
        drawn = {n: float(rng.uniform(*getattr(self, n))) for n in self.RANGED}
        radius = self.start_offset * math.sqrt(float(rng.uniform()))
        angle = float(rng.uniform(0.0, 2.0 * math.pi))
        yaw = float(rng.uniform(-self.start_yaw, self.start_yaw))
        noise_seed = int(rng.integers(0, 2**63))
        params = replace(self.base, **drawn)
        pert = Perturbation((radius * math.cos(angle), radius * math.sin(angle), yaw),
                            self.tracking_noise, self.finger_noise, noise_seed)
        return PhysicsSample(int(index), seed, params, pert)

    def samples(self, n: int, seed: int, *, start: int = 0) -> list[PhysicsSample]:
        """Samples ``start .. start + n - 1`` of ``seed``, each seeded by its index."""
        if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 10**7:
            raise InputError(f"the number of samples must be a whole number in [0, 10^7], "
                             f"got {n!r}")
        return [self.sample(seed, index=i) for i in range(start, start + n)]

    def to_dict(self) -> dict[str, Any]:
        """JSON form (the base parameters included)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "base"}
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}
        return {**d, "base": asdict(self.base)}


#: The documented distribution for a 5 cm cube (``for_object`` scales it).
DEFAULT_DISTRIBUTION = PhysicsDistribution()
