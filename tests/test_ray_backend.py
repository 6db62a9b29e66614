"""Scaling out: the Ray backend gives the same results as the local process pool, seed by seed."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from agents.scenario_runner import run_tasks, tasks_of
from agents.scenarios import load_scenario

ray = pytest.importorskip("ray")

GENERATED = {
    "generator": {"n_fittings": 8, "planar": False, "allow_loops": True},
    "seed": 11,
}


@pytest.mark.slow
def test_ray_and_local_backends_agree_seed_by_seed(tmp_path: Path) -> None:
    data = {
        "network": GENERATED,
        "fidelity": "fast",
        "detector": "improved",
        "agent": "goal_greedy",
        "seeds": [0, 1, 2],
        "max_decisions": 12,
        "criteria": {"success": True},
    }
    (tmp_path / "generated.yaml").write_text(yaml.safe_dump(data))
    tasks = tasks_of([load_scenario(tmp_path / "generated.yaml")])
    local = run_tasks(tasks, jobs=2, backend="local")
    on_ray = run_tasks(tasks, jobs=2, backend="ray")
    assert [r.seed for r in on_ray] == [0, 1, 2]
    for a, b in zip(local, on_ray):
        assert a.error is None and b.error is None, (a.error, b.error)
        assert a.passed == b.passed
        assert a.metrics == b.metrics
