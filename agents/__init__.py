"""Agents that choose among structure options, training and evaluation, and the CLI."""

from agents.scripted import GoalGreedy, LeftHand, RandomAgent, RoutePlanner, make_agent

__all__ = ["GoalGreedy", "LeftHand", "RandomAgent", "RoutePlanner", "make_agent"]
