"""Where the fast fidelity disagrees with the full one, from the full loop's own outcomes.

Runs RoutePlanner (improved detector) on the same held-out networks
(:func:`agents.evaluate.held_out_networks`, ``--networks`` of them; 6-fitting 3D networks with
loops unless ``--network-config``) in both fidelities: ``full`` once per network with seed
``EVAL_POOL_SEED + i`` (as ``pipenav eval``), ``fast`` ``--fast-repeats`` times per network
(repeat 0 with the same seed, the others with other seeds: the fast loop is cheap, so its side
of every comparison is estimated more tightly). Each episode's
:class:`pipe_env.envs.outcome_log.OutcomeLog` gives, per fidelity:

- episode outcomes: success rate, decisions, jams and structures per episode, jams while
  driving to a structure (per structure);
- jams per attempt by the true structure kind, by the deflection class of the true way taken
  and by the side it turns to (left/up/right/down), backing out and phantom ways apart;
- sensing at the decision point: the rate of missed true ways, of structures with a phantom way,
  of misclassified structures, of structures with no way reported; the largest absolute option
  errors (distance and diameter in mm, angle and direction in deg) at each structure.

For each statistic: the fast value, the full value, their difference (full - fast) and a
test (two-sided): Fisher's exact test for rates, the Mann-Whitney U test for per-episode
counts (their means shown), the two-sample Kolmogorov-Smirnov test for error distributions
(their medians shown).
``p < --alpha`` is flagged ``differs``; ``Holm`` marks the flags that survive the
Holm-Bonferroni correction over all the tests of the run (with many tests some plain flags are
chance). A p above alpha means no difference detectable at this sample size, not equality: a
few networks detect only large ones.

Usage: python benchmarks/calibrate_fidelity.py [--networks 6] [--jobs 1] [--fast-repeats 10]
       [--network-config JSON] [--alpha 0.05] [--json out.json] [--write-docs]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

# Runnable as a script from anywhere: the repository root holds the benchmarks package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.workers import run_plan  # noqa: E402
from detector.atomic import atomic_write_text

FIDELITIES = ("fast", "full")
NETWORK_CONFIG: dict[str, Any] = {"n_fittings": 6, "planar": False, "allow_loops": True}
DETECTOR = "improved"
AGENT = "route_planner"
#: Seed offset between the fast fidelity's repeats of one network.
REPEAT_SEED_STRIDE = 100_000


# ------------------------------------------------------------------------- episodes
#: Per process: (fidelity, detector, network config) -> env, reused across episodes.
_ENVS: dict[str, Any] = {}


def run_episode(
    fidelity: str, index: int, seed: int, network_config: dict[str, Any], detector: str = DETECTOR
) -> dict[str, Any]:
    """RoutePlanner on held-out network ``index`` in ``fidelity`` with ``seed``; the episode's
    outcome and its outcome log as plain data."""
    import gymnasium as gym

    import pipe_env  # noqa: F401  (registers the environment ids)
    from agents.evaluate import EVAL_POOL_SEED
    from agents.scripted import make_agent
    from pipe_env.envs import pool_network
    from pipe_env.generator import NetworkConfig

    cfg = NetworkConfig.from_dict(network_config)
    key = json.dumps([fidelity, detector, network_config], sort_keys=True)
    env = _ENVS.get(key)
    if env is None:
        for old in _ENVS.values():
            old.close()
        _ENVS.clear()
        env = _ENVS[key] = gym.make(
            "pipenav/PipeNav-v0", fidelity=fidelity, detector=detector, network_config=cfg
        )
    base: Any = env.unwrapped
    agent = make_agent(AGENT, env)
    t0 = time.perf_counter()
    network = pool_network(cfg, EVAL_POOL_SEED, index)
    obs, info = env.reset(seed=seed, options={"network": network})
    agent.reset()
    done = bool(base.terminated or base.truncated)
    while not done:
        obs, _, term, trunc, info = env.step(agent.act(obs, info))
        done = term or trunc
    return {
        "fidelity": fidelity,
        "network": index,
        "seed": seed,
        "success": bool(info["is_success"]),
        "decisions": int(info["decisions"]),
        "jams": int(info["jams"]),
        "structures": int(info["structures"]),
        "wall_s": time.perf_counter() - t0,
        "outcomes": base.outcome_log.to_dict(),
    }


def episode_plan(networks: int, fast_repeats: int) -> list[tuple[str, int, int]]:
    """(fidelity, network index, seed) of every episode: the full ones first (the slow part,
    scheduled early), then the fast ones."""
    from agents.evaluate import EVAL_POOL_SEED

    plan = [("full", i, EVAL_POOL_SEED + i) for i in range(networks)]
    plan += [
        ("fast", i, EVAL_POOL_SEED + i + k * REPEAT_SEED_STRIDE)
        for k in range(fast_repeats)
        for i in range(networks)
    ]
    return plan


def run_all(
    plan: list[tuple[str, int, int]],
    network_config: dict[str, Any],
    jobs: int = 1,
    on_episode: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run the episodes of ``plan`` (in ``jobs`` spawned worker processes when > 1: each builds
    its own environments, so no MuJoCo world is shared); results in plan order."""
    calls = [(fid, index, seed, network_config) for fid, index, seed in plan]
    return run_plan(run_episode, calls, jobs, on_episode)


