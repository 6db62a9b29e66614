"""The robot's own log of which way it took where, from odometry.

An operator (or a policy) returning to a junction wants to know which ways were already tried.
The robot knows only its odometry, so the log keys decisions by odometry position: a decision
within ``radius`` metres of a logged one is the same place, and a way whose outgoing axis (in
the world frame, from the odometry heading) is within ``match_angle`` of a logged one is the
same way. Backing out is logged as its own way. Odometry drifts as a random walk: each motion of
``d`` metres adds an independent N(0, (0.01 m/sqrt(m) * sqrt(d))^2) error per world axis, so
the drift's std grows with the square root of the distance driven (about 3 cm per axis after
10 m), well inside the radius for the distances between revisits here.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


class WayLog:
    """Counts of ways taken, keyed by odometry position and world direction (see module doc)."""

    def __init__(self, radius: float = 0.3, match_angle: float = math.radians(25.0)) -> None:
        self.radius = float(radius)
        self.cos_match = math.cos(match_angle)
        self._pos: list[NDArray[np.float64]] = []
        self._vec: list[NDArray[np.float64] | None] = []

    def __len__(self) -> int:
        return len(self._pos)

    def record(self, position: NDArray[np.float64], way: NDArray[np.float64] | None) -> None:
        """Log taking ``way`` (a unit world vector, or None for backing out) at ``position``."""
        self._pos.append(np.asarray(position, dtype=float).copy())
        self._vec.append(None if way is None else np.asarray(way, dtype=float).copy())

    def count(self, position: NDArray[np.float64], way: NDArray[np.float64] | None) -> int:
        """How often ``way`` was taken within ``radius`` of ``position``."""
        return self.counts(position, [way])[0]

    def counts(
        self, position: NDArray[np.float64], ways: list[NDArray[np.float64] | None]
    ) -> list[int]:
        """:meth:`count` for several ways at one position (the log is searched once)."""
        out = [0] * len(ways)
        if not self._pos:
            return out
        px, py, pz = (float(c) for c in position)
        r2 = self.radius * self.radius
        for q, v in zip(self._pos, self._vec):
            dx, dy, dz = float(q[0]) - px, float(q[1]) - py, float(q[2]) - pz
            if dx * dx + dy * dy + dz * dz >= r2:
                continue
            for i, way in enumerate(ways):
                if way is None or v is None:
                    out[i] += int(way is None and v is None)
                elif float(v @ way) >= self.cos_match:
                    out[i] += 1
        return out
