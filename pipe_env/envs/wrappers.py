"""Gymnasium wrappers for pipenav's environments: a video recorder that keeps the motion.

Gymnasium's ``RecordVideo`` captures one ``render()`` per ``reset``/``step`` and, for a list of
frames, only the last; a pipenav step is a whole decision (the robot drives for seconds), so its
videos would jump from decision to decision. :class:`RecordVideo` here is the same wrapper
(same arguments, same files) that records every frame the environment collected while the robot
moved (see :mod:`pipe_env.envs`, "Rendering"). It needs the ``video`` extra (``moviepy`` with
``imageio-ffmpeg``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from gymnasium.wrappers import RecordVideo as _GymRecordVideo


class RecordVideo(_GymRecordVideo):
    """``gymnasium.wrappers.RecordVideo`` that records every motion frame of a pipenav env.

    Args:
        env: a pipenav environment made with ``render_mode="rgb_array"`` or
            ``"rgb_array_list"`` (any other env is recorded as Gymnasium would).
        *args, **kwargs: as for ``gymnasium.wrappers.RecordVideo`` (``video_folder``,
            ``episode_trigger``, ``name_prefix``, ``fps``...).
    """

    def __init__(self, env: gym.Env, *args: Any, **kwargs: Any) -> None:
        super().__init__(env, *args, **kwargs)
        base = env.unwrapped
        if env.render_mode == "rgb_array" and hasattr(base, "collect_frames"):
            base.collect_frames = True

    def _capture_frame(self) -> None:
        base = self.env.unwrapped
        if self.env.render_mode == "rgb_array" and getattr(base, "collect_frames", False):
            frames = base.take_frames()  # type: ignore[attr-defined]  # DecisionEnv's, checked above
        elif self.env.render_mode == "rgb_array_list":
            frames = self.env.render()
        else:
            super()._capture_frame()
            return
        self.recorded_frames.extend(frames)
