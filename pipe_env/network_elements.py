"""The elements of a pipe network: :class:`Fitting` and :class:`Run`, and the network's limits.

This module owns the two element types and the constants that bound a network (schema version,
diameters, bend and taper limits, clearance, extent). It sits below the model
(:mod:`pipe_env.network`), its validation (:mod:`pipe_env.network_validation`) and its I/O
(:mod:`pipe_env.network_io`), which all import it; it imports nothing from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from detector.validation import ArgumentError, check_number, check_vector, fail

__all__ = [
    "BEND_ANGLE_RANGE",
    "BEND_RADIUS_RANGE",
    "MAX_EXTENT",
    "MAX_TAPER_HALF_ANGLE",
    "NETWORK_DIAMETER_RANGE",
    "SCHEMA_VERSION",
    "TAPER_LENGTH_RANGE",
    "WALL_CLEARANCE",
    "Fitting",
    "Run",
]

SCHEMA_VERSION = 1
#: Inner diameters a network may contain, metres. Wider than the robot's 57-125 mm so that
#: networks can hold pipes the robot must refuse (a reducer to 40 mm) or the thesis's 20 cm rig.
NETWORK_DIAMETER_RANGE = (0.020, 0.250)
#: Deflection of a bend, radians (30 to 90 deg).
BEND_ANGLE_RANGE = (math.radians(30.0), math.radians(90.0))
BEND_RADIUS_RANGE = (1.0, 3.0)  # long-radius bends, in diameters
TAPER_LENGTH_RANGE = (0.005, 1.0)  # metres
MAX_TAPER_HALF_ANGLE = math.radians(60.0)
#: Wall thickness assumed when checking clearance between non-adjacent pipes, metres.
WALL_CLEARANCE = 0.005
#: Largest coordinate of a fitting, goal or start position, metres (absurd geometry beyond it
#: is rejected by :meth:`pipe_env.network.PipeNetwork.validate`).
MAX_EXTENT = 1000.0


def _optional_string(field: str, value: Any, where: str) -> None:
    if value is not None and not isinstance(value, str):
        raise fail(field, value, "a string", "not a string", where)


@dataclass(frozen=True)
class Fitting:
    """A node of the network (see :mod:`pipe_env.network`). ``position`` in metres,
    ``bend_radius`` and ``taper_length`` in metres."""

    id: str
    kind: str
    position: tuple[float, float, float]
    style: str | None = None
    bend_radius: float | None = None
    taper_length: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "id", str(self.id))
        where = f"fitting {self.id!r}"
        try:
            pos = check_vector("position", self.position, 3, unit="m")
        except ArgumentError as exc:
            raise exc.within(where) from None
        object.__setattr__(self, "position", (float(pos[0]), float(pos[1]), float(pos[2])))
        if not isinstance(self.kind, str):
            raise fail("kind", self.kind, "a fitting kind (a string)", "not a string", where)
        _optional_string("style", self.style, where)
        for key in ("bend_radius", "taper_length"):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, check_number(key, value, unit="m", where=where))
        if self.kind == "bend" and self.style is None:
            object.__setattr__(self, "style", "mitre")

    def to_dict(self) -> dict[str, Any]:
        """The fitting as written in a network file."""
        d: dict[str, Any] = {"id": self.id, "kind": self.kind, "position": list(self.position)}
        for key in ("style", "bend_radius", "taper_length"):
            if getattr(self, key) is not None:
                d[key] = getattr(self, key)
        return d


@dataclass(frozen=True)
class Run:
    """A straight pipe between fittings ``a`` and ``b`` with one inner ``diameter`` (metres)."""

    id: str
    a: str
    b: str
    diameter: float

    def __post_init__(self) -> None:
        for key in ("id", "a", "b"):
            object.__setattr__(self, key, str(getattr(self, key)))
        # finiteness and range are checked by validate() (a NaN diameter may be built and
        # written, e.g. to show that JSON output stays finite)
        value = self.diameter
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            try:
                value = check_number("diameter", value, unit="m")
            except ArgumentError as exc:
                raise exc.within(f"run {self.id!r}") from None
        try:
            object.__setattr__(self, "diameter", float(value))
        except OverflowError:  # an int too large for a float
            raise fail("diameter", value, "a number (m)", "too large", f"run {self.id!r}") from None

    def other(self, node_id: str) -> str:
        """The fitting at the other end from ``node_id``."""
        return self.b if node_id == self.a else self.a

    def to_dict(self) -> dict[str, Any]:
        """The run as written in a network file."""
        return {"id": self.id, "a": self.a, "b": self.b, "diameter": self.diameter}
