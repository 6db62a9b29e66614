"""One recorded episode: run an agent, keep a log, and draw its plots.

The log (``episode.json``) holds the network, the driven path, the decision points, every
detection with its ground truth, and a summary. Plots: the network map with the driven path and
the decisions (top and side views), and the detection estimates against the true distance to
the structure with the ground truth (like thesis figure 5.2).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.scripted import make_agent
from detector.atomic import atomic_write_text
from pipe_env.envs.oracle import oracle_of
from pipe_env.generator import NetworkConfig
from pipe_env.network import PipeNetwork
from pipe_env.network_io import finite_json
from pipe_env.plotting import save_figure

#: The embedded default of the demo: a small 3D network with junctions and a loop.
DEMO_CONFIG = {"n_fittings": 6, "planar": False, "allow_loops": True}


def run_episode(
    seed: int = 7,
    agent: str = "route_planner",
    fidelity: str = "full",
    detector: str = "improved",
    lidar: str = "ideal",
    n_fittings: int = 6,
    network: PipeNetwork | None = None,
    render: bool = False,
    out: Path | None = None,
    max_decisions: int = 40,
    on_decision: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run one PipeNav episode and return its log (see module docstring);
    ``on_decision(n)`` is called after the n-th decision (e.g. for a progress display)."""
    config = NetworkConfig.from_dict({**DEMO_CONFIG, "n_fittings": n_fittings})
    kwargs: dict[str, Any] = {
        "network_config": config,
        "fidelity": fidelity,
        "detector": detector,
        "lidar": lidar,
    }
    if network is not None:
        kwargs["network"] = network
    env = gym.make(
        "pipenav/PipeNav-v0",
        max_episode_steps=max_decisions,
        render_mode="rgb_array" if render else None,
        **kwargs,
    )
    actor = make_agent(agent, env)
    t0 = time.perf_counter()
    obs, info = env.reset(seed=seed)
    actor.reset()
    rewards = []
    choices = []
    done = False
    while not done:
        action = actor.act(obs, info)
        choices.append(int(action))
        obs, reward, term, trunc, info = env.step(action)
        rewards.append(float(reward))
        done = term or trunc
        if on_decision:
            on_decision(len(choices))
    wall = time.perf_counter() - t0
    oracle = oracle_of(env)
    driven = oracle.network
    files = []
    render_skipped = None
    if render and out is not None:
        from pipe_env.rendering import RenderingUnavailable, save_image

        try:
            frame = env.render()
            if not isinstance(frame, np.ndarray):  # rgb_array mode returns one image
                raise RuntimeError(f"render() returned {type(frame).__name__}, not an image")
            save_image(frame, str(Path(out) / "render.png"))
            files.append("render.png")
        except RenderingUnavailable as exc:  # no OpenGL here: the rest of the episode stands
            render_skipped = str(exc)
    log = {
        "network": driven.to_dict(),
        "path": oracle.driven_path().tolist(),
        "decisions": [np.asarray(p).tolist() for p in oracle.decision_points],
        "choices": choices,
        "detections": list(oracle.detection_log),
        "summary": {
            "seed": seed,
            "agent": agent,
            "fidelity": fidelity,
            "detector": detector,
            "lidar": lidar,
            "network": repr(driven),
            "is_success": bool(info["is_success"]),
            "decisions": int(info["decisions"]),
            "structures": int(info["structures"]),
            "jams": int(info["jams"]),
            "travelled_m": round(float(info["travelled"]), 3),
            "shortest_route_m": round(float(info.get("shortest_route", math.nan)), 3),
            "sim_time_s": round(float(info["sim_time"]), 1),
            "wall_time_s": round(wall, 2),
            "return": round(float(sum(rewards)), 3),
            "detections": len(oracle.detection_log),
        },
        "files": files,
        "render_skipped": render_skipped,
    }
    env.close()
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(out) / "episode.json", json.dumps(finite_json(log), allow_nan=False))
    return log


def load_episode(path: str | Path) -> dict[str, Any]:
    """Read an ``episode.json`` written by :func:`run_episode`."""
    p = Path(path)
    try:
        log = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{p}: not a readable episode log ({exc})") from None
    missing = {"network", "path", "detections", "summary"} - set(log)
    if missing:
        raise ValueError(f"{p}: episode log lacks keys {sorted(missing)}")
    return log


def save_episode_plots(log: dict[str, Any], out: str | Path, which: str = "all") -> list[str]:
    """Write ``map.png`` and/or ``detection.png`` into ``out``; return the names of the files
    written here (not those the episode itself wrote, listed in ``log["files"]``)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from pipe_env.plotting import plot_network

    out = Path(out)
    files: list[str] = []
    if which in ("all", "map"):
        net = PipeNetwork.from_dict(log["network"])
        s = log["summary"]
        title = (
            f"{s.get('agent')} / {s.get('fidelity')} / {s.get('detector')}: "
            f"{'goal reached' if s.get('is_success') else 'goal not reached'}, "
            f"{s.get('decisions')} decisions, {s.get('jams')} jams"
        )
        fig = plot_network(net, path=log["path"], decisions=log.get("decisions", []), title=title)
        save_figure(fig, out / "map.png", dpi=110)
        plt.close(fig)
        files.append("map.png")
    if which in ("all", "detection"):
        fig = plot_detections(log["detections"])
        save_figure(fig, out / "detection.png", dpi=110)
        plt.close(fig)
        files.append("detection.png")
    return files


def plot_detections(records: list[dict[str, Any]]):
    """Estimates (distance, diameter, angle, direction) against the true distance to the
    structure, with the ground truth, one colour per structure."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    panels = [
        ("distance", 100.0, "distance [cm]"),
        ("diameter", 1000.0, "diameter [mm]"),
        ("angle", math.degrees(1), "angle [deg]"),
        ("direction", math.degrees(1), "direction [deg]"),
    ]
    nodes = sorted({r["node"] for r in records})
    colours = {n: plt.cm.tab10(i % 10) for i, n in enumerate(nodes)}
    for ax, (key, scale, label) in zip(axes.ravel(), panels):
        for r in records:
            if r["true_distance"] is None:
                continue
            x = r["true_distance"] * 100.0
            c = colours[r["node"]]
            for o in r["options"]:
                ax.plot(x, o[key] * scale, "o", color=c, ms=4, alpha=0.8)
            for t in r["truth"]:
                ax.plot(x, t[key] * scale, "_", color="k", ms=12, mew=2)
        ax.set_xlabel("true distance to the structure [cm]")
        ax.set_ylabel(label)
        ax.invert_xaxis()
        ax.grid(True, alpha=0.3)
    axes[0, 0].plot([], [], "o", color="grey", label="estimate")
    axes[0, 0].plot([], [], "_", color="k", mew=2, label="ground truth")
    axes[0, 0].legend(loc="best")
    fig.suptitle(f"detections: {len(records)} ({len(nodes)} structures)")
    fig.tight_layout()
    return fig
