"""Reliability at the edges (issue: bounded work, errors that name the problem, atomic writes):
strict actions, network specs and files, JSON without NaN, absurd geometry, a corrupt packaged
data file, atomic writes, and no episode that is over before it starts."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import pipe_env  # noqa: F401
from pipe_env import layouts
from pipe_env.generator import NetworkConfig, generate_network
from pipe_env.network import PipeNetwork
from pipe_env.network_io import NetworkSpecError


# ------------------------------------------------------------------------ strict actions
@pytest.fixture(scope="module")
def env() -> gym.Env:
    net = layouts.t_junction(0.1).with_goals([[0.0, 0.4, 0.0]])
    e = gym.make("pipenav/PipeNav-v0", network=net, max_episode_steps=50)
    yield e
    e.close()


@pytest.mark.parametrize("action", [0.9, -0.5, 2.5, "1", b"1", True, np.bool_(True), None, 6, -1])
def test_step_rejects_anything_but_an_integer_action(env: gym.Env, action: object) -> None:
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"^action = .*: not allowed \(\w+\); allowed: an integer"):
        env.step(action)


@pytest.mark.parametrize("action", [1, np.int64(1), np.int32(1), np.uint8(1), np.array(1)])
def test_step_accepts_python_and_numpy_integers(env: gym.Env, action: object) -> None:
    env.reset(seed=0)
    env.step(action)


# ------------------------------------------------------------------- network specs / files
def spec() -> dict:
    return layouts.t_junction(0.1).to_dict()


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (
            lambda d: d.update(start={"position": [0, 0, 0], "forward": "x"}),
            r"^start.forward = 'x': not a list of numbers",
        ),
        (lambda d: d.update(start={"position": [0, 0, 0], "forward": [0, 0, 0]}), "start.forward"),
        (lambda d: d.update(start=5), r"^start = 5: not a mapping; allowed: a mapping"),
        (
            lambda d: d.update(goals=[[1, 2]]),
            r"^goals\[0\] = \[1, 2\]: shape \(2,\); allowed: 3 finite",
        ),
        (lambda d: d.update(goals=[[10**400, 0, 0]]), r"^goals\[0\] = \[1000"),
        (lambda d: d["fittings"][3].update(position=[0, float("nan"), 0]), r"fittings\[3\]"),
        (
            lambda d: d["fittings"][1].update(position=[10**400, 0, 0]),
            r"^fittings\[1\] \(id 's'\).position = \[1000",
        ),
        (lambda d: d.update(metadata=[1]), r"^metadata = \[1\]: not a mapping; allowed: a mapping"),
        (lambda d: d.update(metadata={"x": float("inf")}), r"^metadata.x = inf: not finite"),
        (
            lambda d: d["runs"][0].update(diameter=[0.1]),
            r"^runs\[0\] \(id 'r_in'\).diameter = \[0.1\]: not a number",
        ),
        (
            lambda d: d["runs"][0].update(diameter=float("inf")),
            r"^runs\[0\] \(id 'r_in'\).diameter = inf: not finite",
        ),
        (
            lambda d: d["fittings"].append(7),
            r"^fittings\[4\] = 7: not a mapping; allowed: a mapping",
        ),
        (lambda d: d.update(name=["x"]), r"^name = \['x'\]: not a string; allowed: a string"),
        (lambda d: d.update(version=True), r"^version = True: unsupported"),
    ],
)
def test_spec_errors_name_the_field_path(mutate, message: str) -> None:
    d = spec()
    mutate(d)
    with pytest.raises(NetworkSpecError, match=message) as err:
        PipeNetwork.from_dict(d)
    assert "numpy" not in str(err.value) and "float()" not in str(err.value)


def test_absurd_geometry_is_rejected_by_validate() -> None:
    d = layouts.straight(0.1, 3.0).to_dict()
    for f in d["fittings"]:
        f["position"] = [1e308 * (1 if v > 0 else 0) + v for v in f["position"]]
    d["fittings"][1]["position"] = [1e308, 0, 0]
    with pytest.raises(ValueError, match=r"outside the allowed extent; allowed: coordinates"):
        PipeNetwork.from_dict(d)
    far = PipeNetwork.from_dict(layouts.straight(0.1, 3.0).to_dict(), validate=False)
    far = far.with_goals([[5000.0, 0, 0]])
    with pytest.raises(ValueError, match=r"goals\[0\].*outside the allowed extent"):
        far.validate()


def test_to_json_never_writes_nan_or_infinity() -> None:
    import dataclasses

    base = layouts.t_junction(0.1)
    runs = (dataclasses.replace(base.runs[0], diameter=float("nan")), *base.runs[1:])
    net = PipeNetwork(base.fittings, runs, base.start_pose, metadata={"m": np.float64("inf")})
    text = net.to_json()
    assert "NaN" not in text and "Infinity" not in text
    json.loads(text)


def test_missing_and_corrupt_network_files_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"nope.json: file = 'nope.json': network file not found"):
        PipeNetwork.load(tmp_path / "nope.json")
    (tmp_path / "bad.json").write_text('{"version": 1, "fittings": [')
    with pytest.raises(ValueError, match=r"bad.json: contents = .*: not valid JSON at line 1"):
        PipeNetwork.load(tmp_path / "bad.json")
    (tmp_path / "bad.yaml").write_text("version: [1\n")
    with pytest.raises(ValueError, match=r"bad.yaml: contents = .*: not valid YAML at line"):
        PipeNetwork.load(tmp_path / "bad.yaml")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match=r"bin.json: file = 'bin.json': not UTF-8 text"):
        PipeNetwork.load(tmp_path / "bin.json")
    d = spec()
    d["goals"] = [[0, 0]]
    (tmp_path / "field.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match=r"field.json: goals\[0\] = \[0, 0\]: shape \(2,\)"):
        PipeNetwork.load(tmp_path / "field.json")
    with pytest.raises(ValueError, match=r"PipeNav-v0: .*missing.yaml.*network file not found"):
        gym.make("pipenav/PipeNav-v0", network=str(tmp_path / "missing.yaml"))


def test_network_save_is_atomic(tmp_path: Path) -> None:
    target = tmp_path / "net.json"
    net = layouts.t_junction(0.1)
    net.save(target)
    before = target.read_text()
    broken = net.derived(metadata={"bad": object()})  # cannot be serialised
    with pytest.raises(TypeError):
        broken.save(target)
    assert target.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["net.json"]


def test_corrupt_packaged_sensing_models_fail_naming_the_file(tmp_path: Path) -> None:
    """A truncated sensing_models.json (what a crash during a non-atomic write left) is an
    error naming the file, not a bare JSONDecodeError (run in a copy of the package)."""
    import shutil

    root = Path(pipe_env.__file__).resolve().parents[1]
    for pkg in ("pipe_env", "detector"):
        shutil.copytree(root / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    data = tmp_path / "pipe_env" / "data" / "sensing_models.json"
    data.write_text(data.read_text()[:100])
    code = (
        "import gymnasium as gym, pipe_env\n"
        "try:\n"
        "    gym.make('pipenav/PipeNav-v0').reset(seed=0)\n"
        "except ValueError as exc:\n"
        "    print('ValueError:', exc)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
    )
    assert "sensing_models.json: the sensing models file is corrupt" in proc.stdout, (
        proc.stdout + proc.stderr
    )
    assert "Traceback" not in proc.stderr


# ------------------------------------------------------------- no episode over at reset
def test_fixed_network_whose_goal_reset_reaches_is_rejected() -> None:
    net = layouts.mitre_bend(0.1).with_goals([[0.0, 0.4, 0.0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth")
    with pytest.raises(ValueError, match=r"the goal is reached inside reset\(\)"):
        env.reset(seed=0)
    fine = layouts.t_junction(0.1).with_goals([[0.0, 0.4, 0.0]])
    env = gym.make("pipenav/PipeNav-v0", network=fine, detector="ground_truth")
    env.reset(seed=0)
    assert env.unwrapped.decision is not None


@pytest.mark.parametrize("seed", [156, 276, 0, 1, 2])
def test_generated_networks_never_put_the_goal_where_reset_reaches_it(seed: int) -> None:
    """Seeds 156 and 276 placed the goal before the closure that the start's single ways lead
    to (found by generating 400 default networks)."""
    net = generate_network(NetworkConfig(), np.random.default_rng(seed))
    env = gym.make("pipenav/PipeNav-v0", detector="ground_truth")
    env.reset(seed=0, options={"network": net})
    assert env.unwrapped.decision is not None
    assert not math.isnan(float(env.unwrapped.jams))


# ------------------------------------------------------------------ scenario files
@pytest.mark.parametrize(
    ("extra", "key"),
    [
        ({"start": {"position": [10**400, 0, 0], "forward": [1, 0, 0]}}, "start.position"),
        ({"goal": [10**400, 0, 0]}, "goal"),
        ({"criteria": {"max_detection_error": {"angle_deg": 10**400}}}, "criteria"),
        ({"seeds": [10**30]}, "seeds"),
        ({"timeout_s": 10**400}, "timeout_s"),
    ],
)
def test_over_large_integers_in_a_scenario_are_named_errors(
    tmp_path: Path, extra: dict, key: str
) -> None:
    import yaml

    from agents.scenarios import ScenarioError, load_scenario

    data = {"network": {"layout": "t_junction", "params": {"diameter": 0.1}}, **extra}
    (tmp_path / "big.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match=rf"big.yaml: {key}"):
        load_scenario(tmp_path / "big.yaml")


# ---------------------------------------------------------------------- atomic writes
def test_figures_and_telemetry_are_written_atomically(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipe_env.plotting import save_figure
    from primitives.executor import SequenceOutcome

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    save_figure(fig, tmp_path / "a.png", dpi=50)
    save_figure(fig, tmp_path / "a.svg")
    plt.close(fig)
    assert (tmp_path / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<svg" in (tmp_path / "a.svg").read_bytes()[:400]
    out = SequenceOutcome(telemetry={"times": np.arange(3.0)})
    out.save(tmp_path / "run")
    with np.load(tmp_path / "run.npz") as z:
        assert z["status"] == "done" and z["times"].tolist() == [0.0, 1.0, 2.0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "a.svg", "run.npz"]


# --------------------------------------------------------------------------- soak
@pytest.mark.slow
def test_full_fidelity_episodes_keep_one_world_and_renderer() -> None:
    """Nothing accumulates across full-fidelity episodes with rendering: one world, one
    plant, at most one renderer alive (benchmarks/soak.py measures the RSS)."""
    import collections
    import gc

    from agents.evaluate import random_valid_episode

    env = gym.make(
        "pipenav/PipeNav-v0",
        fidelity="full",
        render_mode="rgb_array",
        network_config={"n_fittings": 4},
        max_episode_steps=2,
    )
    names = ("PipeWorld", "PhysicalPlant", "Renderer", "RotatingLidar")

    def alive() -> tuple[int, ...]:
        gc.collect()
        c = collections.Counter(type(o).__name__ for o in gc.get_objects())
        return tuple(c[n] for n in names)

    # (counted against what the process held before: tests run earlier in the same worker
    # may have left their own objects for the collector)
    before = alive()
    rng = np.random.default_rng(0)
    counts = []
    for ep in range(4):
        random_valid_episode(env, rng, ep)
        env.render()
        counts.append(tuple(n - b for n, b in zip(alive(), before)))
    env.close()
    for worlds, plants, renderers, lidars in counts:
        assert plants == 1 and lidars == 1 and renderers <= 1 and worlds <= 2, counts
    assert counts[-1] == counts[0], counts


def _spawned_children(pid: int) -> list[int]:
    """The pids of ``pid``'s living children that are multiprocessing spawn workers (Linux)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[1]) == pid and fields[0] != "Z" and b"spawn_main" in cmdline:
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2 :].split()[0] != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signal: Linux")
def test_benchmark_workers_end_when_the_benchmark_is_killed() -> None:
    """A benchmark's worker pool (``benchmarks.workers.run_plan``) killed with SIGKILL, as a
    stopped job is: its spawned workers end too, rather than living on idle with their
    worlds."""
    import signal
    import time

    root = str(Path(__file__).resolve().parents[1])
    code = (
        f"import sys, time; sys.path.insert(0, {root!r}); "
        "from benchmarks.workers import run_plan; "
        "run_plan(time.sleep, [(120,)] * 4, jobs=2)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while len(workers) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
            workers = _spawned_children(proc.pid)
        assert len(workers) == 2, workers
        time.sleep(3.0)  # (each has run its initializer and taken a task)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 20
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(w) for w in workers), "workers outlived the killed benchmark"
    finally:
        for w in [proc.pid, *workers]:
            if _alive(w):
                os.kill(w, signal.SIGKILL)
