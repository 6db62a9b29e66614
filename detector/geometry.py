"""Rigid poses and small 3D geometry helpers shared by the whole package.

Units are SI: metres and radians. A :class:`Pose` is world-from-body: ``rotation`` maps body
vectors to world vectors and its columns are the body axes in the world frame, following
REP-103 (x forward along the pipe, y left, z up when the robot's roll is zero).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

WORLD_UP = np.array([0.0, 0.0, 1.0])
#: Fallback "up" hint for frames whose forward axis is (nearly) vertical.
FALLBACK_UP = np.array([1.0, 0.0, 0.0])
_VERTICAL_COS = 0.999


def wrap_angle(a: Any) -> Any:
    """``a`` (radians; a real number or an array of them) wrapped to (-pi, pi].

    A real number gives a float (computed with :func:`math.fmod`, fast for the detector's
    loops); an array gives an array and a 0-d array a float. Both paths give the same values.
    """
    if isinstance(a, numbers.Real):
        w = math.fmod(float(a) + math.pi, 2.0 * math.pi)
        if w <= 0.0:
            w += 2.0 * math.pi
        w -= math.pi
        return math.pi if w == -math.pi else w
    arr = np.mod(np.asarray(a, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    arr = np.where(arr == -np.pi, np.pi, arr)
    return float(arr) if np.ndim(arr) == 0 else arr


def norm3(v: NDArray[np.float64]) -> float:
    """Euclidean length of a small 1-D vector (much cheaper than ``np.linalg.norm`` per call)."""
    return math.sqrt(float(np.dot(v, v)))


def unit(v: ArrayLike, name: str = "vector") -> NDArray[np.float64]:
    """Return ``v`` normalised; raise ``ValueError`` naming ``name`` if it is zero or not finite."""
    a = np.asarray(v, dtype=float).reshape(3)
    n = math.sqrt(float(a @ a))
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"{name} must be a finite non-zero 3-vector, got {a.tolist()}")
    return a / n


def frame_from_forward(forward: ArrayLike, up_hint: ArrayLike | None = None) -> NDArray[np.float64]:
    """Rotation whose x axis is ``forward`` and whose z axis is as close as possible to ``up_hint``.

    ``up_hint`` defaults to world +z; when ``forward`` is (nearly) vertical the hint falls back to
    world +x so that the frame stays well defined. This is the "roll zero" convention.
    """
    if up_hint is None and type(forward) is np.ndarray and forward.shape == (3,):
        # fast path for the common case (numpy input, default hint): plain float arithmetic
        fx, fy, fz = float(forward[0]), float(forward[1]), float(forward[2])
        n = math.sqrt(fx * fx + fy * fy + fz * fz)
        if not (n > 1e-12 and math.isfinite(n)):
            raise ValueError(f"forward must be a finite non-zero 3-vector, got {forward.tolist()}")
        fx, fy, fz = fx / n, fy / n, fz / n
        if abs(fz) <= _VERTICAL_COS:  # hint +z: z = ez - fz * f
            zx, zy, zz = -fz * fx, -fz * fy, 1.0 - fz * fz
        else:  # hint +x (forward is nearly vertical, so nearly perpendicular to +x)
            zx, zy, zz = 1.0 - fx * fx, -fx * fy, -fx * fz
        m = math.sqrt(zx * zx + zy * zy + zz * zz)
        zx, zy, zz = zx / m, zy / m, zz / m
        return np.array(
            [
                [fx, zy * fz - zz * fy, zx],
                [fy, zz * fx - zx * fz, zy],
                [fz, zx * fy - zy * fx, zz],
            ]
        )
    x = unit(forward, "forward")
    hint = WORLD_UP if up_hint is None else unit(up_hint, "up_hint")
    if abs(float(x @ hint)) > _VERTICAL_COS:
        hint = (
            FALLBACK_UP
            if up_hint is None or abs(float(x @ FALLBACK_UP)) < _VERTICAL_COS
            else (np.array([0.0, 1.0, 0.0]))
        )
    z = hint - (hint @ x) * x
    z /= math.sqrt(float(z @ z))
    y = cross(z, x)
    out = np.empty((3, 3))
    out[:, 0], out[:, 1], out[:, 2] = x, y, z
    return out


def clamp(value: float, lo: float, hi: float) -> float:
    """``value`` limited to [lo, hi] as a Python float (``np.clip`` is slow on scalars)."""
    v = float(value)
    return lo if v < lo else hi if v > hi else v


def cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cross product of two 3-vectors (much faster than ``np.cross`` for single vectors)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def rotation_about(axis: ArrayLike, angle: float) -> NDArray[np.float64]:
    """Rotation matrix of ``angle`` radians about ``axis`` (right-handed, Rodrigues)."""
    k = unit(axis, "axis")
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * (kx @ kx)


def direction_from_angles(angle: float, direction: float) -> NDArray[np.float64]:
    """Body-frame unit vector deflected by ``angle`` from +x, rolled by ``direction`` about +x.

    ``direction`` follows docs/design.md: atan2(z, y), so 0 = left (+y), pi/2 = up (+z), pi = right.
    """
    sa = math.sin(angle)
    return np.array([math.cos(angle), sa * math.cos(direction), sa * math.sin(direction)])


def angles_from_direction(vec_body: ArrayLike) -> tuple[float, float]:
    """Inverse of :func:`direction_from_angles`: (deflection angle, roll direction) in radians.

    The direction of a vector along +x is undefined and reported as 0.
    """
    v = unit(vec_body, "vector")
    angle = float(np.arccos(np.clip(v[0], -1.0, 1.0)))
    lateral = float(np.hypot(v[1], v[2]))
    direction = float(np.arctan2(v[2], v[1])) if lateral > 1e-9 else 0.0
    return angle, direction


def segment_distance(
    p0: NDArray[np.float64],
    p1: NDArray[np.float64],
    q0: NDArray[np.float64],
    q1: NDArray[np.float64],
) -> float:
    """Shortest distance between segments p0-p1 and q0-q1 (metres)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    if a < 1e-18 and e < 1e-18:
        return norm3(r)
    if a < 1e-18:
        s, t = 0.0, clamp(f / e, 0.0, 1.0)
    else:
        c = float(d1 @ r)
        if e < 1e-18:
            t, s = 0.0, clamp(-c / a, 0.0, 1.0)
        else:
            b = float(d1 @ d2)
            denom = a * e - b * b
            s = clamp((b * f - c * e) / denom, 0.0, 1.0) if denom > 1e-18 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t, s = 0.0, clamp(-c / a, 0.0, 1.0)
            elif t > 1.0:
                t, s = 1.0, clamp((b - c) / a, 0.0, 1.0)
    return norm3((p0 + d1 * s) - (q0 + d2 * t))


