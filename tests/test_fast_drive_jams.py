"""The fast fidelity's drive jams: a drive to a structure stalls at the full fidelity's own rate
(``pipe_env.envs.plant.DRIVE_JAM_RATE``), costs the jam and leaves the robot deciding."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.scripted import RoutePlanner
from detector.validation import ArgumentError
from pipe_env import layouts
from pipe_env.envs.plant import DRIVE_JAM_RATE, KinematicPlant, PlantStatus


def _advance(rate: float, seed: int = 0) -> tuple[KinematicPlant, object, object]:
    plant = KinematicPlant(layouts.mitre_bend(0.1), "ground_truth", drive_jam_rate=rate)
    plant.reset(np.random.default_rng(seed))
    dec, out = plant.advance()
    return plant, dec, out


def test_a_stalled_drive_costs_the_jam_and_the_robot_still_decides() -> None:
    calm, dec0, out0 = _advance(0.0)
    stalled, dec1, out1 = _advance(1.0)
    assert out0.status == PlantStatus.DONE and out1.status == PlantStatus.JAMMED
    assert "jammed while driving" in out1.note
    assert out1.sim_time == pytest.approx(out0.sim_time + stalled.jam_time)
    # the robot decides where the drive ended, on the same ways
    assert dec1 is not None and dec0 is not None
    assert [o.kind for o in dec1.options] == [o.kind for o in dec0.options]
    assert stalled.travelled == pytest.approx(calm.travelled)


def test_drive_jams_come_at_their_rate() -> None:
    rate = 0.25
    jams = sum(_advance(rate, seed)[2].status == PlantStatus.JAMMED for seed in range(400))
    # binomial(400, 0.25): mean 100, sd 8.7
    assert 65 <= jams <= 135
    assert 0.0 <= DRIVE_JAM_RATE <= 0.1


@pytest.mark.parametrize("rate", [-0.1, 1.5, float("nan"), "often"])
def test_a_bad_rate_is_refused_naming_the_field(rate: object) -> None:
    with pytest.raises((ArgumentError, ValueError, TypeError), match="drive_jam_rate"):
        KinematicPlant(layouts.mitre_bend(0.1), drive_jam_rate=rate)  # type: ignore[arg-type]


def test_the_env_counts_a_modelled_drive_jam() -> None:
    env = gym.make("pipenav/PipeNav-v0", network_config={"n_fittings": 6}, auto_single=False)
    base = env.unwrapped
    obs, info = env.reset(seed=3)
    base.plant.drive_jam_rate = 1.0  # every drive to a structure from now on stalls
    agent = RoutePlanner(env)
    for _ in range(10):
        obs, _, term, trunc, info = env.step(agent.act(obs, info))
        if base.outcome_log.drive_jams or term or trunc:
            break
    assert base.outcome_log.drive_jams >= 1
    assert info["jams"] >= base.outcome_log.drive_jams
