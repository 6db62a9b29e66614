"""Scan fixtures for the detector tests: canonical layouts scanned by the simulated LiDAR."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from detector.geometry import Pose
from detector.scan import Scan
from pipe_env import layouts
from pipe_env.lidar import RotatingLidar
from pipe_env.world import build_world


def rot_tilt(yaw: float, pitch: float) -> np.ndarray:
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return rz @ ry


@lru_cache(maxsize=32)
def _world(layout: str, params: tuple):
    far = 3.0 if layout == "straight" else 0.5
    net = layouts.make_layout(layout, **dict(params), distance=far)
    return net, build_world(net, contact_walls=False)


def scan_layout(
    layout: str,
    distance: float,
    sensor: str = "ideal",
    seed: int = 0,
    misalignment: Pose | None = None,
    planar: bool = False,
    **params,
) -> tuple[Scan, list, float]:
    """(scan, ground-truth options at the true sensor pose, clamped diameter)."""
    net, world = _world(layout, tuple(sorted(params.items())))
    lid = RotatingLidar(world, sensor, misalignment=misalignment)
    ref_x = net.start_pose.position[0] + (0.0 if layout == "straight" else 0.5)
    pose = Pose(np.array([ref_x - distance, 0.0, 0.0]), np.eye(3))
    rng = np.random.default_rng(seed)
    scan = lid.scan_plane(pose, 0.0, rng) if planar else lid.scan(pose, rng)
    true_pose = pose if misalignment is None else pose.compose(misalignment)
    return scan, net.structures_ahead(true_pose), net.runs[0].diameter


def continuous_scan(layout: str, pose_at, sensor: str = "ideal", seed: int = 0, **params):
    """(scan, network) of a continuous sweep while the body moves: ``pose_at(s)`` gives the
    body's pose relative to the layout's start at the fraction ``s`` in [0, 1) of the sweep."""
    net, world = _world(layout, tuple(sorted(params.items())))
    lid = RotatingLidar(world, sensor, mode="continuous")
    start = net.start_pose.position

    def body(t: float) -> Pose:
        p = pose_at(t / lid.sweep_duration)
        return Pose(start + p.position, p.rotation)

    return lid.scan(body, np.random.default_rng(seed)), net


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def match(est, truth):
    """Pairs (estimate, truth) matched greedily by angle and direction."""
    pairs, left = [], list(est)
    for t in sorted(truth, key=lambda o: o.angle):
        if not left:
            break
        best = min(
            left,
            key=lambda o: (
                abs(o.angle - t.angle) + abs(wrap(o.direction - t.direction)) * math.sin(t.angle)
            ),
        )
        left.remove(best)
        pairs.append((best, t))
    return pairs
