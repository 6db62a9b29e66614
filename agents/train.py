"""MaskablePPO training on the pipenav environments (sb3-contrib).

A run is described by a YAML file (see ``agents/configs/maskable_ppo.yaml``): environment id and
keyword arguments, vectorisation, PPO hyperparameters, evaluation on a held-out network pool,
checkpoints and a wall-clock budget. The output folder gets TensorBoard logs (``tb/``),
checkpoints (``checkpoints/``), the best model by validation success (``best/best_model.zip``,
only when the run lasted long enough for a validation evaluation), the final model
(``final_model.zip``) and ``summary.json`` (timesteps, wall time, and a closing evaluation of
the best model, else the final one, on the held-out networks that neither training nor model
selection saw; see :mod:`agents.evaluate`).

Every model file (checkpoints, the best and the final model) is written atomically
(:func:`atomic_maskable_ppo`): a run interrupted while saving leaves the previous file whole.

A run may start from a trained model (``init``, ``pipenav train --init MODEL``): its weights and
hyper-parameters are loaded and learning continues in the run's environment, e.g. fine-tuning
the fast-fidelity policy in the full fidelity's physical loop (``--fidelity full``: every
vector-env worker builds its own MuJoCo world). The rollout (``ppo.n_steps``, ``ppo.batch_size``,
:data:`INIT_OVERRIDES`) follows the run's config, since a full-fidelity rollout must be far
shorter; the model must have the environment's observation and action spaces
(:func:`check_init`).

Every key is checked before any work: the top-level keys, the ``eval`` keys
(:data:`EVAL_KEYS`) and the ``ppo`` keys (MaskablePPO's own keyword arguments); a mistyped key
is a ValueError naming it and the allowed ones.
"""

from __future__ import annotations

import inspect
import io
import json
import math
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from detector.atomic import atomic_write_bytes, atomic_write_text
from detector.validation import fail
from pipe_env.network_io import finite_json

if TYPE_CHECKING:
    from sb3_contrib import MaskablePPO