# ----------------------------------------------------------------------- statistics
@dataclass
class Comparison:
    """One statistic of both fidelities and the test of their difference.

    Attributes:
        section, statistic, group: where it belongs (table, row, sub-row).
        unit: of ``fast``, ``full`` and ``difference``.
        fast, full: the value of each fidelity (a rate, or the median of a distribution).
        difference: full - fast.
        n_fast, n_full: the sample sizes (trials of a rate, values of a distribution).
        k_fast, k_full: the events of a rate (None for a distribution).
        test: ``fisher``, ``mann-whitney`` or ``ks``.
        p: the two-sided p-value (nan when a side has no sample).
        significant: p < alpha.
        holm: still significant after the Holm-Bonferroni correction over the run's tests.
    """

    section: str
    statistic: str
    group: str
    unit: str
    fast: float
    full: float
    difference: float
    n_fast: int
    n_full: int
    test: str
    p: float
    k_fast: int | None = None
    k_full: int | None = None
    significant: bool = False
    holm: bool = False


def fisher_p(k_fast: int, n_fast: int, k_full: int, n_full: int) -> float:
    """Two-sided Fisher exact p-value of ``k_fast`` events in ``n_fast`` trials against
    ``k_full`` in ``n_full`` (nan when either side has no trial)."""
    if n_fast <= 0 or n_full <= 0:
        return math.nan
    table = [[k_fast, n_fast - k_fast], [k_full, n_full - k_full]]
    return float(stats.fisher_exact(table, alternative="two-sided").pvalue)


def ks_p(fast: Iterable[float], full: Iterable[float]) -> float:
    """Two-sided two-sample Kolmogorov-Smirnov p-value (nan when either side is empty)."""
    a, b = np.asarray(list(fast), dtype=float), np.asarray(list(full), dtype=float)
    if len(a) == 0 or len(b) == 0:
        return math.nan
    return float(stats.ks_2samp(a, b).pvalue)


def mann_whitney_p(fast: Iterable[float], full: Iterable[float]) -> float:
    """Two-sided Mann-Whitney U p-value (nan when either side is empty; 1 when every value is
    the same). For small counts with many ties, where KS is conservative."""
    a, b = np.asarray(list(fast), dtype=float), np.asarray(list(full), dtype=float)
    if len(a) == 0 or len(b) == 0:
        return math.nan
    if np.all(np.concatenate([a, b]) == a[0]):
        return 1.0
    return float(stats.mannwhitneyu(a, b, alternative="two-sided").pvalue)


def rate_comparison(
    section: str,
    statistic: str,
    group: str,
    k_fast: int,
    n_fast: int,
    k_full: int,
    n_full: int,
    alpha: float = 0.05,
) -> Comparison:
    """A rate (``k`` of ``n``) of both fidelities with Fisher's exact test."""
    for name, k, n in (("fast", k_fast, n_fast), ("full", k_full, n_full)):
        if not (0 <= k <= n):
            raise ValueError(
                f"rate_comparison: {statistic}: k_{name} = {k}, n_{name} = {n}; "
                "allowed: 0 <= k <= n"
            )
    fast = k_fast / n_fast if n_fast else math.nan
    full = k_full / n_full if n_full else math.nan
    p = fisher_p(k_fast, n_fast, k_full, n_full)
    return Comparison(
        section,
        statistic,
        group,
        "rate",
        fast,
        full,
        full - fast,
        n_fast,
        n_full,
        "fisher",
        p,
        k_fast,
        k_full,
        significant=bool(p < alpha),
    )


