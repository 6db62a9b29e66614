"""Videos show the robot moving: frames collected during full-fidelity steps reach the mp4."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.scripted import make_agent
from pipe_env import layouts

NET = layouts.t_junction(0.1, direction=0.0, distance=0.3).with_goals([[0, 0.5, 0]])


def _episode(env: gym.Env) -> int:
    """Run the route planner to the end; the number of decisions (steps)."""
    actor = make_agent("route_planner", env)
    obs, info = env.reset(seed=0)
    actor.reset()
    steps, done = 0, False
    while not done:
        obs, reward, term, trunc, info = env.step(actor.act(obs, info))
        steps += 1
        done = term or trunc
    return steps


@pytest.mark.slow
def test_record_video_of_a_full_fidelity_episode_shows_motion(tmp_path: Path, needs_gl: str):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    pytest.importorskip("moviepy")
    from pipe_env.envs.wrappers import RecordVideo

    env = gym.make(
        "pipenav/PipeNav-v0",
        network=NET,
        fidelity="full",
        detector="ground_truth",
        render_mode="rgb_array",
        max_episode_steps=4,
    )
    env = RecordVideo(env, str(tmp_path), episode_trigger=lambda e: True, disable_logger=True)
    decisions = _episode(env)
    env.close()
    (video,) = tmp_path.glob("*.mp4")
    reader = imageio_ffmpeg.read_frames(str(video))
    meta = next(reader)
    w, h = meta["size"]
    frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]
    assert len(frames) > decisions + 1  # more than one frame per reset and decision
    changes = [np.abs(a.astype(int) - b).mean() for a, b in zip(frames, frames[1:])]
    assert sum(c > 0.5 for c in changes) >= len(frames) // 3  # the picture moves
    assert frames[0].mean() > 150  # a light background


@pytest.mark.slow
def test_rgb_array_list_returns_the_frames_since_the_last_call(needs_gl: str) -> None:
    env = gym.make(
        "pipenav/PipeNav-v0",
        network=NET,
        fidelity="full",
        detector="ground_truth",
        render_mode="rgb_array_list",
    )
    env.reset(seed=0)
    first = env.render()
    assert isinstance(first, list) and len(first) >= 1 and first[0].shape == (360, 480, 3)
    assert env.render() == []  # taken
    env.step(int(np.flatnonzero(env.unwrapped.action_masks())[0]))
    frames = env.render()
    assert len(frames) > 1
    env.close()


@pytest.mark.slow
def test_collecting_frames_leaves_the_run_unchanged(needs_gl: str) -> None:
    runs = []
    for mode in (None, "rgb_array_list"):
        env = gym.make(
            "pipenav/PipeNav-v0",
            network=NET,
            fidelity="full",
            detector="improved",
            render_mode=mode,
        )
        obs, info = env.reset(seed=0)
        obs, reward, term, trunc, info = env.step(0)
        runs.append((obs["proprio"].tobytes(), obs["goal"].tobytes(), reward, info["travelled"]))
        env.close()
    assert runs[0] == runs[1]
