"""What the agent observes: the observation type of the environments, with named columns.

In the manner of highway-env's ``ObservationType``: :class:`DecisionObservation` owns the
observation space (:meth:`~DecisionObservation.space`) and builds each observation
(:meth:`~DecisionObservation.observe`) from what the robot knows: the pending decision's
detected options, its odometry, its clamped diameter, its log of ways taken and (PipeNav) the
goal point. The options table's columns are :data:`OPTION_COLUMNS`, each with a name, bounds and
meaning; code reads a column by name (``OPTIONS.index("taken")``), never by a number.

Observation (a ``Dict`` with fixed shapes and finite bounds):

| key | shape | meaning |
|---|---|---|
| ``options`` | (K, 15) | rows: the ways on, then back out; columns :data:`OPTION_COLUMNS` |
| ``goal`` | (3,) | the goal in the robot frame from odometry, m, within +-20 (or zeros) |
| ``proprio`` | (3,) | clamped diameter (m), cos and sin of the robot's roll |
| ``scan`` | (16, 32) | with ``scan_image=True``: the last sweep's ranges / max range |
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from detector.geometry import Pose, clamp, frame_from_forward, norm3
from detector.options import StructureOption, option_vector
from pipe_env.envs.actions import BACK_ROW, K_OPTIONS
from pipe_env.envs.way_log import WayLog

#: Shape of the optional range image (rows, columns).
SCAN_SHAPE = (16, 32)
#: The goal vector is clipped to +-this, m.
GOAL_CLIP = 20.0
#: ``taken`` saturates at this many times (see :mod:`pipe_env.envs.way_log`).
MAX_TAKEN = 3
#: Largest clamped diameter observed, m.
MAX_DIAMETER = 0.3


@dataclass(frozen=True)
class Column:
    """One column of the options table: its name, bounds and meaning (units in the text)."""

    name: str
    low: float
    high: float
    meaning: str


#: The options table's columns, in order.
OPTION_COLUMNS: tuple[Column, ...] = (
    Column("valid", 0.0, 1.0, "1 if the action mask allows this row"),
    Column("straight", 0.0, 1.0, "kind one-hot: straight on (no structure ahead)"),
    Column("reducer", 0.0, 1.0, "kind one-hot: a diameter change"),
    Column("closure", 0.0, 1.0, "kind one-hot: an end wall or obstacle"),
    Column("bend", 0.0, 1.0, "kind one-hot: a bend (one way on)"),
    Column("junction", 0.0, 1.0, "kind one-hot: a junction (two or more ways on)"),
    Column("back_out", 0.0, 1.0, "1 on the back-out row"),
    Column(
        "distance",
        -1.0,
        5.0,
        "from the sensor to the structure's reference point along the pipe, m",
    ),
    Column(
        "diameter", 0.0, MAX_DIAMETER, "inner diameter of the outgoing pipe, m (0 for a closure)"
    ),
    Column(
        "cos_direction",
        -1.0,
        1.0,
        "cosine of the outgoing axis' roll about the incoming one (0 = left)",
    ),
    Column("sin_direction", -1.0, 1.0, "sine of that roll (pi/2 = up)"),
    Column("angle", 0.0, math.pi, "deflection of the outgoing axis from straight on, rad"),
    Column("confidence", 0.0, 1.0, "the detector's confidence in this way"),
    Column(
        "taken",
        0.0,
        1.0,
        "times the robot's odometry log says it took this way from here (/3, capped)",
    ),
    Column(
        "goal_alignment",
        -1.0,
        1.0,
        "cosine between the way's outgoing axis and the direction to the goal",
    ),
)
#: The column names, in order.
OPTION_FEATURES: tuple[str, ...] = tuple(c.name for c in OPTION_COLUMNS)
_INDEX = {name: i for i, name in enumerate(OPTION_FEATURES)}


def column(name: str) -> int:
    """The index of the options table's column ``name``.

    Raises:
        KeyError: an unknown column name.
    """
    return _INDEX[name]


VALID, BACK, DISTANCE, DIAMETER = (column(n) for n in ("valid", "back_out", "distance", "diameter"))
COS_DIR, SIN_DIR, ANGLE = (column(n) for n in ("cos_direction", "sin_direction", "angle"))
CONFIDENCE, TAKEN, GOAL_ALIGN = (column(n) for n in ("confidence", "taken", "goal_alignment"))
_LOW = np.array([c.low for c in OPTION_COLUMNS], dtype=np.float32)
_HIGH = np.array([c.high for c in OPTION_COLUMNS], dtype=np.float32)


class RobotReadings(Protocol):
    """What the observation is built from: the plant's robot-side readings."""

    @property
    def clamped_diameter(self) -> float: ...

    @property
    def scan_image(self) -> NDArray[np.floating] | None: ...

    def odometry_pose(self) -> Pose: ...


def roll_of(pose: Pose) -> float:
    """Roll of a pose about its forward axis relative to the roll-zero frame, rad."""
    ref = frame_from_forward(pose.forward)
    return math.atan2(float(pose.up @ ref[:, 1]) * -1.0, float(pose.up @ ref[:, 2]))


