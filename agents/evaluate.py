"""Evaluate an agent (scripted or a trained MaskablePPO policy) on held-out networks.

Metrics per agent: success rate, jams per episode, decisions per episode, and path length over
the shortest drivable route (median, successful episodes). Networks come from a pool seed that
training never uses, so the same ``n_episodes`` and ``pool_seed`` give the same networks.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.scripted import SCRIPTED_AGENTS, make_agent
from pipe_env.envs import pool_network
from pipe_env.generator import NetworkConfig

#: Held-out networks for evaluation: a pool seed that training configs do not use.
EVAL_POOL_SEED = 1_000_003


@dataclass
class EvalResult:
    agent: str
    episodes: int
    success_rate: float
    jams_per_episode: float
    decisions_per_episode: float
    path_over_shortest: float
    sim_seconds_per_episode: float
    wall_seconds: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class PolicyAgent:
    """A trained MaskablePPO policy acting through ``act(observation, info)``."""

    def __init__(self, path: str | Path, env: gym.Env | None = None) -> None:
        import torch
        from sb3_contrib import MaskablePPO

        torch.set_num_threads(1)  # small MLP: one thread is fastest
        self.model = MaskablePPO.load(str(path), device="cpu")
        self.env = env

    def reset(self) -> None:
        pass

    def act(self, observation: dict, info: dict[str, Any]) -> int:
        action, _ = self.model.predict(
            observation, action_masks=info["action_mask"], deterministic=True
        )
        return int(action)


def evaluate(
    agent: str,
    n_episodes: int = 200,
    env_id: str = "pipenav/PipeNav-v0",
    env_kwargs: dict[str, Any] | None = None,
    pool_seed: int = EVAL_POOL_SEED,
) -> EvalResult:
    """Run ``agent`` (a scripted name or a model .zip path) on ``n_episodes`` held-out networks."""
    import time

    kwargs = dict(env_kwargs or {})
    config = kwargs.pop("network_config", None)
    cfg = (
        NetworkConfig.from_dict(config) if isinstance(config, dict) else (config or NetworkConfig())
    )
    env = gym.make(env_id, network_config=cfg, **kwargs)
    if agent in SCRIPTED_AGENTS:
        actor: Any = make_agent(agent, env)
    elif str(agent).endswith(".zip") and Path(agent).exists():
        actor = PolicyAgent(agent, env)
    else:
        raise ValueError(
            f"agent {agent!r} is neither a scripted agent {sorted(SCRIPTED_AGENTS)} "
            "nor an existing model .zip"
        )
    rows = []
    t0 = time.perf_counter()
    for i in range(n_episodes):
        network = pool_network(cfg, pool_seed, i)
        obs, info = env.reset(seed=pool_seed + i, options={"network": network})
        actor.reset()
        done = False
        while not done:
            obs, _, term, trunc, info = env.step(actor.act(obs, info))
            done = term or trunc
        shortest = info.get("shortest_route", math.nan)
        ratio = info["travelled"] / shortest if info["is_success"] and shortest > 0 else math.nan
        rows.append((info["is_success"], info["jams"], info["decisions"], ratio, info["sim_time"]))
    wall = time.perf_counter() - t0
    arr = np.array(rows, dtype=float)
    ratios = arr[:, 3][np.isfinite(arr[:, 3])]
    return EvalResult(
        agent=str(agent),
        episodes=n_episodes,
        success_rate=float(arr[:, 0].mean()),
        jams_per_episode=float(arr[:, 1].mean()),
        decisions_per_episode=float(arr[:, 2].mean()),
        path_over_shortest=float(np.median(ratios)) if len(ratios) else math.nan,
        sim_seconds_per_episode=float(arr[:, 4].mean()),
        wall_seconds=round(wall, 2),
    )