def distribution_comparison(
    section: str,
    statistic: str,
    group: str,
    fast: Iterable[float],
    full: Iterable[float],
    unit: str,
    alpha: float = 0.05,
    centre: str = "median",
) -> Comparison:
    """Two samples compared by their ``centre`` and a test: ``"median"`` with the two-sample KS
    test (error distributions), ``"mean"`` with the Mann-Whitney U test (small counts, whose
    medians hide differences and whose ties make KS conservative)."""
    if centre not in ("median", "mean"):
        raise ValueError(
            f"distribution_comparison: centre = {centre!r}: not allowed; allowed: median, mean"
        )
    a, b = np.asarray(list(fast), dtype=float), np.asarray(list(full), dtype=float)
    centre_of = np.median if centre == "median" else np.mean
    ma = float(centre_of(a)) if len(a) else math.nan
    mb = float(centre_of(b)) if len(b) else math.nan
    p = ks_p(a, b) if centre == "median" else mann_whitney_p(a, b)
    return Comparison(
        section,
        statistic,
        group,
        unit,
        ma,
        mb,
        mb - ma,
        len(a),
        len(b),
        "ks" if centre == "median" else "mann-whitney",
        p,
        significant=bool(p < alpha),
    )


def holm_correct(comparisons: list[Comparison], alpha: float = 0.05) -> None:
    """Set ``holm`` on the comparisons whose test survives the Holm-Bonferroni step-down
    correction at family-wise level ``alpha`` (tests without a p-value do not count)."""
    tested = sorted((c for c in comparisons if math.isfinite(c.p)), key=lambda c: c.p)
    m = len(tested)
    for rank, c in enumerate(tested):
        if c.p >= alpha / (m - rank):
            break
        c.holm = True


# ---------------------------------------------------------------------- the tables
#: Detection error statistics: key in the outcome log, label, unit, scale from SI.
ERRORS = (
    ("distance", "distance error", "mm", 1000.0),
    ("diameter", "diameter error", "mm", 1000.0),
    ("angle", "angle error", "deg", 180.0 / math.pi),
    ("direction", "direction error", "deg", 180.0 / math.pi),
)
SECTIONS = (
    "episode outcomes",
    "jams per attempt by structure kind",
    "jams per attempt by way (deflection)",
    "jams per attempt by way (turn side)",
    "sensing at the decision point",
)


