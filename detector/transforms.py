"""Point transforms: polar to Cartesian, the thesis's sensor-offset radius, and sensor-pose
compensation into the local pipe-axis frame.

Frames (REP-103, as in :mod:`detector.scan`):

- *sensor frame*: x forward, y left, z up; a beam at in-plane angle ``beta`` on a plane rotated
  by ``alpha`` about x points along ``(cos beta, sin beta cos alpha, sin beta sin alpha)``.
- *pipe frame*: x along the local pipe axis (forward), origin on the axis at the axial position
  of the sensor origin; y and z span the cross-section. When the sensor is perfectly centred
  and aligned (thesis assumptions i and iii) the two frames coincide.

:class:`SensorInPipe` holds the sensor pose in the pipe frame (``position`` of the sensor
origin, ``rotation`` pipe-from-sensor); ``to_pipe`` maps sensor points into the pipe frame, and
:func:`option_direction` expresses an outgoing axis found in the pipe frame as the option's
angle and its direction (atan2(z, y) in the sensor frame, as docs/design.md defines them). Units:
metres and radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from detector.validation import fail

_WHERE = "SensorInPipe"


def polar_to_cartesian(
    ranges: ArrayLike, beam_angles: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """In-plane Cartesian coordinates of planar returns (thesis Algorithm 1 step A).

    Args:
        ranges: (..., B) ranges, metres (``inf`` for no return gives ``inf``/``nan``; filter
            with the scan's ``valid`` mask first).
        beam_angles: (B,) in-plane beam angles, radians, 0 = forward, positive = left/up.

    Returns:
        ``(forward, lateral)``: forward distance along the sensor x axis and the signed lateral
        distance in the plane (positive on the ``beta > 0`` side), metres.
    """
    r = np.asarray(ranges, dtype=float)
    b = np.asarray(beam_angles, dtype=float)
    return r * np.cos(b), r * np.sin(b)


def sensor_offset_radius(
    lateral: ArrayLike,
    plane_angle: ArrayLike,
    offset_y: float = 0.0,
    offset_z: float = 0.0,
) -> NDArray[np.float64]:
    """Radius of wall points about the pipe axis for an off-centre sensor (thesis eq. 2.2).

    The thesis writes ``x_s = d cos(alpha)``, ``z_s = d sin(alpha)``,
    ``r = sqrt(z_s^2 + (x_P + x_s)^2)`` for a sensor displaced by ``x_P`` along one axis of
    the cross-section; this is the same with the displacement in both cross-section axes.

    Args:
        lateral: signed in-plane lateral distance ``d`` of each point, metres.
        plane_angle: servo angle ``alpha`` of each point's plane, radians.
        offset_y, offset_z: sensor origin relative to the pipe axis in the cross-section, m.

    Returns:
        The radius of each point about the pipe axis, metres.
    """
    d = np.asarray(lateral, dtype=float)
    a = np.asarray(plane_angle, dtype=float)
    ys = d * np.cos(a)
    zs = d * np.sin(a)
    return np.sqrt((offset_z + zs) ** 2 + (offset_y + ys) ** 2)


_EYE3 = np.eye(3)


def _det3(m: NDArray[np.float64]) -> float:
    """Determinant of a 3x3 matrix (cheaper than the LAPACK call for one small matrix)."""
    return float(
        m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
        - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
        + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
    )


@dataclass(frozen=True)
class SensorInPipe:
    """Pose of the sensor in the local pipe-axis frame.

    Attributes:
        position: (3,) sensor origin in the pipe frame, metres. Only the cross-section part
            (y, z) matters for detection; x shifts every reported distance.
        rotation: (3, 3) pipe-from-sensor rotation (columns: the sensor axes in the pipe frame).
    """

    position: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    rotation: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        p = np.asarray(self.position, dtype=float).reshape(-1)
        r = np.asarray(self.rotation, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise fail(
                "position", p.tolist(), "three finite numbers (m)", "not 3 finite numbers", _WHERE
            )
        if r.shape != (3, 3) or not np.all(np.isfinite(r)):
            raise fail(
                "rotation", r.tolist(), "a finite 3x3 matrix", "not a finite 3x3 matrix", _WHERE
            )
        ortho = float(np.abs(r.T @ r - _EYE3).max())
        det = _det3(r)
        if ortho > 1e-6 or det < 0:
            raise fail(
                "rotation",
                r.tolist(),
                "a proper rotation matrix (R^T R = I within 1e-6, det R = +1)",
                f"not a rotation (max |R^T R - I| = {ortho:.3g}, det R = {det:.6g})",
                _WHERE,
            )
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "rotation", r)

    @classmethod
    def trusted(cls, position: NDArray[np.float64], rotation: NDArray[np.float64]) -> SensorInPipe:
        """A pose from a (3,) position and a (3, 3) rotation known to be valid (built by the
        detector itself from a rotation formula), without the checks of the constructor."""
        pose = object.__new__(cls)
        object.__setattr__(pose, "position", position)
        object.__setattr__(pose, "rotation", rotation)
        return pose

    @classmethod
    def identity(cls) -> SensorInPipe:
        """The thesis's assumption: sensor centred and aligned with the pipe axis."""
        return cls.trusted(np.zeros(3), np.eye(3))

    @classmethod
    def coerce(cls, value: Any) -> SensorInPipe:
        """Accept a :class:`SensorInPipe`, a ``(position, rotation)`` pair or ``None``."""
        if value is None:
            return cls.identity()
        if isinstance(value, SensorInPipe):
            return value
        if hasattr(value, "position") and hasattr(value, "rotation"):
            return cls(np.asarray(value.position), np.asarray(value.rotation))
        try:
            position, rotation = value
        except (TypeError, ValueError) as exc:
            raise fail(
                "sensor_in_pipe",
                value,
                "a SensorInPipe, an object with .position/.rotation or a "
                "(position (3,), rotation (3, 3)) pair",
                f"a {type(value).__name__}",
            ) from exc
        return cls(np.asarray(position), np.asarray(rotation))

    @classmethod
    def from_offset_tilt(
        cls, offset_y: float = 0.0, offset_z: float = 0.0, yaw: float = 0.0, pitch: float = 0.0
    ) -> SensorInPipe:
        """A sensor displaced in the cross-section and tilted by ``yaw`` (about z) then
        ``pitch`` (about y), radians."""
        cy, sy = math.cos(yaw), math.sin(yaw)
        cp, sp = math.cos(pitch), math.sin(pitch)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        return cls(np.array([0.0, offset_y, offset_z]), rz @ ry)

    @property
    def is_identity(self) -> bool:
        return bool(np.allclose(self.position, 0.0) and np.allclose(self.rotation, np.eye(3)))

    def to_pipe(self, points: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) sensor-frame points into the pipe frame."""
        p = np.asarray(points, dtype=float)
        return p @ self.rotation.T + self.position

    def to_sensor(self, points: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) pipe-frame points into the sensor frame."""
        p = np.asarray(points, dtype=float)
        return (p - self.position) @ self.rotation

    def compose(self, inner: SensorInPipe) -> SensorInPipe:
        """``self`` maps frame A to the pipe frame; ``inner`` maps the sensor to frame A."""
        return SensorInPipe.trusted(
            self.rotation @ inner.position + self.position, self.rotation @ inner.rotation
        )


def option_direction(axis_pipe: ArrayLike, pose: SensorInPipe) -> tuple[float, float]:
    """(angle, direction) of an outgoing axis given in the pipe frame.

    ``angle`` is the deflection from the pipe axis (+x); ``direction`` is atan2(z, y) of the
    axis's component perpendicular to the pipe axis, expressed in the sensor's y and z axes
    (0 for a way straight on), radians. Matches the ground-truth definition.
    """
    v = np.asarray(axis_pipe, dtype=float)
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n < 1e-12:
        return 0.0, 0.0
    v = v / n
    angle = math.acos(max(-1.0, min(1.0, float(v[0]))))
    perp = np.array([0.0, v[1], v[2]])
    if np.linalg.norm(perp) < 1e-9:
        return angle, 0.0
    y_axis = pose.rotation[:, 1]
    z_axis = pose.rotation[:, 2]
    return angle, math.atan2(float(perp @ z_axis), float(perp @ y_axis))