@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid pose, world-from-body.

    Attributes:
        position: (3,) body origin in the world frame, metres.
        rotation: (3, 3) rotation matrix; columns are the body x (forward), y (left), z (up)
            axes expressed in the world frame.
    """

    position: NDArray[np.float64]
    rotation: NDArray[np.float64]

    def __post_init__(self) -> None:
        p = np.asarray(self.position, dtype=float)
        r = np.asarray(self.rotation, dtype=float)
        if p.shape != (3,):
            raise ValueError(f"Pose.position must have shape (3,), got {p.shape}")
        if r.shape != (3, 3):
            raise ValueError(f"Pose.rotation must have shape (3, 3), got {r.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"Pose.position must be finite, got {p.tolist()}")
        if not np.all(np.isfinite(r)):
            raise ValueError(f"Pose.rotation must be finite, got {r.tolist()}")
        if np.abs(r.T @ r - np.eye(3)).max() > 1e-6 or np.linalg.det(r) < 0:
            raise ValueError("Pose.rotation must be a proper rotation matrix (orthonormal, det +1)")
        p.setflags(write=False)
        r.setflags(write=False)
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "rotation", r)

    @classmethod
    def trusted(cls, position: NDArray[np.float64], rotation: NDArray[np.float64]) -> Pose:
        """A pose from values already known to be valid (skips the checks; hot paths only)."""
        pose = object.__new__(cls)
        object.__setattr__(pose, "position", position)
        object.__setattr__(pose, "rotation", rotation)
        return pose

    @classmethod
    def identity(cls) -> Pose:
        return cls(np.zeros(3), np.eye(3))

    @classmethod
    def from_forward(
        cls, position: ArrayLike, forward: ArrayLike, up_hint: ArrayLike | None = None
    ) -> Pose:
        """Pose at ``position`` looking along ``forward`` with roll zero (z towards ``up_hint``)."""
        p = np.asarray(position, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"Pose.position must be three finite numbers, got {position!r}")
        return cls.trusted(p, frame_from_forward(forward, up_hint))

    @property
    def forward(self) -> NDArray[np.float64]:
        return self.rotation[:, 0]

    @property
    def left(self) -> NDArray[np.float64]:
        return self.rotation[:, 1]

    @property
    def up(self) -> NDArray[np.float64]:
        return self.rotation[:, 2]

    def transform_points(self, points_body: ArrayLike) -> NDArray[np.float64]:
        """Map (..., 3) body-frame points to the world frame."""
        return np.asarray(points_body, dtype=float) @ self.rotation.T + self.position

    def inverse_transform_points(self, points_world: ArrayLike) -> NDArray[np.float64]:
        """Map (..., 3) world-frame points to the body frame."""
        return (np.asarray(points_world, dtype=float) - self.position) @ self.rotation

    def compose(self, other: Pose) -> Pose:
        """``self * other``: ``other`` is expressed in this pose's body frame."""
        return Pose(self.position + self.rotation @ other.position, self.rotation @ other.rotation)

    def inverse(self) -> Pose:
        return Pose(-self.rotation.T @ self.position, self.rotation.T)

    def rolled(self, angle: float) -> Pose:
        """This pose rotated by ``angle`` radians about its own forward (x) axis."""
        return Pose(self.position, self.rotation @ rotation_about([1.0, 0.0, 0.0], angle))

    def translated(self, distance: float) -> Pose:
        """This pose moved ``distance`` metres along its own forward axis."""
        return Pose(self.position + distance * self.forward, self.rotation)

    def to_dict(self) -> dict[str, list]:
        return {"position": self.position.tolist(), "rotation": self.rotation.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Pose:
        if "rotation" in d:
            return cls(np.asarray(d["position"], float), np.asarray(d["rotation"], float))
        return cls.from_forward(d["position"], d["forward"], d.get("up"))

    def allclose(self, other: Pose, atol: float = 1e-9) -> bool:
        return bool(
            np.allclose(self.position, other.position, atol=atol)
            and np.allclose(self.rotation, other.rotation, atol=atol)
        )

    def __repr__(self) -> str:
        p = np.array2string(self.position, precision=4, suppress_small=True)
        f = np.array2string(self.forward, precision=3, suppress_small=True)
        return f"Pose(position={p}, forward={f})"
