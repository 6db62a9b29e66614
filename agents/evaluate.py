"""Evaluate an agent (scripted or a trained MaskablePPO policy) on held-out networks.

Metrics per agent: success rate, jams per episode, decisions per episode, and path length over
the shortest drivable route (median over successful episodes). The held-out networks are
``pool_network(config, EVAL_POOL_SEED, i)`` for i = 0, 1, ...: a pool seed that training uses
for neither its episodes nor its model selection (``VALIDATION_POOL_SEED``), so the same
``n_episodes`` give the same networks. A learned policy is evaluated with ``evaluate_policy``
(deterministic actions): a MaskablePPO model (sb3-contrib) with action masks on; a plain SB3 PPO
model (e.g. trained with RL Zoo) without masks, so a masked choice it makes costs a decision and
the invalid-action penalty, as in its training.
"""

from __future__ import annotations

import json
import math
import time
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.scripted import SCRIPTED_AGENTS, make_agent
from pipe_env.envs import pool_network
from pipe_env.generator import NetworkConfig
from pipe_env.network import PipeNetwork

#: Held-out networks for reported evaluations.
EVAL_POOL_SEED = 1_000_003
#: Networks for model selection during training (never the reported held-out ones).
VALIDATION_POOL_SEED = 2_000_003


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


class SequentialNetworks(gym.Wrapper):
    """Resets its environment on the given networks in order (cycling), episode ``i`` on
    ``networks[i]`` with seed ``first_seed + i`` whatever calls ``reset`` (a scripted loop, or
    sb3's automatic resets, which pass no seed): every agent evaluated meets the same networks
    with the same sensing noise."""

    def __init__(self, env: gym.Env, networks: list[PipeNetwork], first_seed: int) -> None:
        super().__init__(env)
        self.networks = networks
        self.first_seed = first_seed
        self.index = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        network = self.networks[self.index % len(self.networks)]
        episode_seed = self.first_seed + self.index
        self.index += 1
        return self.env.reset(seed=episode_seed, options={**(options or {}), "network": network})

    def action_masks(self) -> np.ndarray:
        base: Any = self.env.unwrapped
        return np.asarray(base.action_masks())


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
            observation,
            action_masks=np.asarray(info["action_mask"], dtype=bool),
            deterministic=True,
        )
        return int(action)


def random_valid_episode(env: gym.Env, rng: np.random.Generator, seed: int) -> tuple[int, float]:
    """Run one episode of ``env`` (reset with ``seed``) choosing uniformly among the valid
    actions (``info["action_mask"]``) with ``rng``; returns (decisions, simulated seconds).
    The throughput benchmarks' workload."""
    _, info = env.reset(seed=seed)
    decisions = 0
    done = False
    while not done:
        action = int(rng.choice(np.flatnonzero(info["action_mask"])))
        _, _, term, trunc, info = env.step(action)
        decisions += 1
        done = term or trunc
    return decisions, float(info["sim_time"])


def held_out_networks(
    config: NetworkConfig, n: int, pool_seed: int = EVAL_POOL_SEED
) -> list[PipeNetwork]:
    return [pool_network(config, pool_seed, i) for i in range(n)]


def _summarise(agent: str, infos: list[dict[str, Any]], wall: float) -> EvalResult:
    arr = np.array(
        [(i["is_success"], i["jams"], i["decisions"], i["sim_time"]) for i in infos], dtype=float
    )
    ratios = [
        i["travelled"] / i["shortest_route"]
        for i in infos
        if i["is_success"] and i.get("shortest_route", 0) > 0
    ]
    return EvalResult(
        agent=str(agent),
        episodes=len(infos),
        success_rate=float(arr[:, 0].mean()),
        jams_per_episode=float(arr[:, 1].mean()),
        decisions_per_episode=float(arr[:, 2].mean()),
        path_over_shortest=float(np.median(ratios)) if ratios else math.nan,
        sim_seconds_per_episode=float(arr[:, 3].mean()),
        wall_seconds=round(wall, 2),
    )


