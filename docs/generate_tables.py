"""The README's reference tables, rendered from the code so that they cannot drift.

Owns the generated parts of ``README.md``: the environments' observation (the columns, bounds
and meanings of :data:`pipe_env.envs.observations.OPTION_COLUMNS` and the observation type's
space), actions, keyword options (the fields and defaults of the config classes in
:mod:`pipe_env.envs.config`), reward terms, and the ``pipenav``
commands (from the CLI's argparse parser). Each table sits in the README between
``<!-- begin generated: NAME -->`` and ``<!-- end generated: NAME -->``.

Every name in the code needs a description (an options column carries its own): an argument or
a command without one raises ``KeyError`` naming it, so a new one cannot go undocumented.

Usage (from the repository root)::

    python docs/generate_tables.py            # print the tables
    python docs/generate_tables.py --write    # rewrite them in README.md
    python docs/generate_tables.py --check    # exit 1 if README.md is out of date
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

README = ROOT / "README.md"


#: The other observation keys.
OBSERVATION_DOCS: dict[str, str] = {
    "options": "the options table: one row per action (columns below)",
    "goal": "the goal in the robot frame from noisy odometry, m (x forward, y left, z up; "
    "zeros in PipeExplore)",
    "proprio": "clamped diameter (m), cosine and sine of the robot's roll",
    "scan": "low-resolution range image of the last sweep / maximum range "
    "(only with `scan_image=True`; zeros in fast fidelity)",
}

#: Keyword options of ``gymnasium.make`` (both environments unless marked).
OPTION_DOCS: dict[str, str] = {
    "network_config": "`NetworkConfig` (or its dict) of the generated networks",
    "network": "a fixed network (`PipeNetwork`, dict or JSON/YAML path) instead of generating",
    "detector": "`improved`, `thesis` or `ground_truth`",
    "fidelity": "`fast` (kinematic, modelled sensing; for RL) or `full` (MuJoCo robot, LiDAR, "
    "detector, executor)",
    "lidar": "sensor preset (`ideal`, `ls02`, `ydlidar_x4`) or a `LidarSpec`",
    "misalignment": "true sensor pose relative to its mount (a `Pose`; full fidelity)",
    "render_mode": "`rgb_array` (an image now), `rgb_array_list` (the frames since the last "
    "call, taken while the robot moves) or `ansi` (the options table as text)",
    "trigger_distance": "stop this far before a structure to decide, m, in (0, 1]",
    "auto_single": "take a single way on without asking the agent",
    "max_jams": "end the episode after this many jams",
    "scan_image": "add the `scan` range image to the observation",
    "network_pool": "draw episodes from a reproducible pool of this many networks",
    "pool_seed": "seed of that pool (use another one for held-out evaluation)",
    "coverage_done": "PipeExplore: covered fraction of the reachable pipe that ends the episode",
    "branch_view": "PipeExplore: how far the scans see into each pipe leaving a fitting, m",
    "physics": "full fidelity: `contact` (physics where contact decides; straight drives far "
    "from fittings glide) or `everywhere` (the all-physics reference)",
}

#: Reward terms (keys of ``info["reward_terms"]``) and the option that sets each.
REWARD_TERMS: tuple[tuple[str, str, str, str], ...] = (
    # (term, environment, meaning, option or "")
    ("progress", "PipeNav", "decrease of the along-network distance to the goal, m", ""),
    ("goal", "PipeNav", "the goal was reached", "reward_goal"),
    ("coverage", "PipeExplore", "new pipe length covered by the scans, m", ""),
    ("jam", "both", "per jam of the chosen way or on the way to the next decision", "reward_jam"),
    ("time", "both", "every decision", "reward_time"),
    (
        "invalid",
        "both",
        "a masked action (the robot stays, the decision is offered again)",
        "reward_invalid",
    ),
)

#: One line per ``pipenav`` command where the parser's own help is not enough (else its help).
COMMAND_NOTES: dict[str, str] = {}


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"`{value:g}`"
    if isinstance(value, str):
        return f'`"{value}"`'
    return f"`{value!r}`"


def _row(*cells: str) -> str:
    return "| " + " | ".join(cells) + " |"


#: What each registered environment asks of the agent (keys: ``pipe_env.ENV_IDS``).
ENV_DOCS: dict[str, str] = {
    "pipenav/PipeNav-v0": "reach the goal of a generated network",
    "pipenav/PipeExplore-v0": "cover as much of the network's pipe as possible",
}


def envs_table() -> str:
    """The registered ids, their classes and decision limits (from ``pipe_env.ENV_IDS``)."""
    from pipe_env import ENV_IDS

    lines = [_row("id", "task", "class", "max_episode_steps"), _row("---", "---", "---", "---")]
    for env_id, (entry, steps) in ENV_IDS.items():
        cls = entry.replace(":", ".")
        lines.append(_row(f"`{env_id}`", ENV_DOCS[env_id], f"`{cls}`", str(steps)))
    return "\n".join(lines)


def observation_table() -> str:
    """The observation keys and the options table's columns, with shapes, bounds and meanings
    (from the observation type, :mod:`pipe_env.envs.observations`)."""
    import numpy as np
    from gymnasium.spaces import Box

    from pipe_env.envs.actions import K_OPTIONS
    from pipe_env.envs.observations import OPTION_COLUMNS, DecisionObservation

    space = DecisionObservation(scan_image=True).space()
    lines = [_row("key", "shape", "meaning"), _row("---", "---", "---")]
    for key, sub in space.spaces.items():
        lines.append(_row(f"`{key}`", str(tuple(sub.shape or ())), OBSERVATION_DOCS[key]))
    lines += ["", _row("column", "name", "range", "meaning"), _row("---", "---", "---", "---")]
    opt = space["options"]
    assert isinstance(opt, Box)
    for i, col in enumerate(OPTION_COLUMNS):
        lo, hi = float(np.min(opt.low[:, i])), float(np.max(opt.high[:, i]))
        lines.append(_row(str(i), f"`{col.name}`", f"[{lo:.3g}, {hi:.3g}]", col.meaning))
    lines += [
        "",
        f"Actions: `Discrete({K_OPTIONS})`. Rows 0-{K_OPTIONS - 2} are the detected ways on "
        f"(straight on first, then by roll direction); row {K_OPTIONS - 1} backs out to the "
        "last junction (or the start) and decides again.",
    ]
    return "\n".join(lines)


def _constructor_options() -> list[tuple[str, object, str]]:
    """(argument, default, env) of ``gymnasium.make``: the fields of the envs' config classes
    (shared ones first, then PipeNav's, then PipeExplore's)."""
    import dataclasses

    from pipe_env.envs.config import EnvConfig, ExploreConfig, NavConfig

    seen: list[tuple[str, object, str]] = []
    shared = {f.name for f in dataclasses.fields(EnvConfig)}
    for cls, where in ((EnvConfig, "both"), (NavConfig, "PipeNav"), (ExploreConfig, "")):
        for f in dataclasses.fields(cls):
            if cls is EnvConfig or f.name not in shared:
                seen.append((f.name, f.default, where))
    return seen


def options_table() -> str:
    """Keyword options of ``gymnasium.make`` with their defaults (from the signatures); the
    reward options are in :func:`rewards_table`."""
    lines = [_row("option", "default", "meaning"), _row("---", "---", "---")]
    names = set()
    rewards = {option for *_, option in REWARD_TERMS if option}
    for name, default, _ in _constructor_options():
        names.add(name)
        if name not in rewards:
            if name not in OPTION_DOCS:
                raise KeyError(f"OPTION_DOCS has no description of the env option {name!r}")
            lines.append(_row(f"`{name}`", _fmt(default), OPTION_DOCS[name]))
    unknown = set(OPTION_DOCS) - names
    if unknown:
        raise KeyError(f"OPTION_DOCS describes options the code does not have: {sorted(unknown)}")
    return "\n".join(lines)


def rewards_table() -> str:
    """Reward terms, the option that sets each and its default."""
    defaults = {name: default for name, default, _ in _constructor_options()}
    lines = [_row("term", "env", "when", "option (default)"), _row("---", "---", "---", "---")]
    for term, env, meaning, option in REWARD_TERMS:
        setting = f"`{option}` ({_fmt(defaults[option])})" if option else "-"
        lines.append(_row(f"`{term}`", env, meaning, setting))
    return "\n".join(lines)


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _help_of(parser: argparse.ArgumentParser, name: str) -> str:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                if choice.dest == name:
                    return choice.help or ""
    return ""


def _options_of(parser: argparse.ArgumentParser) -> str:
    parts = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if action.option_strings:
            parts.append(f"`{max(action.option_strings, key=len)}`")
        else:
            parts.append(f"`{action.dest.upper()}`")
    return " ".join(parts)


def cli_table() -> str:
    """The ``pipenav`` commands, what each does and its arguments (from the parser)."""
    from agents.cli import build_parser

    root = build_parser()
    lines = [_row("command", "what it does", "arguments"), _row("---", "---", "---")]
    for name, sub in _subcommands(root).items():
        nested = _subcommands(sub)
        entries = (
            [(f"{name} {n}", s, _help_of(sub, n)) for n, s in nested.items()]
            if nested
            else [(name, sub, _help_of(root, name))]
        )
        for label, parser, text in entries:
            note = COMMAND_NOTES.get(label, text)
            lines.append(_row(f"`pipenav {label}`", note, _options_of(parser)))
    return "\n".join(lines)


TABLES: dict[str, Callable[[], str]] = {
    "envs": envs_table,
    "observation": observation_table,
    "options": options_table,
    "rewards": rewards_table,
    "cli": cli_table,
}


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(
        rf"(<!-- begin generated: {name} -->\n)(?:.*?\n)?(<!-- end generated: {name} -->)",
        re.DOTALL,
    )


def render_readme(text: str) -> str:
    """``text`` (the README) with every generated table rendered anew."""
    for name, make in TABLES.items():
        pattern = _pattern(name)
        if not pattern.search(text):
            raise KeyError(f"README.md has no generated section {name!r}")
        table = make()

        def put(m: re.Match[str], table: str = table) -> str:
            return m.group(1) + table + "\n" + m.group(2)

        text = pattern.sub(put, text)
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="rewrite the tables in README.md")
    mode.add_argument("--check", action="store_true", help="exit 1 if README.md is stale")
    args = parser.parse_args(argv)
    if not (args.write or args.check):
        for name, make in TABLES.items():
            print(f"<!-- {name} -->\n{make()}\n")
        return 0
    text = README.read_text(encoding="utf-8")
    new = render_readme(text)
    if args.check:
        if new != text:
            print("README.md is out of date: run python docs/generate_tables.py --write")
            return 1
        return 0
    if new != text:
        from detector.atomic import atomic_write_text

        atomic_write_text(README, new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