DEFAULT_CONFIG = Path(__file__).with_name("configs") / "maskable_ppo.yaml"
VEC_ENVS = ("subproc", "dummy")
#: Keys of a config's ``eval`` mapping: validation episodes and interval (timesteps) during
#: training, the validation pool seed, and the episodes of the closing held-out evaluation.
EVAL_KEYS = ("episodes", "every_timesteps", "pool_seed", "final_episodes")
#: ``ppo`` keys a run started from a model (``init``) takes from its config; every other
#: hyper-parameter comes from the model.
INIT_OVERRIDES = ("n_steps", "batch_size")
#: MaskablePPO arguments train() sets itself (not allowed under ``ppo``).
_PPO_SET_BY_TRAIN = ("self", "policy", "env", "seed", "verbose", "tensorboard_log")


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
    #: a MaskablePPO model .zip to start from (None: a new policy); see the module docstring
    init: str | None = None

    def __post_init__(self) -> None:
        if self.vec_env not in VEC_ENVS:
            raise ValueError(f"vec_env={self.vec_env!r} is not allowed; use one of {VEC_ENVS}")
        if not (isinstance(self.n_envs, int) and 1 <= self.n_envs <= 64):
            raise ValueError(f"n_envs={self.n_envs!r} is not allowed; use an int in [1, 64]")
        if not (isinstance(self.total_timesteps, int) and self.total_timesteps > 0):
            raise ValueError(f"total_timesteps={self.total_timesteps!r}: use a positive int")
        if not (
            isinstance(self.max_minutes, (int, float))
            and not isinstance(self.max_minutes, bool)
            and 0 < self.max_minutes < float("inf")
        ):
            raise ValueError(f"max_minutes={self.max_minutes!r}: use a positive finite number")
        for name in ("seed", "checkpoint_every_timesteps", "torch_threads"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
                raise ValueError(f"{name}={value!r} is not allowed; use a non-negative int")
        if not isinstance(self.env_id, str) or not self.env_id:
            raise ValueError(f"env_id={self.env_id!r} is not allowed; use an environment id")
        for name in ("env_kwargs", "ppo", "eval"):
            if not isinstance(getattr(self, name), dict):
                raise ValueError(f"{name}={getattr(self, name)!r}: use a mapping")
        if self.init is not None and not (isinstance(self.init, str) and self.init):
            raise fail("init", self.init, "a MaskablePPO model .zip path, or null", where="train")
        unknown = sorted(set(self.eval) - set(EVAL_KEYS))
        if unknown:
            raise ValueError(f"eval: unknown keys {unknown}; allowed: {list(EVAL_KEYS)}")

    def check_ppo_keys(self) -> None:
        """Raise ValueError naming any ``ppo`` key MaskablePPO does not take (imports
        sb3-contrib, so it is not part of loading a config)."""
        from sb3_contrib import MaskablePPO

        params = inspect.signature(MaskablePPO.__init__).parameters
        allowed = sorted(set(params) - set(_PPO_SET_BY_TRAIN))
        unknown = sorted(set(self.ppo) - set(allowed))
        if unknown:
            raise ValueError(f"ppo: unknown keys {unknown}; allowed: {allowed}")

    @classmethod
    def from_yaml(cls, path: str | Path) -> TrainConfig:
        """Read a YAML training config; every problem is a ``ValueError`` naming the file."""
        try:
            data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
        except FileNotFoundError:
            raise ValueError(f"{path}: no such training config file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: cannot read the training config ({exc})") from None
        except yaml.YAMLError as exc:
            raise ValueError(f"{path}: not valid YAML ({exc})".replace("\n", " ")) from None
        if not isinstance(data, dict):
            raise ValueError(f"{path}: a training config must be a mapping")
        unknown = sorted(str(key) for key in set(data) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(
                f"{path}: unknown keys {unknown}; allowed: {sorted(cls.__dataclass_fields__)}"
            )
        try:
            return cls(**data)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None


def check_rollout(cfg: TrainConfig) -> None:
    """Raise naming the field when ``ppo.n_steps`` and ``n_envs`` give a rollout of fewer than
    two timesteps (PPO needs at least two to form a minibatch)."""
    n_steps = cfg.ppo.get("n_steps", 2048)
    if not (isinstance(n_steps, int) and not isinstance(n_steps, bool) and n_steps >= 1):
        raise fail("ppo.n_steps", n_steps, "an integer >= 1", where="train")
    if n_steps * cfg.n_envs < 2:
        raise fail(
            "ppo.n_steps",
            n_steps,
            "n_steps * n_envs >= 2",
            problem=f"with n_envs = {cfg.n_envs} a rollout of {n_steps * cfg.n_envs} timestep",
            where="train",
        )


def check_init(cfg: TrainConfig) -> dict[str, Any]:
    """Check the model ``cfg.init`` can start the run: an existing MaskablePPO file whose
    observation and action spaces are the environment's (built without a reset: no MuJoCo
    world). Returns the model's stored data (hyper-parameters, spaces, ``_n_updates``).

    Raises:
        ArgumentError: naming ``init``, the value, the problem and what is allowed.
    """
    import gymnasium as gym
    from stable_baselines3.common.save_util import load_from_zip_file

    import pipe_env  # noqa: F401  (registers the environment ids)
    from agents.evaluate import is_maskable_model

    path = cfg.init
    allowed = "a MaskablePPO model .zip (sb3-contrib) of the environment's spaces"
    if path is None:
        raise fail("init", path, allowed, problem="no model given", where="train")
    if not Path(path).is_file():
        raise fail("init", path, allowed, problem="no such file", where="train")
    try:
        maskable = is_maskable_model(path)
    except ValueError:
        raise fail(
            "init", path, allowed, problem="not a Stable-Baselines3 model file", where="train"
        ) from None
    if not maskable:
        raise fail(
            "init", path, allowed, problem="a plain PPO model (no action masks)", where="train"
        )
    data, _, _ = load_from_zip_file(path, device="cpu", print_system_info=False)
    assert data is not None
    env = gym.make(cfg.env_id, **cfg.env_kwargs)
    try:
        for name in ("observation_space", "action_space"):
            if data.get(name) != getattr(env, name):
                raise fail(
                    "init",
                    path,
                    allowed,
                    problem=f"its {name} differs from that of {cfg.env_id} with env_kwargs "
                    f"{cfg.env_kwargs} (scan_image must match the model's training)",
                    where="train",
                )
    finally:
        env.close()
    return data


def model_zip_path(path: str | os.PathLike[str]) -> Path:
    """The file Stable-Baselines3 writes for ``path``: ``.zip`` is added when it has no
    suffix."""
    target = Path(path)
    return target if target.suffix else Path(f"{target}.zip")


def atomic_maskable_ppo() -> type[MaskablePPO]:
    """MaskablePPO whose :meth:`save` to a path writes atomically (a temporary file in the same
    folder, fsync'ed, then renamed over the target), so that the checkpoint and evaluation
    callbacks, which call ``model.save``, never leave a truncated zip. The files are plain
    MaskablePPO models (``MaskablePPO.load`` reads them). Imports sb3-contrib."""
    from sb3_contrib import MaskablePPO

    class AtomicMaskablePPO(MaskablePPO):
        def save(
            self,
            path: str | os.PathLike[str] | io.BufferedIOBase,
            exclude: Iterable[str] | None = None,
            include: Iterable[str] | None = None,
        ) -> None:
            if isinstance(path, io.BufferedIOBase):
                super().save(path, exclude, include)
                return
            buffer = io.BytesIO()
            super().save(buffer, exclude, include)
            atomic_write_bytes(model_zip_path(path), buffer.getvalue())

    return AtomicMaskablePPO


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


class _BudgetProgress:
    """A rich progress bar whose fraction is the larger of timesteps / ``total_timesteps`` and
    elapsed / ``max_minutes``: training stops at whichever comes first, so the bar and its ETA
    follow the budget that will end the run."""

    def __init__(self, total_timesteps: int, minutes: float) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.total = total_timesteps
        self.seconds = 60.0 * minutes
        self.t0 = time.monotonic()
        self.last = -math.inf
        self.progress = Progress(
            TextColumn("train"),
            BarColumn(),
            TextColumn("{task.percentage:>3.0f}%"),
            TextColumn("{task.fields[timesteps]} timesteps"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=Console(stderr=True),
        )
        self.task = self.progress.add_task("train", total=1000, timesteps=0)
        self.progress.start()

    def update(self, timesteps: int, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self.last < 0.5:
            return
        self.last = now
        frac = max(timesteps / self.total, (now - self.t0) / self.seconds)
        self.progress.update(self.task, completed=min(1000.0, 1000.0 * frac), timesteps=timesteps)

    def close(self, timesteps: int) -> None:
        self.update(timesteps, force=True)
        self.progress.update(self.task, completed=1000)
        self.progress.stop()


def _saved_batch_size(path: str, default: int) -> int:
    """The minibatch size a saved SB3 model was trained with (``default`` if it has none)."""
    from stable_baselines3.common.save_util import load_from_zip_file

    data, _, _ = load_from_zip_file(path, load_data=True, device="cpu")
    return int((data or {}).get("batch_size", default))


def _make_model(cfg: TrainConfig, venv: Any, out: Path) -> MaskablePPO:
    """A new MaskablePPO per ``cfg.ppo``, or the model ``cfg.init`` with the run's rollout
    (:data:`INIT_OVERRIDES`) on ``venv``; model files are saved atomically."""
    cls = atomic_maskable_ppo()
    if cfg.init is None:
        return cls(
            "MultiInputPolicy",
            venv,
            seed=cfg.seed,
            verbose=0,
            tensorboard_log=str(out / "tb"),
            **cfg.ppo,
        )
    overrides = {k: cfg.ppo[k] for k in INIT_OVERRIDES if k in cfg.ppo}
    if "n_steps" in overrides:  # a minibatch no larger than the rollout
        rollout = int(overrides["n_steps"]) * cfg.n_envs
        batch = overrides.get("batch_size", _saved_batch_size(cfg.init, rollout))
        overrides["batch_size"] = min(int(batch), rollout)
    model = cls.load(
        cfg.init, env=venv, device="cpu", tensorboard_log=str(out / "tb"), verbose=0, **overrides
    )
    model.set_random_seed(cfg.seed)
    return model


def train(
    cfg: TrainConfig,
    out: str | Path,
    progress_bar: bool = True,
    final_episodes: int | None = None,
    on_final_episode: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Train MaskablePPO per ``cfg`` into folder ``out``; returns the run summary.

    Args:
        cfg: the run.
        out: output folder (see module docstring).
        progress_bar: show a progress bar that follows the timestep or minutes budget,
            whichever ends the run first.
        final_episodes: episodes of the closing held-out evaluation (default
            ``eval.final_episodes``, else ``eval.episodes``); 0 skips it.
        on_final_episode: called with (episodes done, total) during that evaluation.
    """
    import torch
    from sb3_contrib.common.maskable.callbacks import MaskableEvalCallback
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    cfg.check_ppo_keys()
    check_rollout(cfg)
    if cfg.init is not None:
        check_init(cfg)
    torch.set_num_threads(cfg.torch_threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "config.yaml", yaml.safe_dump(asdict(cfg), sort_keys=False))
    vec_cls = SubprocVecEnv if cfg.vec_env == "subproc" and cfg.n_envs > 1 else DummyVecEnv
    venv = vec_cls(make_env_fns(cfg))
    from agents.evaluate import VALIDATION_POOL_SEED

    eval_cfg = {"episodes": 50, "every_timesteps": 50_000, "pool_seed": VALIDATION_POOL_SEED}
    eval_cfg.update(cfg.eval)
    model = _make_model(cfg, venv, out)
    n_updates_at_start = int(model._n_updates)

    class Budget(BaseCallback):
        """Stops training when the wall-clock budget is spent."""

        def __init__(self, minutes: float) -> None:
            super().__init__()
            self.deadline = time.monotonic() + 60.0 * minutes

        def _on_step(self) -> bool:
            return time.monotonic() < self.deadline

    class ShowProgress(BaseCallback):
        def __init__(self, bar: _BudgetProgress) -> None:
            super().__init__()
            self.bar = bar

        def _on_step(self) -> bool:
            self.bar.update(self.num_timesteps)
            return True

    bar = _BudgetProgress(cfg.total_timesteps, cfg.max_minutes) if progress_bar else None
    every = max(int(eval_cfg["every_timesteps"]) // cfg.n_envs, 1)
    # the validation env only when a validation can happen within the timestep budget (learn
    # runs whole rollouts): building it resets an episode, a MuJoCo world in full fidelity
    rollout = int(model.n_steps) * cfg.n_envs
    reachable = -(-cfg.total_timesteps // rollout) * rollout
    eval_env = (
        DummyVecEnv(make_env_fns(cfg, pool_seed=int(eval_cfg["pool_seed"]), n=1))
        if reachable >= every * cfg.n_envs
        else None
    )
    callbacks = CallbackList(
        [
            *([ShowProgress(bar)] if bar is not None else []),
            Budget(cfg.max_minutes),
            CheckpointCallback(
                max(cfg.checkpoint_every_timesteps // cfg.n_envs, 1),
                str(out / "checkpoints"),
                name_prefix="ppo",
            ),
            *(
                [
                    MaskableEvalCallback(
                        eval_env,
                        n_eval_episodes=int(eval_cfg["episodes"]),
                        eval_freq=every,
                        best_model_save_path=str(out / "best"),
                        log_path=str(out / "eval"),
                        deterministic=True,
                        verbose=0,
                    )
                ]
                if eval_env is not None
                else []
            ),
        ]
    )
    t0 = time.monotonic()
    try:
        model.learn(cfg.total_timesteps, callback=callbacks, tb_log_name="maskable_ppo")
    finally:
        if bar is not None:
            bar.close(int(model.num_timesteps))
    wall = time.monotonic() - t0
    model.save(out / "final_model.zip")
    venv.close()
    if eval_env is not None:
        eval_env.close()
    best = out / "best" / "best_model.zip"
    summary: dict[str, Any] = {
        "timesteps": int(model.num_timesteps),
        "init": cfg.init,
        "fidelity": cfg.env_kwargs.get("fidelity", "fast"),
        "n_updates_at_start": n_updates_at_start,
        "n_updates": int(model._n_updates),
        "wall_seconds": round(wall, 1),
        "timesteps_per_second": round(model.num_timesteps / max(wall, 1e-9), 1),
        "final_model": str(out / "final_model.zip"),
        "best_model": str(best) if best.is_file() else None,
    }
    if not best.is_file():
        summary["note"] = (
            f"no validation evaluation ran: the run stopped after {model.num_timesteps} "
            f"timesteps, before the first one at {int(eval_cfg['every_timesteps'])} (eval."
            "every_timesteps); so there is no best_model.zip, and final_model.zip is the model"
        )
    if final_episodes is None:
        final_episodes = int(eval_cfg.get("final_episodes", eval_cfg["episodes"]))
    if final_episodes > 0:
        from agents.evaluate import EVAL_POOL_SEED, evaluate

        chosen = best if best.is_file() else out / "final_model.zip"
        result = evaluate(
            str(chosen),
            final_episodes,
            env_id=cfg.env_id,
            env_kwargs=cfg.env_kwargs,
            on_episode=on_final_episode,
        )
        summary["held_out_evaluation"] = {
            "model": str(chosen),
            "pool_seed": EVAL_POOL_SEED,
            **result.to_dict(),
        }
    atomic_write_text(
        out / "summary.json", json.dumps(finite_json(summary), indent=2, allow_nan=False)
    )
    return summary
