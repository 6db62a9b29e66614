"""Primitive sequences: the motions that carry out a chosen structure option.

A :class:`Sequence` is data (a name and a tuple of :mod:`primitives.steps`): it prints, converts
to and from plain dicts (JSON/YAML), and replays on the executor. Builders (lengths in metres,
angles in radians, ``option`` distances from the sensor as docs/design.md defines them):

- :func:`go_straight`, :func:`back_out`, :func:`stop_before`;
- :func:`take_turn`: drive to where the turn arc starts (from the option's distance), unclamp,
  roll the front half to the option's direction, bend the steering joint and drive the arc
  through the option's angle, straighten, drive until the whole robot is in the outgoing pipe,
  roll back, centre on the outgoing pipe's axis (the V probes both walls), clamp to the
  outgoing diameter, check the heading. The arc is the robot's tightest (``TURN_RADIUS_FACTOR``
  x D, inside a mitre's corner) unless the option gives a long bend's ``bend_radius``: then the
  robot follows that arc, reversing first if it decided inside the arc already;
- :func:`pass_reducer`: drive through the taper unclamped and clamp at the new diameter; a
  reducer to a diameter outside the robot's range is refused before entering (``blocked``);
- :func:`pass_junction`: a branch is a turn; the way straight on is driven through;
- :func:`for_option`: the sequence for an option of any kind (a closure is a ``dead_end``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from detector.options import StructureOption
from pipe_env.robot import RobotConfig
from pipe_env.robot_limits import SENSED_DIAMETER_MARGIN
from primitives.steps import (
    DEFAULT_SPEED,
    Bend,
    Centre,
    CheckHeading,
    Clamp,
    Drive,
    Halt,
    Roll,
    Step,
    Stop,
    Unclamp,
    step_from_dict,
)

#: Turn arc radius as a fraction of the incoming diameter (fits inside a mitre's corner).
TURN_RADIUS_FACTOR = 0.65
#: A tight turn starts this early (towards the inner corner), m. Measured passing windows of a
#: tee's branch: 5.5-7.5 mm early at 57 mm (the robot's smallest pipe), 3-15 mm at 60-75 mm; a
#: 90 deg mitre at 57 mm passes from 3.5 mm early on.
TURN_INSIDE = 0.0065
#: The robot attempts sensed turns up to this angle (90 deg fittings plus sensing noise), rad.
MAX_TURN_ATTEMPT = math.radians(100.0)
#: Distance kept before a structure's reference point by :func:`stop_before`, m.
STOP_MARGIN = 0.05


@dataclass(frozen=True)
class Sequence:
    """A named tuple of primitives."""

    name: str
    steps: tuple[Step, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Sequence.name = {self.name!r} is invalid; allowed: a non-empty str")
        steps = tuple(self.steps)
        for i, s in enumerate(steps):
            if not isinstance(s, Step):
                raise ValueError(f"Sequence.steps[{i}] = {s!r} is not a primitive Step")
        object.__setattr__(self, "steps", steps)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "steps": [s.to_dict() for s in self.steps]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Sequence:
        if not isinstance(d, dict) or "name" not in d or "steps" not in d:
            raise ValueError(f"a sequence must be a dict with 'name' and 'steps', got {d!r}")
        return cls(str(d["name"]), tuple(step_from_dict(s) for s in d["steps"]))

    def __str__(self) -> str:
        inner = ", ".join(_fmt(s) for s in self.steps)
        return f"{self.name}: [{inner}]"

    def __len__(self) -> int:
        return len(self.steps)


def _fmt(s: Step) -> str:
    d = s.to_dict()
    op = d.pop("op")
    args = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v!r}" for k, v in d.items())
    return f"{op}({args})"


def _cfg(config: RobotConfig | None) -> RobotConfig:
    return config or RobotConfig()


def go_straight(distance: float, speed: float = DEFAULT_SPEED) -> Sequence:
    """Drive ``distance`` m straight on."""
    return Sequence("go_straight", (Drive(distance, speed),))


def back_out(
    distance: float, speed: float = DEFAULT_SPEED, diameter: float | None = None
) -> Sequence:
    """Reverse ``distance`` m along the driven path. With ``diameter`` (m, the pipe the robot
    backs into) the robot unclamps first, so the V's straight legs do not cut the corners of
    the turns it retraces, and clamps there again."""
    if diameter is None:
        return Sequence("back_out", (Drive(-abs(distance), speed),))
    return Sequence(
        "back_out", (Unclamp(), Drive(-abs(distance), speed), Centre(), Clamp(diameter))
    )


def stop_before(option: StructureOption, margin: float = STOP_MARGIN) -> Sequence:
    """Drive up to ``margin`` m before the option's reference point and stop."""
    return Sequence("stop_before", (Drive(max(option.distance - margin, 0.0)), Stop()))


def _refuse(option: StructureOption, config: RobotConfig) -> Sequence | None:
    # a sensed diameter is noisy: a way sensed just outside the range is attempted, as the
    # options table's mask offers it (the clamp is force-controlled: it finds the real wall)
    lo, hi = config.diameter_range
    lo, hi = lo - SENSED_DIAMETER_MARGIN, hi + SENSED_DIAMETER_MARGIN
    if option.kind == "closure" or option.diameter <= 0.0:
        return Sequence("dead_end", (Stop(), Halt("dead_end", "closure ahead: no way on")))
    if not lo <= option.diameter <= hi:
        return Sequence(
            "refuse",
            (
                Stop(),
                Halt(
                    "blocked",
                    f"way on is {option.diameter * 1000:.0f} mm, outside the robot's "
                    f"{config.diameter_range[0] * 1000:.0f}-"
                    f"{config.diameter_range[1] * 1000:.0f} mm",
                ),
            ),
        )
    if option.angle > MAX_TURN_ATTEMPT:
        return Sequence(
            "refuse",
            (
                Stop(),
                Halt(
                    "blocked",
                    f"turn of {math.degrees(option.angle):.0f} deg exceeds the "
                    f"{math.degrees(MAX_TURN_ATTEMPT):.0f} deg the robot attempts",
                ),
            ),
        )
    return None


