"""A full-fidelity episode rendered to an mp4 in which the robot is seen moving.

The MuJoCo robot, the rotating LiDAR, the detector and the executor run the closed loop on a
small generated network while the RoutePlanner chooses; ``pipe_env.envs.wrappers.RecordVideo``
(Gymnasium's ``RecordVideo`` that keeps the frames the env collects while the robot drives,
every 0.5 simulated s, instead of one per decision) writes them with ``moviepy``
(``pip install "pipenav[video]"``). Rendering needs a GL backend (EGL or OSMesa); on a machine
without one the example says so and exits without a video.

Usage: python examples/record_video.py [--out videos] [--fittings 6] [--seed 1] [--quick]
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import gymnasium as gym

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.scripted import RoutePlanner
from pipe_env.envs.wrappers import RecordVideo

#: What the example prints when it cannot render (tests look for it).
NO_VIDEO = "no video:"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("videos"), help="video folder")
    parser.add_argument("--fittings", type=int, default=6, help="fittings in the network (6)")
    parser.add_argument("--seed", type=int, default=1, help="episode seed (1)")
    parser.add_argument("--quick", action="store_true", help="3 fittings, at most 3 decisions")
    args = parser.parse_args(argv)
    if importlib.util.find_spec("moviepy") is None:
        print(f'{NO_VIDEO} RecordVideo needs moviepy (pip install "pipenav[video]")')
        return 0
    fittings = 3 if args.quick else args.fittings
    env = gym.make(
        "pipenav/PipeNav-v0",
        fidelity="full",
        render_mode="rgb_array",
        network_config={"n_fittings": fittings, "planar": False},
        max_episode_steps=3 if args.quick else 40,
    )
    obs, info = env.reset(seed=args.seed)
    try:
        env.render()  # the first frame: the GL context is made here
    except Exception as exc:  # no GL backend: the simulation works, rendering does not
        print(f"{NO_VIDEO} rendering is unavailable on this machine ({type(exc).__name__}: {exc})")
        env.close()
        return 0
    # record every episode of this wrapper; the file is written when the episode ends
    env = RecordVideo(env, str(args.out), episode_trigger=lambda _: True, name_prefix="pipenav")
    obs, info = env.reset(seed=args.seed)
    agent = RoutePlanner(env)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
        done = terminated or truncated
    env.close()
    videos = sorted(args.out.glob("pipenav-episode-*.mp4"))
    print(
        f"success={info['is_success']} decisions={info['decisions']} "
        f"simulated {info['sim_time']:.1f} s; video: {videos[-1] if videos else 'none written'}"
    )
    return 0 if videos else 1


if __name__ == "__main__":
    raise SystemExit(main())
