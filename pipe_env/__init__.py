"""pipenav's simulator side: pipe networks, their MuJoCo worlds, the robot, the rotating LiDAR
and the Gymnasium environments.

Importing this package sets ``MUJOCO_GL=osmesa`` when no GL backend is chosen and no display
is present (headless machines), before MuJoCo is imported.
"""

from __future__ import annotations

import os

if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "osmesa"

from pipe_env.geometry import Pose  # noqa: E402
from pipe_env.network import PipeNetwork  # noqa: E402

__all__ = ["Pose", "PipeNetwork"]
