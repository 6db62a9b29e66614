"""Every script in ``examples/`` runs in its reduced mode (``--quick``) as a user would run it:
a subprocess from the repository root, its output checked."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def run_example(name: str, *args: str, timeout: float = 600) -> str:
    """Run ``examples/<name>`` with ``args``; its stdout (the test fails on a non-zero exit)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def test_every_example_is_tested() -> None:
    tested = {"random_agent.py", "route_planner.py", "maskable_ppo.py", "detect_recorded_scan.py"}
    tested |= {"make_recorded_scan.py", "record_video.py"}
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_random_agent() -> None:
    out = run_example("random_agent.py", "--quick")
    assert out.count("episode ") == 2
    assert "success rate" in out


def test_route_planner() -> None:
    out = run_example("route_planner.py", "--quick")
    assert "RoutePlanner success" in out and "GoalGreedy" in out


def test_detect_recorded_scan_matches_its_truth() -> None:
    out = run_example("detect_recorded_scan.py", "--quick")
    assert "improved: junction" in out
    assert "thesis:" in out and "truth:" in out


def test_make_recorded_scan_records_the_shipped_kind_of_scan(tmp_path: Path) -> None:
    # the shipped file is a recording: it need not match a later simulator bit for bit, but
    # the script must still record the same sweep of the same structure
    from detector.scan import Scan

    out = tmp_path / "scan.npz"
    run_example("make_recorded_scan.py", "--quick", "--out", str(out))
    made, shipped = Scan.load(out), Scan.load(EXAMPLES / "data" / "tee_100mm_ydlidar_x4.npz")
    assert made.ranges.shape == shipped.ranges.shape
    assert made.metadata["truth"] == shipped.metadata["truth"]
    assert abs(made.n_valid - shipped.n_valid) <= 0.05 * shipped.n_valid


@pytest.mark.slow
def test_maskable_ppo(tmp_path: Path) -> None:
    out = run_example("maskable_ppo.py", "--quick", "--out", str(tmp_path))
    assert (tmp_path / "maskable_ppo.zip").is_file()
    assert "trained policy: success" in out and "shipped policy: success" in out


@pytest.mark.slow
def test_record_video(tmp_path: Path, needs_gl: str) -> None:
    pytest.importorskip("moviepy", reason="RecordVideo needs moviepy")
    out = run_example("record_video.py", "--quick", "--out", str(tmp_path))
    if "no video:" in out:
        pytest.skip(out.strip())
    videos = list(tmp_path.glob("pipenav-episode-*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000, out
