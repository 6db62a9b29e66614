"""The scripted RoutePlanner (the ideal operator) next to the goal-greedy agent.

``agents.scripted.RoutePlanner`` knows the plant drawing and its true pose, plans the shortest
drivable route to the goal and picks the detected option nearest the route's next pipe;
``GoalGreedy`` only sees the observation (the goal vector from odometry). Both act through
``act(observation, info) -> int``. ``--fidelity full`` runs the MuJoCo robot, the rotating
LiDAR and the detector instead of the fast kinematic model (about a decision a second).

Usage: python examples/route_planner.py [--episodes 10] [--fidelity fast|full] [--quick]
"""

from __future__ import annotations

import argparse

import gymnasium as gym

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.scripted import GoalGreedy, RoutePlanner


def run(agent_cls: type, fidelity: str, episodes: int, config: dict) -> list[dict]:
    """``episodes`` episodes of ``agent_cls`` (seeds 0, 1, ...); the final info of each."""
    env = gym.make("pipenav/PipeNav-v0", fidelity=fidelity, network_config=config)
    agent = agent_cls(env)
    finals = []
    for seed in range(episodes):
        obs, info = env.reset(seed=seed)
        agent.reset()
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(agent.act(obs, info))
            done = terminated or truncated
        finals.append(info)
    env.close()
    return finals


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=10, help="episodes per agent (10)")
    parser.add_argument("--fidelity", default="fast", choices=["fast", "full"])
    parser.add_argument("--quick", action="store_true", help="2 episodes on small networks")
    args = parser.parse_args(argv)
    episodes = 2 if args.quick else args.episodes
    config = {"n_fittings": 4 if args.quick else 12, "planar": False, "allow_loops": True}
    for agent_cls in (RoutePlanner, GoalGreedy):
        finals = run(agent_cls, args.fidelity, episodes, config)
        success = sum(bool(f["is_success"]) for f in finals) / len(finals)
        decisions = sum(f["decisions"] for f in finals) / len(finals)
        jams = sum(f["jams"] for f in finals) / len(finals)
        print(
            f"{agent_cls.__name__:12s} success {success:.2f}  decisions/episode {decisions:.1f}"
            f"  jams/episode {jams:.2f}  ({args.fidelity} fidelity, {episodes} episodes)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
