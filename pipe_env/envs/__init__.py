"""The Gymnasium environments and what only they need: their config, observation and action
types, tasks and network sources, the oracle accessor, the two plants (fast and full), the fast
fidelity's sensing error models, the fidelity names, the way log and the wrappers.

This package sits above :mod:`primitives` (the full plant runs primitive sequences) and below
:mod:`agents`. The environments' public names are re-exported here; import a submodule for the
rest (``pipe_env.envs.plant`` for the plant interface).
"""

from __future__ import annotations

from pipe_env.envs.config import EnvConfig, ExploreConfig, NavConfig
from pipe_env.envs.env import (
    GOAL_CLIP,
    K_OPTIONS,
    OPTION_FEATURES,
    SCAN_SHAPE,
    PipeExploreEnv,
    PipeNavEnv,
    pool_network,
    reachable_runs,
)
from pipe_env.envs.fidelity import FIDELITIES, Fidelity
from pipe_env.envs.oracle import Oracle, oracle_of

__all__ = [
    "FIDELITIES",
    "EnvConfig",
    "ExploreConfig",
    "NavConfig",
    "Oracle",
    "oracle_of",
    "GOAL_CLIP",
    "K_OPTIONS",
    "OPTION_FEATURES",
    "SCAN_SHAPE",
    "Fidelity",
    "PipeExploreEnv",
    "PipeNavEnv",
    "pool_network",
    "reachable_runs",
]
