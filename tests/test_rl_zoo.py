"""The shipped RL Zoo hyperparameters: the zoo reads them, and a zoo-trained plain PPO model
runs through ``pipenav eval``."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import pipe_env

rl_zoo3 = pytest.importorskip("rl_zoo3")

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "agents" / "configs" / "rl_zoo_ppo.yml"


@pytest.mark.parametrize("env_id", sorted(pipe_env.ENV_IDS))
def test_the_zoo_reads_the_hyperparameters_and_builds_ppo(env_id: str, tmp_path: Path) -> None:
    from rl_zoo3.exp_manager import ExperimentManager
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    manager = ExperimentManager(
        argparse.Namespace(), "ppo", env_id, str(tmp_path), config=str(CONFIG), verbose=0
    )
    hyperparams, saved = manager.read_hyperparameters()
    assert saved["policy"] == "MultiInputPolicy"
    hyperparams, _, _, _ = manager._preprocess_hyperparams(hyperparams)
    assert manager.n_timesteps > 0 and manager.env_kwargs["fidelity"] == "fast"
    env = make_vec_env(env_id, n_envs=1, env_kwargs=manager.env_kwargs)
    model = PPO(env=env, device="cpu", **hyperparams)  # every key is one PPO takes
    assert model.n_steps == 1024
    env.close()


@pytest.mark.slow
def test_a_zoo_trained_model_runs_through_pipenav_eval(tmp_path: Path) -> None:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    zoo = [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "pipenav/PipeNav-v0"]
    proc = subprocess.run(
        [
            *zoo,
            "--gym-packages",
            "pipe_env",
            "--conf-file",
            str(CONFIG),
            "-n",
            "64",
            "--hyperparams",
            "n_steps:32",
            "batch_size:32",
            "n_envs:1",
            "--eval-freq",
            "-1",
            "-f",
            str(tmp_path),
            "--vec-env",
            "dummy",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    (model,) = tmp_path.glob("ppo/*/pipenav-PipeNav-v0.zip")
    proc = subprocess.run(
        [sys.executable, "-m", "agents.cli", "eval", str(model), "--episodes", "2"],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert json.loads(proc.stdout)["episodes"] == 2
