"""The structure option: one way on past a detected (or true) pipe structure.

Both the detector and the network's ground truth return this type, so estimates and truth can
be compared field by field. Definitions follow docs/design.md (SI units in the API):

- ``kind``: ``straight``, ``reducer`` (diameter change), ``closure`` (the thesis's "reduction to
  0 mm": an end wall or obstacle), ``bend`` or ``junction`` (two or more ways on).
- ``distance``: along the current pipe axis, from the sensor origin to the structure's reference
  point, metres. Reference point: where the incoming and outgoing centrelines meet (bends,
  junctions); the start of the taper (reducer); the end wall (closure).
- ``diameter``: inner diameter of the outgoing pipe, metres (0 for a closure).
- ``angle``: deflection between the incoming and the outgoing axis, radians, 0 = straight on.
- ``direction``: roll of the outgoing axis about the incoming axis, measured in the sensor frame
  as atan2(z, y): 0 = left, +pi/2 = up, pi = right, -pi/2 = down. Wrapped to (-pi, pi].
- ``confidence``: in [0, 1]; 1 for ground truth.
- ``bend_radius``: centreline radius of a long-radius bend's arc, metres; 0 for a mitre bend,
  any other kind, or when the method does not estimate it. A turn primitive follows this arc
  (a tight turn cuts the inside of a wide bend and jams).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.geometry import clamp, direction_from_angles, wrap_angle
from detector.vocab import Kind

#: The numeric fields of a :class:`StructureOption` (each a finite float once built).
_NUMBER_FIELDS = ("distance", "diameter", "direction", "angle", "confidence", "bend_radius")

#: The structure kinds as plain strings, in :class:`~detector.vocab.Kind` order.
KINDS: tuple[str, ...] = tuple(k.value for k in Kind)


@dataclass(frozen=True)
class StructureOption:
    """One way on past a structure ahead. Units: metres and radians (see module docstring)."""

    kind: str
    distance: float
    diameter: float
    direction: float = 0.0
    angle: float = 0.0
    confidence: float = 1.0
    bend_radius: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"StructureOption.kind must be one of {KINDS}, got {self.kind!r}")
        for name in _NUMBER_FIELDS:
            value = getattr(self, name)
            if type(value) is float and math.isfinite(value):
                continue  # (a finite float already: the common case, kept cheap)
            ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
            if not ok or not math.isfinite(value):
                raise ValueError(
                    f"StructureOption.{name} must be a finite real number (not a bool), "
                    f"got {value!r}"
                )
            object.__setattr__(self, name, float(value))
        if self.diameter < 0.0:
            raise ValueError(f"StructureOption.diameter must be >= 0 m, got {self.diameter}")
        if not 0.0 <= self.angle <= math.pi + 1e-9:
            raise ValueError(f"StructureOption.angle must be in [0, pi] rad, got {self.angle}")
        if self.bend_radius < 0.0:
            raise ValueError(f"StructureOption.bend_radius must be >= 0 m, got {self.bend_radius}")
        if not 0.0 <= self.confidence <= 1.0:
            raise ValueError(f"StructureOption.confidence must be in [0, 1], got {self.confidence}")
        object.__setattr__(self, "direction", wrap_angle(self.direction))

    @property
    def is_straight_on(self) -> bool:
        """True for a way on that continues (nearly) along the current axis (angle < 10 deg)."""
        return self.angle < math.radians(10.0)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "distance": self.distance,
            "diameter": self.diameter,
            "direction": self.direction,
            "angle": self.angle,
            "confidence": self.confidence,
            "bend_radius": self.bend_radius,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StructureOption:
        return cls(**d)

    def describe(self) -> str:
        """Human-readable summary in operator units, e.g. 'bend 45 deg up in 18.0 cm, 100 mm'."""
        where = f"in {self.distance * 100:.1f} cm"
        if self.kind == Kind.CLOSURE:
            return f"closure {where}"
        if self.kind == Kind.STRAIGHT:
            return f"straight pipe, {self.diameter * 1000:.0f} mm"
        if self.kind == Kind.REDUCER:
            return f"reducer to {self.diameter * 1000:.0f} mm {where}"
        if self.is_straight_on:
            return f"{self.kind}: straight on {where}, {self.diameter * 1000:.0f} mm"
        radius = f", radius {self.bend_radius * 100:.0f} cm" if self.bend_radius > 0 else ""
        return (
            f"{self.kind}: {math.degrees(self.angle):.0f} deg {direction_name(self.direction)} "
            f"{where}, {self.diameter * 1000:.0f} mm{radius}"
        )


def option_order(option: StructureOption) -> tuple[int, float]:
    """Sort key of the options of one structure: the way straight on first, then the others by
    roll direction. Noise in the deflection angle cannot swap two branches this way."""
    return (0 if option.is_straight_on else 1, option.direction)


def direction_name(direction: float) -> str:
    """Nearest of eight compass-like names for a roll direction (0 = left, pi/2 = up)."""
    names = ["left", "up-left", "up", "up-right", "right", "down-right", "down", "down-left"]
    k = int(round(wrap_angle(direction) / (math.pi / 4.0))) % 8
    deg = round(math.degrees(wrap_angle(direction)))
    return f"{names[k]} ({deg + 0:+d} deg)"


def arc_start(option: StructureOption) -> float:
    """How far ahead a bend's arc starts, m: its reference point (``distance``, where the
    centrelines meet) less ``bend_radius x tan(angle / 2)``; the reference point itself for a
    mitre (``bend_radius`` 0)."""
    return option.distance - option.bend_radius * math.tan(0.5 * option.angle)


def option_vector(option: StructureOption) -> NDArray[np.float64]:
    """Outgoing axis of an option in the sensor frame."""
    return direction_from_angles(option.angle, option.direction)


def match_option(chosen: StructureOption, truth: list[StructureOption]) -> tuple[int, float]:
    """Index of the true way on closest to ``chosen`` and the angle (rad) between their axes."""
    # cosine of the angle between two (angle, direction) axes, without building the vectors
    ca, sa = math.cos(chosen.angle), math.sin(chosen.angle)
    sep = [
        math.acos(
            clamp(
                ca * math.cos(t.angle)
                + sa * math.sin(t.angle) * math.cos(chosen.direction - t.direction),
                -1.0,
                1.0,
            )
        )
        for t in truth
    ]
    k = min(range(len(sep)), key=sep.__getitem__)
    return k, sep[k]


#: Roll-direction errors count only for ways turning more than this (rad): the direction of a
#: nearly straight way is ill-defined.
DIRECTION_ERROR_MIN_ANGLE = math.radians(10.0)


def option_errors(options: list[StructureOption], truth: list[StructureOption]) -> dict[str, float]:
    """Largest absolute errors of sensed ``options`` against the true ways they match.

    Each option is compared with its closest true way (:func:`match_option`). Returns
    ``distance`` and ``diameter`` (m) and ``angle`` (rad) when there are options, and
    ``direction`` (rad, wrapped to [0, pi]) only when a matched true way turns by more than
    ``DIRECTION_ERROR_MIN_ANGLE``. Empty when there are no options or no true ways.
    """
    if not options or not truth:
        return {}
    d_err, dia, ang, dirs = [], [], [], []
    for o in options:
        k, _ = match_option(o, truth)
        t = truth[k]
        d_err.append(abs(o.distance - t.distance))
        dia.append(abs(o.diameter - t.diameter))
        ang.append(abs(o.angle - t.angle))
        if t.angle > DIRECTION_ERROR_MIN_ANGLE:
            dirs.append(abs(wrap_angle(o.direction - t.direction)))
    errs = {"distance": max(d_err), "diameter": max(dia), "angle": max(ang)}
    if dirs:
        errs["direction"] = max(dirs)
    return errs
