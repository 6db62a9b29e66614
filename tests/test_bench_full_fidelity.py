"""The equivalence benchmark's statistics (the figures, not the simulation)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_full_fidelity.py"
_spec = importlib.util.spec_from_file_location("bench_full_fidelity", _PATH)
assert _spec is not None and _spec.loader is not None
bench = importlib.util.module_from_spec(_spec)
sys.modules["bench_full_fidelity"] = bench
_spec.loader.exec_module(bench)


def _episode(success: bool, jams: int, dist: float, x: float) -> dict:
    return {
        "success": success,
        "jams": jams,
        "decisions": 2,
        "reset_s": 1.0,
        "steps_s": 1.0,
        "errors": [{"distance": dist, "angle": 0.01, "direction": 0.02}],
        "first_pose": {"position": [x, 0.0, 0.0], "forward": [1.0, 0.0, 0.0]},
        "physics_ticks": 100,
        "kinematic_ticks": 10,
    }


def test_mcnemar_counts_only_discordant_pairs() -> None:
    assert bench.mcnemar_exact([True] * 10, [True] * 10) == 1.0
    # 8 episodes only one mode succeeded in, all the same way: a real difference
    assert bench.mcnemar_exact([True] * 8 + [False] * 2, [False] * 8 + [False] * 2) < 0.01
    # balanced discordance: none
    assert bench.mcnemar_exact([True, False] * 5, [False, True] * 5) == pytest.approx(1.0)


def test_summary_reports_both_modes_the_ratio_and_the_pose_difference() -> None:
    results = {
        "contact": [_episode(True, 0, 0.001, 0.0) for _ in range(6)],
        "everywhere": [_episode(True, 0, 0.001, 0.002) for _ in range(6)],
    }
    results["everywhere"][0]["steps_s"] = 3.0  # the reference is slower
    figures, text = bench.summarise(results)
    assert figures["speed_ratio"] > 1.0
    assert figures["first_pose"]["median_mm"] == pytest.approx(2.0)
    assert figures["tests"]["success_mcnemar_p"] == 1.0
    assert "| contact |" in text and "| everywhere |" in text and "McNemar" in text


def test_the_tick_profile_times_mj_step_and_restores_the_executor() -> None:
    from pipe_env import layouts
    from pipe_env.world import NearContacts
    from primitives.executor import Executor
    from primitives.sequences import go_straight

    methods = (Executor.run, Executor.place, Executor._scan, NearContacts.update)
    clock = bench._Clock()
    with bench._instrumented(clock):
        ex = Executor.for_network(layouts.straight(0.1), lidar=None)
        ticks = ex.physics_ticks
        ex.run(go_straight(0.05))
    assert clock.steps == ex.physics_ticks > ticks > 0
    assert clock.updates >= ex.physics_ticks
    assert 0.0 < clock.step_s < clock.executor_s
    assert (Executor.run, Executor.place, Executor._scan, NearContacts.update) == methods
    import primitives.executor as executor_module

    assert executor_module.mujoco is bench.mujoco


def test_the_phase_profile_counts_every_physics_tick_and_restores_the_executor() -> None:
    from pipe_env import layouts
    from primitives.executor import Executor
    from primitives.sequences import Sequence
    from primitives.steps import Centre, Clamp, Drive, Unclamp

    methods = (Executor._physics, Executor._settle, Executor._clamp, Executor.run)
    counter = bench.PhaseCounter()
    with bench._phased(counter):
        ex = Executor.for_network(layouts.straight(0.09, 1.0), lidar=None)
        ticks = ex.physics_ticks
        ex.run(Sequence("probe", (Unclamp(), Drive(0.02), Centre(), Clamp(0.09))))
    assert sum(counter.by_phase.values()) == ex.physics_ticks
    assert counter.by_phase["place (reset)"] == ticks > 0
    for phase in ("unclamp", "drive: straight unclamped", "centre: probes", "clamp: settle"):
        assert counter.by_phase.get(phase, 0) > 0, (phase, counter.by_phase)
    assert counter.by_sequence["probe"] == ex.physics_ticks - ticks
    assert (Executor._physics, Executor._settle, Executor._clamp, Executor.run) == methods
    profile = {
        "physics": "contact",
        "episodes": 1,
        "decisions": 1,
        "success": 1,
        "jams": 0,
        "steps_s": 1.0,
        "reset_s": 1.0,
        "kinematic_ticks": 0,
        "by_phase": counter.by_phase,
        "by_sequence": counter.by_sequence,
    }
    text = bench.phase_table(profile)
    assert "| centre: probes |" in text and "(resets)" in text and "| total (steps) |" in text
    empty = dict(profile, episodes=0, decisions=0, steps_s=0.0, reset_s=0.0)
    with pytest.raises(ValueError, match=r"phase_table: profile\['steps_s'\] = 0.0: no episode"):
        bench.phase_table(empty)
