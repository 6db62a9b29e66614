"""Analytic inner-wall surfaces of a network, for checking meshes and contact walls in tests."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from pipe_env.network import PipeNetwork


def wall_distance(network: PipeNetwork, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance (m) of each point to the nearest analytic inner-wall surface of ``network``:
    the infinite cylinders of all runs (which also carry fitting legs), the tori of long bends,
    the cones of reducers and the end planes of closures."""
    pts = np.atleast_2d(points)
    best = np.full(len(pts), np.inf)
    for r in network.runs:
        a, b = network.position(r.a), network.position(r.b)
        u = (b - a) / np.linalg.norm(b - a)
        rel = pts - a
        radial = np.linalg.norm(rel - (rel @ u)[:, None] * u, axis=1)
        best = np.minimum(best, np.abs(radial - 0.5 * r.diameter))
    for g in network.geometry.values():
        if g.kind == "bend" and g.style == "long":
            c, n, big_r, _ = g.bend_arc()
            rel = pts - c
            h = rel @ n
            rho = np.linalg.norm(rel - h[:, None] * n, axis=1)
            best = np.minimum(best, np.abs(np.hypot(rho - big_r, h) - g.ports[0].radius))
        elif g.kind == "reducer":
            a, b = g.ports
            u, length = b.axis, a.leg + b.leg
            rel = pts - a.position
            t = rel @ u
            radius = a.radius + (b.radius - a.radius) * np.clip(t / length, 0, 1)
            radial = np.linalg.norm(rel - t[:, None] * u, axis=1)
            slope = math.cos(math.atan2(abs(b.radius - a.radius), length))
            best = np.minimum(best, np.abs(radial - radius) * slope)
        elif g.kind == "closure":
            best = np.minimum(best, np.abs((pts - g.centre) @ g.ports[0].axis))
    return best
