"""A seeded full-fidelity run's outcome and decision log, pinned by its recorded values.

The executor's state (drive command, clamping V, driven path, telemetry) and the plant's sensing
(the sweep callback with a detector source) were taken apart into named parts; the run below
(the MuJoCo robot sensing a tee, taking its branch and driving to a goal beyond it) must give
the same decisions, detection log, motion and clock as before. They were recorded on the code
before the split, first as digests with floats rounded to 9 decimals; now as values
(``tests/data/full_fidelity_records.json``, compared as :mod:`recorded` says: strings, flags
and counts exactly, floats to 10 micrometres), since another machine's arithmetic moved the
physics beyond the 9th decimal with every decision, count and tick the same. Regenerate (only
for an intended change of behaviour, saying so in the commit) by running this file as a
script.

The digests were recorded again when the plant's default time compression became 1.5
(``pipe_env.envs.plant_full.TIME_COMPRESSION``: drives, rolls, the V and centring run 1.5 times
as fast in physics, the clock keeps the nominal speeds), after confirming that every run's outcome
is unchanged: each seeded run reaches its goal with the same options and statuses, the episode
takes the same eight actions with the same termination, success and jams; poses, clocks and
rewards differ in the last millimetres and seconds (the thesis run's confirmation sweeps add
22 s to its clock), and the physics ticks fall (the episode's from 16115 to 11466).

Recorded again when straight drives leaving the free run began to glide up to its end
(``primitives.executor.KINEMATIC_SPLIT``, unclamped robots too) and straightening the V was
compressed further (``RELEASE_COMPRESSION``), after confirming the outcomes are unchanged: each
seeded run decides with the same options (the thesis run's bend angle 1.415 -> 1.428 rad) and
statuses and the same number of sweeps; the episode takes the same eight actions with the same
termination, success and jams; poses differ by about a millimetre, and the physics ticks fall
(the runs' from 903-913 to 816-825, the episode's from 11466 to 11125).

Recorded again when a centring probe began to settle the robot before folding a straight V
(``primitives.executor.Executor._probe``), after confirming the outcomes are unchanged: each
seeded run decides with the same options and statuses, the same sweeps and end position (to
0.1 mm); the episode takes the same eight actions, rewards, termination, success and jams; only
the probes' settle ticks are added (the runs' 816-825 -> 832-841 physics ticks, the episode's
11125 -> 11243) and the clocks with them (0.3 s per run, 2.3 s in the episode).

The episode was recorded again when the improved detector began to measure the wall radius
about a pose a few tenths of a degree off (``detector.axis_fit.measure_wall_radius``: the
first harmonic of the wall's scatter left out), after confirming the outcome is unchanged: the
same eight actions, termination, success and jams, the same 91 sweeps; the options read differ
by a millimetre or less (a junction's diameter 1.9 mm off is now exact, a reducer's far
reading 0.5 mm off instead of 0.15), one far bend reading 3.5 deg short instead of 0.9, and
the clock by 9 s (fewer rescans).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from recorded import mismatches

from pipe_env import layouts
from pipe_env.envs.plant_full import PhysicalPlant
from pipe_env.network_io import plain
from pipe_env.routing import EdgePosition, edge_length

#: The recorded runs: ``run/<detector>`` of :func:`seeded_run`, ``episode`` of
#: :func:`seeded_episode`.
RECORDS = Path(__file__).parent / "data" / "full_fidelity_records.json"
DETECTORS = ("ground_truth", "improved", "thesis")


def as_recorded(record: dict[str, object]) -> object:
    """``record`` in the recorded file's types (enums and other objects by their repr)."""
    return json.loads(json.dumps(plain(record), default=repr))


def _recorded(name: str) -> object:
    return json.loads(RECORDS.read_text())[name]


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


@pytest.mark.slow
def test_a_seeded_environment_episode_is_as_before_the_split() -> None:
    assert mismatches(as_recorded(seeded_episode()), _recorded("episode")) == []


@pytest.mark.parametrize("detector", DETECTORS)
def test_a_seeded_run_is_as_before_the_split(detector: str) -> None:
    record = seeded_run(detector)
    assert record["execute"][0] == "goal"
    assert mismatches(as_recorded(record), _recorded(f"run/{detector}")) == []


if __name__ == "__main__":
    runs = {f"run/{d}": as_recorded(seeded_run(d)) for d in DETECTORS}
    RECORDS.write_text(
        json.dumps({**runs, "episode": as_recorded(seeded_episode())}, indent=1, sort_keys=True)
        + "\n"
    )
    print(f"wrote {RECORDS}")
