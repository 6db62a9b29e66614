"""MaskablePPO training on the pipenav environments (sb3-contrib).

A run is described by a YAML file (see ``agents/configs/maskable_ppo.yaml``): environment id and
keyword arguments, vectorisation, PPO hyperparameters, evaluation on a held-out network pool,
checkpoints and a wall-clock budget. The output folder gets TensorBoard logs (``tb/``),
checkpoints (``checkpoints/``), the best model by held-out success (``best/best_model.zip``), the
final model (``final_model.zip``) and ``summary.json`` (timesteps, wall time, evaluation).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from detector.atomic import atomic_open, atomic_write_text
from pipe_env.network_io import finite_json

DEFAULT_CONFIG = Path(__file__).with_name("configs") / "maskable_ppo.yaml"
VEC_ENVS = ("subproc", "dummy")


@dataclass
class TrainConfig:
    """A training run (see module docstring); loaded with :meth:`from_yaml`."""

    env_id: str = "pipenav/PipeNav-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 2
    vec_env: str = "subproc"
    total_timesteps: int = 1_000_000
    max_minutes: float = 30.0
    seed: int = 0
    ppo: dict[str, Any] = field(default_factory=dict)
    eval: dict[str, Any] = field(default_factory=dict)
    checkpoint_every_timesteps: int = 100_000
    #: torch threads for the policy: 1 is fastest for small MLPs (OpenMP spin-waiting costs
    #: milliseconds per layer when the cores are also busy with environment workers).
    torch_threads: int = 1

    def __post_init__(self) -> None:
        if self.vec_env not in VEC_ENVS:
            raise ValueError(f"vec_env={self.vec_env!r} is not allowed; use one of {VEC_ENVS}")
        if not (isinstance(self.n_envs, int) and 1 <= self.n_envs <= 64):
            raise ValueError(f"n_envs={self.n_envs!r} is not allowed; use an int in [1, 64]")
        if not (isinstance(self.total_timesteps, int) and self.total_timesteps > 0):
            raise ValueError(f"total_timesteps={self.total_timesteps!r}: use a positive int")
        if not self.max_minutes > 0:
            raise ValueError(f"max_minutes={self.max_minutes!r}: use a positive number")

    @classmethod
    def from_yaml(cls, path: str | Path) -> TrainConfig:
        data = yaml.safe_load(Path(path).read_text()) or {}
        if not isinstance(data, dict):
            raise ValueError(f"{path}: a training config must be a mapping")
        unknown = sorted(set(data) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(
                f"{path}: unknown keys {unknown}; allowed: {sorted(cls.__dataclass_fields__)}"
            )
        return cls(**data)


def make_env_fns(cfg: TrainConfig, pool_seed: int | None = None, n: int | None = None):
    """Environment factories; ``pool_seed`` overrides the network pool (held-out sets)."""
    import gymnasium as gym

    kwargs = dict(cfg.env_kwargs)
    if pool_seed is not None:
        kwargs["pool_seed"] = pool_seed

    def make(rank: int):
        def _init():
            from stable_baselines3.common.monitor import Monitor

            import pipe_env  # noqa: F401  (registers the ids in worker processes)

            env = gym.make(cfg.env_id, **kwargs)
            env.reset(seed=cfg.seed + rank)
            return Monitor(env, info_keywords=("is_success", "jams", "decisions"))

        return _init

    return [make(i) for i in range(n or cfg.n_envs)]


def train(cfg: TrainConfig, out: str | Path, progress_bar: bool = True) -> dict[str, Any]:
    """Train MaskablePPO per ``cfg`` into folder ``out``; returns the run summary."""
    import torch
    from sb3_contrib import MaskablePPO
    from sb3_contrib.common.maskable.callbacks import MaskableEvalCallback
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    torch.set_num_threads(cfg.torch_threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "config.yaml", yaml.safe_dump(asdict(cfg), sort_keys=False))
    vec_cls = SubprocVecEnv if cfg.vec_env == "subproc" and cfg.n_envs > 1 else DummyVecEnv
    venv = vec_cls(make_env_fns(cfg))
    from agents.evaluate import VALIDATION_POOL_SEED

    eval_cfg = {"episodes": 50, "every_timesteps": 50_000, "pool_seed": VALIDATION_POOL_SEED}
    eval_cfg.update(cfg.eval)
    eval_env = DummyVecEnv(make_env_fns(cfg, pool_seed=int(eval_cfg["pool_seed"]), n=1))
    ppo_kwargs = dict(cfg.ppo)
    model = MaskablePPO(
        "MultiInputPolicy",
        venv,
        seed=cfg.seed,
        verbose=0,
        tensorboard_log=str(out / "tb"),
        **ppo_kwargs,
    )

    class Budget(BaseCallback):
        """Stops training when the wall-clock budget is spent."""

        def __init__(self, minutes: float) -> None:
            super().__init__()
            self.deadline = time.monotonic() + 60.0 * minutes

        def _on_step(self) -> bool:
            return time.monotonic() < self.deadline

    every = max(int(eval_cfg["every_timesteps"]) // cfg.n_envs, 1)
    callbacks = CallbackList(
        [
            Budget(cfg.max_minutes),
            CheckpointCallback(
                max(cfg.checkpoint_every_timesteps // cfg.n_envs, 1),
                str(out / "checkpoints"),
                name_prefix="ppo",
            ),
            MaskableEvalCallback(
                eval_env,
                n_eval_episodes=int(eval_cfg["episodes"]),
                eval_freq=every,
                best_model_save_path=str(out / "best"),
                log_path=str(out / "eval"),
                deterministic=True,
                verbose=0,
            ),
        ]
    )
    t0 = time.monotonic()
    model.learn(
        cfg.total_timesteps,
        callback=callbacks,
        progress_bar=progress_bar,
        tb_log_name="maskable_ppo",
    )
    wall = time.monotonic() - t0
    with atomic_open(out / "final_model.zip", "wb") as handle:
        model.save(handle)
    venv.close()
    summary = {
        "timesteps": int(model.num_timesteps),
        "wall_seconds": round(wall, 1),
        "timesteps_per_second": round(model.num_timesteps / max(wall, 1e-9), 1),
        "final_model": str(out / "final_model.zip"),
        "best_model": str(out / "best" / "best_model.zip"),
    }
    atomic_write_text(
        out / "summary.json", json.dumps(finite_json(summary), indent=2, allow_nan=False)
    )
    return summary
