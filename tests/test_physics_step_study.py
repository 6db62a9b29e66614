"""The physics step and control period: settable per world and executor, in SI units, and the
study that chose them (``benchmarks/physics_step_study.py``)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from typing import Any

import pytest

from detector.validation import ArgumentError
from pipe_env import layouts
from pipe_env.world import TIMESTEP, build_world
from primitives.executor import CONTROL_DT, NEAR_INTERVAL, TRACKING_DELAY, Executor
from primitives.sequences import Sequence
from primitives.steps import Drive, Stop, Unclamp

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "physics_step_study.py"
_spec = importlib.util.spec_from_file_location("physics_step_study", _PATH)
assert _spec is not None and _spec.loader is not None
study = importlib.util.module_from_spec(_spec)
sys.modules["physics_step_study"] = study
_spec.loader.exec_module(study)


def test_the_defaults_are_a_whole_number_of_physics_steps() -> None:
    n = CONTROL_DT / TIMESTEP
    assert n == pytest.approx(round(n), abs=1e-9) and round(n) >= 1


@pytest.mark.parametrize("value", [0.0, -0.02, 0.5, math.nan, "0.02", True])
def test_a_bad_control_period_names_the_field(value: object) -> None:
    net = layouts.straight(0.09, 1.0)
    with pytest.raises(ArgumentError, match="control_dt"):
        Executor.for_network(net, lidar=None, control_dt=value)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [0.0, 0.05, math.inf])
def test_a_bad_physics_step_names_the_field(value: float) -> None:
    with pytest.raises(ArgumentError, match="timestep"):
        build_world(layouts.straight(0.09, 1.0), timestep=value)


def test_the_control_period_is_rounded_to_whole_physics_steps() -> None:
    net = layouts.straight(0.09, 1.0)
    ex = Executor.for_network(net, lidar=None, timestep=0.003, control_dt=0.02)
    assert ex.model.opt.timestep == pytest.approx(0.003)
    assert ex.substeps == 7 and ex.control_dt == pytest.approx(0.021)


def test_speeds_and_durations_keep_their_meaning_at_a_longer_control_period() -> None:
    # a 5 cm drive at 5 cm/s and a 0.2 s stop: the same distance and (to a tick) the same
    # simulated time at two control periods, in fewer ticks at the longer one
    runs = {}
    for period in (0.02, 0.04):
        ex = Executor.for_network(
            layouts.straight(0.09, 1.0), lidar=None, timestep=0.002, control_dt=period
        )
        x0 = ex.robot.sensor_pose().position[0]
        ticks0 = ex.physics_ticks
        out = ex.run(Sequence("s", (Drive(0.05, 0.05), Stop(0.2))))
        assert out.status == "done", out.reason
        runs[period] = (
            ex.robot.sensor_pose().position[0] - x0,
            out.duration,
            ex.physics_ticks - ticks0,
        )
    (d1, t1, n1), (d2, t2, n2) = runs[0.02], runs[0.04]
    assert d2 == pytest.approx(d1, abs=0.001)
    assert t2 == pytest.approx(t1, abs=0.041)
    assert n2 < 0.6 * n1


def test_the_grid_rounds_periods_and_puts_the_reference_first() -> None:
    pts = study.grid([0.002, 0.003, 0.008], [0.02, 0.1])
    assert (pts[0].timestep, pts[0].period) == study.REFERENCE
    labels = [p.label() for p in pts]
    assert labels == ["2/20", "2/100", "3/21", "3/99", "8/16", "8/96"]


def _result(ts: float, cp: float, ok: bool, episodes: bool = False) -> Any:
    r = study.Result(study.Point(ts, cp))
    r.checks["case"] = ok
    if episodes:
        r.episodes = [{"success": True}]
        r.checks["episodes"] = ok
    return r


def test_a_point_is_adopted_only_with_one_grid_step_of_margin_in_the_step() -> None:
    ts, cp = [0.002, 0.003, 0.004], [0.02, 0.04, 0.06]
    ok = {(0.002, 0.02), (0.002, 0.04), (0.002, 0.06), (0.003, 0.02), (0.003, 0.04)}
    ok |= {(0.004, 0.02)}
    results = [_result(t, c, (t, c) in ok, episodes=True) for t in ts for c in cp]
    # 2/60's larger step (3/60) fails, 3/40's (4/40) too, 4 ms has no larger step; of 2/20,
    # 3/21 and 2/40 (larger step passing) the longest period wins
    chosen = study.adopt(results, ts)
    assert chosen is not None and chosen.point.label() == "2/40"
    # with its episodes failing, the next longest
    for r in results:
        if r.point.label() == "2/40":
            r.checks["episodes"] = False
    chosen = study.adopt(results, ts)
    assert chosen is not None and chosen.point.label() == "3/21"


def test_the_near_contact_check_counts_overruns() -> None:
    ex = Executor.for_network(layouts.straight(0.09, 1.0), lidar=None, control_dt=0.02)
    assert ex.near is not None
    ok, note = study.near_contact_check([ex])
    assert ok and note.startswith("overruns 0")
    ex.near.overruns = 2
    ok, note = study.near_contact_check([ex])
    assert not ok and note.startswith("overruns 2")


@pytest.mark.slow
def test_the_quick_study_runs_and_its_reference_passes(capsys: pytest.CaptureFixture) -> None:
    assert study.main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "Checks per grid point" in out and "| 2/20 | pass |" in out


# ---------------------------------------------------------------- time compression
@pytest.mark.parametrize("value", [0.5, 0.0, 9.0, math.nan, "2"])
def test_a_bad_time_compression_names_the_field(value: object) -> None:
    net = layouts.straight(0.09, 1.0)
    with pytest.raises(ArgumentError, match="time_compression"):
        Executor.for_network(net, lidar=None, time_compression=value)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("k", "period", "chunks"),
    [
        (1.0, 0.02, (10,)),
        (1.5, 0.02, (5, 5)),
        (2.0, 0.02, (5, 5)),
        (3.0, 0.02, (4, 3, 3)),
        (4.0, 0.02, (3, 3, 2, 2)),
        (1.0, 0.04, (10, 10)),
        (1.0, 0.06, (10, 10, 10)),
        (1.5, 0.04, (7, 7, 6)),
    ],
)
def test_near_contacts_are_selected_as_often_per_metre_moved(
    k: float, period: float, chunks: tuple[int, ...]
) -> None:
    ex = Executor.for_network(
        layouts.straight(0.09, 1.0), lidar=None, time_compression=k, control_dt=period
    )
    assert ex.near_steps == chunks and sum(chunks) == ex.substeps
    # the robot moves no further between two selections than in NEAR_INTERVAL uncompressed
    assert max(chunks) * ex.model.opt.timestep * k <= NEAR_INTERVAL + 1e-9


def test_a_compressed_drive_keeps_the_nominal_clock_in_fewer_physics_ticks() -> None:
    # a 10 cm drive at 5 cm/s and a 0.2 s stop: the same distance and (to a tick) the same
    # clock compressed 2 times, in fewer physics ticks; the settling is not compressed
    runs = {}
    for k in (1.0, 2.0):
        ex = Executor.for_network(layouts.straight(0.09, 1.0), lidar=None, time_compression=k)
        x0 = ex.robot.sensor_pose().position[0]
        out = ex.run(Sequence("s", (Drive(0.1, 0.05), Stop(0.2))))
        assert out.status == "done", out.reason
        assert ex.jam_lag == ex.config.jam_lag  # (the allowance only while driving)
        runs[k] = (ex.robot.sensor_pose().position[0] - x0, out.duration, ex.physics_ticks)
    (d1, t1, n1), (d2, t2, n2) = runs[1.0], runs[2.0]
    assert d2 == pytest.approx(d1, abs=0.001)
    assert t2 == pytest.approx(t1, abs=0.021)
    assert 0.5 * n1 < n2 < 0.7 * n1  # 100 drive ticks become 50; 13 settling ticks stay


def test_a_compressed_stall_is_still_called_at_the_same_margin_over_the_free_lag() -> None:
    ex = Executor.for_network(layouts.straight(0.09, 1.0), lidar=None, time_compression=3.0)
    assert ex._speed_lag(0.05, 1.0) == 0.0
    assert ex._speed_lag(0.05, 3.0) == pytest.approx(2 * 0.05 * TRACKING_DELAY)
    # driven into a bore it cannot enter, the robot still stalls before its mouth
    net = layouts.reducer(0.1, 0.045, taper_length=0.1, distance=0.5)
    ex = Executor.for_network(net, lidar=None, time_compression=3.0)
    out = ex.run(Sequence("force_in", (Unclamp(), Drive(1.2))))
    assert out.status == "jammed" and "stalled" in out.reason
    mouth = float(net.geometry["s"].reference_point("r_out0")[0])
    assert ex.robot.front_pose().position[0] + 0.5 * ex.config.pitch < mouth


def test_the_grid_has_a_speedup_dimension_and_labels_it() -> None:
    pts = study.grid([0.002], [0.02], [1.0, 2.0, 4.0])
    assert [p.label() for p in pts] == ["2/20", "2/20 x2", "2/20 x4"]
    assert pts[1].args["time_compression"] == 2.0


def test_a_speedup_is_adopted_only_with_one_grid_step_of_margin_in_k() -> None:
    ks = [1.0, 1.5, 2.0, 3.0, 4.0]
    ok = {1.0, 1.5, 2.0, 3.0}
    results = []
    for k in ks:
        r = study.Result(study.Point(0.002, 0.02, k))
        r.checks["case"] = k in ok
        r.episodes = [{"success": True}]
        r.checks["episodes"] = k in ok
        results.append(r)
    # 3 passes but 4 (its larger k) fails: 2 is adopted
    chosen = study.adopt(results, [0.002], ks)
    assert chosen is not None and chosen.point.speedup == 2.0
