"""Low-level motion primitives: frozen dataclasses, the vocabulary of a sequence.

Each primitive is plain data (SI units: metres, radians, m/s) that prints, serialises
(:meth:`Step.to_dict` / :func:`step_from_dict`) and replays; :mod:`primitives.executor` gives it
meaning on the robot:

- :class:`Drive`: move the front ``distance`` metres along its heading (negative: reverse along
  the driven path) at ``speed``; while a bend is set, the heading turns as it drives; with
  ``comply`` the walls may take over the heading held after a turn (a long bend going on);
- :class:`Stop`: stand still (brakes) for ``duration`` seconds;
- :class:`Roll`: turn the front half about its axis by ``angle`` (the middle roll joint);
- :class:`Bend`: set bending joint ``joint`` (1 = behind the front module, the steering joint)
  to ``angle``; the front then drives on the arc of radius ``pitch / (2 sin(angle / 2))``
  through the joints, turning towards its +y (rolled) side;
- :class:`Clamp` / :class:`Unclamp`: fold the V to span ``diameter`` / straighten it;
- :class:`Centre`: probe both walls in two planes with the V and move onto the pipe axis;
- :class:`Sweep`: stop-and-scan servo sweep of the LiDAR;
- :class:`CheckHeading`: the turn is complete: the front's heading must be within
  ``tolerance`` of the commanded one (else the bend was blocked: a jam);
- :class:`Halt`: end the sequence with ``status`` (``blocked`` or ``dead_end``) without moving.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

from detector.validation import check_int, check_number, fail
from detector.vocab import StrEnum

DEFAULT_SPEED = 0.05  # m/s


def _num(obj: Any, name: str, lo: float, hi: float, unit: str) -> None:
    v = check_number(f"{type(obj).__name__}.{name}", getattr(obj, name), lo, hi, unit)
    object.__setattr__(obj, name, v)


class SequenceStatus(StrEnum):
    """How a primitive sequence (or a drive) ended: the executor's outcome status."""

    DONE = "done"
    JAMMED = "jammed"
    BLOCKED = "blocked"
    DEAD_END = "dead_end"


#: The statuses a :class:`Halt` step may end a sequence with, as plain strings.
HALT_STATUSES: tuple[str, ...] = (SequenceStatus.BLOCKED.value, SequenceStatus.DEAD_END.value)


@dataclass(frozen=True)
class Step:
    """Base class of primitives."""

    op: ClassVar[str] = "step"

    def to_dict(self) -> dict[str, Any]:
        return {"op": self.op, **asdict(self)}


@dataclass(frozen=True)
class Drive(Step):
    """Drive ``distance`` m (negative: back along the driven path) at ``speed`` m/s.

    ``comply``: coming out of a long bend's arc, where the arc may go on beyond what the sensor
    saw, the turn's heading is held only while the walls agree; once they force the front off
    it (the bend goes on), the walls set the heading and the commanded heading follows them
    instead of the drive reporting a stalled steering (``primitives.executor.COMPLY_ONSET``)."""

    op: ClassVar[str] = "drive"
    distance: float
    speed: float = DEFAULT_SPEED
    comply: bool = False

    def __post_init__(self) -> None:
        _num(self, "distance", -50.0, 50.0, "m")
        _num(self, "speed", 0.001, 0.5, "m/s")
        if not isinstance(self.comply, bool):
            raise fail("Drive.comply", self.comply, "True, False", "not a bool")

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        if not self.comply:
            d.pop("comply")
        return d


@dataclass(frozen=True)
class Stop(Step):
    """Stand still for ``duration`` s."""

    op: ClassVar[str] = "stop"
    duration: float = 0.1

    def __post_init__(self) -> None:
        _num(self, "duration", 0.0, 60.0, "s")


@dataclass(frozen=True)
class Roll(Step):
    """Roll the front half by ``angle`` rad about its axis at ``rate`` rad/s."""

    op: ClassVar[str] = "roll"
    angle: float
    rate: float = math.radians(90.0)

    def __post_init__(self) -> None:
        _num(self, "angle", -2 * math.pi, 2 * math.pi, "rad")
        _num(self, "rate", 0.01, 10.0, "rad/s")


@dataclass(frozen=True)
class Bend(Step):
    """Set bending joint ``joint`` (1 = steering joint behind the front module) to ``angle``."""

    op: ClassVar[str] = "bend"
    joint: int
    angle: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "joint", check_int("Bend.joint", self.joint, low=1))
        _num(self, "angle", -math.radians(170), math.radians(170), "rad")


@dataclass(frozen=True)
class Clamp(Step):
    """Fold the V to span ``diameter`` m (plus the configured preload)."""

    op: ClassVar[str] = "clamp"
    diameter: float

    def __post_init__(self) -> None:
        _num(self, "diameter", 0.0, 0.3, "m")


@dataclass(frozen=True)
class Unclamp(Step):
    """Straighten the V (wheels off the walls)."""

    op: ClassVar[str] = "unclamp"


@dataclass(frozen=True)
class Centre(Step):
    """Probe the walls with the V on four sides (up, down, left, right) and move the robot's
    ends onto the pipe axis if they are more than ``tolerance`` m off it (at most
    ``max_shift`` m); leaves the robot unclamped. Nothing moves where the V finds no wall."""

    op: ClassVar[str] = "centre"
    tolerance: float = 0.0005
    max_shift: float = 0.05

    def __post_init__(self) -> None:
        _num(self, "tolerance", 0.0, 0.05, "m")
        _num(self, "max_shift", 0.0, 0.2, "m")


@dataclass(frozen=True)
class Sweep(Step):
    """A stop-and-scan servo sweep of the LiDAR (the robot stands still)."""

    op: ClassVar[str] = "scan"


@dataclass(frozen=True)
class CheckHeading(Step):
    """Jam unless the front's heading is within ``tolerance`` rad of the commanded heading."""

    op: ClassVar[str] = "check_heading"
    tolerance: float = math.radians(30.0)

    def __post_init__(self) -> None:
        _num(self, "tolerance", 0.0, math.pi, "rad")


@dataclass(frozen=True)
class Halt(Step):
    """End the sequence here with ``status`` (``blocked`` or ``dead_end``) and ``reason``."""

    op: ClassVar[str] = "halt"
    status: str = "blocked"
    reason: str = ""

    def __post_init__(self) -> None:
        if self.status not in HALT_STATUSES:
            raise fail("Halt.status", self.status, "'blocked', 'dead_end'")


STEP_TYPES: dict[str, type[Step]] = {
    t.op: t for t in (Drive, Stop, Roll, Bend, Clamp, Unclamp, Centre, Sweep, CheckHeading, Halt)
}


def step_from_dict(d: dict[str, Any]) -> Step:
    """The primitive a :meth:`Step.to_dict` made; errors name the unknown op or field."""
    if not isinstance(d, dict) or "op" not in d:
        raise fail("step", d, "a mapping with an 'op' key", "not a step")
    op = d["op"]
    if op not in STEP_TYPES:
        raise fail("op", op, ", ".join(sorted(STEP_TYPES)), "unknown", where="step")
    cls = STEP_TYPES[op]
    names = {f.name for f in fields(cls)}
    extra = set(d) - names - {"op"}
    if extra:
        raise fail(
            "fields", sorted(extra), ", ".join(sorted(names)), "unknown", where=f"step {op!r}"
        )
    return cls(**{k: v for k, v in d.items() if k != "op"})