def take_turn(
    option: StructureOption,
    incoming_diameter: float | None = None,
    config: RobotConfig | None = None,
    speed: float = DEFAULT_SPEED,
) -> Sequence:
    """Turn into the way on described by ``option`` (see module docstring)."""
    c = _cfg(config)
    refused = _refuse(option, c)
    if refused is not None:
        return refused
    d_in = float(incoming_diameter) if incoming_diameter else option.diameter
    theta = option.angle
    if theta < math.radians(3.0):
        return pass_straight(option, d_in, c, speed)
    radius = max(TURN_RADIUS_FACTOR * d_in, 0.55 * c.pitch)
    follow_arc = option.bend_radius > radius  # a long bend: its own, wider arc
    if follow_arc:
        radius = option.bend_radius
    bend = 2.0 * math.asin(min(c.pitch / (2.0 * radius), 1.0))
    # the front module's centre follows the arc; it starts radius*tan(theta/2) before the
    # reference point, which is option.distance ahead of the sensor
    pre = option.distance + c.lidar_offset - radius * math.tan(0.5 * theta)
    if not follow_arc:
        # start a little early so the arc hugs the inner corner: the front module's outer
        # front wheel then clears the far corner of a branch's mouth (a tee in a 60 mm pipe)
        if min(d_in, option.diameter) > c.width:
            pre -= TURN_INSIDE
    through = c.length + 0.5 * option.diameter + 0.03
    steps: list[Step] = [Unclamp()]
    if pre > 0 or (follow_arc and pre < -0.001):
        steps.append(Drive(pre, speed))  # negative: back up to where a long bend's arc starts
    steps += [
        Roll(option.direction),
        Bend(1, bend),
        Drive(radius * theta, speed),
        Bend(1, 0.0),
        Drive(through, speed, comply=follow_arc),
        Roll(-option.direction),
        Centre(),
        Clamp(option.diameter),
        CheckHeading(c.jam_heading),
    ]
    return Sequence("take_turn", tuple(steps))


def _drive_through(
    name: str,
    option: StructureOption,
    incoming_diameter: float | None,
    config: RobotConfig | None,
    speed: float,
    run_out_diameters: float,
) -> Sequence:
    """Unclamped, drive until the whole robot is ``run_out_diameters`` (x the larger diameter,
    x the outgoing one for a reducer: into a narrower pipe a shorter run-out suffices, and a
    short run after it must not be overshot) past the structure, centre and clamp at the
    option's diameter."""
    c = _cfg(config)
    refused = _refuse(option, c)
    if refused is not None:
        return refused
    d_in = float(incoming_diameter) if incoming_diameter else option.diameter
    run_out = run_out_diameters * (
        option.diameter if option.kind == "reducer" else max(d_in, option.diameter)
    )
    dist = max(option.distance, 0.0) + c.length + run_out + 0.03
    return Sequence(
        name,
        (
            Unclamp(),
            Drive(dist, speed),
            Centre(),
            Clamp(option.diameter),
            CheckHeading(c.jam_heading),
        ),
    )


def pass_straight(
    option: StructureOption,
    incoming_diameter: float | None = None,
    config: RobotConfig | None = None,
    speed: float = DEFAULT_SPEED,
) -> Sequence:
    """Drive straight through the structure until the whole robot is past it."""
    return _drive_through("pass_straight", option, incoming_diameter, config, speed, 0.5)


def pass_reducer(
    option: StructureOption,
    incoming_diameter: float | None = None,
    config: RobotConfig | None = None,
    speed: float = DEFAULT_SPEED,
) -> Sequence:
    """Drive through a reducer (taper) unclamped and clamp at its outgoing diameter."""
    return _drive_through("pass_reducer", option, incoming_diameter, config, speed, 2.0)


def pass_junction(
    option: StructureOption,
    incoming_diameter: float | None = None,
    config: RobotConfig | None = None,
    speed: float = DEFAULT_SPEED,
) -> Sequence:
    """Take one way on at a junction: a branch is a turn, straight on is driven through."""
    if option.is_straight_on:
        seq = pass_straight(option, incoming_diameter, config, speed)
    else:
        seq = take_turn(option, incoming_diameter, config, speed)
    return Sequence("pass_junction", seq.steps) if seq.name not in ("refuse", "dead_end") else seq


def for_option(
    option: StructureOption,
    incoming_diameter: float | None = None,
    config: RobotConfig | None = None,
    speed: float = DEFAULT_SPEED,
) -> Sequence:
    """The sequence that carries out ``option`` of any kind."""
    if not isinstance(option, StructureOption):
        raise ValueError(f"option must be a StructureOption, got {type(option).__name__}")
    c = _cfg(config)
    refused = _refuse(option, c)
    if refused is not None:
        return refused
    if option.kind == "reducer":
        return pass_reducer(option, incoming_diameter, c, speed)
    if option.kind == "junction":
        return pass_junction(option, incoming_diameter, c, speed)
    if option.kind == "bend":
        return take_turn(option, incoming_diameter, c, speed)
    return go_straight(max(option.distance, 0.0) + c.length, speed)
