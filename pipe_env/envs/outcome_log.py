"""The decision loop's own outcome accounting, the same in both fidelities.

:class:`OutcomeLog` (``env.unwrapped.outcome_log``, fresh every episode) keeps the jams while
driving and two lists:

- :class:`SensedStructure`: what was sensed at every structure the robot stopped before (single
  ways taken automatically and senses after a jam included) against the ground truth at the
  same pose: the kinds, the ways missed and the phantom ways, and the largest absolute option
  errors (:func:`detector.options.option_errors`: distance and diameter in metres, angle and
  direction in radians);
- :class:`Attempt`: every way the plant was asked to take (chosen by the agent or taken
  automatically, backing out included) with the true structure kind, the class of the true way
  it matched (:func:`way_class`) and how it ended (a :class:`~pipe_env.envs.plant.PlantStatus`
  value).

A sensed way and a true way are the same way when their outgoing axes are within
``MATCH_ANGLE`` (the fast plant's ``ExecutionTolerance.match``: a chosen way farther from every
true way is a phantom and jams). Records are plain data (:meth:`OutcomeLog.to_dict`), so worker
processes can return them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from detector.options import StructureOption, match_option, option_errors

#: Largest angle between a sensed and a true way's outgoing axes for them to be one way, rad.
MATCH_ANGLE = math.radians(40.0)
#: Deflection classes of a way on: (upper bound in degrees, label), in order.
ANGLE_CLASSES: tuple[tuple[float, str], ...] = (
    (10.0, "straight"),
    (50.0, "shallow (10-50 deg)"),
    (80.0, "oblique (50-80 deg)"),
    (100.0, "square (80-100 deg)"),
    (180.0, "sharp (> 100 deg)"),
)
#: The label of backing out (no way of the structure) and of a way that matches no true way.
BACK_OUT_CLASS = "back out"
PHANTOM_CLASS = "phantom"


def angle_class(angle: float) -> str:
    """The deflection class (:data:`ANGLE_CLASSES`) of a way turning by ``angle`` rad."""
    deg = math.degrees(abs(angle))
    for bound, label in ANGLE_CLASSES:
        if deg < bound:
            return label
    return ANGLE_CLASSES[-1][1]


def turn_direction(option: StructureOption) -> str:
    """The side a way turns to in the robot frame (REP-103: ``direction`` 0 = left, pi/2 = up):
    ``left``, ``up``, ``right`` or ``down`` (the nearest of the four), ``none`` for a way within
    10 deg of straight on."""
    if math.degrees(option.angle) < ANGLE_CLASSES[0][0]:
        return "none"
    sides = ("left", "up", "right", "down")
    quarter = round(math.remainder(option.direction, 2 * math.pi) / (math.pi / 2)) % 4
    return sides[quarter]


def way_class(option: StructureOption) -> str:
    """A way's class: its deflection class and the side it turns to, e.g. ``square
    (80-100 deg) up``; ``straight`` for straight on."""
    cls = angle_class(option.angle)
    side = turn_direction(option)
    return cls if side == "none" else f"{cls} {side}"


@dataclass(frozen=True)
class SensedStructure:
    """What was sensed at one structure against the truth at the same pose.

    Attributes:
        true_kind, kind: the true and the reported kind of the structure.
        n_true, n_sensed: true ways on and reported ways on.
        missed: true ways no reported way matches (within ``MATCH_ANGLE``).
        phantoms: reported ways matching no true way.
        errors: largest absolute errors of the reported ways against the true ways they match
            (``distance``, ``diameter`` m; ``angle``, ``direction`` rad; ``direction`` only
            when a matched true way turns); empty without reported ways.
    """

    true_kind: str
    kind: str
    n_true: int
    n_sensed: int
    missed: int
    phantoms: int
    errors: dict[str, float] = field(default_factory=dict)

    @property
    def misclassified(self) -> bool:
        return self.kind != self.true_kind


@dataclass(frozen=True)
class Attempt:
    """One way the plant was asked to take and how it ended.

    Attributes:
        true_kind: the true kind of the structure decided at.
        way: the deflection class (:func:`angle_class`) of the true way the chosen one
            matched, ``"phantom"`` when it matched none, ``"back out"`` for backing out.
        side: the side that true way turns to (:func:`turn_direction`; ``"none"`` for
            straight on, a phantom or backing out).
        status: how the plant's action ended (``done``, ``jammed``, ``blocked``, ``goal``,
            ``back_out``).
        auto: True for a single way the environment took without asking.
    """

    true_kind: str
    way: str
    side: str
    status: str
    auto: bool

    @property
    def jammed(self) -> bool:
        return self.status == "jammed"


def sensed_structure(
    options: list[StructureOption], kind: str, truth: list[StructureOption]
) -> SensedStructure:
    """The record of reporting ``options`` (of kind ``kind``) where ``truth`` holds."""
    matched_true: set[int] = set()
    phantoms = 0
    for o in options:
        if not truth:
            phantoms += 1
            continue
        k, sep = match_option(o, truth)
        if sep <= MATCH_ANGLE:
            matched_true.add(k)
        else:
            phantoms += 1
    return SensedStructure(
        true_kind=truth[0].kind if truth else "straight",
        kind=str(kind),
        n_true=len(truth),
        n_sensed=len(options),
        missed=len(truth) - len(matched_true),
        phantoms=phantoms,
        errors={k: float(v) for k, v in option_errors(options, truth).items()},
    )


def attempted_way(choice: StructureOption | str, truth: list[StructureOption]) -> tuple[str, str]:
    """The deflection class and side of the true way ``choice`` (an option, or the back-out
    string) stands for (see :class:`Attempt`)."""
    if isinstance(choice, str):
        return BACK_OUT_CLASS, "none"
    if not truth:
        return PHANTOM_CLASS, "none"
    k, sep = match_option(choice, truth)
    if sep > MATCH_ANGLE:
        return PHANTOM_CLASS, "none"
    return angle_class(truth[k].angle), turn_direction(truth[k])


@dataclass
class OutcomeLog:
    """One episode's :class:`SensedStructure` and :class:`Attempt` records, in order, and
    ``drive_jams``: drives to a structure that ended jammed (the robot stalled while driving;
    no attempt of a way), in the full fidelity physically, in the fast one drawn at
    :data:`pipe_env.envs.plant.DRIVE_JAM_RATE`."""

    sensed: list[SensedStructure] = field(default_factory=list)
    attempts: list[Attempt] = field(default_factory=list)
    drive_jams: int = 0

    def record_sensing(
        self, options: list[StructureOption], kind: str, truth: list[StructureOption]
    ) -> None:
        """Log a detection at a structure (see :func:`sensed_structure`)."""
        self.sensed.append(sensed_structure(options, kind, truth))

    def record_attempt(
        self,
        choice: StructureOption | str,
        truth: list[StructureOption],
        status: str,
        auto: bool = False,
    ) -> None:
        """Log that taking ``choice`` at a structure with true ways ``truth`` ended ``status``."""
        true_kind = truth[0].kind if truth else "straight"
        way, side = attempted_way(choice, truth)
        self.attempts.append(Attempt(true_kind, way, side, str(status), bool(auto)))

    def to_dict(self) -> dict[str, Any]:
        """Plain data: ``{"sensed": [...], "attempts": [...], "drive_jams": n}``."""
        return {
            "sensed": [asdict(s) for s in self.sensed],
            "attempts": [asdict(a) for a in self.attempts],
            "drive_jams": int(self.drive_jams),
        }
