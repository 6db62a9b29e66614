"""Per-control-tick telemetry of the executor: what the robot did, for outcomes and plots.

:class:`Telemetry` records one row per control tick (simulated time, sensor position, front
pose, contact force, joint angles, the front's lag behind its drive target) into one growing
float array, and turns it into named arrays for an outcome
(:class:`primitives.executor.SequenceOutcome`). The executor starts a fresh one for every
sequence or drive and when the robot is placed, so it holds one run's rows at most: a 4 m drive of
thousands of ticks is one array (not five small arrays and a tuple per tick, which left the
allocator's heap fragmented over long soaks).
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import NDArray

from pipe_env.robot import Robot

#: Rows the buffer starts with; it doubles when full.
MIN_ROWS = 256


class Telemetry:
    """Rows of per-tick telemetry (see module docstring)."""

    def __init__(self) -> None:
        self._rows: NDArray[np.float64] = np.zeros((0, 0))
        self._n = 0

    def __len__(self) -> int:
        return self._n

    @property
    def capacity(self) -> int:
        """Rows the buffer holds before it grows."""
        return int(self._rows.shape[0])

    def record(self, time: float, data: mujoco.MjData, robot: Robot, lag: float) -> None:
        """Append the row of simulated time ``time`` (s) with the front's ``lag`` (m): written
        in place into the preallocated buffer (no per-row arrays)."""
        b = robot.body_ids[0]
        joints = robot.joint_qpos
        width = 13 + len(joints)
        if self._n >= self._rows.shape[0] or self._rows.shape[1] != width:
            self._grow(width)
        row = self._rows[self._n]
        p = data.xpos[b]
        row[0] = time
        # the sensor: lidar_offset along the front's axis (the first column of its rotation)
        np.multiply(data.xmat[b, 0::3], robot.config.lidar_offset, out=row[1:4])
        row[1:4] += p
        row[4:7] = p
        row[7:11] = data.xquat[b]
        row[11] = robot.contact_force()
        row[12:-1] = data.qpos[joints]
        row[-1] = lag
        self._n += 1

    def _grow(self, width: int) -> None:
        if self._n and self._rows.shape[1] != width:
            raise ValueError(f"telemetry row width = {width}: the robot's joints changed")
        rows = np.zeros((max(MIN_ROWS, 2 * self._n), width))
        if self._n:
            rows[: self._n] = self._rows[: self._n]
        self._rows = rows

    def arrays(self) -> dict[str, NDArray[np.float64]]:
        """The rows as arrays: ``times`` (N,) s, ``sensor_position`` (N, 3) m, ``poses`` (N, 7:
        front position m and quaternion w, x, y, z), ``contact_force`` (N,) N,
        ``joint_angles`` (N, J) rad, ``lag`` (N,) m; empty without rows."""
        if not self._n:
            return {}
        r = self._rows[: self._n]
        return {
            "times": r[:, 0].copy(),
            "sensor_position": r[:, 1:4].copy(),
            "poses": r[:, 4:11].copy(),
            "contact_force": r[:, 11].copy(),
            "joint_angles": r[:, 12:-1].copy(),
            "lag": r[:, -1].copy(),
        }