def evaluate(
    agent: str,
    n_episodes: int = 200,
    env_id: str = "pipenav/PipeNav-v0",
    env_kwargs: dict[str, Any] | None = None,
    pool_seed: int = EVAL_POOL_SEED,
    on_episode: Callable[[int, int], None] | None = None,
) -> EvalResult:
    """Run ``agent`` (a scripted name or a model .zip path: MaskablePPO or plain PPO) on
    ``n_episodes`` held-out networks; ``on_episode(done, n_episodes)`` after each episode."""
    kwargs = dict(env_kwargs or {})
    kwargs.pop("network_pool", None)
    kwargs.pop("pool_seed", None)
    config = kwargs.pop("network_config", None)
    cfg = (
        NetworkConfig.from_dict(config) if isinstance(config, dict) else (config or NetworkConfig())
    )
    networks = held_out_networks(cfg, n_episodes, pool_seed)
    env = SequentialNetworks(gym.make(env_id, network_config=cfg, **kwargs), networks, pool_seed)
    t0 = time.perf_counter()
    if agent in SCRIPTED_AGENTS:
        actor: Any = make_agent(agent, env)
        infos = []
        for _ in range(n_episodes):
            obs, info = env.reset()
            actor.reset()
            done = False
            while not done:
                obs, _, term, trunc, info = env.step(actor.act(obs, info))
                done = term or trunc
            infos.append(info)
            if on_episode:
                on_episode(len(infos), n_episodes)
    elif str(agent).endswith(".zip") and Path(agent).exists():
        infos = _evaluate_policy(agent, env, n_episodes, on_episode)
    else:
        raise ValueError(
            f"agent {agent!r} is neither a scripted agent {sorted(SCRIPTED_AGENTS)} "
            "nor an existing model .zip"
        )
    env.close()
    return _summarise(agent, infos, time.perf_counter() - t0)


def is_maskable_model(path: str | Path) -> bool:
    """Was the SB3 model file ``path`` saved by sb3-contrib's MaskablePPO (its policy class is a
    maskable one)? False for a plain SB3 PPO model.

    Raises:
        ValueError: ``path`` is not an SB3 model file.
    """
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data"))
        module = str(data["policy_class"]["__module__"])
    except (OSError, KeyError, TypeError, ValueError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a Stable-Baselines3 model file ({exc!r})") from None
    return "maskable" in module


def _evaluate_policy(
    path: str,
    env: gym.Env,
    n_episodes: int,
    on_episode: Callable[[int, int], None] | None = None,
) -> list[dict]:
    """``evaluate_policy`` (deterministic; masks on for MaskablePPO, see module docstring) on
    ``env``, a :class:`SequentialNetworks` that seeds each episode itself; the final info of
    each."""
    import torch
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(1)
    if is_maskable_model(path):
        from sb3_contrib import MaskablePPO
        from sb3_contrib.common.maskable.evaluation import evaluate_policy as masked_evaluation

        evaluate_policy: Callable[..., Any] = masked_evaluation
        model: Any = MaskablePPO.load(str(path), device="cpu")
        masking: dict[str, Any] = {"use_masking": True}
    else:
        from stable_baselines3 import PPO
        from stable_baselines3.common.evaluation import evaluate_policy as plain_evaluation

        evaluate_policy = plain_evaluation

        model = PPO.load(str(path), device="cpu")
        masking = {}
    venv = DummyVecEnv([lambda: env])
    finals: list[dict] = []

    def keep_final_info(local: dict, _global: dict) -> None:
        if local["dones"][local["i"]]:
            finals.append(dict(local["infos"][local["i"]]))
            if on_episode and len(finals) <= n_episodes:
                on_episode(len(finals), n_episodes)

    evaluate_policy(
        model,
        venv,
        n_eval_episodes=n_episodes,
        deterministic=True,
        callback=keep_final_info,
        warn=False,
        **masking,
    )
    return finals[:n_episodes]
