"""Agents that choose among structure options, training and evaluation, and the CLI."""
