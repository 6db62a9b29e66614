"""A seeded full-fidelity run's outcome and decision log, pinned by a digest.

The executor's state (drive command, clamping V, driven path, telemetry) and the plant's sensing
(the sweep callback with a detector source) were taken apart into named parts; the run below
(the MuJoCo robot sensing a tee, taking its branch and driving to a goal beyond it) must give
the same decisions, detection log, motion and clock as before. The digests were recorded on the
code before the split; floats are rounded to 9 decimals so that the digest pins behaviour, not
the last bit of a platform's arithmetic.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from pipe_env import layouts
from pipe_env.envs.plant_full import PhysicalPlant
from pipe_env.routing import EdgePosition, edge_length

#: detector -> digest of :func:`seeded_run` (recorded before the executor was split).
DIGESTS = {
    "improved": "6bd34654a2a763e1f24cc0b6cd4fa7014822e328d55e57eccdc6281c0ba7d38e",
    "ground_truth": "8de104909c73e22386ad75acc3d2a90b4af14bfd48e739e7450a46be0d332df5",
    "thesis": "2330a29fb1406eaa60a31825d4159584658d110d2af41a19a305d4bfa346e7b5",
}


def _rounded(value: object) -> object:
    if isinstance(value, float):
        return round(value, 9)
    if isinstance(value, dict):
        return {str(k): _rounded(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(v) for v in value]
    if isinstance(value, np.ndarray):
        return _rounded(value.tolist())
    if isinstance(value, (np.floating, np.integer)):
        return _rounded(value.item())
    return value


def seeded_run(detector: str) -> dict[str, object]:
    """Sense a tee, take its branch and drive on to a goal 45 cm into it (seed 11)."""
    net = layouts.t_junction(0.09, direction=0.0, distance=0.5)
    plant = PhysicalPlant(net, detector=detector)
    plant.reset(np.random.default_rng(11))
    goal = EdgePosition("r_out1", 0.45, edge_length(net, "r_out1"))
    dec, out = plant.advance(goal)
    assert dec is not None
    options = [[o.kind, o.distance, o.angle, o.diameter] for o in dec.options]
    branch = [o for o in dec.options if o.angle > 1.0]
    res = plant.execute(branch[0], goal)
    _, res2 = plant.advance(goal)
    ex = plant.executor
    return {
        "options": options,
        "advance": [out.status, out.distance, out.sim_time],
        "execute": [res.status, res.note, res.distance],
        "advance2": [res2.status, res2.distance],
        "log": plant.detection_log,
        "ticks": [ex.physics_ticks, ex.kinematic_ticks],
        "time": ex.time,
        "odometer": ex.odometer,
        "position": plant.pose().position.tolist(),
        "clamp": plant.read_clamp(),
    }


def digest(record: dict[str, object]) -> str:
    text = json.dumps(_rounded(record), sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


def seeded_episode() -> dict[str, object]:
    """An environment episode (8 random valid decisions, seed 3) on a 4-fitting 3D network."""
    import gymnasium as gym

    import pipe_env  # noqa: F401
    from pipe_env.envs import pool_network
    from pipe_env.generator import NetworkConfig

    cfg = {"n_fittings": 4, "planar": False, "allow_loops": False}
    env = gym.make(
        "pipenav/PipeNav-v0",
        fidelity="full",
        detector="improved",
        network_config=cfg,
        max_episode_steps=8,
    )
    _, info = env.reset(seed=3, options={"network": pool_network(NetworkConfig(**cfg), 7, 0)})
    rng = np.random.default_rng(3)
    rows = []
    done = False
    while not done:
        action = int(rng.choice(np.flatnonzero(info["action_mask"])))
        _, reward, term, trunc, info = env.step(action)
        rows.append([action, reward, term, trunc, info["travelled"], info["sim_time"]])
        done = term or trunc
    plant = env.unwrapped.plant  # type: ignore[attr-defined]
    ex = plant.executor
    record = {
        "rows": rows,
        "log": plant.detection_log,
        "success": bool(info["is_success"]),
        "jams": info["jams"],
        "position": plant.pose().position.tolist(),
        "ticks": [ex.physics_ticks, ex.kinematic_ticks],
        "time": ex.time,
        "odometer": ex.odometer,
    }
    env.close()
    return record


#: digest of :func:`seeded_episode` (the same record bit for bit before and after the split).
EPISODE_DIGEST = "9b9d754f87a3fe215e5ea839e3f346107ed3b25e43e93da8622c9b0af6846f09"


@pytest.mark.slow
def test_a_seeded_environment_episode_is_as_before_the_split() -> None:
    record = seeded_episode()
    assert digest(record) == EPISODE_DIGEST, record


@pytest.mark.parametrize("detector", sorted(DIGESTS))
def test_a_seeded_run_is_as_before_the_split(detector: str) -> None:
    record = seeded_run(detector)
    assert record["execute"][0] == "goal"
    assert digest(record) == DIGESTS[detector], record
