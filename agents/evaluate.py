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


#: Parallel evaluation backends: worker processes of this machine, or Ray tasks.
BACKENDS = ("process", "ray")


def env_setup(env_kwargs: dict[str, Any] | None) -> tuple[NetworkConfig, dict[str, Any]]:
    """The network config and the remaining env arguments of an evaluation (the held-out
    pool replaces any pool the arguments name)."""
    kwargs = dict(env_kwargs or {})
    kwargs.pop("network_pool", None)
    kwargs.pop("pool_seed", None)
    config = kwargs.pop("network_config", None)
    cfg = (
        NetworkConfig.from_dict(config) if isinstance(config, dict) else (config or NetworkConfig())
    )
    return cfg, kwargs


def _check_agent(agent: str) -> None:
    if agent in SCRIPTED_AGENTS or (str(agent).endswith(".zip") and Path(agent).exists()):
        return
    raise ValueError(
        f"agent {agent!r} is neither a scripted agent {sorted(SCRIPTED_AGENTS)} "
        "nor an existing model .zip"
    )


def evaluate(
    agent: str,
    n_episodes: int = 200,
    env_id: str = "pipenav/PipeNav-v0",
    env_kwargs: dict[str, Any] | None = None,
    pool_seed: int = EVAL_POOL_SEED,
    on_episode: Callable[[int, int], None] | None = None,
    jobs: int = 1,
    backend: str = "process",
) -> EvalResult:
    """Run ``agent`` (a scripted name or a model .zip path: MaskablePPO or plain PPO) on
    ``n_episodes`` held-out networks; ``on_episode(done, n_episodes)`` after each episode.

    ``jobs`` > 1 runs the episodes in that many worker processes (``backend`` ``"process"``)
    or Ray tasks (``"ray"``): episode ``i`` is still network ``i`` with seed ``pool_seed + i``,
    so the figures are those of ``jobs=1`` (the wall time aside)."""
    _check_agent(agent)
    if not (isinstance(jobs, int) and not isinstance(jobs, bool) and jobs >= 1):
        raise ValueError(f"evaluate: jobs = {jobs!r}: not allowed; allowed: an integer >= 1")
    if backend not in BACKENDS:
        raise ValueError(f"evaluate: backend = {backend!r}: not allowed; allowed: {BACKENDS}")
    if jobs > 1 and n_episodes > 1:
        t0 = time.perf_counter()
        infos = _evaluate_parallel(
            agent, n_episodes, env_id, env_kwargs, pool_seed, on_episode, jobs, backend
        )
        return _summarise(agent, infos, time.perf_counter() - t0)
    cfg, kwargs = env_setup(env_kwargs)
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
    else:
        infos = _evaluate_policy(agent, env, n_episodes, on_episode)
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


# ------------------------------------------------------------------ parallel evaluation
#: Per worker process: (agent, env id, env arguments) -> (env, actor), reused across episodes.
_WORKER_CACHE: dict[str, tuple[gym.Env, Any]] = {}


class _PlainPolicyAgent:
    """A plain SB3 PPO policy acting without masks (as ``evaluate_policy`` runs it)."""

    def __init__(self, path: str) -> None:
        import torch
        from stable_baselines3 import PPO

        torch.set_num_threads(1)
        self.model = PPO.load(str(path), device="cpu")

    def reset(self) -> None:
        pass

    def act(self, observation: dict, info: dict[str, Any]) -> int:
        del info
        action, _ = self.model.predict(observation, deterministic=True)
        return int(action)


def worker_env(agent: str, env_id: str, env_kwargs: dict[str, Any] | None) -> tuple[gym.Env, Any]:
    """The env (``env_id`` made with the held-out evaluation's arguments, see
    :func:`env_setup`) and the actor of ``agent`` (a scripted agent, a MaskablePPO policy or
    a plain policy) this process evaluates with; the last pair is cached and reused while the
    arguments stay the same (a new pair closes the old env)."""
    key = repr((agent, env_id, sorted((env_kwargs or {}).items(), key=lambda kv: kv[0])))
    hit = _WORKER_CACHE.get(key)
    if hit is None:
        for env, _ in _WORKER_CACHE.values():
            env.close()
        _WORKER_CACHE.clear()
        cfg, kwargs = env_setup(env_kwargs)
        env = gym.make(env_id, network_config=cfg, **kwargs)
        actor: Any
        if agent in SCRIPTED_AGENTS:
            actor = make_agent(agent, env)
        elif is_maskable_model(agent):
            actor = PolicyAgent(agent, env)
        else:
            actor = _PlainPolicyAgent(agent)
        hit = _WORKER_CACHE[key] = (env, actor)
    return hit


def run_held_out_episode(
    agent: str,
    index: int,
    env_id: str = "pipenav/PipeNav-v0",
    env_kwargs: dict[str, Any] | None = None,
    pool_seed: int = EVAL_POOL_SEED,
) -> dict[str, Any]:
    """Held-out episode ``index`` (network ``index`` of the pool, seed ``pool_seed + index``)
    of ``agent``; its final info (the worker's env and agent are reused between calls)."""
    env, actor = worker_env(agent, env_id, env_kwargs)
    cfg, _ = env_setup(env_kwargs)
    network = pool_network(cfg, pool_seed, index)
    obs, info = env.reset(seed=pool_seed + index, options={"network": network})
    actor.reset()
    done = False
    while not done:
        obs, _, term, trunc, info = env.step(actor.act(obs, info))
        done = term or trunc
    return {k: v for k, v in info.items() if k != "action_mask"}


def _evaluate_parallel(
    agent: str,
    n_episodes: int,
    env_id: str,
    env_kwargs: dict[str, Any] | None,
    pool_seed: int,
    on_episode: Callable[[int, int], None] | None,
    jobs: int,
    backend: str,
) -> list[dict[str, Any]]:
    """Final infos of episodes 0..n-1 run by ``jobs`` workers, in episode order; progress
    reported as episodes finish."""
    args = [(agent, i, env_id, env_kwargs, pool_seed) for i in range(n_episodes)]
    if backend == "ray":
        return _evaluate_ray(args, on_episode, jobs)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    infos: dict[int, dict[str, Any]] = {}
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(jobs, n_episodes), mp_context=context) as pool:
        futures = {pool.submit(run_held_out_episode, *a): a[1] for a in args}
        for future in as_completed(futures):
            infos[futures[future]] = future.result()
            if on_episode:
                on_episode(len(infos), n_episodes)
    return [infos[i] for i in range(n_episodes)]


def _evaluate_ray(
    args: list[tuple[Any, ...]], on_episode: Callable[[int, int], None] | None, jobs: int
) -> list[dict[str, Any]]:
    """:func:`_evaluate_parallel` on Ray (a local cluster of ``jobs`` CPUs unless one runs)."""
    import ray

    if not ray.is_initialized():
        ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False)
    task = ray.remote(num_cpus=1)(run_held_out_episode)
    pending = {task.remote(*a): a[1] for a in args}
    infos: dict[int, dict[str, Any]] = {}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            infos[pending.pop(ref)] = ray.get(ref)
            if on_episode:
                on_episode(len(infos), len(args))
    return [infos[i] for i in range(len(args))]
