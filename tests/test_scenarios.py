"""The packaged autonomy scenario suite as tests (``pytest -m scenarios``)."""

from __future__ import annotations

import pytest

from agents.scenarios import discover, run_scenario

CASES = [(sc, seed) for sc in discover() for seed in sc.seeds]


@pytest.mark.scenarios
@pytest.mark.parametrize(
    ("scenario", "seed"), CASES, ids=[f"{sc.name}[seed={seed}]" for sc, seed in CASES]
)
def test_scenario(scenario, seed: int) -> None:
    result = run_scenario(scenario, seed)
    assert result.passed, "; ".join(c.message for c in result.failures) + (
        f" (replay: {result.replay_command()})"
    )
