"""The accuracy study's own geometry: whether a long bend's scan reaches the end of its arc."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest
from detector_scans import scan_layout

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_detection.py"
_spec = importlib.util.spec_from_file_location("bench_detection", _PATH)
bench = importlib.util.module_from_spec(_spec)
sys.modules["bench_detection"] = bench  # (its dataclasses look their module up)
_spec.loader.exec_module(bench)


@pytest.mark.parametrize(
    ("distance", "params", "seen"),
    [
        # a gentle 47 deg bend of 57 mm: its whole arc is in view from 40 cm
        (
            0.4,
            {"diameter": 0.057, "angle": 0.8147, "direction": 2.7253, "radius_factor": 1.8903},
            True,
        ),
        # a 74 deg, 3 D bend of 75 mm: from 40 cm the beams reach 53 deg into its arc
        (
            0.4,
            {"diameter": 0.075, "angle": 1.2981, "direction": 1.7289, "radius_factor": 2.9862},
            False,
        ),
        # the same bend from 17.5 cm, where its arc starts: now the returns reach its end
        (
            0.175,
            {"diameter": 0.075, "angle": 1.2981, "direction": 1.7289, "radius_factor": 2.9862},
            True,
        ),
    ],
)
def test_long_bend_arc_end_seen(distance: float, params: dict, seen: bool) -> None:
    scan, _, d = scan_layout("long_bend", distance, **params)
    case = bench.Case("long bend", "long_bend", params, d)
    assert bench.arc_end_seen(case, distance, scan) is seen


def test_other_layouts_have_no_arc() -> None:
    scan, _, d = scan_layout("closure", 0.3, diameter=0.1)
    assert (
        bench.arc_end_seen(bench.Case("closure", "closure", {"diameter": 0.1}, d), 0.3, scan)
        is None
    )


def test_thesis_bend_row_is_the_same_case_for_every_sensor(monkeypatch, tmp_path) -> None:
    # the tables compare one geometry across sensors; the 31-position approach of figure 5.2
    # runs apart from them (its records in no table)
    calls: list[tuple[str, str, float, int, bool]] = []

    def run_case(self, case, sensor, distances, table, misalignment=None, keep=False, rng=None):
        direction = case.params.get("direction")
        calls.append((case.group, sensor, direction, len(distances), keep))
        for method in bench.METHODS:
            self.timings[method].append(0.001)
        return []

    monkeypatch.setattr(bench.Runner, "run_case", run_case)
    monkeypatch.setattr(bench, "planar_study", lambda rng, distances: ("", []))
    monkeypatch.setattr(bench, "misalignment_study", lambda *a, **k: ("", []))
    monkeypatch.setattr(bench, "clamp_error_study", lambda *a, **k: "")
    monkeypatch.setattr(bench, "straight_false_alarms", lambda *a, **k: "")
    monkeypatch.setattr(bench, "long_bend_study", lambda *a, **k: "")
    monkeypatch.setattr(bench, "plots", lambda *a, **k: [])
    monkeypatch.setattr(bench, "overall_table", lambda *a, **k: "")
    monkeypatch.setattr(bench, "summarise", lambda *a, **k: "")
    bench.main(["--out", str(tmp_path)])
    group = "thesis: mitre bend 90 deg"
    rows = [c for c in calls if c[0] == group and not c[4]]
    assert sorted(c[1] for c in rows) == ["ideal", "ls02", "ydlidar_x4"]
    assert all(c[2] == pytest.approx(math.radians(136)) and c[3] == 13 for c in rows), rows
    (sweep,) = [c for c in calls if c[0] == group and c[4]]
    assert sweep[1:4] == ("ideal", pytest.approx(math.pi), 31)


def test_filters_parse_and_reject_unknown_names() -> None:
    args = bench.parse_args(["--kinds", "reducer", "--sensors", "ls02", "--parts", "accuracy"])
    assert args.kinds == ["reducer"]
    assert args.sensors == ["ls02"]
    assert args.parts == {"accuracy"}
    full = bench.parse_args([])
    assert full.kinds == [] and full.sensors == list(bench.SENSORS)
    assert full.parts == set(bench.PARTS)
    for bad in (["--sensors", "lidar9"], ["--parts", "speedy"], ["--sensors", ""]):
        with pytest.raises(SystemExit):
            bench.parse_args(bad)
    # (the docs take full runs only)
    with pytest.raises(SystemExit):
        bench.parse_args(["--write-docs", "--kinds", "reducer"])
