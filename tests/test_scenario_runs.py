"""Scenario runs that lose nothing: dead workers, hangs, Ctrl-C, broken files, known failures.

Everything runs the real ``pipenav scenarios run`` in a subprocess with real worker processes.
A worker is made to die or hang with the runner's documented test hook
(``PIPENAV_SCENARIO_FAULT="STEM=exit|hang"``); a timeout is also shown on a real full-fidelity
run given an absurdly short ``timeout_s``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest
import yaml

TEE = {"layout": "t_junction", "params": {"diameter": 0.1, "direction": 0.0, "distance": 0.5}}
BASE = {
    "network": TEE,
    "goal": {"way": 1, "distance": 0.45},
    "fidelity": "fast",
    "detector": "ground_truth",
    "agent": "route_planner",
    "max_decisions": 8,
    "criteria": {"success": True},
}


def write(folder: Path, name: str, data: dict) -> None:
    (folder / f"{name}.yaml").write_text(yaml.safe_dump(data))


def run_cli(
    *args: str, fault: str = "", timeout: int = 300
) -> tuple[subprocess.CompletedProcess, dict, ET.Element]:
    folder = Path(args[args.index("--dir") + 1])
    junit, js = folder / "out" / "r.xml", folder / "out" / "r.json"
    env = {**os.environ, "PIPENAV_SCENARIO_FAULT": fault}
    proc = subprocess.run(
        [sys.executable, "-m", "agents.cli", "scenarios", "run", *args]
        + ["--junit", str(junit), "--json", str(js)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )
    assert "Traceback" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr
    return proc, json.loads(js.read_text()), ET.parse(junit).getroot()


def cases_of(root: ET.Element) -> dict[str, ET.Element]:
    return {c.get("name"): c for c in root.iter("testcase")}


def test_dead_worker_is_an_error_testcase_and_the_others_go_on(tmp_path: Path) -> None:
    for name in ("a_ok", "b_dies", "c_ok"):
        write(tmp_path, name, BASE)
    proc, doc, root = run_cli("--dir", str(tmp_path), "--jobs", "2", fault="b_dies=exit")
    assert proc.returncode == 1
    by = {r["scenario"]: r for r in doc["results"]}
    assert by["a_ok"]["status"] == by["c_ok"]["status"] == "passed"
    assert by["b_dies"]["status"] == "error"
    assert "worker process died (exit code 86)" in by["b_dies"]["error"]
    cases = cases_of(root)
    assert cases["b_dies[seed=0]"].find("error") is not None
    assert cases["a_ok[seed=0]"].find("error") is None
    assert doc["summary"]["errors"] == 1 and doc["summary"]["passed"] == 2


def test_hang_times_out_by_file_and_by_option(tmp_path: Path) -> None:
    write(tmp_path, "a_ok", BASE)
    write(tmp_path, "b_hangs", {**BASE, "timeout_s": 3})
    proc, doc, root = run_cli("--dir", str(tmp_path), fault="b_hangs=hang")
    assert proc.returncode == 1
    by = {r["scenario"]: r for r in doc["results"]}
    assert by["a_ok"]["status"] == "passed"
    assert by["b_hangs"]["status"] == "error"
    assert by["b_hangs"]["error"].startswith("timed out after 3 s")
    assert cases_of(root)["b_hangs[seed=0]"].find("error") is not None
    # --timeout overrides the file's limit, for every scenario
    write(tmp_path, "b_hangs", {**BASE, "timeout_s": 600})
    proc, doc, _ = run_cli("--dir", str(tmp_path), "--timeout", "8", fault="b_hangs=hang")
    assert {r["scenario"]: r["status"] for r in doc["results"]} == {
        "a_ok": "passed",
        "b_hangs": "error",
    }
    assert "timed out after 8 s" in doc["results"][1]["error"]


def test_real_full_fidelity_run_past_its_timeout_is_an_error(tmp_path: Path) -> None:
    # (a real run, no injected fault, under a limit far below its cost: building the MuJoCo
    # world and the first sweeps alone take longer; the whole episode took 0.5 s on a fast
    # machine, when an earlier 0.5 s limit let it pass)
    write(tmp_path, "slow", {**BASE, "fidelity": "full", "detector": "improved", "timeout_s": 0.02})
    proc, doc, _ = run_cli("--dir", str(tmp_path))
    assert proc.returncode == 1
    assert doc["results"][0]["status"] == "error"
    assert "timed out after 0.02 s" in doc["results"][0]["error"]


def test_ctrl_c_writes_every_finished_result_and_exits_130(tmp_path: Path) -> None:
    for name in ("a_ok", "b_ok", "c_hangs", "d_later"):
        write(tmp_path, name, BASE)
    junit, js = tmp_path / "r.xml", tmp_path / "r.json"
    env = {**os.environ, "PIPENAV_SCENARIO_FAULT": "c_hangs=hang"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "agents.cli", "scenarios", "run", "--dir", str(tmp_path)]
        + ["--junit", str(junit), "--json", str(js)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,  # (its own process group: a stuck run is killed with its workers)
    )
    try:
        # (both pipes drained as the run writes them: a run blocked on a full stderr pipe would
        # look like a run that ignores Ctrl-C)
        lines: list[str] = []
        errors: list[str] = []
        readers = [
            threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True),
            threading.Thread(target=lambda: errors.extend(proc.stderr), daemon=True),
        ]
        for reader in readers:
            reader.start()
        deadline = time.monotonic() + 240
        while sum("PASS" in ln for ln in lines) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert sum("PASS" in ln for ln in lines) == 2, lines
        time.sleep(1.0)  # c_hangs is running
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"still running 60 s after Ctrl-C: {lines} {errors}") from None
        assert code == 130
        for reader in readers:
            reader.join(timeout=10)
        assert "Traceback" not in "".join(lines + errors)
    finally:
        if proc.poll() is None:  # (a stuck run and its workers: never left behind)
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    doc = json.loads(js.read_text())
    assert doc["interrupted"] is True
    assert [r["status"] for r in doc["results"]] == ["passed", "passed", "not_run", "not_run"]
    cases = cases_of(ET.parse(junit).getroot())
    assert cases["d_later[seed=0]"].find("skipped") is not None
    assert cases["a_ok[seed=0]"].find("skipped") is None


def test_discovery_parses_only_selected_files(tmp_path: Path) -> None:
    write(tmp_path, "a_ok", BASE)
    (tmp_path / "zz_broken.yaml").write_text("network: [unclosed\n")
    proc, doc, _ = run_cli("a_*", "--dir", str(tmp_path))
    assert proc.returncode == 0, proc.stdout
    assert [r["scenario"] for r in doc["results"]] == ["a_ok"]
    proc, doc, root = run_cli("--dir", str(tmp_path))
    assert proc.returncode == 1
    by = {r["scenario"]: r for r in doc["results"]}
    assert by["a_ok"]["status"] == "passed"
    assert by["zz_broken"]["status"] == "error"
    assert "zz_broken.yaml: not valid YAML at line" in by["zz_broken"]["error"]
    assert cases_of(root)["zz_broken[seed=0]"].find("error") is not None


def test_known_failures_are_expected_and_strict_counts_them(tmp_path: Path) -> None:
    write(
        tmp_path,
        "a_known",
        {**BASE, "criteria": {"max_decisions": 0}, "known_failure": "decides once"},
    )
    write(tmp_path, "b_ok", BASE)
    proc, doc, root = run_cli("--dir", str(tmp_path))
    assert proc.returncode == 0, proc.stdout
    assert "XFAIL a_known [seed=0]" in proc.stdout
    r = doc["results"][0]
    assert r["expected_failure"] is True and r["status"] == "expected_failure"
    skipped = cases_of(root)["a_known[seed=0]"].find("skipped")
    assert skipped is not None and "decides once" in skipped.get("message")
    proc, doc, root = run_cli("--dir", str(tmp_path), "--strict")
    assert proc.returncode == 1
    assert cases_of(root)["a_known[seed=0]"].find("failure") is not None
    # a known failure that starts passing is flagged, and fails under --strict
    write(tmp_path, "a_known", {**BASE, "known_failure": "fixed since"})
    proc, doc, root = run_cli("--dir", str(tmp_path))
    assert proc.returncode == 0
    assert "passes but is marked known_failure (fixed since); remove the note" in proc.stdout
    assert doc["results"][0]["unexpected_pass"] is True
    assert doc["summary"]["unexpected_passes"] == 1
    proc, doc, root = run_cli("--dir", str(tmp_path), "--strict")
    assert proc.returncode == 1
    fail = cases_of(root)["a_known[seed=0]"].find("failure")
    assert fail is not None and "unexpected pass" in fail.get("message")


def test_bad_seed_and_timeout_options_are_usage_errors(tmp_path: Path) -> None:
    write(tmp_path, "a_ok", BASE)
    for bad in (["--seed", "-1"], ["--timeout", "0"], ["--timeout", "nan"]):
        proc = subprocess.run(
            [sys.executable, "-m", "agents.cli", "scenarios", "run", "--dir", str(tmp_path), *bad],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 2 and "is not allowed" in proc.stderr, bad


@pytest.mark.slow
def test_ray_backend_dead_worker_and_timeout(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    for name in ("a_ok", "b_dies", "c_ok"):
        write(tmp_path, name, BASE)
    write(tmp_path, "d_hangs", {**BASE, "timeout_s": 20})
    proc, doc, root = run_cli(
        "--dir",
        str(tmp_path),
        "--jobs",
        "2",
        "--backend",
        "ray",
        fault="b_dies=exit,d_hangs=hang",
        timeout=600,
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr
    by = {r["scenario"]: r for r in doc["results"]}
    assert by["a_ok"]["status"] == by["c_ok"]["status"] == "passed"
    assert by["b_dies"]["status"] == "error" and "Ray worker failed" in by["b_dies"]["error"]
    assert by["d_hangs"]["status"] == "error" and "timed out" in by["d_hangs"]["error"]


def test_ctrl_c_during_a_run_is_taken_at_the_wait() -> None:
    """SIGINT while the pool runs sets a flag and wakes its wait; the interrupt is raised by
    ``check``, not where the signal landed; the handler before the run is restored after."""
    from multiprocessing import connection as mp_connection

    from agents.scenario_runner import _CtrlCAtTheWait

    before = signal.getsignal(signal.SIGINT)
    with _CtrlCAtTheWait() as ctrl_c:
        ctrl_c.check()  # nothing yet
        assert mp_connection.wait(ctrl_c.fds(), timeout=0.0) == []
        os.kill(os.getpid(), signal.SIGINT)  # (handled here: no KeyboardInterrupt raised)
        assert mp_connection.wait(ctrl_c.fds(), timeout=5.0) == ctrl_c.fds()
        with pytest.raises(KeyboardInterrupt):
            ctrl_c.check()
    assert signal.getsignal(signal.SIGINT) is before
