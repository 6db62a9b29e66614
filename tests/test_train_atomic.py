"""Model files written atomically: an interrupted save leaves the previous model whole.

Training writes checkpoints, the best model and the final model through ``model.save``
(:func:`agents.train.atomic_maskable_ppo`); these tests interrupt that save part-way.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from sb3_contrib import MaskablePPO
from stable_baselines3.common import save_util
from stable_baselines3.common.vec_env import DummyVecEnv

from agents.train import TrainConfig, atomic_maskable_ppo, make_env_fns, model_zip_path


@pytest.fixture(scope="module")
def model() -> MaskablePPO:
    cfg = TrainConfig(
        n_envs=1,
        vec_env="dummy",
        env_kwargs={"fidelity": "fast", "network_config": {"n_fittings": 2}},
        ppo={"n_steps": 32, "batch_size": 32, "n_epochs": 1},
    )
    venv = DummyVecEnv(make_env_fns(cfg))
    made = atomic_maskable_ppo()("MultiInputPolicy", venv, seed=0, verbose=0)
    yield made
    venv.close()


def _perturb(model: MaskablePPO) -> None:
    with torch.no_grad():
        for p in model.policy.parameters():
            p.add_(0.5)


def _weights(model: MaskablePPO) -> list[np.ndarray]:
    return [p.detach().cpu().numpy().copy() for p in model.policy.parameters()]


def test_models_are_plain_maskable_ppo_files(model: MaskablePPO, tmp_path: Path) -> None:
    model.save(tmp_path / "m")  # Stable-Baselines3 adds .zip to a path without a suffix
    assert model_zip_path(tmp_path / "m") == tmp_path / "m.zip"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.zip"]
    loaded = MaskablePPO.load(tmp_path / "m.zip")
    assert type(loaded) is MaskablePPO
    for a, b in zip(_weights(loaded), _weights(model), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("where", ["serialising", "renaming"])
def test_an_interrupted_save_leaves_the_previous_model_intact(
    model: MaskablePPO, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    path = tmp_path / "final_model.zip"
    model.save(path)
    before = path.read_bytes()
    saved_weights = _weights(model)
    _perturb(model)

    def interrupt(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt  # as Ctrl-C (or a kill) part-way through the save

    if where == "serialising":
        # the zip's header and "data" entry are written by then: a plain save would leave them
        monkeypatch.setattr(save_util.th, "save", interrupt)
    else:
        monkeypatch.setattr("detector.atomic.os.replace", interrupt)
    with pytest.raises(KeyboardInterrupt):
        model.save(path)
    monkeypatch.undo()

    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["final_model.zip"]  # no temp files
    loaded = MaskablePPO.load(path)
    for a, b in zip(_weights(loaded), saved_weights, strict=True):
        np.testing.assert_array_equal(a, b)
    model.save(path)  # a later save goes through
    assert path.read_bytes() != before
