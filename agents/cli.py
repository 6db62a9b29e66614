"""The ``pipenav`` command line.

Subcommands are thin: each parses its arguments and calls the library function that owns the
job. ``pipenav <command> --help`` documents each one. Bad arguments (an unknown choice, a
missing or unreadable input file, a value out of range, an output folder that cannot be
created) are reported as one ``error: ...`` line with exit code 2.

- ``demo``: the main job on the embedded default: one closed-loop episode (drive, scan, detect,
  decide, act) with a report and plots;
- ``scenarios list`` / ``scenarios run``: the autonomy scenario suite with JUnit XML and JSON;
- ``train`` / ``eval``: MaskablePPO training from a YAML config, agent evaluation;
- ``drive``: the operator console (Decision Support: the robot proposes, you choose);
- ``bench``: run a benchmark script; ``plot``: plots from an episode log.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

EXIT_FAILED = 1
EXIT_USAGE = 2


def _print(*args: Any) -> None:
    print(*args, flush=True)


def _int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an int >= ``minimum`` (argparse reports anything else as a usage
    error naming the option)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{text!r} is not allowed; use an int >= {minimum}")
        return value

    return parse


def _positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"{text!r} is not allowed; use a number > 0")
    return value


def _out_dir(path: str, option: str = "--out") -> Path | None:
    """Create the output folder ``path``; None (after printing the error) if it cannot be."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _print(f"error: {option} {path!r} cannot be created ({exc})")
        return None
    return out


def _out_file(path: str | None, option: str) -> bool:
    """Can the output file ``path`` be written (its folder created, no folder in its place)?
    True when no file is asked for; False after printing the error."""
    if path is None:
        return True
    target = Path(path)
    if target.is_dir():
        _print(f"error: {option} {path!r} is a folder; give a file name")
        return False
    return _out_dir(str(target.parent), option) is not None


# ------------------------------------------------------------------------------- demo
def _demo(args: argparse.Namespace) -> int:
    from agents.episodes import DEMO_CONFIG, run_episode, save_episode_plots
    from pipe_env.generator import NetworkConfig

    try:
        NetworkConfig.from_dict({**DEMO_CONFIG, "n_fittings": args.fittings})
    except ValueError as exc:
        _print(f"error: --fittings {args.fittings}: {exc}")
        return EXIT_USAGE
    out = _out_dir(args.out)
    if out is None:
        return EXIT_USAGE
    log = run_episode(
        seed=args.seed,
        agent=args.agent,
        fidelity=args.fidelity,
        detector=args.detector,
        lidar=args.lidar,
        n_fittings=args.fittings,
        render=not args.no_render,
        out=out,
    )
    files = save_episode_plots(log, out)
    report = dict(log["summary"])
    # the files of this folder: the episode's own (log, render) and the plots
    report["files"] = sorted({"episode.json", "report.json", *log["files"], *files})
    (out / "report.json").write_text(json.dumps(report, indent=2))
    _print(json.dumps(report, indent=2))
    return 0


# -------------------------------------------------------------------------- scenarios
def _scenarios_list(args: argparse.Namespace) -> int:
    from agents.scenarios import ScenarioError, discover

    try:
        found = discover(args.glob, args.dir)
    except ScenarioError as exc:
        _print(f"error: {exc}")
        return EXIT_USAGE
    for sc in found:
        _print(
            f"{sc.name:42s} {sc.mode:8s} {sc.fidelity:4s} {sc.detector:12s} "
            f"seeds={sc.seeds}  {sc.description}"
        )
    _print(f"{len(found)} scenario(s)")
    return 0


def _scenarios_run(args: argparse.Namespace) -> int:
    from rich.markup import escape
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    from agents.scenario_runner import run_and_report, tasks_of
    from agents.scenarios import ScenarioError, discover

    try:
        found = discover(args.glob, args.dir)
    except ScenarioError as exc:
        _print(f"error: {exc}")
        return EXIT_USAGE
    if not found:
        _print(f"error: no scenario matches {args.glob!r}")
        return EXIT_USAGE
    if args.backend == "ray" and importlib.util.find_spec("ray") is None:
        _print("error: --backend ray needs Ray: install the optional extra 'pipenav[ray]'")
        return EXIT_USAGE
    if not (_out_file(args.junit, "--junit") and _out_file(args.json, "--json")):
        return EXIT_USAGE
    seeds = args.seed if args.seed else None
    total = len(tasks_of(found, seeds))
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        transient=False,
    ) as progress:
        task = progress.add_task("scenarios", total=total)

        def done(r: Any) -> None:
            mark = "[green]PASS[/green]" if r.passed else "[red]FAIL[/red]"
            # names and "[seed=N]" are text, not rich markup
            text = f"{r.scenario} [seed={r.seed}] ({sum(r.timings.values()):.1f} s)"
            progress.console.print(f"{mark} {escape(text)}")
            progress.advance(task)

        results = run_and_report(found, seeds, args.jobs, args.backend, args.junit, args.json, done)
    failed = [r for r in results if not r.passed]
    _print(f"{len(results) - len(failed)} passed, {len(failed)} failed")
    for r in failed:
        for c in r.failures:
            _print(f"  {r.scenario}[seed={r.seed}]: {c.message}")
        _print(f"  replay: {r.replay_command()}")
    return EXIT_FAILED if failed else 0


