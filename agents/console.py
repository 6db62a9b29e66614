"""The operator console: Decision Support from a terminal.

The robot drives and senses on its own; at each confirmed structure the console shows the
options it found as a table, the person picks one by key, and the robot executes the
motion-primitive sequence. With a display, a live matplotlib window shows the last scan (full
fidelity) or the map; without one, the picture is written to ``--out`` after every decision.

Keys: ``0``-``5`` choose a row, ``b`` backs out, ``q`` quits; the end of the input (Ctrl-D, or
a script of keys that runs out) also ends the session.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
from rich.console import Console
from rich.markup import escape
from rich.table import Table

import pipe_env  # noqa: F401  (registers the environment ids)
from detector.options import direction_name
from pipe_env.envs.actions import K_OPTIONS
from pipe_env.envs.oracle import oracle_of
from pipe_env.plotting import save_figure


class OperatorConsole:
    """Drives one episode of ``env`` with choices read from ``read`` (``input`` by default)."""

    def __init__(
        self,
        env: gym.Env,
        seed: int = 0,
        out: str | Path = "results/drive",
        read: Callable[[str], str] = input,
        console: Console | None = None,
    ) -> None:
        self.env = env
        self.seed = seed
        self.out = Path(out)
        self.read = read
        self.console = console or Console()
        self.live = bool(os.environ.get("DISPLAY"))
        self._fig: Any = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> OperatorConsole:
        from pipe_env.layouts import make_layout
        from pipe_env.network import PipeNetwork

        kwargs: dict[str, Any] = {
            "fidelity": args.fidelity,
            "detector": args.detector,
            "lidar": args.lidar,
        }
        if args.layout:
            try:
                params = json.loads(args.params)
            except json.JSONDecodeError as exc:
                raise ValueError(f"--params is not JSON ({exc}): {args.params!r}") from None
            if not isinstance(params, dict):
                raise ValueError(f"--params must be a JSON object, got {args.params!r}")
            net = make_layout(args.layout, **params)
            if not net.goals:
                end = [f for f in net.fittings if f.kind == "closure" and f.id != "entry"]
                goal = net.geometry[end[-1].id]
                net = net.with_goals([(goal.centre + goal.ports[0].axis * 0.2).tolist()])
            kwargs["network"] = net
        elif args.network:
            kwargs["network"] = PipeNetwork.load(args.network)
        env = gym.make("pipenav/PipeNav-v0", **kwargs)
        return cls(env, seed=args.seed, out=args.out)

    def table(self, info: dict[str, Any]) -> Table:
        oracle = oracle_of(self.env)
        dec = oracle.decision
        title = f"structure ahead: {dec.kind}" if dec is not None else "no decision pending"
        t = Table(
            title=title,
            caption=f"clamped diameter {oracle.clamped_diameter * 1000:.0f}"
            f" mm, jams {info['jams']}, travelled {info['travelled']:.2f} m",
        )
        for col in ("key", "way", "angle", "direction", "distance", "diameter", "confidence"):
            t.add_column(col)
        mask = info["action_mask"]
        if dec is not None:
            for i, o in enumerate(dec.options[: K_OPTIONS - 1]):
                style = None if mask[i] else "dim"
                t.add_row(
                    str(i) if mask[i] else f"({i})",
                    o.kind,
                    f"{math.degrees(o.angle):.0f} deg",
                    "-" if o.is_straight_on else direction_name(o.direction),
                    f"{o.distance * 100:.1f} cm",
                    f"{o.diameter * 1000:.0f} mm",
                    f"{o.confidence:.2f}",
                    style=style,
                )
        t.add_row(f"{K_OPTIONS - 1} / b", "back out", "", "", "", "", "")
        return t

    def picture(self) -> Path:
        """Draw the last scan (full fidelity) or the map, live or to a file."""
        import matplotlib

        if not self.live:
            matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        oracle = oracle_of(self.env)
        scan = oracle.last_scan
        if self._fig is None:
            self._fig = plt.figure(figsize=(7, 6))
        fig = self._fig
        fig.clf()
        if scan is not None:
            ax = fig.add_subplot(projection="3d")
            pts = scan.points("sensor")
            ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=1, c=pts[:, 0], cmap="viridis")
            ax.set_xlabel("x forward [m]")
            ax.set_ylabel("y left [m]")
            ax.set_zlabel("z up [m]")
            ax.set_title(f"last scan: {scan.n_valid} returns")
        else:
            from pipe_env.plotting import draw_network

            ax = fig.add_subplot()
            draw_network(
                ax,
                oracle.network,
                "top",
                path=oracle.driven_path(),
                decisions=oracle.decision_points,
            )
            ax.set_title("map (fast fidelity has no scans)")
        self.out.mkdir(parents=True, exist_ok=True)
        target = self.out / "view.png"
        save_figure(fig, target, dpi=90)
        if self.live:
            plt.pause(0.01)
        return target

    def run(self) -> int:
        try:
            obs, info = self.env.reset(seed=self.seed)
        except ValueError as exc:  # e.g. a network whose goal the reset's drive reaches
            self.console.print(f"error: {escape(str(exc))}")
            return 2
        # the reset's drive can end the episode (jams, or a chain of single ways too long to
        # follow): nothing to ask
        done = oracle_of(self.env).decision is None
        while True:
            self.console.print(self.table(info))
            where = self.picture()
            if not self.live:
                self.console.print(f"view: {where}")
            if done:
                break
            try:
                key = self.read(f"choose [0-{K_OPTIONS - 1}], b back out, q quit: ")
            except EOFError:
                self.console.print("end of input: stopped")
                return 0
            key = key.strip().lower()
            if key in ("q", "quit", "exit"):
                self.console.print("stopped by the operator")
                return 0
            if key == "b":
                key = str(K_OPTIONS - 1)
            if not key.isdigit() or not 0 <= int(key) < K_OPTIONS:
                self.console.print(f"[yellow]'{escape(key)}' is not a choice[/yellow]")
                continue
            if not info["action_mask"][int(key)]:
                self.console.print(f"[yellow]row {key} is not available here[/yellow]")
                continue
            obs, reward, term, trunc, info = self.env.step(int(key))
            outcome = info.get("outcome", "")
            self.console.print(f"-> {outcome}, reward {reward:+.2f}")
            done = term or trunc
        verdict = "goal reached" if info["is_success"] else "episode ended"
        self.console.print(
            f"[bold]{verdict}[/bold]: {info['decisions']} decisions, "
            f"{info['jams']} jams, {info['travelled']:.2f} m"
        )
        return 0
