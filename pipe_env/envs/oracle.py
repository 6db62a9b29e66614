"""What an agent may know beyond its observation: the oracle accessor of the environments.

An environment's observation is what the robot senses. Some agents are allowed more: the ideal
operator (:class:`agents.scripted.RoutePlanner`) holds the plant drawing and knows where the
robot truly is; a console shows the operator the last scan. They read it through
``env.unwrapped.oracle`` (an :class:`Oracle`), never through the environment's internals, so
what they use is named, typed and documented here.

| member | what | ground truth? |
|---|---|---|
| :attr:`Oracle.network` | the network being driven (the plant drawing) | yes |
| :attr:`Oracle.goal` | the goal point in the world frame, m (PipeNav) | yes |
| :meth:`Oracle.true_pose` | the sensor's true pose in the world frame | yes |
| :attr:`Oracle.decision` | the pending decision (detected options, true node and pose) | partly |
| :attr:`Oracle.clamped_diameter` | the diameter the robot is clamped in, m | no |
| :attr:`Oracle.last_scan` | the last LiDAR sweep (full fidelity), None otherwise | no |
| :attr:`Oracle.detection_log` | one record per detection: sensed and true options | yes |
| :meth:`Oracle.driven_path` | the path driven so far, world positions, m | yes |
| :attr:`Oracle.decision_points` | where the robot was asked to decide, world positions, m | yes |

Get it with :func:`oracle_of` (``oracle_of(env)`` for any wrapped pipenav environment).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from detector.geometry import Pose
from detector.scan import Scan as ScanData
from pipe_env.envs.plant import Decision, Plant
from pipe_env.network import PipeNetwork


class _Source(Protocol):
    """The environment as the oracle reads it."""

    @property
    def plant(self) -> Plant | None: ...

    @property
    def decision(self) -> Decision | None: ...

    @property
    def goal_point(self) -> NDArray[np.float64] | None: ...

    @property
    def path(self) -> NDArray[np.float64]: ...

    @property
    def decision_points(self) -> list[NDArray[np.float64]]: ...


class Oracle:
    """Read-only access to what an agent may know beyond its observation (module docstring).

    Valid after ``reset()``; before it, the members raise ``RuntimeError``.
    """

    def __init__(self, env: _Source) -> None:
        self._env = env

    def _plant(self) -> Plant:
        plant = self._env.plant
        if plant is None:
            raise RuntimeError("the oracle is available after reset()")
        return plant

    @property
    def network(self) -> PipeNetwork:
        """The network being driven: the plant drawing (fittings, runs, goals)."""
        return self._plant().network

    @property
    def goal(self) -> NDArray[np.float64] | None:
        """The goal point in the world frame (m), None without a goal (PipeExplore)."""
        self._plant()
        return self._env.goal_point

    def true_pose(self) -> Pose:
        """The sensor's true pose in the world frame (positions in m)."""
        return self._plant().pose()

    @property
    def decision(self) -> Decision | None:
        """The pending decision (None when the episode has ended)."""
        return self._env.decision

    @property
    def clamped_diameter(self) -> float:
        """The diameter of the pipe the robot is clamped in, m."""
        return self._plant().clamped_diameter

    @property
    def last_scan(self) -> ScanData | None:
        """The last LiDAR sweep (full fidelity), None in fast fidelity or before one."""
        return self._plant().last_scan

    @property
    def detection_log(self) -> list[dict]:
        """One record per detection since the reset (sensed and true options)."""
        return self._plant().detection_log

    def driven_path(self) -> NDArray[np.float64]:
        """The path driven so far as (N, 3) world positions, m."""
        self._plant()
        return self._env.path

    @property
    def decision_points(self) -> list[NDArray[np.float64]]:
        """The true sensor positions where the robot was asked to decide (world frame, m)."""
        return list(self._env.decision_points)


def oracle_of(env: Any) -> Oracle:
    """The oracle of a pipenav environment (``env`` may be wrapped).

    Raises:
        TypeError: ``env`` is not a pipenav environment.
    """
    oracle = getattr(getattr(env, "unwrapped", env), "oracle", None)
    if not isinstance(oracle, Oracle):
        raise TypeError(f"{type(env).__name__} is not a pipenav environment (it has no oracle)")
    return oracle
