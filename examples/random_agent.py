"""A random agent on ``pipenav/PipeNav-v0``: the Gymnasium loop with the action mask.

Each step is one decision: the environment drives, scans and detects until a structure is
confirmed ahead, then offers its options; ``info["action_mask"]`` marks the rows the robot
would attempt. The agent picks uniformly among them.

Usage: python examples/random_agent.py [--episodes 20] [--seed 0] [--quick]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import pipe_env  # noqa: F401  (registers the environment ids)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=20, help="episodes to run (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    parser.add_argument("--quick", action="store_true", help="2 episodes on small networks")
    args = parser.parse_args(argv)
    episodes = 2 if args.quick else args.episodes
    config = {"n_fittings": 6 if args.quick else 20, "planar": False, "allow_loops": True}

    env = gym.make("pipenav/PipeNav-v0", fidelity="fast", network_config=config)
    rng = np.random.default_rng(args.seed)
    successes = 0
    for episode in range(episodes):
        obs, info = env.reset(seed=args.seed + episode)
        total, done = 0.0, False
        while not done:
            action = int(rng.choice(np.flatnonzero(info["action_mask"])))
            obs, reward, terminated, truncated, info = env.step(action)
            total += float(reward)
            done = terminated or truncated
        successes += bool(info["is_success"])
        print(
            f"episode {episode}: success={info['is_success']} return={total:.2f} "
            f"decisions={info['decisions']} jams={info['jams']}"
        )
    env.close()
    print(f"success rate {successes / episodes:.2f} over {episodes} episodes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
