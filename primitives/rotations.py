"""Small rotation-matrix helpers of the executor's parts (angles in radians)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


def rx(a: float) -> NDArray[np.float64]:
    """Rotation by ``a`` rad about x."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def ry(a: float) -> NDArray[np.float64]:
    """Rotation by ``a`` rad about y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rz(a: float) -> NDArray[np.float64]:
    """Rotation by ``a`` rad about z."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def log_rotation(r: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """Angle (rad) and unit axis of a rotation matrix."""
    cosang = float(np.clip(0.5 * (np.trace(r) - 1.0), -1.0, 1.0))
    angle = math.acos(cosang)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        return angle, np.array([1.0, 0.0, 0.0])
    return angle, v / n


def orthonormal(r: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation nearest to ``r`` (its SVD's U V^T)."""
    u, _, vt = np.linalg.svd(r)
    return np.asarray(u @ vt)
