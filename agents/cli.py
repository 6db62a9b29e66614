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
- ``bench``: run a benchmark script (source checkout only); ``plot``: plots from an episode log.

Commands that take longer than a few seconds show a progress bar on stderr; results go to
stdout (JSON, figures rounded) and to the files asked for (full precision).
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
EXIT_INTERRUPTED = 130


def _print(*args: Any) -> None:
    print(*args, flush=True)


def _rounded(value: Any, digits: int = 3) -> Any:
    """``value`` with every float rounded to ``digits`` decimals (for printed results)."""
    if isinstance(value, float):
        return round(value, digits) if math.isfinite(value) else value
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(v, digits) for v in value]
    return value


def _progress(transient: bool = False) -> Any:
    """A rich progress display on stderr: description, bar, done/total, elapsed, remaining."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        SpinnerColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        SpinnerColumn(),
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=transient,
    )


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("pipenav")
    except metadata.PackageNotFoundError:
        from agents import __version__

        return __version__


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
_demo_doc = (
    "One closed-loop episode (drive, scan, detect, decide, act) on the embedded default "
    "network: writes report.json, episode.json, map.png, detection.png and render.png (the 3D "
    "render, skipped with the reason when no OpenGL backend works) into --out."
)


def _demo(args: argparse.Namespace) -> int:
    from agents.episodes import DEMO_CONFIG, run_episode, save_episode_plots
    from detector.atomic import atomic_write_text
    from pipe_env.generator import NetworkConfig

    try:
        NetworkConfig.from_dict({**DEMO_CONFIG, "n_fittings": args.fittings})
    except ValueError as exc:
        _print(f"error: --fittings {args.fittings}: {exc}")
        return EXIT_USAGE
    out = _out_dir(args.out)
    if out is None:
        return EXIT_USAGE
    with _progress() as progress:
        task = progress.add_task(f"demo ({args.fidelity} fidelity): decisions", total=None)
        log = run_episode(
            seed=args.seed,
            agent=args.agent,
            fidelity=args.fidelity,
            detector=args.detector,
            lidar=args.lidar,
            n_fittings=args.fittings,
            render=not args.no_render,
            out=out,
            on_decision=lambda n: progress.update(task, completed=n),
        )
        progress.update(task, total=log["summary"]["decisions"])
    files = save_episode_plots(log, out)
    report = dict(log["summary"])
    # the files of this folder: the episode's own (log, render) and the plots
    report["files"] = sorted({"episode.json", "report.json", *log["files"], *files})
    if log.get("render_skipped"):
        report["render_skipped"] = log["render_skipped"]
    from pipe_env.network_io import finite_json

    atomic_write_text(
        out / "report.json", json.dumps(finite_json(report), indent=2, allow_nan=False)
    )
    _print(json.dumps(_rounded(report), indent=2))
    if log.get("render_skipped"):
        _print(f"3D render skipped: {log['render_skipped']}")
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

    from agents.scenario_runner import RunInterrupted, run_and_report, tasks_of
    from agents.scenarios import ResultStatus, discover_with_errors

    found, broken = discover_with_errors(args.glob, args.dir)
    if not found and not broken:
        _print(f"error: no scenario matches {args.glob!r}")
        return EXIT_USAGE
    if args.backend == "ray" and importlib.util.find_spec("ray") is None:
        _print("error: --backend ray needs Ray: install the optional extra 'pipenav[ray]'")
        return EXIT_USAGE
    if not (_out_file(args.junit, "--junit") and _out_file(args.json, "--json")):
        return EXIT_USAGE
    seeds = args.seed if args.seed else None
    total = len(tasks_of(found, seeds)) + len(broken)
    marks = {
        ResultStatus.PASSED: "[green]PASS[/green]",
        ResultStatus.FAILED: "[red]FAIL[/red]",
        ResultStatus.ERROR: "[red]ERROR[/red]",
        ResultStatus.EXPECTED_FAILURE: "[yellow]XFAIL[/yellow]",
        ResultStatus.UNEXPECTED_PASS: "[yellow]XPASS[/yellow]",
        ResultStatus.NOT_RUN: "[dim]NOT RUN[/dim]",
    }
    interrupted = False
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        transient=False,
    ) as progress:
        task = progress.add_task("scenarios", total=total)

        def done(r: Any) -> None:
            # names and "[seed=N]" are text, not rich markup
            text = f"{r.scenario} [seed={r.seed}] ({sum(r.timings.values()):.1f} s)"
            progress.console.print(f"{marks[r.status]} {escape(text)}")
            progress.advance(task)

        try:
            results = run_and_report(
                found,
                seeds,
                args.jobs,
                args.backend,
                args.junit,
                args.json,
                done,
                broken=broken,
                timeout=args.timeout,
                strict=args.strict,
                ray_address=args.ray_address,
            )
        except RunInterrupted as exc:
            results, interrupted = exc.results, True
    failed = [r for r in results if r.counts_as_failure(args.strict)]
    statuses = [r.status for r in results]
    line = f"{statuses.count(ResultStatus.PASSED)} passed, {len(failed)} failed"
    for status, label in (
        (ResultStatus.ERROR, "errors"),
        (ResultStatus.EXPECTED_FAILURE, "expected failures"),
        (ResultStatus.UNEXPECTED_PASS, "unexpected passes"),
        (ResultStatus.NOT_RUN, "not run"),
    ):
        if status in statuses:
            line += f", {statuses.count(status)} {label}"
    _print(line)
    for r in failed:
        for c in r.failures:
            _print(f"  {r.scenario}[seed={r.seed}]: {c.message}")
        _print(f"  replay: {r.replay_command()}")
    for r in results:
        if r.unexpected_pass:
            _print(
                f"  {r.scenario}[seed={r.seed}]: passes but is marked known_failure "
                f"({r.known_failure}); remove the note"
            )
    if interrupted:
        _print("interrupted: the reports hold every finished result; the rest is marked not run")
        return EXIT_INTERRUPTED
    return EXIT_FAILED if failed else 0


# ---------------------------------------------------------------------- train / eval
def _train(args: argparse.Namespace) -> int:
    import gymnasium as gym
    import yaml

    import pipe_env  # noqa: F401  (registers the environment ids)
    from agents.train import DEFAULT_CONFIG, TrainConfig, check_init, check_rollout, train

    try:
        cfg = TrainConfig.from_yaml(args.config or DEFAULT_CONFIG)
    except (OSError, ValueError, TypeError, yaml.YAMLError) as exc:
        _print(f"error: --config {args.config!r}: {exc}")
        return EXIT_USAGE
    try:
        cfg = _train_overrides(cfg, args)
        cfg.check_ppo_keys()
        check_rollout(cfg)
    except ValueError as exc:
        _print(f"error: --config {args.config or DEFAULT_CONFIG!s}: {exc}")
        return EXIT_USAGE
    try:  # (the environment's own argument checks, before the workers start)
        gym.make(cfg.env_id, **cfg.env_kwargs).close()
    except (ValueError, TypeError, gym.error.Error) as exc:
        _print(f"error: --config {args.config or DEFAULT_CONFIG!s}: env_kwargs: {exc}")
        return EXIT_USAGE
    if cfg.init is not None:
        try:
            check_init(cfg)
        except ValueError as exc:
            _print(f"error: --init: {exc}")
            return EXIT_USAGE
    if _out_dir(args.out) is None:
        return EXIT_USAGE
    with _progress() as progress:
        task = progress.add_task("held-out evaluation", total=None, visible=False)

        def on_final(done: int, total: int) -> None:
            progress.update(task, completed=done, total=total, visible=not args.no_progress)

        summary = train(
            cfg,
            args.out,
            progress_bar=not args.no_progress,
            final_episodes=args.eval_episodes,
            on_final_episode=on_final,
        )
    _print(json.dumps(_rounded(summary), indent=2))
    if summary.get("note"):
        _print(f"note: {summary['note']}")
    return 0


def _train_overrides(cfg: Any, args: argparse.Namespace) -> Any:
    """``cfg`` with the command line's overrides, checked again as a whole (ValueError)."""
    from dataclasses import replace

    changes: dict[str, Any] = {}
    if args.minutes is not None:
        changes["max_minutes"] = args.minutes
    if args.timesteps is not None:
        changes["total_timesteps"] = args.timesteps
    if args.n_envs is not None:
        changes["n_envs"] = args.n_envs
    if args.init is not None:
        changes["init"] = args.init
    if args.fidelity is not None:
        changes["env_kwargs"] = {**cfg.env_kwargs, "fidelity": args.fidelity}
    if args.n_steps is not None:
        changes["ppo"] = {**cfg.ppo, "n_steps": args.n_steps}
    return replace(cfg, **changes)  # (replace re-runs the config's checks)


