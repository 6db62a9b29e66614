"""The transfer benchmark: its statistics on known and synthetic inputs, that its episodes are
``pipenav eval``'s, and the script end to end on one network (slow: it runs the full fidelity)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import stats

from benchmarks import bench_transfer as bt

# ------------------------------------------------------------------ the statistics


def test_wilson_interval_matches_published_values() -> None:
    # Newcombe (1998), Table I: 0/10 -> [0, 0.2775]; 81/263 -> [0.2553, 0.3662]
    low, high = bt.wilson_interval(0, 10)
    assert low == 0.0 and high == pytest.approx(0.2775, abs=5e-5)
    low, high = bt.wilson_interval(81, 263)
    assert (low, high) == pytest.approx((0.2553, 0.3662), abs=5e-5)
    low, high = bt.wilson_interval(10, 10)
    assert low == pytest.approx(0.7225, abs=5e-5) and high == 1.0
    assert all(math.isnan(v) for v in bt.wilson_interval(0, 0))


@given(n=st.integers(1, 400), data=st.data())
def test_wilson_interval_agrees_with_scipy(n: int, data: st.DataObject) -> None:
    k = data.draw(st.integers(0, n))
    ref = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    low, high = bt.wilson_interval(k, n)
    assert low == pytest.approx(ref.low, abs=1e-9) and high == pytest.approx(ref.high, abs=1e-9)
    assert low <= k / n <= high


def test_wilson_interval_rejects_impossible_counts() -> None:
    with pytest.raises(ValueError, match="successes = 11"):
        bt.wilson_interval(11, 10)


def test_mcnemar_exact_uses_only_the_discordant_pairs() -> None:
    # 5 discordant pairs all one way: p = 2 * 0.5**5; concordant pairs change nothing
    a = [True] * 5 + [True] * 20 + [False] * 7
    b = [False] * 5 + [True] * 20 + [False] * 7
    assert bt.mcnemar_exact(a, b) == (5, 0, pytest.approx(0.0625))
    assert bt.mcnemar_exact(b, a) == (0, 5, pytest.approx(0.0625))
    # 6 against 1: p = 2 * (1 + 7) / 128
    a = [True] * 6 + [False] + [True] * 3
    b = [False] * 6 + [True] + [True] * 3
    assert bt.mcnemar_exact(a, b)[2] == pytest.approx(16 / 128)
    assert bt.mcnemar_exact([True, False], [True, False]) == (0, 0, 1.0)
    with pytest.raises(ValueError, match="len"):
        bt.mcnemar_exact([True], [True, False])


def _ep(agent: str, fidelity: str, network: int, success: bool, jams: int = 0) -> dict[str, Any]:
    return {
        "agent": agent,
        "fidelity": fidelity,
        "network": network,
        "seed": network,
        "success": success,
        "jams": jams,
        "decisions": 2 + jams,
        "sim_s": 10.0,
        "wall_s": 1.0 if fidelity == "fast" else 8.0 + network,
    }


def test_summary_gaps_fractions_and_tests_on_synthetic_outcomes() -> None:
    agents = ["route_planner", "policy.zip"]
    eps = []
    for n in range(20):
        eps.append(_ep("route_planner", "fast", n, True))
        eps.append(_ep("route_planner", "full", n, n < 16, jams=1 if n >= 16 else 0))  # 16/20
        eps.append(_ep("policy.zip", "fast", n, n < 19))  # 19/20
        eps.append(_ep("policy.zip", "full", n, n < 12))  # 12/20
    eps.append(_ep("route_planner", "fast", 99, False))  # incomplete network: ignored
    fig = bt.summarise(eps, agents)
    assert fig["n"] == 20 and fig["networks"] == list(range(20))
    rp, pol = fig["agents"]["route_planner"], fig["agents"]["policy.zip"]
    assert rp["fast"]["rate"] == 1.0 and rp["full"]["rate"] == 0.8
    assert rp["transfer"]["gap_points"] == pytest.approx(20.0)
    assert (rp["transfer"]["only_fast"], rp["transfer"]["only_full"]) == (4, 0)
    assert rp["transfer"]["mcnemar_p"] == pytest.approx(2 * 0.5**4)
    assert rp["full"]["jams_per_episode"] == pytest.approx(0.2)
    assert rp["full"]["ci95"] == pytest.approx(list(bt.wilson_interval(16, 20)))
    assert pol["transfer"]["gap_points"] == pytest.approx(35.0)
    assert rp["full"]["wall_s_median"] == pytest.approx(17.5)
    against = fig["against_reference"]["policy.zip"]
    assert against["fast"]["fraction"] == pytest.approx(0.95)
    assert against["fast"]["gap_points"] == pytest.approx(5.0)
    assert against["full"]["fraction"] == pytest.approx(12 / 16)
    assert (against["full"]["only_agent"], against["full"]["only_reference"]) == (0, 4)
    assert not against["fast"]["target_met"] and not against["full"]["target_met"]
    # the agents' full episodes differ on networks 12..15 (success) and 16..19 (jams)
    assert fig["identical"] == {"fast": 19, "full": 12}
    text = bt.markdown(fig, "header")
    assert "| RoutePlanner | 100.0 % [83.9, 100.0] | 80.0 % [58.4, 91.9] | +20.0 |" in text
    assert "not met" in text


def test_merge_keeps_one_episode_per_key_the_later_one() -> None:
    first = [_ep("route_planner", "full", 0, False), _ep("route_planner", "full", 1, True)]
    later = [_ep("route_planner", "full", 0, True)]
    merged = bt.merge_episodes(first, later)
    assert [(e["network"], e["success"]) for e in merged] == [(0, True), (1, True)]


def test_merge_refuses_another_network_config(tmp_path: Path) -> None:
    path = tmp_path / "run.json"
    path.write_text(json.dumps({"network_config": {"n_fittings": 20}, "episodes": []}))
    with pytest.raises(ValueError, match="network_config"):
        bt.load_run(path, bt.NETWORK_CONFIG)


def test_bad_arguments_name_the_option(capsys: pytest.CaptureFixture[str]) -> None:
    for argv, word in (
        (["--agents", "nobody"], "--agents"),
        (["--network-config", "[1]"], "--network-config"),
        (["--networks", "0"], "--merge"),
        (["--jobs", "0"], "--jobs"),
    ):
        with pytest.raises(SystemExit):
            bt.parse_args(argv)
        assert word in capsys.readouterr().err


# ------------------------------------------------------------------ the episodes


def _same_as_evaluate(agent: str, n: int) -> None:
    """The benchmark's per-episode outcomes give evaluate()'s figures for the same networks
    (the same env arguments, networks and seeds)."""
    from agents.evaluate import evaluate

    eps = bt.run_all([(agent, "fast", i) for i in range(n)], bt.NETWORK_CONFIG)
    assert [e["network"] for e in eps] == list(range(n))
    ref = evaluate(agent, n, env_kwargs=bt.env_kwargs("fast", bt.NETWORK_CONFIG))
    assert ref.success_rate == pytest.approx(sum(e["success"] for e in eps) / n)
    assert ref.jams_per_episode == pytest.approx(sum(e["jams"] for e in eps) / n)
    assert ref.decisions_per_episode == pytest.approx(sum(e["decisions"] for e in eps) / n)


def test_fast_episodes_are_those_of_pipenav_eval() -> None:
    _same_as_evaluate("route_planner", 4)


@pytest.mark.slow
def test_fast_policy_episodes_are_those_of_pipenav_eval() -> None:
    _same_as_evaluate(bt.POLICY, 6)


@pytest.mark.slow
def test_script_end_to_end_on_one_network_and_extended(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    first = tmp_path / "a.json"
    bt.main(["--networks", "1", "--agents", "route_planner", "--json", str(first)])
    data = json.loads(first.read_text())
    assert {(e["fidelity"], e["network"]) for e in data["episodes"]} == {
        ("fast", 0),
        ("full", 0),
    }
    assert data["figures"]["n"] == 1
    out = capsys.readouterr().out
    assert "| RoutePlanner |" in out and "n_fittings" in out
    # a merge-only run summarises the earlier episodes again
    fig = bt.main(["--networks", "0", "--agents", "route_planner", "--merge", str(first)])
    assert fig == data["figures"]


def test_paired_difference_interval_is_newcombes() -> None:
    # 12 pairs both succeeded, 5 only a, 2 only b, 21 neither (values of this implementation,
    # which follows Altman et al.'s formulas; the interval is asymmetric about 3/40)
    both, only_a, only_b, neither = 12, 5, 2, 21
    a = [True] * (both + only_a) + [False] * (only_b + neither)
    b = [True] * both + [False] * only_a + [True] * only_b + [False] * neither
    low, high = bt.paired_difference_interval(a, b)
    assert low < 3 / 40 < high
    assert (low, high) == (pytest.approx(-0.0594, abs=5e-4), pytest.approx(0.2046, abs=5e-4))
    # swapping the two sides mirrors the interval
    low_ba, high_ba = bt.paired_difference_interval(b, a)
    assert (low_ba, high_ba) == (pytest.approx(-high), pytest.approx(-low))
    # no discordant pair: the interval keeps the width the sample size allows (Wald: a point);
    # with every pair a success it is +-(1 - Wilson's lower bound of n/n) = +-z^2 / (n + z^2)
    n, z = 48, bt.Z95
    low, high = bt.paired_difference_interval([True] * n, [True] * n)
    assert (low, high) == (pytest.approx(-z * z / (n + z * z)), pytest.approx(z * z / (n + z * z)))
    with pytest.raises(ValueError, match="len"):
        bt.paired_difference_interval([True], [True, False])
