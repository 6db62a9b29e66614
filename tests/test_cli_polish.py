"""The CLI as a new user meets it: help with defaults, --version, progress bars, rounded
results, a training run that is honest about what it produced, eval of plain PPO models,
a console that does not ask after the end, and Ray's address chosen as Ray users expect."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import pytest
import yaml

import agents
from agents.cli import _HelpFormatter, build_parser, main
from agents.scenario_runner import ray_init_kwargs

ROOT = Path(__file__).resolve().parents[1]
SHIPPED_POLICY = Path(agents.__file__).parent / "maskable_ppo_policy.zip"


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def pipenav(*args: str, cwd: Path = ROOT, timeout: int = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run(
        [sys.executable, "-m", "agents.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
        env=env,
    )


def _parsers(parser: argparse.ArgumentParser, name: str = "pipenav"):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from _parsers(sub, f"{name} {sub_name}")


def test_every_option_has_help_and_shows_its_default() -> None:
    checked = 0
    for name, parser in _parsers(build_parser()):
        fmt = _HelpFormatter(name)
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
                continue
            if isinstance(action, argparse._SubParsersAction):
                continue
            label = f"{name} {'/'.join(action.option_strings) or action.dest}"
            assert action.help, f"{label} has no help"
            if isinstance(action, argparse._StoreTrueAction):
                continue  # an off flag
            if action.option_strings or action.default is not None:
                assert "default" in fmt._get_help_string(action), f"{label} shows no default"
            checked += 1
    assert checked > 30


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(["--version"], capsys)
    assert code == 0 and out.strip() == f"pipenav {agents.__version__}"


def test_eval_shows_progress_and_prints_rounded_figures(tmp_path: Path) -> None:
    proc = pipenav("eval", "route_planner", "--episodes", "3", "--json", str(tmp_path / "e.json"))
    assert proc.returncode == 0, proc.stderr
    assert "eval (fast fidelity)" in proc.stderr and "3/3" in proc.stderr
    printed = json.loads(proc.stdout)
    for key, value in printed.items():
        if isinstance(value, float):
            assert round(value, 3) == value, key
    full = json.loads((tmp_path / "e.json").read_text())
    assert full["episodes"] == printed["episodes"] == 3


@pytest.mark.slow
def test_eval_shows_progress_in_full_fidelity() -> None:
    proc = pipenav(
        "eval",
        "route_planner",
        "--episodes",
        "1",
        "--fidelity",
        "full",
        "--network-config",
        '{"n_fittings": 2}',
    )
    assert proc.returncode == 0, proc.stderr
    assert "eval (full fidelity)" in proc.stderr and "1/1" in proc.stderr


def _tiny_config(tmp_path: Path, **changes: object) -> Path:
    data = yaml.safe_load((ROOT / "agents" / "configs" / "maskable_ppo.yaml").read_text())
    data.update(
        n_envs=1,
        vec_env="dummy",
        total_timesteps=64,
        ppo={"n_steps": 32, "batch_size": 32, "n_epochs": 1},
        eval={"episodes": 2, "every_timesteps": 50_000, "final_episodes": 2},
    )
    data["env_kwargs"]["network_config"]["n_fittings"] = 4
    data.update(changes)
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("section", "typo", "message"),
    [
        ("ppo", {"learning_rat": 0.001}, "ppo: unknown keys ['learning_rat']; allowed:"),
        ("eval", {"episodez": 5}, "eval: unknown keys ['episodez']; allowed:"),
    ],
)
def test_a_mistyped_training_key_is_an_error_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], section: str, typo: dict, message: str
) -> None:
    config = _tiny_config(tmp_path, **{section: typo})
    out = tmp_path / "run"
    code, text, err = run_cli(["train", "--config", str(config), "--out", str(out)], capsys)
    assert code == 2
    assert text.startswith("error: --config") and message in text
    assert not out.exists()  # no work started


@pytest.mark.slow
def test_a_run_too_short_to_evaluate_says_so_and_ends_with_held_out_evaluation(
    tmp_path: Path,
) -> None:
    out = tmp_path / "run"
    proc = pipenav("train", "--config", str(_tiny_config(tmp_path)), "--out", str(out))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads(proc.stdout[: proc.stdout.rindex("}") + 1])
    assert summary["best_model"] is None and not (out / "best" / "best_model.zip").exists()
    assert "no validation evaluation ran" in summary["note"]
    assert "note: no validation evaluation ran" in proc.stdout
    held_out = summary["held_out_evaluation"]
    assert held_out["episodes"] == 2 and held_out["model"].endswith("final_model.zip")
    assert "train" in proc.stderr and "held-out evaluation" in proc.stderr
    assert json.loads((out / "summary.json").read_text())["best_model"] is None


def test_train_progress_follows_the_minutes_budget() -> None:
    """With far more timesteps than the budget allows, the bar is as far along as the time."""
    from agents.train import _BudgetProgress

    bar = _BudgetProgress(total_timesteps=10**9, minutes=1.0)
    bar.t0 = time.monotonic() - 30.0  # half the minute spent
    bar.update(10, force=True)
    done = bar.progress.tasks[0].completed
    bar.progress.stop()
    assert 495 <= done <= 600
    bar = _BudgetProgress(total_timesteps=100, minutes=60.0)
    bar.update(75, force=True)  # the timesteps end this one
    done = bar.progress.tasks[0].completed
    bar.progress.stop()
    assert 745 <= done <= 760


@pytest.mark.slow
def test_eval_accepts_a_plain_ppo_model(tmp_path: Path) -> None:
    from stable_baselines3 import PPO

    import pipe_env  # noqa: F401
    from agents.evaluate import is_maskable_model

    env = gym.make("pipenav/PipeNav-v0", network_config={"n_fittings": 4})
    path = tmp_path / "plain_ppo.zip"
    PPO("MultiInputPolicy", env, n_steps=16, batch_size=16, seed=0, device="cpu").save(path)
    env.close()
    assert not is_maskable_model(path) and is_maskable_model(SHIPPED_POLICY)
    proc = pipenav("eval", str(path), "--episodes", "2", "--network-config", '{"n_fittings": 4}')
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = json.loads(proc.stdout)
    assert result["episodes"] == 2 and 0.0 <= result["success_rate"] <= 1.0


def test_eval_refuses_a_zip_that_is_not_a_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "notes.zip"
    bad.write_bytes(b"not a zip")
    code, text, _ = run_cli(["eval", str(bad)], capsys)
    assert code == 2 and "not a Stable-Baselines3 model file" in text


def test_drive_does_not_ask_when_the_reset_already_ended_the_episode(tmp_path: Path) -> None:
    from rich.console import Console

    import pipe_env  # noqa: F401
    from agents.console import OperatorConsole
    from pipe_env import layouts

    net = layouts.straight(0.1, 1.0)
    goal = net.start_pose.position + 0.3 * net.start_pose.forward
    env = gym.make("pipenav/PipeNav-v0", network=net.with_goals([goal]), fidelity="fast")

    def read(prompt: str) -> str:
        raise AssertionError(f"asked {prompt!r} after the episode ended")

    console = Console(record=True, width=120)
    # a network whose goal the reset's drive reaches is refused (one clear error), not asked
    assert OperatorConsole(env, read=read, console=console, out=tmp_path).run() == 2
    assert "the goal is reached inside reset()" in console.export_text()


def test_bench_is_a_checkout_command_and_finds_its_scripts_from_anywhere(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, text, _ = run_cli(["bench", "--help"], capsys)
    assert code == 0 and "checkout" in text
    proc = pipenav("bench", "world", "--help", cwd=tmp_path)
    assert proc.returncode == 0 and "usage" in proc.stdout.lower()


def test_ray_connects_to_the_given_cluster_else_starts_a_local_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    local = ray_init_kwargs(jobs=3)
    assert local["address"] == "local" and local["num_cpus"] == 3
    monkeypatch.setenv("RAY_ADDRESS", "ray://head:10001")
    env = ray_init_kwargs(jobs=3)
    assert env["address"] == "ray://head:10001" and "num_cpus" not in env
    given = ray_init_kwargs(jobs=3, address="10.0.0.5:6379")  # the option wins
    assert given["address"] == "10.0.0.5:6379" and "num_cpus" not in given
    monkeypatch.setenv("RAY_ADDRESS", "")
    assert ray_init_kwargs(jobs=1)["address"] == "local"


def test_scenarios_run_takes_a_ray_address(capsys: pytest.CaptureFixture[str]) -> None:
    code, text, _ = run_cli(["scenarios", "run", "--help"], capsys)
    assert code == 0 and "--ray-address" in text and "RAY_ADDRESS" in text
