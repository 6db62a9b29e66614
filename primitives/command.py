"""The drive command: where the executor tells the front module to be, and how it steers.

:class:`DriveCommand` holds the drive target of the front module (position m, rotation), the
commanded heading (open loop, compared with the real one at the end of a turn), the steering
curvature of the front joint, the commanded roll of the front half against the rear half, the
bend offsets of other joints, and whether the robot holds a turn's heading coming out of its
arc. The executor moves the target every control tick; the walls guide a slightly-off command
(:meth:`DriveCommand.anchor`: lateral offsets beyond ``ANCHOR_POS``, heading beyond
``ANCHOR_ROT`` on an arc, ``ANCHOR_ROT_STRAIGHT`` driving straight).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from detector.geometry import rotation_about
from primitives.rotations import log_rotation, rotation_angle

#: The drive target follows the front module's lateral offset beyond this, m.
ANCHOR_POS = 0.003
#: The drive target follows the front module's heading beyond this, rad.
ANCHOR_ROT = math.radians(8.0)
#: Driving straight (no bend set), the drive target follows the front's heading beyond this,
#: rad: with no steering, the walls set the heading.
ANCHOR_ROT_STRAIGHT = math.radians(1.0)


@dataclass
class DriveCommand:
    """The executor's command to the robot (see module docstring).

    Attributes:
        position: drive target of the front module, world, m.
        rotation: its rotation (columns: forward, left, up).
        heading: the commanded heading's rotation (open loop).
        curvature: steering curvature of the front joint, 1/m (0: straight).
        roll: commanded roll of the front half against the rear half, rad.
        hold_heading: out of a turn's arc, keep the turn's heading until centring or clamping.
        bend_offsets: joint index -> commanded bend of joints other than the front's, rad.
    """

    position: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    rotation: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))
    heading: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))
    curvature: float = 0.0
    roll: float = 0.0
    hold_heading: bool = False
    bend_offsets: dict[int, float] = field(default_factory=dict)

    def reset(self, position: NDArray[np.float64], rotation: NDArray[np.float64]) -> None:
        """A straight, unrolled command at ``position`` (m) and ``rotation``."""
        self.curvature = 0.0
        self.roll = 0.0
        self.hold_heading = False
        self.bend_offsets = {}
        self.position = position.copy()
        self.rotation = rotation.copy()
        self.heading = rotation.copy()

    @property
    def steering(self) -> bool:
        """True while the front joint is bent (an arc)."""
        return self.curvature != 0.0

    @property
    def bent(self) -> bool:
        """True if any other joint has a bend commanded."""
        return any(v != 0.0 for v in self.bend_offsets.values())

    def anchor(self, p: NDArray[np.float64], r: NDArray[np.float64]) -> None:
        """Let the drive target follow the walls' guidance beyond the dead bands, the front
        module being at ``p`` (m) with rotation ``r``."""
        x = r[:, 0]
        diff = self.position - p
        axial = float(diff @ x)
        lateral = diff - axial * x
        n = math.sqrt(float(lateral.dot(lateral)))
        if n > ANCHOR_POS:
            lateral *= ANCHOR_POS / n
        self.position = p + axial * x + lateral
        # rotation error from actual to commanded; coming out of a turn the commanded heading
        # is the turn's (open loop), else the walls set it
        hold = self.hold_heading and self.curvature == 0.0
        want = self.heading if hold else self.rotation
        rel = r.T @ want
        limit = ANCHOR_ROT if self.curvature != 0.0 or hold else ANCHOR_ROT_STRAIGHT
        if rotation_angle(rel) <= limit:
            self.rotation = want
        else:
            _, axis = log_rotation(rel)
            self.rotation = r @ rotation_about(axis, limit)

    def aim(self, direction: NDArray[np.float64], max_angle: float) -> float:
        """Turn the target's heading towards the unit world ``direction`` by at most
        ``max_angle`` rad, keeping its roll; returns the angle turned, rad."""
        x = self.rotation[:, 0]
        angle = math.acos(max(-1.0, min(1.0, float(x @ direction))))
        axis = np.cross(x, direction)
        if angle < 1e-5 or float(np.linalg.norm(axis)) < 1e-12:
            return 0.0
        turn = min(angle, max_angle)
        self.rotation = rotation_about(axis, turn) @ self.rotation
        return turn
