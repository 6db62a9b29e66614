"""The pipenav CLI in-process: bad input is one "error: ..." line and exit code 2, never a
traceback; ``plot`` reports only the files it wrote."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from agents.cli import EXIT_USAGE, main


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Exit code and printed text (stdout and stderr) of ``pipenav argv``."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out + captured.err


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["demo", "--lidar", "foo"], "argument --lidar: invalid choice: 'foo'"),
        (["demo", "--agent", "nobody"], "argument --agent: invalid choice: 'nobody'"),
        (["demo", "--fittings", "0"], "argument --fittings: '0' is not allowed; use an int >= 1"),
        (["eval", "goal_greedy", "--detector", "foo"], "argument --detector: invalid choice"),
        (["eval", "goal_greedy", "--episodes", "0"], "argument --episodes: '0' is not allowed"),
        (["eval", "nobody"], "error: agent 'nobody' is neither a scripted agent"),
        (["eval", "goal_greedy", "--network-config", "[1]"], "must be a JSON object"),
        (
            ["eval", "goal_greedy", "--network-config", '{"n_fittings": -3}'],
            "error: --network-config: NetworkConfig.n_fittings = -3: out of range",
        ),
        (["plot", "/nonexistent/episode.json"], "error: /nonexistent/episode.json: not a readable"),
        (["train", "--config", "/nonexistent/run.yaml"], "error: --config '/nonexistent/run.yaml'"),
        (["train", "--minutes", "-1"], "argument --minutes: '-1' is not allowed"),
        (["scenarios", "run", "--jobs", "0"], "argument --jobs: '0' is not allowed"),
        (["drive", "--detector", "oracle"], "argument --detector: invalid choice: 'oracle'"),
        (["drive", "--lidar", "hokuyo"], "argument --lidar: invalid choice: 'hokuyo'"),
    ],
)
def test_bad_input_is_a_usage_error(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, text = run_cli(argv, capsys)
    assert code == EXIT_USAGE, text
    assert "error: " in text and expected in text, text
    assert "Traceback" not in text


def test_bad_training_config_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "run.yaml"
    config.write_text("n_envs: 0\n")
    code, text = run_cli(["train", "--config", str(config)], capsys)
    assert code == EXIT_USAGE
    assert "n_envs=0 is not allowed" in text


def test_bad_output_paths_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Output files and folders are checked before any work starts."""
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    cases = [
        (["eval", "goal_greedy", "--episodes", "1", "--json", str(tmp_path)], "is a folder"),
        (["eval", "goal_greedy", "--json", str(blocker / "out.json")], "cannot be created"),
        (["scenarios", "run", "tee_*", "--junit", str(tmp_path)], "is a folder"),
        (["train", "--out", str(blocker / "run")], "cannot be created"),
    ]
    for argv, expected in cases:
        code, text = run_cli(argv, capsys)
        assert code == EXIT_USAGE, text
        assert "error: " in text and expected in text and "Traceback" not in text, text


def test_training_config_with_bad_env_kwargs_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The environment's argument checks run before the training workers start."""
    config = tmp_path / "run.yaml"
    config.write_text("env_kwargs:\n  trigger_distance: -1.0\n")
    code, text = run_cli(["train", "--config", str(config)], capsys)
    assert code == EXIT_USAGE, text
    assert "env_kwargs: PipeNav-v0: trigger_distance = -1.0: out of range" in text, text


def test_plot_reports_only_the_files_it_wrote(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from agents.episodes import run_episode, save_episode_plots

    episode = tmp_path / "episode"
    log = run_episode(fidelity="fast", detector="ground_truth", n_fittings=4, out=episode)
    # an episode run with rendering lists its render, which lives in its own folder
    log["files"] = ["render.png"]
    (episode / "episode.json").write_text(json.dumps(log))
    plots = tmp_path / "plots"
    code, text = run_cli(["plot", str(episode / "episode.json"), "--out", str(plots)], capsys)
    assert code == 0, text
    assert text.split() == [str(plots / "map.png"), str(plots / "detection.png")]
    assert sorted(p.name for p in plots.iterdir()) == ["detection.png", "map.png"]
    assert save_episode_plots(log, plots, which="map") == ["map.png"]
