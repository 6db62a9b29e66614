"""Direct least-squares ellipse fitting (Halir and Flusser 1998; thesis section 2.2.3).

The conic ``a x^2 + b xy + c y^2 + d x + e y + f = 0`` is fitted by minimising the algebraic
distance subject to ``4ac - b^2 = 1`` (Fitzgibbon's ellipse-specific constraint), solved through
Halir and Flusser's decomposition (thesis eqs. 2.9-2.16), which avoids the singular scatter
matrix of the original method. The points are centred and scaled before the fit and the conic is
mapped back, which keeps the matrices well conditioned for any unit.

:func:`fit_ellipse` returns an :class:`Ellipse` (centre, semi-axes, orientation, conic, RMS
geometric residual) or an :class:`EllipseFitFailure` naming why no ellipse exists (too few
points, collinear points, no ellipse-specific solution, non-finite numbers). Both have ``ok``,
so callers can branch without isinstance checks; a failure never carries numbers that could be
mistaken for an ellipse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Fewest points that determine an ellipse.
MIN_POINTS = 5


@dataclass(frozen=True)
class Ellipse:
    """A fitted ellipse. Lengths in the input unit, angles in radians.

    Attributes:
        centre: (2,) centre.
        semi_major, semi_minor: semi-axis lengths, ``semi_major >= semi_minor > 0``.
        orientation: angle of the major axis from the +x axis, in (-pi/2, pi/2].
        conic: (6,) normalised coefficients ``(a, b, c, d, e, f)`` with unit norm.
        rms_residual: RMS of the approximate geometric (Sampson) distance of the points.
        n_points: points used.
    """

    centre: NDArray[np.float64]
    semi_major: float
    semi_minor: float
    orientation: float
    conic: NDArray[np.float64]
    rms_residual: float
    n_points: int

    ok = True

    @property
    def axis_ratio(self) -> float:
        """semi_minor / semi_major in (0, 1]."""
        return self.semi_minor / self.semi_major

    def points(self, n: int = 100) -> NDArray[np.float64]:
        """(n, 2) points on the ellipse, for plots and tests."""
        t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
        c, s = math.cos(self.orientation), math.sin(self.orientation)
        x = self.semi_major * np.cos(t)
        y = self.semi_minor * np.sin(t)
        return np.stack([self.centre[0] + c * x - s * y, self.centre[1] + s * x + c * y], axis=1)


@dataclass(frozen=True)
class EllipseFitFailure:
    """No ellipse could be fitted; ``reason`` says why."""

    reason: str
    n_points: int

    ok = False


def fit_ellipse(x: ArrayLike, y: ArrayLike) -> Ellipse | EllipseFitFailure:
    """Fit an ellipse to 2D points with the Halir-Flusser direct method.

    Args:
        x, y: (N,) coordinates; non-finite entries are dropped.

    Returns:
        An :class:`Ellipse`, or an :class:`EllipseFitFailure` for degenerate input.
    """
    xa = np.asarray(x, dtype=float).reshape(-1)
    ya = np.asarray(y, dtype=float).reshape(-1)
    if xa.shape != ya.shape:
        return EllipseFitFailure(f"x and y differ in length ({xa.size} vs {ya.size})", 0)
    keep = np.isfinite(xa) & np.isfinite(ya)
    xa, ya = xa[keep], ya[keep]
    n = int(xa.size)
    if n < MIN_POINTS:
        return EllipseFitFailure(f"needs at least {MIN_POINTS} finite points, got {n}", n)
    # normalise: centre on the mean, unit RMS distance
    mx, my = float(xa.mean()), float(ya.mean())
    scale = float(np.sqrt(np.mean((xa - mx) ** 2 + (ya - my) ** 2)))
    if not math.isfinite(scale) or scale <= 1e-12 * max(1.0, abs(mx), abs(my)):
        return EllipseFitFailure("points coincide", n)
    u = (xa - mx) / scale
    v = (ya - my) / scale
    d1 = np.stack([u * u, u * v, v * v], axis=1)
    d2 = np.stack([u, v, np.ones_like(u)], axis=1)
    s1 = d1.T @ d1
    s2 = d1.T @ d2
    s3 = d2.T @ d2
    # S3 is singular when the points are collinear (thesis eq. 2.16 needs its inverse)
    if np.linalg.cond(s3) > 1e10:
        return EllipseFitFailure("points are collinear", n)
    t = -np.linalg.solve(s3, s2.T)  # a2 = T a1
    m = s1 + s2 @ t  # reduced scatter matrix
    m = np.stack([m[2] / 2.0, -m[1], m[0] / 2.0])  # C1^-1 M
    if not np.all(np.isfinite(m)):
        return EllipseFitFailure("non-finite reduced scatter matrix", n)
    try:
        evals, evecs = np.linalg.eig(m)
    except np.linalg.LinAlgError:
        return EllipseFitFailure("eigen-decomposition failed", n)
    evecs = np.real_if_close(evecs, tol=1e6)
    if np.iscomplexobj(evecs):
        evecs = evecs.real
    cond = 4.0 * evecs[0] * evecs[2] - evecs[1] ** 2
    candidates = np.flatnonzero(cond > 0)
    if candidates.size == 0:
        return EllipseFitFailure("no ellipse-specific solution (points fit a hyperbola/line)", n)
    a1 = evecs[:, candidates[np.argmin(np.abs(np.real(evals[candidates])))]]
    a2 = t @ a1
    a, b, c = a1
    d, e, f = a2
    # undo the normalisation: u = (x - mx)/s, v = (y - my)/s
    s = scale
    A = a / s**2
    B = b / s**2
    C = c / s**2
    D = d / s - 2 * A * mx - B * my
    E = e / s - 2 * C * my - B * mx
    F = f + A * mx**2 + B * mx * my + C * my**2 - d * mx / s - e * my / s
    conic = np.array([A, B, C, D, E, F])
    return _from_conic(conic, xa, ya)


def _from_conic(conic: NDArray[np.float64], x: NDArray, y: NDArray) -> Ellipse | EllipseFitFailure:
    """Centre, semi-axes and orientation of an ellipse conic; failure if it is not one."""
    n = int(x.size)
    norm = float(np.linalg.norm(conic))
    if not math.isfinite(norm) or norm == 0.0:
        return EllipseFitFailure("degenerate conic", n)
    A, B, C, D, E, F = conic / norm
    disc = B * B - 4.0 * A * C
    if not disc < 0.0:
        return EllipseFitFailure("conic is not an ellipse", n)
    x0 = (2.0 * C * D - B * E) / disc
    y0 = (2.0 * A * E - B * D) / disc
    f0 = A * x0 * x0 + B * x0 * y0 + C * y0 * y0 + D * x0 + E * y0 + F
    q = np.array([[A, B / 2.0], [B / 2.0, C]])
    lam, vec = np.linalg.eigh(q)
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = -f0 / lam
    if not np.all(np.isfinite(sq)) or np.any(sq <= 0.0):
        return EllipseFitFailure("conic is an imaginary or degenerate ellipse", n)
    axes = np.sqrt(sq)
    i_major = int(np.argmax(axes))
    major = vec[:, i_major]
    theta = math.atan2(float(major[1]), float(major[0]))
    if theta <= -math.pi / 2:
        theta += math.pi
    elif theta > math.pi / 2:
        theta -= math.pi
    # Sampson distance |F| / |grad F|
    val = A * x * x + B * x * y + C * y * y + D * x + E * y + F
    gx = 2 * A * x + B * y + D
    gy = B * x + 2 * C * y + E
    grad = np.sqrt(np.square(gx) + np.square(gy))
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.where(grad > 0, np.abs(val) / grad, 0.0)
    rms = float(np.sqrt(np.mean(dist**2)))
    centre = np.array([x0, y0], dtype=float)
    out = (float(axes[i_major]), float(axes[1 - i_major]), theta, rms)
    if not (np.all(np.isfinite(centre)) and all(math.isfinite(v) for v in out)):
        return EllipseFitFailure("non-finite ellipse parameters", n)
    sign = 1.0 if A >= 0 else -1.0
    return Ellipse(centre, out[0], out[1], out[2], sign * np.array([A, B, C, D, E, F]), out[3], n)
