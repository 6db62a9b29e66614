"""The operator console in-process: keys from a script, the end of input ends the session."""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import pytest
from rich.console import Console

import pipe_env  # noqa: F401  (registers the environment ids)
from agents.console import OperatorConsole
from pipe_env import layouts


def scripted(keys: list[str]) -> Callable[[str], str]:
    """A ``read`` function that answers with ``keys``, then signals the end of input."""
    it = iter(keys)

    def read(prompt: str) -> str:
        try:
            return next(it)
        except StopIteration:
            raise EOFError from None

    return read


def make_console(keys: list[str], out: Path) -> tuple[OperatorConsole, io.StringIO]:
    net = layouts.t_junction(0.1, direction=0.0).with_goals([[0, 0.5, 0]])
    env = gym.make("pipenav/PipeNav-v0", network=net, detector="ground_truth")
    read = scripted(keys)
    text = io.StringIO()
    console = OperatorConsole(env, out=out, read=read, console=Console(file=text, width=120))
    console.live = False
    return console, text


def test_end_of_input_ends_the_session_cleanly(tmp_path: Path) -> None:
    console, text = make_console(["7", "[b]"], tmp_path)
    assert console.run() == 0
    shown = text.getvalue()
    assert "'7' is not a choice" in shown
    assert "'[b]' is not a choice" in shown  # the key is shown as typed, not as markup
    assert shown.rstrip().endswith("end of input: stopped")


def test_keys_drive_to_the_goal(tmp_path: Path) -> None:
    console, text = make_console(["b", "1"], tmp_path)
    assert console.run() == 0
    shown = text.getvalue()
    assert "-> back_out" in shown and "goal reached" in shown
    assert "end of input" not in shown


def test_docstring_documents_only_the_keys_the_loop_takes() -> None:
    import agents.console

    doc = agents.console.__doc__ or ""
    assert "``b`` backs out" in doc and "``q`` quits" in doc
    assert "``m``" not in doc


@pytest.mark.parametrize("key", ["q", "quit"])
def test_quit(tmp_path: Path, key: str) -> None:
    console, text = make_console([key], tmp_path)
    assert console.run() == 0
    assert "stopped by the operator" in text.getvalue()
