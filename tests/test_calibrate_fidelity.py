"""The fidelity calibration: its statistics on synthetic inputs, the outcome log both fidelities
fill, and the script end to end (slow: it runs the full fidelity)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import pipe_env  # noqa: F401  (registers the environment ids)
from benchmarks import calibrate_fidelity as cf
from detector.options import StructureOption
from pipe_env.envs.outcome_log import (
    BACK_OUT_CLASS,
    PHANTOM_CLASS,
    OutcomeLog,
    angle_class,
    attempted_way,
    sensed_structure,
    turn_direction,
)

# ------------------------------------------------------------------ the statistics


def test_fisher_p_matches_the_tea_tasting_table() -> None:
    # Fisher's lady tasting tea: 3 of 4 right against 1 of 4; two-sided p = 34/70
    assert cf.fisher_p(3, 4, 1, 4) == pytest.approx(34 / 70)


def test_a_large_rate_difference_is_flagged_and_a_small_one_is_not() -> None:
    big = cf.rate_comparison("s", "jams/attempt", "bend", 0, 50, 25, 50)
    assert big.significant and big.p < 1e-6
    assert big.fast == 0.0 and big.full == 0.5 and big.difference == 0.5
    small = cf.rate_comparison("s", "jams/attempt", "bend", 10, 50, 11, 50)
    assert not small.significant and small.p > 0.5


def test_a_side_without_trials_is_not_tested() -> None:
    c = cf.rate_comparison("s", "jams/attempt", "back out", 0, 3, 0, 0)
    assert math.isnan(c.p) and math.isnan(c.full) and not c.significant


def test_a_rate_with_more_events_than_trials_is_refused() -> None:
    with pytest.raises(ValueError, match="k_full = 5, n_full = 4"):
        cf.rate_comparison("s", "x", "g", 0, 4, 5, 4)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 40).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))),
    st.integers(1, 40).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))),
)
def test_fisher_p_is_a_symmetric_probability(a: tuple[int, int], b: tuple[int, int]) -> None:
    p = cf.fisher_p(a[0], a[1], b[0], b[1])
    assert 0.0 <= p <= 1.0 + 1e-12
    assert p == pytest.approx(cf.fisher_p(b[0], b[1], a[0], a[1]))
    if a[0] * b[1] == b[0] * a[1]:  # equal rates
        assert p > 0.999


def test_ks_flags_shifted_errors_and_not_the_same_ones() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(0.0, 1.0, 200)
    same = cf.distribution_comparison("s", "distance error", "g", a, a.copy(), "mm")
    assert same.p == pytest.approx(1.0) and not same.significant and same.difference == 0.0
    moved = cf.distribution_comparison("s", "distance error", "g", a, a + 3.0, "mm")
    assert moved.significant and moved.p < 1e-10
    assert moved.difference == pytest.approx(3.0)


def test_counts_are_summarised_by_their_mean() -> None:
    c = cf.distribution_comparison(
        "s", "jams/episode", "g", [0, 0, 1], [0, 0, 3], "n", centre="mean"
    )
    assert (c.fast, c.full, c.difference) == pytest.approx((1 / 3, 1.0, 2 / 3))
    assert c.test == "mann-whitney" and not c.significant
    # a quarter of the episodes with a jam against none: flagged; the same counts: not
    none, some = [0] * 80, [0, 0, 0, 1] * 20
    jams = cf.distribution_comparison("s", "jams", "g", none, some, "n", centre="mean")
    assert jams.significant and jams.p < 1e-4
    same = cf.distribution_comparison("s", "jams", "g", none, none, "n", centre="mean")
    assert same.p == 1.0 and not same.significant
    with pytest.raises(ValueError, match="centre = 'mode'"):
        cf.distribution_comparison("s", "x", "g", [1], [1], "n", centre="mode")


def test_holm_keeps_only_the_flags_that_survive_the_step_down() -> None:
    def comp(p: float) -> cf.Comparison:
        return cf.Comparison(
            "s", "x", "g", "rate", 0, 0, 0, 1, 1, "fisher", p, significant=p < 0.05
        )

    all_pass = [comp(0.01), comp(0.02), comp(0.04)]  # 0.01 < .05/3, .02 < .05/2, .04 < .05
    cf.holm_correct(all_pass)
    assert [c.holm for c in all_pass] == [True, True, True]
    stops = [comp(0.04), comp(0.01), comp(0.03), comp(math.nan)]  # .03 >= .05/2: stop there
    cf.holm_correct(stops)
    assert [c.holm for c in stops] == [False, True, False, False]


def _episode(fidelity: str, attempts: list[tuple[str, str, str, str]], sensed: int) -> dict:
    """A synthetic episode: attempts (kind, way, side, status) and ``sensed`` clean bends."""
    return {
        "fidelity": fidelity,
        "success": True,
        "decisions": len(attempts),
        "jams": sum(a[3] == "jammed" for a in attempts),
        "structures": sensed,
        "outcomes": {
            "attempts": [
                {"true_kind": k, "way": w, "side": s, "status": st_, "auto": False}
                for k, w, s, st_ in attempts
            ],
            "sensed": [
                {
                    "true_kind": "bend",
                    "kind": "bend",
                    "n_true": 1,
                    "n_sensed": 1,
                    "missed": 0,
                    "phantoms": 0,
                    "errors": {"distance": 0.001 * (i % 5), "angle": 0.01},
                }
                for i in range(sensed)
            ],
        },
    }


def test_compare_flags_exactly_the_statistic_that_differs() -> None:
    square = ("bend", "square (80-100 deg)", "up", "done")
    shallow = ("bend", "shallow (10-50 deg)", "left", "done")
    straight = ("junction", "straight", "none", "done")
    fast = [_episode("fast", [square, shallow, straight] * 4, 12) for _ in range(4)]
    jam = ("bend", "square (80-100 deg)", "up", "jammed")
    full = [_episode("full", [jam, shallow, straight] * 4, 12) for _ in range(4)]
    rows = cf.compare(fast + full)
    flagged = {(c.section, c.group) for c in rows if c.significant}
    assert ("jams per attempt by way (deflection)", "square (80-100 deg)") in flagged
    assert ("jams per attempt by way (turn side)", "up") in flagged
    assert ("jams per attempt by structure kind", "bend") in flagged
    assert not any(g in ("straight", "shallow (10-50 deg)", "left", "junction") for _, g in flagged)
    square_row = next(c for c in rows if c.group == "square (80-100 deg)")
    assert (square_row.k_fast, square_row.n_fast, square_row.k_full, square_row.n_full) == (
        0,
        16,
        16,
        16,
    )
    text = cf.markdown(rows, "header", 0.05)
    for section in cf.SECTIONS:
        assert f"**{section}**" in text
    assert "differs" in text


# ------------------------------------------------------------------ the outcome log


def _opt(angle_deg: float, direction_deg: float, kind: str = "bend") -> StructureOption:
    return StructureOption(
        kind=kind,
        distance=0.2,
        diameter=0.1,
        direction=math.radians(direction_deg),
        angle=math.radians(angle_deg),
    )


def test_way_classes() -> None:
    assert angle_class(0.0) == "straight"
    assert angle_class(math.radians(45)) == "shallow (10-50 deg)"
    assert angle_class(math.radians(90)) == "square (80-100 deg)"
    assert [turn_direction(_opt(90, d)) for d in (0, 90, 180, -90, 265)] == [
        "left",
        "up",
        "right",
        "down",
        "down",
    ]
    assert turn_direction(_opt(5, 90)) == "none"


def test_missed_and_phantom_ways_are_counted_against_the_truth() -> None:
    truth = [_opt(0, 0, "junction"), _opt(90, 0, "junction"), _opt(90, 180, "junction")]
    sensed = [_opt(2, 0, "junction"), _opt(88, 5, "junction"), _opt(90, 90, "junction")]
    rec = sensed_structure(sensed, "junction", truth)
    assert (rec.n_true, rec.n_sensed, rec.missed, rec.phantoms) == (3, 3, 1, 1)
    assert not rec.misclassified
    assert sensed_structure([], "straight", truth).missed == 3
    assert sensed_structure(sensed[:1], "bend", truth).misclassified
    assert attempted_way(sensed[1], truth) == ("square (80-100 deg)", "left")
    assert attempted_way(sensed[2], truth) == (PHANTOM_CLASS, "none")
    assert attempted_way("back_out", truth) == (BACK_OUT_CLASS, "none")


def test_the_fast_env_logs_every_sensed_structure_and_attempt() -> None:
    env = gym.make("pipenav/PipeNav-v0", network_config={"n_fittings": 8}, max_jams=5)
    base: Any = env.unwrapped
    rng = np.random.default_rng(0)
    for seed in range(6):
        _, info = env.reset(seed=seed)
        auto = info.get("auto_structures", 0)
        done = False
        while not done:
            action = int(rng.choice(np.flatnonzero(info["action_mask"])))
            _, _, term, trunc, info = env.step(action)
            auto += info.get("auto_structures", 0)
            done = term or trunc
        log: OutcomeLog = base.outcome_log
        assert len(log.attempts) == info["decisions"] + auto
        assert len(log.sensed) >= info["structures"]
        assert sum(a.jammed for a in log.attempts) + log.drive_jams == info["jams"]
        assert sum(a.auto for a in log.attempts) == auto
        json.dumps(log.to_dict())
    env.close()


# ------------------------------------------------------------------ the script


def test_the_fast_fidelity_agrees_with_itself_on_other_seeds() -> None:
    """Fast against fast with other seeds: nothing survives the Holm correction (a check that
    the tests do not flag noise as disagreement)."""
    config = dict(cf.NETWORK_CONFIG)
    plan = [("fast", i, 1000 + i + 97 * k) for k in range(3) for i in range(6)]
    plan += [("full", i, 5000 + i) for i in range(6)]  # labelled full, run in fast
    episodes = [cf.run_episode("fast", i, seed, config) for _, i, seed in plan]
    for e, (label, _, _) in zip(episodes, plan, strict=True):
        e["fidelity"] = label
    rows = cf.compare(episodes)
    assert rows and not any(c.holm for c in rows)
    assert any(c.n_full > 0 for c in rows if c.section == cf.SECTIONS[4])


@pytest.mark.slow
def test_the_script_runs_both_fidelities_and_prints_the_tables(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "calib.json"
    figures = cf.main(["--networks", "1", "--fast-repeats", "2", "--json", str(out)])
    text = capsys.readouterr().out
    for section in cf.SECTIONS:
        assert f"**{section}**" in text
    assert "full network 0:" in text and "tests flag a disagreement" in text
    doc = json.loads(out.read_text())
    assert doc["figures"]["networks"] == 1
    fidelities = [e["fidelity"] for e in doc["episodes"]]
    assert fidelities.count("full") == 1 and fidelities.count("fast") == 2
    full = next(e for e in doc["episodes"] if e["fidelity"] == "full")
    assert full["outcomes"]["sensed"], "the full loop logs what it sensed"
    attempt_jams = sum(a["status"] == "jammed" for a in full["outcomes"]["attempts"])
    assert attempt_jams + full["outcomes"]["drive_jams"] == full["jams"]
    stats = {(c["section"], c["statistic"]) for c in figures["comparisons"]}
    assert ("episode outcomes", "success") in stats
    assert ("sensing at the decision point", "distance error") in stats
