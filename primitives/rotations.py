"""Small rotation-matrix helpers of the executor's parts (angles in radians), and the batched
rotation-to-quaternion conversion of the executor's per-tick targets (:func:`quats_into`)."""

from __future__ import annotations

import math

import numba
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


def rotation_angle(r: NDArray[np.float64]) -> float:
    """Angle of a rotation matrix, rad (that of :func:`log_rotation`, without the axis)."""
    trace = r.item(0) + r.item(4) + r.item(8)
    return math.acos(max(-1.0, min(1.0, 0.5 * (trace - 1.0))))


def log_rotation(r: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """Angle (rad) and unit axis of a rotation matrix."""
    angle = rotation_angle(r)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    n = math.sqrt(float(v.dot(v)))
    if n < 1e-12:
        return angle, np.array([1.0, 0.0, 0.0])
    return angle, v / n


def orthonormal(r: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation nearest to ``r`` (its SVD's U V^T)."""
    u, _, vt = np.linalg.svd(r)
    return np.asarray(u @ vt)


#: MuJoCo's ``mjMINVAL``: quaternions this close to unit length are not normalised again.
_MINVAL = 1e-15


@numba.njit(cache=True, error_model="numpy")
def quats_into(rotations: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """Write the MuJoCo quaternions (w, x, y, z) of ``rotations`` (N, 3, 3) into ``out`` (N, 4).

    The same arithmetic, in the same order, as MuJoCo's ``mju_mat2Quat`` (the largest
    component from the diagonal, the others from the off-diagonal sums, then
    ``mju_normalize4``), so the quaternions are bit-for-bit those of ``mju_mat2Quat``, for all
    the rotations of a tick in one call (tests compare them)."""
    for i in range(rotations.shape[0]):
        m = rotations[i]
        m0, m1, m2 = m[0, 0], m[0, 1], m[0, 2]
        m3, m4, m5 = m[1, 0], m[1, 1], m[1, 2]
        m6, m7, m8 = m[2, 0], m[2, 1], m[2, 2]
        if m0 + m4 + m8 > 0:
            w = 0.5 * math.sqrt(1 + m0 + m4 + m8)
            x = 0.25 * (m7 - m5) / w
            y = 0.25 * (m2 - m6) / w
            z = 0.25 * (m3 - m1) / w
        elif m0 > m4 and m0 > m8:
            x = 0.5 * math.sqrt(1 + m0 - m4 - m8)
            w = 0.25 * (m7 - m5) / x
            y = 0.25 * (m1 + m3) / x
            z = 0.25 * (m2 + m6) / x
        elif m4 > m8:
            y = 0.5 * math.sqrt(1 - m0 + m4 - m8)
            w = 0.25 * (m2 - m6) / y
            x = 0.25 * (m1 + m3) / y
            z = 0.25 * (m5 + m7) / y
        else:
            z = 0.5 * math.sqrt(1 - m0 - m4 + m8)
            w = 0.25 * (m3 - m1) / z
            x = 0.25 * (m2 + m6) / z
            y = 0.25 * (m5 + m7) / z
        norm = math.sqrt((w * w + x * x) + (y * y + z * z))
        if norm < _MINVAL:
            w, x, y, z = 1.0, 0.0, 0.0, 0.0
        elif abs(norm - 1.0) > _MINVAL:
            inv = 1.0 / norm
            w, x, y, z = w * inv, x * inv, y * inv, z * inv
        out[i, 0] = w
        out[i, 1] = x
        out[i, 2] = y
        out[i, 3] = z
