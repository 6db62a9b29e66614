"""The packaged autonomy scenario suite as tests (``pytest -m scenarios``)."""

from __future__ import annotations

import pytest

from agents.scenarios import discover, run_scenario

CASES = [
    pytest.param(
        sc,
        seed,
        id=f"{sc.name}[seed={seed}]",
        marks=[pytest.mark.xfail(reason=sc.known_failure, strict=True)] if sc.known_failure else [],
    )
    for sc in discover()
    for seed in sc.seeds
]


@pytest.mark.scenarios
@pytest.mark.parametrize(("scenario", "seed"), CASES)
def test_scenario(scenario, seed: int) -> None:
    result = run_scenario(scenario, seed)
    assert result.passed, "; ".join(c.message for c in result.failures) + (
        f" (replay: {result.replay_command()})"
    )