def _attempts(episodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [a for e in episodes for a in e["outcomes"]["attempts"]]


def _sensed(episodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [s for e in episodes for s in e["outcomes"]["sensed"]]


def _jam_rates(
    section: str,
    fast: list[dict[str, Any]],
    full: list[dict[str, Any]],
    key: Callable[[dict[str, Any]], str],
    alpha: float,
) -> list[Comparison]:
    groups = sorted({key(a) for a in fast + full})
    out = []
    for g in groups:
        fa = [a for a in fast if key(a) == g]
        fu = [a for a in full if key(a) == g]
        k_fast = sum(a["status"] == "jammed" for a in fa)
        k_full = sum(a["status"] == "jammed" for a in fu)
        out.append(
            rate_comparison(section, "jams/attempt", g, k_fast, len(fa), k_full, len(fu), alpha)
        )
    return out


def _episode_outcomes(
    fast: list[dict[str, Any]], full: list[dict[str, Any]], alpha: float
) -> list[Comparison]:
    section = SECTIONS[0]
    out = [
        rate_comparison(
            section,
            "success",
            "per episode",
            sum(e["success"] for e in fast),
            len(fast),
            sum(e["success"] for e in full),
            len(full),
            alpha,
        )
    ]
    out.append(
        rate_comparison(
            section,
            "drive jams",
            "per structure",
            sum(int(e["outcomes"].get("drive_jams", 0)) for e in fast),
            sum(e["structures"] for e in fast),
            sum(int(e["outcomes"].get("drive_jams", 0)) for e in full),
            sum(e["structures"] for e in full),
            alpha,
        )
    )
    for key in ("decisions", "jams", "structures"):
        out.append(
            distribution_comparison(
                section,
                f"{key}/episode",
                "per episode",
                [e[key] for e in fast],
                [e[key] for e in full],
                "mean count",
                alpha,
                centre="mean",
            )
        )
    return out


def _sensing(fast: list[dict[str, Any]], full: list[dict[str, Any]], alpha: float):
    section = SECTIONS[4]
    rates: tuple[tuple[str, Callable[[dict[str, Any]], int], Callable[[dict[str, Any]], int]], ...]
    rates = (
        ("missed ways", lambda s: int(s["missed"]), lambda s: int(s["n_true"])),
        ("structures with a phantom way", lambda s: int(s["phantoms"] > 0), lambda s: 1),
        ("misclassified structures", lambda s: int(s["kind"] != s["true_kind"]), lambda s: 1),
        ("structures with no way reported", lambda s: int(s["n_sensed"] == 0), lambda s: 1),
    )
    out = []
    for name, event, trials in rates:
        out.append(
            rate_comparison(
                section,
                name,
                "per way" if name == "missed ways" else "per structure",
                sum(event(s) for s in fast),
                sum(trials(s) for s in fast),
                sum(event(s) for s in full),
                sum(trials(s) for s in full),
                alpha,
            )
        )
    for key, label, unit, scale in ERRORS:

        def values(rows: list[dict[str, Any]], key: str = key, scale: float = scale):
            return [
                scale * float(s["errors"][key])
                for s in rows
                if key in s["errors"] and math.isfinite(float(s["errors"][key]))
            ]

        out.append(
            distribution_comparison(
                section, label, "per structure", values(fast), values(full), unit, alpha
            )
        )
    return out


def compare(episodes: list[dict[str, Any]], alpha: float = 0.05) -> list[Comparison]:
    """Every statistic of the fast against the full episodes (see the module docstring)."""
    fast = [e for e in episodes if e["fidelity"] == "fast"]
    full = [e for e in episodes if e["fidelity"] == "full"]
    fa, fu = _attempts(fast), _attempts(full)
    out = _episode_outcomes(fast, full, alpha)
    out += _jam_rates(SECTIONS[1], fa, fu, lambda a: str(a["true_kind"]), alpha)
    out += _jam_rates(SECTIONS[2], fa, fu, lambda a: str(a["way"]), alpha)
    ways = [a for a in fa if a["side"] != "none"], [a for a in fu if a["side"] != "none"]
    out += _jam_rates(SECTIONS[3], ways[0], ways[1], lambda a: str(a["side"]), alpha)
    out += _sensing(_sensed(fast), _sensed(full), alpha)
    holm_correct(out, alpha)
    return out


def _fmt(value: float, unit: str) -> str:
    if not math.isfinite(value):
        return "-"
    return f"{value:.3f}" if unit == "rate" else f"{value:.2f}"


def _flag(c: Comparison) -> str:
    if not c.significant:
        return ""
    return "**differs** (Holm)" if c.holm else "differs"


def _counts(c: Comparison, side: str) -> str:
    k = c.k_fast if side == "fast" else c.k_full
    n = c.n_fast if side == "fast" else c.n_full
    return f"{k}/{n}" if k is not None else str(n)


def markdown(comparisons: list[Comparison], header: str, alpha: float) -> str:
    """The report: a header line, one table per section, the flagged rows listed last."""
    lines = [header, ""]
    for section in SECTIONS:
        rows = [c for c in comparisons if c.section == section]
        if not rows:
            continue
        lines += [
            f"**{section}**",
            "",
            "| statistic | group | unit | fast | full | full - fast | n fast | n full | test | p "
            "| flag |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for c in rows:
            p = f"{c.p:.3g}" if math.isfinite(c.p) else "-"
            lines.append(
                f"| {c.statistic} | {c.group} | {c.unit} | {_fmt(c.fast, c.unit)} | "
                f"{_fmt(c.full, c.unit)} | {_fmt(c.difference, c.unit)} | {_counts(c, 'fast')} | "
                f"{_counts(c, 'full')} | {c.test} | {p} | {_flag(c)} |"
            )
        lines.append("")
    flagged = [c for c in comparisons if c.significant]
    tested = sum(math.isfinite(c.p) for c in comparisons)
    lines.append(
        f"{len(flagged)} of {tested} tests flag a disagreement at p < {alpha} "
        f"({sum(c.holm for c in flagged)} after the Holm correction); rates: Fisher exact, "
        "counts: Mann-Whitney U (means shown), errors: two-sample KS (medians shown)."
    )
    for c in flagged:
        lines.append(
            f"- {c.section}: {c.statistic} ({c.group}): fast {_fmt(c.fast, c.unit)}, full "
            f"{_fmt(c.full, c.unit)} {c.unit}, p = {c.p:.3g}{' (Holm)' if c.holm else ''}"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------------- main
def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--networks", type=int, default=6, help="held-out networks (>= 1)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (>= 1)")
    parser.add_argument(
        "--fast-repeats", type=int, default=10, help="fast episodes per network (>= 1)"
    )
    parser.add_argument(
        "--network-config", default=None, help="NetworkConfig as JSON (default: 6-fitting 3D)"
    )
    parser.add_argument("--alpha", type=float, default=0.05, help="significance level (0, 1)")
    parser.add_argument("--json", default=None, help="write figures and episodes here")
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = parser.parse_args(argv)
    for name in ("networks", "jobs", "fast_repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} = {getattr(args, name)}; allowed: >= 1")
    if not 0.0 < args.alpha < 1.0:
        parser.error(f"--alpha = {args.alpha}; allowed: (0, 1)")
    if args.network_config is not None:
        try:
            config = json.loads(args.network_config)
        except json.JSONDecodeError as exc:
            parser.error(f"--network-config = {args.network_config!r}: not JSON ({exc})")
        if not isinstance(config, dict):
            parser.error(f"--network-config = {args.network_config!r}; allowed: a JSON object")
        from pipe_env.generator import NetworkConfig

        try:
            NetworkConfig.from_dict(config)
        except (TypeError, ValueError) as exc:
            parser.error(f"--network-config: {exc}")
        args.config = config
    else:
        args.config = dict(NETWORK_CONFIG)
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the calibration; prints the report and returns the figures."""
    args = parse_args(argv)
    plan = episode_plan(args.networks, args.fast_repeats)
    t0 = time.perf_counter()

    def progress(e: dict[str, Any]) -> None:
        if e["fidelity"] == "full":
            print(
                f"full network {e['network']}: success {e['success']}, {e['decisions']} "
                f"decisions, {e['jams']} jams, {e['wall_s']:.1f} s",
                flush=True,
            )

    episodes = run_all(plan, args.config, args.jobs, progress)
    wall = time.perf_counter() - t0
    comparisons = compare(episodes, args.alpha)
    config_arg = (
        f" --network-config '{json.dumps(args.config)}'" if args.config != NETWORK_CONFIG else ""
    )
    header = (
        f"RoutePlanner, {DETECTOR} detector, {args.networks} held-out networks "
        f"({json.dumps(args.config, sort_keys=True)}): full fidelity once per network, fast "
        f"{args.fast_repeats} times (other seeds); {wall:.0f} s wall with {args.jobs} job(s). "
        "Command: `python benchmarks/calibrate_fidelity.py "
        f"--networks {args.networks} --fast-repeats {args.fast_repeats}{config_arg}`."
    )
    report = markdown(comparisons, header, args.alpha)
    print("\n" + report)
    figures = {
        "networks": args.networks,
        "fast_repeats": args.fast_repeats,
        "network_config": args.config,
        "alpha": args.alpha,
        "wall_seconds": wall,
        "comparisons": [asdict(c) for c in comparisons],
    }
    if args.json:
        from pipe_env.network_io import finite_json

        atomic_write_text(
            args.json,
            json.dumps(
                finite_json({"figures": figures, "episodes": episodes}), indent=1, allow_nan=False
            ),
        )
    if args.write_docs:
        from benchmarks.report import write_section

        write_section("fidelity calibration", report)
    return figures


if __name__ == "__main__":
    main()
