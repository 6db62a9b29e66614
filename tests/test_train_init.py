"""``pipenav train --init MODEL``: fine-tuning a MaskablePPO policy, in the full fidelity's
physical loop too, and the errors for combinations that cannot work."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from sb3_contrib import MaskablePPO

from agents.cli import main
from agents.train import TrainConfig, check_init, check_rollout
from detector.validation import ArgumentError

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "agents" / "maskable_ppo_policy.zip"


def _weights(path: Path) -> list[np.ndarray]:
    model = MaskablePPO.load(path, device="cpu")
    return [p.detach().cpu().numpy().copy() for p in model.policy.parameters()]


def _small_config(tmp_path: Path) -> Path:
    """The packaged config on small networks (the observation is the same on any network)."""
    cfg = yaml.safe_load((ROOT / "agents" / "configs" / "maskable_ppo.yaml").read_text())
    cfg["env_kwargs"]["network_config"] = {"n_fittings": 6, "planar": False, "allow_loops": True}
    cfg["env_kwargs"]["network_pool"] = 8
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _train(tmp_path: Path, fidelity: str, timesteps: int, n_envs: int) -> dict:
    out = tmp_path / f"run_{fidelity}"
    code = main(
        [
            "train",
            "--config",
            str(_small_config(tmp_path)),
            "--fidelity",
            fidelity,
            "--init",
            str(SHIPPED),
            "--n-envs",
            str(n_envs),
            "--n-steps",
            "8",
            "--timesteps",
            str(timesteps),
            "--eval-episodes",
            "0",
            "--no-progress",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fidelity"] == fidelity and summary["init"] == str(SHIPPED)
    final = out / "final_model.zip"
    assert Path(summary["final_model"]) == final and final.is_file()
    loaded = MaskablePPO.load(final, device="cpu")
    # the shipped model's hyper-parameters, the run's rollout (the minibatch within it)
    shipped = MaskablePPO.load(SHIPPED, device="cpu")
    rollout = 8 * n_envs
    assert (loaded.n_steps, loaded.batch_size, loaded.n_envs) == (8, rollout, n_envs)
    assert loaded.n_epochs == shipped.n_epochs and loaded.gamma == shipped.gamma
    assert loaded.policy_kwargs == shipped.policy_kwargs
    # learning ran: one update (n_epochs gradient passes) per rollout, and the weights moved
    # away from the shipped ones
    rollouts = -(-timesteps // rollout)
    assert summary["n_updates"] - summary["n_updates_at_start"] == rollouts * shipped.n_epochs
    assert summary["n_updates_at_start"] == shipped._n_updates
    changed = [
        not np.array_equal(a, b) for a, b in zip(_weights(final), _weights(SHIPPED), strict=True)
    ]
    assert any(changed)
    return summary


def test_fine_tuning_in_the_fast_fidelity(tmp_path: Path) -> None:
    summary = _train(tmp_path, "fast", 16, n_envs=1)
    assert summary["timesteps"] == 16


@pytest.mark.slow
def test_fine_tuning_the_shipped_policy_in_the_full_fidelity(tmp_path: Path) -> None:
    summary = _train(tmp_path, "full", 16, n_envs=2)  # two workers, a MuJoCo world each
    assert summary["timesteps"] == 16


def test_a_missing_or_wrong_init_model_names_the_field(tmp_path: Path) -> None:
    cfg = TrainConfig(init=str(tmp_path / "none.zip"))
    with pytest.raises(ArgumentError, match=r"init = '.*: no such file; allowed: a MaskablePPO"):
        check_init(cfg)
    junk = tmp_path / "junk.zip"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ArgumentError, match="not a Stable-Baselines3 model file"):
        check_init(TrainConfig(init=str(junk)))
    with pytest.raises(ArgumentError, match=r"observation_space differs .*scan_image"):
        check_init(TrainConfig(init=str(SHIPPED), env_kwargs={"scan_image": True}))
    with pytest.raises(ValueError, match="init = ''"):
        TrainConfig(init="")


def test_a_rollout_shorter_than_two_timesteps_is_refused() -> None:
    with pytest.raises(ArgumentError, match=r"ppo.n_steps = 1: .*allowed: n_steps \* n_envs"):
        check_rollout(TrainConfig(n_envs=1, ppo={"n_steps": 1}))
    check_rollout(TrainConfig(n_envs=2, ppo={"n_steps": 1}))


def test_the_cli_reports_a_bad_init_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    code = main(["train", "--init", str(tmp_path / "x.zip"), "--out", str(out), "--no-progress"])
    assert code == 2
    assert "--init: train: init = " in capsys.readouterr().out
    assert not out.exists()
    code = main(["train", "--n-envs", "65", "--out", str(out), "--no-progress"])
    assert code == 2 and "n_envs=65" in capsys.readouterr().out


def test_without_a_configured_minibatch_the_saved_models_is_kept() -> None:
    # a config without ppo.batch_size fine-tunes with the model's own minibatch (capped at the
    # rollout), not with the whole rollout
    from agents.train import _saved_batch_size

    shipped = MaskablePPO.load(SHIPPED, device="cpu")
    assert _saved_batch_size(str(SHIPPED), 10**6) == shipped.batch_size < 10**6
