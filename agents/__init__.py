"""Agents that choose among structure options, training and evaluation, and the CLI."""

#: The pipenav version (pyproject.toml reads it from here).
__version__ = "0.1.0"

from agents.scripted import GoalGreedy, LeftHand, RandomAgent, RoutePlanner, make_agent

__all__ = ["__version__", "GoalGreedy", "LeftHand", "RandomAgent", "RoutePlanner", "make_agent"]