# ---------------------------------------------------------------------- train / eval
def _train(args: argparse.Namespace) -> int:
    import gymnasium as gym
    import yaml

    import pipe_env  # noqa: F401  (registers the environment ids)
    from agents.train import DEFAULT_CONFIG, TrainConfig, train

    try:
        cfg = TrainConfig.from_yaml(args.config or DEFAULT_CONFIG)
    except (OSError, ValueError, TypeError, yaml.YAMLError) as exc:
        _print(f"error: --config {args.config!r}: {exc}")
        return EXIT_USAGE
    if args.minutes is not None:
        cfg.max_minutes = args.minutes
    if args.timesteps is not None:
        cfg.total_timesteps = args.timesteps
    try:  # (the environment's own argument checks, before the workers start)
        gym.make(cfg.env_id, **cfg.env_kwargs).close()
    except (ValueError, TypeError, gym.error.Error) as exc:
        _print(f"error: --config {args.config or DEFAULT_CONFIG!s}: env_kwargs: {exc}")
        return EXIT_USAGE
    if _out_dir(args.out) is None:
        return EXIT_USAGE
    summary = train(cfg, args.out, progress_bar=not args.no_progress)
    _print(json.dumps(summary, indent=2))
    return 0


def _eval(args: argparse.Namespace) -> int:
    from agents.evaluate import evaluate
    from agents.scripted import SCRIPTED_AGENTS
    from agents.train import DEFAULT_CONFIG, TrainConfig
    from pipe_env.generator import NetworkConfig

    agent = str(args.agent)
    if agent not in SCRIPTED_AGENTS and not (agent.endswith(".zip") and Path(agent).is_file()):
        _print(
            f"error: agent {agent!r} is neither a scripted agent {sorted(SCRIPTED_AGENTS)} "
            "nor an existing model .zip"
        )
        return EXIT_USAGE
    # default: the training distribution of the packaged config
    kwargs: dict[str, Any] = dict(TrainConfig.from_yaml(DEFAULT_CONFIG).env_kwargs)
    kwargs.update(detector=args.detector, fidelity=args.fidelity)
    if args.network_config:
        try:
            config = json.loads(args.network_config)
        except json.JSONDecodeError as exc:
            _print(f"error: --network-config is not JSON ({exc})")
            return EXIT_USAGE
        if not isinstance(config, dict):
            _print(f"error: --network-config must be a JSON object, got {args.network_config!r}")
            return EXIT_USAGE
        try:
            NetworkConfig.from_dict(config)
        except (TypeError, ValueError) as exc:
            _print(f"error: --network-config: {exc}")
            return EXIT_USAGE
        kwargs["network_config"] = config
    if not _out_file(args.json, "--json"):
        return EXIT_USAGE
    result = evaluate(args.agent, args.episodes, env_kwargs=kwargs)
    _print(json.dumps(result.to_dict(), indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(result.to_dict(), indent=2))
    return 0


# ------------------------------------------------------------------------------ drive
def _drive(args: argparse.Namespace) -> int:
    from agents.console import OperatorConsole

    try:
        console = OperatorConsole.from_args(args)
    except (ValueError, OSError) as exc:  # bad --params JSON, layout or network file
        _print(f"error: {exc}")
        return EXIT_USAGE
    return console.run()


# ------------------------------------------------------------------------ bench / plot
BENCHES = ("world", "lidar", "detection", "primitives", "agents")


def _bench(args: argparse.Namespace) -> int:
    import runpy

    for root in (Path.cwd(), Path(__file__).resolve().parents[1]):
        script = root / "benchmarks" / f"bench_{args.name}.py"
        if script.exists():
            sys.argv = [str(script), *args.extra]
            runpy.run_path(str(script), run_name="__main__")
            return 0
    _print(f"error: benchmarks/bench_{args.name}.py not found; run from the source checkout")
    return EXIT_USAGE


def _plot(args: argparse.Namespace) -> int:
    from agents.episodes import load_episode, save_episode_plots

    try:
        log = load_episode(args.episode)
    except ValueError as exc:
        _print(f"error: {exc}")
        return EXIT_USAGE
    out = _out_dir(args.out)
    if out is None:
        return EXIT_USAGE
    for f in save_episode_plots(log, out, which=args.what):
        _print(out / f)
    return 0


def build_parser() -> argparse.ArgumentParser:
    from agents.scripted import SCRIPTED_AGENTS
    from pipe_env.envs import FIDELITIES
    from pipe_env.lidar import PRESETS
    from pipe_env.sensing_model import DETECTORS

    agents = sorted(SCRIPTED_AGENTS)
    lidars = sorted(PRESETS)
    parser = argparse.ArgumentParser(
        prog="pipenav", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="one closed-loop episode on the embedded default")
    demo.add_argument("--out", default="results/demo", help="output folder")
    demo.add_argument("--seed", type=int, default=7)
    demo.add_argument(
        "--fittings", type=_int_at_least(1), default=6, help="fittings in the network"
    )
    demo.add_argument("--agent", default="route_planner", choices=agents)
    demo.add_argument("--fidelity", default="full", choices=FIDELITIES)
    demo.add_argument("--detector", default="improved", choices=DETECTORS)
    demo.add_argument("--lidar", default="ideal", choices=lidars)
    demo.add_argument("--no-render", action="store_true", help="skip the MuJoCo render")
    demo.set_defaults(func=_demo)

    sc = sub.add_parser("scenarios", help="the autonomy scenario suite")
    scs = sc.add_subparsers(dest="action", required=True)
    ls = scs.add_parser("list", help="list scenarios")
    ls.add_argument("glob", nargs="?", default="*")
    ls.add_argument("--dir", default=None, help="a folder of scenario files (default: packaged)")
    ls.set_defaults(func=_scenarios_list)
    run = scs.add_parser("run", help="run scenarios; non-zero exit if any fails")
    run.add_argument("glob", nargs="?", default="*")
    run.add_argument("--dir", default=None, help="a folder of scenario files (default: packaged)")
    run.add_argument("--junit", default=None, help="write JUnit XML here")
    run.add_argument("--json", default=None, help="write the JSON report here")
    run.add_argument("--jobs", type=_int_at_least(1), default=1, help="worker processes")
    run.add_argument("--backend", default="local", choices=["local", "ray"])
    run.add_argument(
        "--seed",
        type=int,
        action="append",
        help="run with this seed instead of the scenarios' own (repeatable)",
    )
    run.set_defaults(func=_scenarios_run)

    tr = sub.add_parser("train", help="train MaskablePPO from a YAML config")
    tr.add_argument("--config", default=None, help="YAML (default: the packaged one)")
    tr.add_argument("--out", default="runs/ppo")
    tr.add_argument(
        "--minutes", type=_positive_float, default=None, help="wall-clock budget override"
    )
    tr.add_argument("--timesteps", type=_int_at_least(1), default=None)
    tr.add_argument("--no-progress", action="store_true")
    tr.set_defaults(func=_train)

    ev = sub.add_parser("eval", help="evaluate an agent on held-out networks")
    ev.add_argument("agent", help="scripted agent name or a model .zip")
    ev.add_argument("--episodes", type=_int_at_least(1), default=200)
    ev.add_argument("--detector", default="improved", choices=DETECTORS)
    ev.add_argument("--fidelity", default="fast", choices=FIDELITIES)
    ev.add_argument(
        "--network-config",
        default=None,
        help="NetworkConfig as JSON (default: the training distribution)",
    )
    ev.add_argument("--json", default=None)
    ev.set_defaults(func=_eval)

    dr = sub.add_parser("drive", help="operator console: you choose, the robot acts")
    dr.add_argument("--layout", default=None, help="a canonical layout instead of a network")
    dr.add_argument("--params", default="{}", help="layout parameters as JSON")
    dr.add_argument("--network", default=None, help="a network file (.json/.yaml)")
    dr.add_argument("--seed", type=int, default=0)
    dr.add_argument("--fidelity", default="full", choices=FIDELITIES)
    dr.add_argument("--detector", default="improved", choices=DETECTORS)
    dr.add_argument("--lidar", default="ideal", choices=lidars)
    dr.add_argument("--out", default="results/drive", help="where scan images go headless")
    dr.set_defaults(func=_drive)

    be = sub.add_parser("bench", help="run a benchmark script from benchmarks/")
    be.add_argument("name", choices=BENCHES)
    be.add_argument("extra", nargs=argparse.REMAINDER, help="arguments for the script")
    be.set_defaults(func=_bench)

    pl = sub.add_parser("plot", help="plots from an episode log (episode.json)")
    pl.add_argument("episode")
    pl.add_argument("--what", default="all", choices=["all", "map", "detection"])
    pl.add_argument("--out", default="results/plots")
    pl.set_defaults(func=_plot)
    from agents.cli_data import add_commands  # detect, record, export

    add_commands(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        code = int(args.func(args))
    except KeyboardInterrupt:
        _print("interrupted")
        return 130
    if getattr(args, "command", "") == "demo":
        _print(f"done in {time.perf_counter() - t0:.1f} s")
    return code


if __name__ == "__main__":
    sys.exit(main())
