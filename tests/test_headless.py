"""No OpenGL needed: importing, making and stepping the envs, and the demo without its render.

Each test runs a fresh interpreter with ``MUJOCO_GL``, ``DISPLAY`` and ``PYOPENGL_PLATFORM``
unset (or with ``MUJOCO_GL`` naming a backend that cannot work here), as on a fresh headless
machine: nothing may set or need a GL backend until something renders.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

STEP_BOTH_ENVS = """
import os
before = os.environ.get("MUJOCO_GL")
import gymnasium as gym
import numpy as np
import agents, detector, primitives, pipe_env
from pipe_env import layouts
assert os.environ.get("MUJOCO_GL") == before, "importing pipenav set MUJOCO_GL"
net = layouts.t_junction(0.1, direction=0.0, distance=0.3).with_goals([[0, 0.5, 0]])
for env_id in ("pipenav/PipeNav-v0", "pipenav/PipeExplore-v0"):
    for fidelity in FIDELITIES:
        env = gym.make(env_id, network=net, fidelity=fidelity, detector="ground_truth")
        obs, info = env.reset(seed=0)
        obs, reward, term, trunc, info = env.step(int(np.flatnonzero(info["action_mask"])[0]))
        assert np.isfinite(reward)
        env.close()
        print(env_id, fidelity, "ok")
assert os.environ.get("MUJOCO_GL") == before
"""


def _headless_env(**extra: str) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")
    }
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(extra)
    return env


def _run(code: str, env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, *(["-c", code] if code else []), *args],
        env=env,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_headless_import_and_fast_envs_need_no_gl() -> None:
    proc = _run(STEP_BOTH_ENVS.replace("FIDELITIES", '("fast",)'), _headless_env())
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count(" ok") == 2


def test_headless_full_fidelity_envs_need_no_gl() -> None:
    proc = _run(STEP_BOTH_ENVS.replace("FIDELITIES", '("fast", "full")'), _headless_env())
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count(" ok") == 4


# GLFW cannot open a window without a display: a backend the user chose that cannot work
NO_BACKEND = {"MUJOCO_GL": "glfw"}


def test_without_a_working_backend_rendering_says_what_to_install() -> None:
    code = STEP_BOTH_ENVS.replace("FIDELITIES", '("fast",)') + (
        "from pipe_env.rendering import RenderingUnavailable, rendering_unavailable_reason\n"
        "env = gym.make('pipenav/PipeNav-v0', network=net, render_mode='rgb_array')\n"
        "env.reset(seed=0)\n"
        "try:\n"
        "    env.render()\n"
        "except RenderingUnavailable as exc:\n"
        "    print('unavailable:', exc)\n"
        "assert rendering_unavailable_reason() is not None\n"
    )
    proc = _run(code, _headless_env(**NO_BACKEND))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count(" ok") == 2
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("unavailable:"))
    assert "glfw" in line and "libosmesa6" in line and "EGL" in line


def test_demo_without_a_working_backend_skips_only_the_render(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    proc = _run(
        "",
        _headless_env(**NO_BACKEND),
        "-m",
        "agents.cli",
        "demo",
        "--fidelity",
        "fast",
        "--fittings",
        "3",
        "--out",
        str(out),
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "report.json").read_text())
    assert "render.png" not in report["files"] and "map.png" in report["files"]
    assert (out / "map.png").stat().st_size > 0
    assert "glfw" in report["render_skipped"]
    assert "3D render skipped:" in proc.stdout


def test_render_picks_a_backend_without_mujoco_gl(needs_gl: str) -> None:
    """With MUJOCO_GL unset, a render works on a machine with EGL or OSMesa and leaves
    MUJOCO_GL unset (the choice is this process's, not the environment's)."""
    code = (
        "import os\n"
        "from pipe_env import layouts\n"
        "from pipe_env.world import build_world\n"
        "from pipe_env.rendering import WorldRenderer, gl_backend\n"
        "img = WorldRenderer(build_world(layouts.mitre_bend(0.1)), 64, 48).render('top')\n"
        "assert img.shape == (48, 64, 3) and img.std() > 1\n"
        "assert 'MUJOCO_GL' not in os.environ\n"
        "print('backend', gl_backend())\n"
    )
    proc = _run(code, _headless_env())
    if proc.returncode != 0 and "RenderingUnavailable" in proc.stderr:
        pytest.skip("EGL and OSMesa both unavailable without MUJOCO_GL here")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[-1] in ("egl", "osmesa", "glfw")


def test_a_broken_mujoco_gl_is_named_on_import() -> None:
    """MuJoCo imports the backend MUJOCO_GL names: when it cannot load, the import error says
    which variable to change instead of PyOpenGL's internals."""
    proc = _run("import pipe_env", _headless_env(MUJOCO_GL="nonsense"))
    assert proc.returncode != 0
    assert "MUJOCO_GL='nonsense'" in proc.stderr and "unset MUJOCO_GL" in proc.stderr
