"""MaskablePPO (sb3-contrib): a short training run, then the shipped policy.

1. Trains a MaskablePPO policy for a few thousand decisions on a small pool of generated
   networks (fast fidelity), saves it and loads it back. MaskablePPO reads the environment's
   ``action_masks()`` through Gymnasium's wrappers; at prediction time pass
   ``info["action_mask"]``. A real run uses ``pipenav train`` (config file, TensorBoard,
   checkpoints, held-out evaluation).
2. Loads the policy shipped with the package (``agents/maskable_ppo_policy.zip``, trained by
   ``pipenav train`` on the packaged config) and runs it on held-out networks of the training
   distribution.

Usage: python examples/maskable_ppo.py [--timesteps 20000] [--episodes 20] [--out runs/example]
       [--quick]
"""

from __future__ import annotations

import argparse
from importlib.resources import files
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.evaluate import EVAL_POOL_SEED
from agents.train import DEFAULT_CONFIG, TrainConfig

SHIPPED_POLICY = files("agents") / "maskable_ppo_policy.zip"


def run_policy(model: Any, env: gym.Env, episodes: int, first_seed: int) -> float:
    """Success rate of ``model`` (deterministic, masked) over ``episodes`` episodes."""
    successes = 0
    for i in range(episodes):
        obs, info = env.reset(seed=first_seed + i)
        done = False
        while not done:
            mask = np.asarray(info["action_mask"], dtype=bool)
            action, _ = model.predict(obs, action_masks=mask, deterministic=True)
            obs, _, terminated, truncated, info = env.step(int(action))
            done = terminated or truncated
        successes += bool(info["is_success"])
    return successes / episodes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--timesteps", type=int, default=20_000, help="decisions to train")
    parser.add_argument("--episodes", type=int, default=20, help="evaluation episodes")
    parser.add_argument("--out", default="runs/example", help="where the model is saved")
    parser.add_argument("--quick", action="store_true", help="256 decisions, 3 episodes")
    args = parser.parse_args(argv)
    timesteps = 256 if args.quick else args.timesteps
    episodes = 3 if args.quick else args.episodes

    import torch
    from sb3_contrib import MaskablePPO

    torch.set_num_threads(1)  # a small MLP: one thread is fastest
    # the packaged training distribution (20-fitting 3D networks with loops)
    env_kwargs = dict(TrainConfig.from_yaml(DEFAULT_CONFIG).env_kwargs)

    # 1. a short training run on a pool of 50 networks
    train_env = gym.make("pipenav/PipeNav-v0", **{**env_kwargs, "network_pool": 50})
    model = MaskablePPO(
        "MultiInputPolicy", train_env, n_steps=128, batch_size=64, seed=0, verbose=0
    )
    model.learn(total_timesteps=timesteps)
    path = Path(args.out) / "maskable_ppo.zip"
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    train_env.close()
    trained = MaskablePPO.load(path, device="cpu")
    print(f"trained {trained.num_timesteps} decisions, saved to {path}")

    # both policies on the same held-out networks (another pool seed than training's)
    eval_env = gym.make(
        "pipenav/PipeNav-v0", **{**env_kwargs, "network_pool": 1000, "pool_seed": EVAL_POOL_SEED}
    )
    print(f"trained policy: success {run_policy(trained, eval_env, episodes, 0):.2f}")

    # 2. the shipped policy
    shipped = MaskablePPO.load(str(SHIPPED_POLICY), device="cpu")
    print(f"shipped policy: success {run_policy(shipped, eval_env, episodes, 0):.2f}")
    eval_env.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
