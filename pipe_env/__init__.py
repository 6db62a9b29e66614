"""pipenav's simulator side: pipe networks, their MuJoCo worlds, the robot, the rotating LiDAR
and the Gymnasium environments.

Importing this package sets ``MUJOCO_GL=osmesa`` when no GL backend is chosen and no display
is present (headless machines), before MuJoCo is imported.
"""

from __future__ import annotations

import os

if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "osmesa"

from gymnasium.envs.registration import register, registry  # noqa: E402

from pipe_env.geometry import Pose  # noqa: E402
from pipe_env.network import PipeNetwork  # noqa: E402

#: Environment ids registered on import, with their default decision limits.
ENV_IDS = {
    "pipenav/PipeNav-v0": ("pipe_env.envs:PipeNavEnv", 64),
    "pipenav/PipeExplore-v0": ("pipe_env.envs:PipeExploreEnv", 128),
}
for _id, (_entry, _steps) in ENV_IDS.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry, max_episode_steps=_steps)

__all__ = ["ENV_IDS", "Pose", "PipeNetwork"]
