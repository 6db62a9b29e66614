"""pipenav's simulator side: pipe networks, their MuJoCo worlds, the robot, the rotating LiDAR
and the Gymnasium environments.

Importing this package never sets or needs an OpenGL backend: rendering picks one when it is
first needed (see :mod:`pipe_env.rendering`).
"""

from __future__ import annotations

import os

try:  # MuJoCo loads the OpenGL backend MUJOCO_GL names as it is imported
    import mujoco  # noqa: F401
except (ImportError, AttributeError, RuntimeError) as _exc:
    if not os.environ.get("MUJOCO_GL"):
        raise
    raise ImportError(
        f"mujoco cannot load the OpenGL backend MUJOCO_GL={os.environ['MUJOCO_GL']!r} names "
        f"({type(_exc).__name__}: {_exc}); unset MUJOCO_GL (pipenav then picks a backend when it "
        "first renders) or install that backend (e.g. libosmesa6 for osmesa)"
    ) from _exc

from gymnasium.envs.registration import register, registry

from detector.geometry import Pose
from pipe_env.network import PipeNetwork

#: Environment ids registered on import, with their default decision limits.
ENV_IDS = {
    "pipenav/PipeNav-v0": ("pipe_env.envs:PipeNavEnv", 64),
    "pipenav/PipeExplore-v0": ("pipe_env.envs:PipeExploreEnv", 128),
}
for _id, (_entry, _steps) in ENV_IDS.items():
    if _id not in registry:
        register(id=_id, entry_point=_entry, max_episode_steps=_steps)

__all__ = ["ENV_IDS", "Pose", "PipeNetwork"]
