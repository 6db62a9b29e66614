"""The pipenav CLI in a subprocess: exit codes, JUnit and JSON reports that agree."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest
import yaml

TEE = {"layout": "t_junction", "params": {"diameter": 0.1, "direction": 0.0, "distance": 0.5}}


def write(folder: Path, name: str, data: dict) -> None:
    (folder / f"{name}.yaml").write_text(yaml.safe_dump(data))


def pipenav(
    *args: str, stdin: str | None = None, timeout: int = 300
) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "agents.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        input=stdin,
    )


@pytest.fixture()
def tiny_suite(tmp_path: Path) -> Path:
    base = {
        "network": TEE,
        "goal": {"way": 1, "distance": 0.45},
        "fidelity": "fast",
        "detector": "ground_truth",
        "agent": "route_planner",
        "max_decisions": 8,
    }
    write(
        tmp_path,
        "reach_branch",
        {**base, "seeds": [0, 1], "criteria": {"success": True, "max_jams": 0}},
    )
    write(tmp_path, "wrong_expectation", {**base, "criteria": {"max_decisions": 0}})
    return tmp_path


def test_scenarios_run_reports_agree_and_exit_code(tiny_suite: Path, tmp_path: Path) -> None:
    junit, js = tmp_path / "r.xml", tmp_path / "r.json"
    proc = pipenav(
        "scenarios",
        "run",
        "--dir",
        str(tiny_suite),
        "--junit",
        str(junit),
        "--json",
        str(js),
        "--jobs",
        "2",
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "replay: pipenav scenarios run 'wrong_expectation' --seed 0" in proc.stdout
    root = ET.parse(junit).getroot()
    cases = root.findall(".//testcase")
    assert sorted(c.get("name") for c in cases) == [
        "reach_branch[seed=0]",
        "reach_branch[seed=1]",
        "wrong_expectation[seed=0]",
    ]
    failures = {c.get("name"): c.find("failure") for c in cases}
    fail = failures["wrong_expectation[seed=0]"]
    assert fail is not None
    assert "max_decisions: measured 1, threshold 0" in fail.get("message")
    assert failures["reach_branch[seed=0]"] is None
    doc = json.loads(js.read_text())
    assert doc["schema_version"] == 1
    assert {"numpy", "mujoco", "gymnasium"} <= set(doc["packages"])
    assert doc["summary"] == {
        "total": 3,
        "passed": 2,
        "failed": 1,
        "errors": 0,
        "expected_failures": 0,
        "unexpected_passes": 0,
        "not_run": 0,
    }
    by_name = {f"{r['scenario']}[seed={r['seed']}]": r for r in doc["results"]}
    for name, case in failures.items():
        assert by_name[name]["passed"] == (case is None)
        assert by_name[name]["metrics"]["decisions"] == int(
            next(
                p.get("value")
                for p in cases[[c.get("name") for c in cases].index(name)].iter("property")
                if p.get("name") == "decisions"
            )
        )
    assert by_name["wrong_expectation[seed=0]"]["replay"].startswith("pipenav scenarios run")


def test_scenarios_run_passing_set_exits_zero_and_list(tiny_suite: Path) -> None:
    proc = pipenav("scenarios", "run", "reach*", "--dir", str(tiny_suite))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "2 passed, 0 failed" in proc.stdout
    # progress lines keep "[seed=N]" (rich would take it for markup and drop it)
    assert "PASS reach_branch [seed=0]" in proc.stdout
    assert "PASS reach_branch [seed=1]" in proc.stdout
    listed = pipenav("scenarios", "list", "--dir", str(tiny_suite))
    assert listed.returncode == 0 and "reach_branch" in listed.stdout


def test_bad_scenario_file_is_an_error_testcase_naming_file_and_key(tmp_path: Path) -> None:
    write(tmp_path, "broken", {"network": TEE, "detectr": "improved"})
    proc = pipenav("scenarios", "run", "--dir", str(tmp_path))
    assert proc.returncode == 1
    assert "ERROR broken [seed=0]" in proc.stdout
    assert "broken.yaml: detectr = 'improved': unknown key; allowed:" in proc.stdout
    assert "Traceback" not in proc.stdout + proc.stderr
    listed = pipenav("scenarios", "list", "--dir", str(tmp_path))
    assert listed.returncode == 2
    assert "broken.yaml: detectr = 'improved': unknown key; allowed:" in listed.stdout


def test_packaged_scenarios_all_validate() -> None:
    proc = pipenav("scenarios", "list")
    assert proc.returncode == 0, proc.stdout
    count = int(proc.stdout.strip().splitlines()[-1].split()[0])
    assert count >= 25


def test_drive_console_takes_keys(tmp_path: Path) -> None:
    proc = pipenav(
        "drive",
        "--layout",
        "t_junction",
        "--fidelity",
        "fast",
        "--out",
        str(tmp_path),
        stdin="7\nb\n1\nq\n",
    )
    assert proc.returncode == 0, proc.stderr
    assert "structure ahead: junction" in proc.stdout
    assert "'7' is not a choice" in proc.stdout
    assert "-> back_out" in proc.stdout
    assert "goal reached" in proc.stdout
    assert (tmp_path / "view.png").exists()


def test_eval_and_plot_commands(tmp_path: Path) -> None:
    proc = pipenav(
        "eval",
        "goal_greedy",
        "--episodes",
        "5",
        "--json",
        str(tmp_path / "e.json"),
        "--network-config",
        '{"n_fittings": 5}',
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "e.json").read_text())
    assert result["episodes"] == 5 and 0.0 <= result["success_rate"] <= 1.0
    demo = pipenav("demo", "--fidelity", "fast", "--out", str(tmp_path / "demo"), "--no-render")
    assert demo.returncode == 0, demo.stderr
    plot = pipenav("plot", str(tmp_path / "demo" / "episode.json"), "--out", str(tmp_path / "p"))
    assert plot.returncode == 0, plot.stderr
    assert (tmp_path / "p" / "map.png").exists() and (tmp_path / "p" / "detection.png").exists()


def test_bad_layout_parameters_and_values_are_usage_errors(tmp_path: Path) -> None:
    write(tmp_path, "too_wide", {"network": {"layout": "t_junction", "params": {"diameter": 0.5}}})
    proc = pipenav("scenarios", "run", "--dir", str(tmp_path))
    # a broken selected file is an error testcase of the run, not an abort
    assert proc.returncode == 1 and "Traceback" not in proc.stdout + proc.stderr
    assert "ERROR too_wide [seed=0]" in proc.stdout
    assert (
        "too_wide.yaml: network.params.diameter = 0.5: out of range; allowed: 0.02 to 0.25 (m)"
        in proc.stdout
    )
    (tmp_path / "too_wide.yaml").unlink()
    write(tmp_path, "unhashable", {"network": {"layout": [1]}, "sensor": {"preset": ["ideal"]}})
    proc = pipenav("scenarios", "list", "--dir", str(tmp_path))
    assert proc.returncode == 2 and "Traceback" not in proc.stdout + proc.stderr
    assert "unhashable.yaml: network.layout = [1]: unknown" in proc.stdout
    bad = pipenav(
        "drive", "--layout", "t_junction", "--params", "{diameter: 1}", "--fidelity", "fast"
    )
    assert bad.returncode == 2 and "--params is not JSON" in bad.stdout
