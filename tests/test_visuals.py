"""Plots, offscreen renders and the demo command produce real images."""

from __future__ import annotations

import json
import subprocess
import sys

import matplotlib.image as mpimg
import numpy as np

from pipe_env import layouts
from pipe_env.plotting import save_network_plot
from pipe_env.rendering import WorldRenderer
from pipe_env.world import build_world


def test_network_plot_is_written(tmp_path) -> None:
    net = layouts.t_junction(0.1, direction=np.pi / 2)
    out = save_network_plot(
        net,
        tmp_path / "net.png",
        path=[[-0.4, 0, 0], [0, 0, 0], [0, 0, 0.3]],
        decisions=[[0, 0, 0]],
    )
    img = mpimg.imread(out)
    assert img.shape[0] > 300 and img.shape[1] > 600
    assert img[..., :3].std() > 0.05  # not blank


def test_offscreen_render_shows_the_pipes(needs_gl: str) -> None:
    world = build_world(layouts.mitre_bend(0.1))
    renderer = WorldRenderer(world, 160, 120)
    top = renderer.render("top")
    assert top.shape == (120, 160, 3) and top.dtype == np.uint8
    background = np.median(top.reshape(-1, 3), axis=0)
    assert background.min() > 200  # a light background, not black
    differs = np.abs(top.astype(int) - background).sum(axis=2) > 30
    assert 0.01 < differs.mean() < 0.9  # some pipe pixels, not all
    renderer.close()


def test_demo_command_writes_report_and_images(tmp_path, needs_gl: str) -> None:
    out = tmp_path / "demo"
    proc = subprocess.run(
        [sys.executable, "-m", "agents.cli", "demo", "--out", str(out), "--fittings", "4"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "report.json").read_text())
    # the embedded default (seed 7, 4 fittings): the robot decides at least once and the route
    # planner reaches the goal
    assert report["is_success"] is True
    assert report["decisions"] >= 1 and report["structures"] >= 1
    assert report["travelled_m"] > 0.0 and report["detections"] >= 1
    assert {"episode.json", "report.json", "map.png", "detection.png", "render.png"} <= set(
        report["files"]
    )
    for name in report["files"]:
        if name.endswith(".png"):
            assert mpimg.imread(out / name).std() > 0.01, name  # a real picture, not blank
        else:
            json.loads((out / name).read_text())


def test_network_plot_has_a_legend_for_its_markers() -> None:
    import matplotlib.pyplot as plt

    from pipe_env.plotting import plot_network

    net = layouts.t_junction(0.1, direction=np.pi / 2).with_goals([[0, 0.5, 0]])
    fig = plot_network(net, path=[[-0.4, 0, 0], [0, 0, 0]], decisions=[[0, 0, 0]])
    labels = {t.get_text() for t in fig.legends[0].get_texts()}
    plt.close(fig)
    assert {"pipe bore", "tee", "closure", "start", "goal", "driven path", "decision"} == labels