def _eval(args: argparse.Namespace) -> int:
    from agents.evaluate import evaluate
    from agents.scripted import SCRIPTED_AGENTS
    from agents.train import DEFAULT_CONFIG, TrainConfig
    from detector.atomic import atomic_write_text
    from pipe_env.generator import NetworkConfig

    agent = str(args.agent)
    if agent not in SCRIPTED_AGENTS and not (agent.endswith(".zip") and Path(agent).is_file()):
        _print(
            f"error: agent {agent!r} is neither a scripted agent {sorted(SCRIPTED_AGENTS)} "
            "nor an existing model .zip"
        )
        return EXIT_USAGE
    if agent not in SCRIPTED_AGENTS:
        from agents.evaluate import is_maskable_model

        try:
            is_maskable_model(agent)
        except ValueError as exc:
            _print(f"error: agent {exc}")
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
    with _progress() as progress:
        task = progress.add_task(f"eval ({args.fidelity} fidelity)", total=args.episodes)
        result = evaluate(
            args.agent,
            args.episodes,
            env_kwargs=kwargs,
            on_episode=lambda done, total: progress.update(task, completed=done),
            jobs=args.jobs,
            backend=args.backend,
        )
    _print(json.dumps(_rounded(result.to_dict()), indent=2))
    if args.json:
        from pipe_env.network_io import finite_json

        atomic_write_text(
            args.json, json.dumps(finite_json(result.to_dict()), indent=2, allow_nan=False)
        )
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


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Help with each option's default shown (unless its help states it, or it is an off
    flag), descriptions kept as written."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "(default" in text or isinstance(action, argparse._StoreTrueAction):
            return text
        return super()._get_help_string(action) or ""


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose help shows defaults (subcommand parsers are of this class too)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    from agents.scripted import SCRIPTED_AGENTS
    from detector.vocab import DETECTORS
    from pipe_env.envs import FIDELITIES
    from pipe_env.lidar import PRESETS

    agents = sorted(SCRIPTED_AGENTS)
    lidars = sorted(PRESETS)
    fidelity_help = "fast: kinematic motion, modelled sensing; full: MuJoCo robot and LiDAR"
    detector_help = "structure detector (ground_truth: the network's own structures)"
    lidar_help = "simulated LiDAR preset"
    parser = _Parser(prog="pipenav", description=__doc__)
    parser.add_argument("--version", action="version", version=f"pipenav {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = sub.add_parser(
        "demo", help="one closed-loop episode on the embedded default", description=_demo_doc
    )
    demo.add_argument("--out", default="results/demo", help="output folder")
    demo.add_argument("--seed", type=int, default=7, help="seed of the network and the episode")
    demo.add_argument(
        "--fittings", type=_int_at_least(1), default=6, help="fittings in the network"
    )
    demo.add_argument("--agent", default="route_planner", choices=agents, help="who decides")
    demo.add_argument("--fidelity", default="full", choices=FIDELITIES, help=fidelity_help)
    demo.add_argument("--detector", default="improved", choices=DETECTORS, help=detector_help)
    demo.add_argument("--lidar", default="ideal", choices=lidars, help=lidar_help)
    demo.add_argument(
        "--no-render",
        action="store_true",
        help="skip the 3D MuJoCo render (render.png); without a working OpenGL backend it is "
        "skipped anyway, with the reason",
    )
    demo.set_defaults(func=_demo)

    sc = sub.add_parser("scenarios", help="the autonomy scenario suite")
    scs = sc.add_subparsers(dest="action", required=True, metavar="ACTION")
    ls = scs.add_parser("list", help="list scenarios")
    ls.add_argument("glob", nargs="?", default="*", help="scenario names matching this glob")
    ls.add_argument("--dir", default=None, help="a folder of scenario files (default: packaged)")
    ls.set_defaults(func=_scenarios_list)
    run = scs.add_parser("run", help="run scenarios; non-zero exit if any fails")
    run.add_argument("glob", nargs="?", default="*", help="scenario names matching this glob")
    run.add_argument("--dir", default=None, help="a folder of scenario files (default: packaged)")
    run.add_argument("--junit", default=None, help="write JUnit XML here")
    run.add_argument("--json", default=None, help="write the JSON report here")
    run.add_argument(
        "--jobs",
        type=_int_at_least(1),
        default=1,
        help="worker processes (local backend) or CPUs of the local Ray instance",
    )
    run.add_argument(
        "--backend",
        default="local",
        choices=["local", "ray"],
        help="local: a process pool on this machine; ray: Ray tasks (the 'ray' extra)",
    )
    run.add_argument(
        "--ray-address",
        default=None,
        help="with --backend ray: the cluster to connect to (default: $RAY_ADDRESS; when "
        "neither is set, a local Ray instance is started for the run and stopped after it)",
    )
    run.add_argument(
        "--seed",
        type=_int_at_least(0),
        action="append",
        help="run with this seed instead of the scenarios' own (repeatable)",
    )
    run.add_argument(
        "--timeout",
        type=_positive_float,
        default=None,
        help="wall-clock limit of each run in s, over the files' timeout_s (default: the "
        "file's timeout_s, else 1800); a run past it is an error testcase",
    )
    run.add_argument(
        "--strict",
        action="store_true",
        help="count expected failures (known_failure) and unexpected passes as failures",
    )
    run.set_defaults(func=_scenarios_run)

    tr = sub.add_parser(
        "train",
        help="train MaskablePPO from a YAML config",
        description="Train MaskablePPO (action masking; see the RL Zoo note in the README for "
        "plain PPO). Ends with an evaluation on held-out networks.",
    )
    tr.add_argument("--config", default=None, help="YAML (default: the packaged one)")
    tr.add_argument("--out", default="runs/ppo", help="output folder (models, logs, summary)")
    tr.add_argument(
        "--minutes",
        type=_positive_float,
        default=None,
        help="wall-clock budget override (default: the config's max_minutes)",
    )
    tr.add_argument(
        "--timesteps",
        type=_int_at_least(1),
        default=None,
        help="timestep budget override (default: the config's total_timesteps)",
    )
    tr.add_argument(
        "--eval-episodes",
        type=_int_at_least(0),
        default=None,
        help="episodes of the closing held-out evaluation; 0 skips it (default: the config's "
        "eval.final_episodes, else eval.episodes)",
    )
    tr.add_argument(
        "--fidelity",
        default=None,
        choices=FIDELITIES,
        help="override the config's env fidelity (full: each worker its own MuJoCo world)",
    )
    tr.add_argument(
        "--init",
        default=None,
        help="start from this MaskablePPO model .zip (its weights and hyper-parameters; the "
        "rollout length is the run's) and keep learning in the run's environment",
    )
    tr.add_argument(
        "--n-envs",
        type=_int_at_least(1),
        default=None,
        help="parallel environments (the config's vec_env when > 1; default: the config's)",
    )
    tr.add_argument(
        "--n-steps",
        type=_int_at_least(1),
        default=None,
        help="timesteps per environment per rollout (ppo.n_steps; the minibatch is at most the "
        "rollout)",
    )
    tr.add_argument("--no-progress", action="store_true", help="no progress bars")
    tr.set_defaults(func=_train)

    ev = sub.add_parser("eval", help="evaluate an agent on held-out networks")
    ev.add_argument(
        "agent",
        help=f"a scripted agent {agents}, or a model .zip: MaskablePPO (masked) or plain SB3 PPO "
        "(unmasked)",
    )
    ev.add_argument("--episodes", type=_int_at_least(1), default=200, help="held-out episodes")
    ev.add_argument("--detector", default="improved", choices=DETECTORS, help=detector_help)
    ev.add_argument("--fidelity", default="fast", choices=FIDELITIES, help=fidelity_help)
    ev.add_argument(
        "--network-config",
        default=None,
        help="NetworkConfig as JSON (default: the training distribution)",
    )
    ev.add_argument("--json", default=None, help="write the result (full precision) here")
    ev.add_argument(
        "--jobs", type=_int_at_least(1), default=1, help="episodes run in parallel (default 1)"
    )
    ev.add_argument(
        "--backend",
        default="process",
        choices=("process", "ray"),
        help="parallel workers: local processes or Ray tasks (with --jobs > 1)",
    )
    ev.set_defaults(func=_eval)

    dr = sub.add_parser("drive", help="operator console: you choose, the robot acts")
    dr.add_argument("--layout", default=None, help="a canonical layout instead of a network")
    dr.add_argument("--params", default="{}", help="layout parameters as JSON")
    dr.add_argument(
        "--network", default=None, help="a network file (.json/.yaml) (default: a generated one)"
    )
    dr.add_argument("--seed", type=int, default=0, help="seed of the network and the episode")
    dr.add_argument("--fidelity", default="full", choices=FIDELITIES, help=fidelity_help)
    dr.add_argument("--detector", default="improved", choices=DETECTORS, help=detector_help)
    dr.add_argument("--lidar", default="ideal", choices=lidars, help=lidar_help)
    dr.add_argument("--out", default="results/drive", help="where scan images go headless")
    dr.set_defaults(func=_drive)

    be = sub.add_parser(
        "bench",
        help="run a benchmark script (source checkout only)",
        description="Run benchmarks/bench_NAME.py of a pipenav source checkout (the scripts "
        "are not part of the installed package): from the checkout's folder, or with pipenav "
        "installed from it in editable mode (pip install -e .).",
    )
    be.add_argument("name", choices=BENCHES, help="which benchmark")
    be.add_argument("extra", nargs=argparse.REMAINDER, help="arguments for the script")
    be.set_defaults(func=_bench)

    pl = sub.add_parser("plot", help="plots from an episode log (episode.json)")
    pl.add_argument("episode", help="an episode.json written by demo")
    pl.add_argument(
        "--what", default="all", choices=["all", "map", "detection"], help="which plots"
    )
    pl.add_argument("--out", default="results/plots", help="output folder")
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
