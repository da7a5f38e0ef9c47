"""The one exception family of nonprehensile.

Every error the library raises on purpose derives from :class:`NonprehensileError`.
Each message says what was expected, what came, and how to fix it, and names the culprit
(a file, a face, a skill, an element) so that the command line can print it on one line.

Errors caused by the user's input (files, models, states, skills) also derive from
:class:`InputError`; the command line maps them to exit code 2.
"""

from __future__ import annotations

__all__ = [
    "ContactError",
    "DemonstrationError",
    "GeometryError",
    "InputError",
    "LockTimeout",
    "ManeuverError",
    "MeshError",
    "ModelError",
    "NonprehensileError",
    "RecordError",
    "SkillError",
    "StateError",
    "StoreError",
]


class NonprehensileError(Exception):
    """Base class of every error raised by nonprehensile."""


class InputError(NonprehensileError, ValueError):
    """The user's input (a file, an argument, a model) is malformed or inconsistent."""


class ModelError(InputError):
    """An object model is not a valid convex polyhedron under the spec's conventions.

    Parameters
    ----------
    message : str
        What is wrong and how to fix it.
    face : str, optional
        The face ID at fault, when one face is.
    source : str, optional
        The file (or other source) the model came from.
    """

    def __init__(self, message: str, *, face: str | None = None, source: str | None = None):
        self.face = face
        self.source = source
        prefix = f"{source}: " if source else ""
        where = f"face {face!r}: " if face is not None else ""
        super().__init__(f"{prefix}{where}{message}")


class DemonstrationError(InputError):
    """A demonstration record or motion-capture file (C3D, Motive CSV) is unreadable or wrong.

    The message names the file (when there is one) and the culprit: a row, a column, a marker,
    a parameter.
    """


class MeshError(InputError):
    """A mesh (or point set) cannot be made into an object model."""


class ContactError(InputError):
    """A contact element, pair or event is malformed, or names what the object does not have."""


class SkillError(InputError):
    """A skill (or a skills file) is malformed or contradicts the object's geometry."""


class StateError(InputError):
    """A state names a face the object does not have, or is not a valid resting state."""


class StoreError(NonprehensileError):
    """A demonstration store cannot be written now (another process holds its write lock
    too long); retry later."""


class LockTimeout(StoreError):
    """A store's write lock was not taken within its timeout (another writer holds it): the
    same line as any :class:`StoreError`, its kind told apart for the service, which answers
    its client a 503 to retry instead of the command line's advice."""


class GeometryError(NonprehensileError):
    """A geometric computation has no answer (for example a pose that rests on no face)."""


class ManeuverError(InputError):
    """A maneuver cannot be carried out (no such edge, passes through the ground, ...)."""


class RecordError(InputError):
    """Some skill of a skills file could not be recorded in physics.

    ``failures`` maps each such skill's name to its one-line reason (the commonest ways its
    takes failed, with counts, and what to change).
    """

    def __init__(self, message: str, failures: dict[str, str]) -> None:
        super().__init__(message)
        self.failures = failures
