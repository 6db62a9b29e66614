"""The episode tracer of benchmarks/trace_episode.py: one traced fast-fidelity episode."""

from __future__ import annotations

import math

from benchmarks.bench_transfer import NETWORK_CONFIG
from benchmarks.trace_episode import option_text, trace_episode
from detector.options import StructureOption


def test_option_text_units() -> None:
    o = StructureOption(
        "junction", 0.2, 0.078, angle=math.radians(45.0), direction=math.radians(180.0)
    )
    assert option_text(o) == "junction:d=0.20,D=78,a=45,r=180"
    assert option_text(o.to_dict()) == option_text(o)


def test_trace_lists_every_decision_with_truth_and_detection() -> None:
    emitted: list[str] = []
    final = trace_episode(
        "route_planner", "fast", 64, dict(NETWORK_CONFIG), sweeps=True, emit=emitted.append
    )
    lines = final["trace"]
    assert emitted == lines
    decisions = [line for line in lines if line.startswith("decision ")]
    assert len(decisions) == final["decisions"] > 0
    assert sum(line.lstrip().startswith("truth ") for line in lines) == final["decisions"]
    assert sum(line.lstrip().startswith("detected ") for line in lines) == final["decisions"]
    assert any(line.lstrip().startswith("sweep ") for line in lines)
    assert any(line.lstrip().startswith("attempt ") for line in lines)
    assert lines[-1] == (
        f"end: success {final['is_success']}, jams {final['jams']}, decisions {final['decisions']}"
    )