def world_way(choice: StructureOption | str, odo: Pose) -> NDArray[np.float64] | None:
    """A chosen way as a world direction from the odometry heading (None: back out)."""
    return None if isinstance(choice, str) else odo.rotation @ option_vector(choice)


class DecisionObservation:
    """The observation type of both environments (see the module docstring).

    Args:
        scan_image: add the ``scan`` range image.
    """

    def __init__(self, scan_image: bool = False) -> None:
        self.scan_image = scan_image

    def space(self) -> spaces.Dict:
        """The observation space (bounds from :data:`OPTION_COLUMNS`)."""
        obs: dict[str, spaces.Space] = {
            "options": spaces.Box(
                np.tile(_LOW, (K_OPTIONS, 1)), np.tile(_HIGH, (K_OPTIONS, 1)), dtype=np.float32
            ),
            "goal": spaces.Box(-GOAL_CLIP, GOAL_CLIP, (3,), dtype=np.float32),
            "proprio": spaces.Box(
                np.array([0.0, -1, -1], np.float32),
                np.array([MAX_DIAMETER, 1, 1], np.float32),
                dtype=np.float32,
            ),
        }
        if self.scan_image:
            obs["scan"] = spaces.Box(0.0, 1.0, SCAN_SHAPE, dtype=np.float32)
        return spaces.Dict(obs)

    def observe(
        self,
        robot: RobotReadings,
        options: list[StructureOption],
        mask: NDArray[np.bool_],
        way_log: WayLog,
        goal: NDArray[np.float64] | None,
    ) -> dict[str, NDArray[np.float32]]:
        """The observation now.

        Args:
            robot: the plant's readings (odometry, clamped diameter, range image).
            options: the pending decision's detected ways on (empty: none pending).
            mask: the action mask (:meth:`pipe_env.envs.actions.OptionAction.mask`).
            way_log: the robot's log of the ways it took.
            goal: the goal point in the world frame (m), None without one.
        """
        pose = robot.odometry_pose()
        roll = roll_of(pose)
        obs = {
            "options": options_table(pose, options[:BACK_ROW], mask, way_log, goal),
            "goal": np.zeros(3, dtype=np.float32),
            "proprio": np.array(
                [clamp(robot.clamped_diameter, 0.0, MAX_DIAMETER), math.cos(roll), math.sin(roll)],
                dtype=np.float32,
            ),
        }
        if goal is not None:
            rel = pose.rotation.T @ (goal - pose.position)
            obs["goal"] = np.clip(rel, -GOAL_CLIP, GOAL_CLIP).astype(np.float32)
        if self.scan_image:  # a copy: observations never share the plant's array
            img = robot.scan_image
            obs["scan"] = (
                np.zeros(SCAN_SHAPE, np.float32) if img is None else np.array(img, np.float32)
            )
        return obs


def _unit_to_goal(odo: Pose, goal: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
    if goal is None:
        return None
    rel = goal - odo.position
    norm = norm3(rel)
    return rel / norm if norm > 1e-9 else None


def options_table(
    odo: Pose,
    options: list[StructureOption],
    mask: NDArray[np.bool_],
    way_log: WayLog,
    goal: NDArray[np.float64] | None,
) -> NDArray[np.float32]:
    """The (K, len(OPTION_COLUMNS)) options table from the odometry pose ``odo``."""
    table = np.zeros((K_OPTIONS, len(OPTION_COLUMNS)), dtype=np.float32)
    to_goal = _unit_to_goal(odo, goal)
    ways = [world_way(o, odo) for o in options]
    taken = way_log.counts(odo.position, [*ways, None])
    for i, (o, way) in enumerate(zip(options, ways)):
        _fill_way(table[i], o, bool(mask[i]), taken[i])
        if to_goal is not None and way is not None:
            table[i, GOAL_ALIGN] = clamp(float(way @ to_goal), -1.0, 1.0)
    back = table[BACK_ROW]
    if to_goal is not None:  # backing out heads the other way
        back[GOAL_ALIGN] = clamp(-float(odo.forward @ to_goal), -1.0, 1.0)
    back[TAKEN] = min(taken[-1], MAX_TAKEN) / MAX_TAKEN
    back[VALID] = float(mask[BACK_ROW])
    back[BACK] = 1.0
    back[COS_DIR] = 1.0
    back[ANGLE] = math.pi
    back[CONFIDENCE] = 1.0
    return table


def _fill_way(row: NDArray[np.float32], o: StructureOption, valid: bool, taken: int) -> None:
    """One detected way's row."""
    row[VALID] = float(valid)
    row[column(str(o.kind))] = 1.0
    row[DISTANCE] = clamp(o.distance, _LOW[DISTANCE], _HIGH[DISTANCE])
    row[DIAMETER] = clamp(o.diameter, 0.0, _HIGH[DIAMETER])
    row[COS_DIR], row[SIN_DIR] = math.cos(o.direction), math.sin(o.direction)
    row[ANGLE] = clamp(o.angle, 0.0, math.pi)
    row[CONFIDENCE] = clamp(o.confidence, 0.0, 1.0)
    row[TAKEN] = min(taken, MAX_TAKEN) / MAX_TAKEN
