"""The environments' keyword arguments as frozen, validated configs.

``gymnasium.make("pipenav/PipeNav-v0", **kwargs)`` passes its keyword arguments to the env, which
builds one config from them: :class:`NavConfig` for PipeNav, :class:`ExploreConfig` for
PipeExplore, both extending the shared :class:`EnvConfig`. The config checks every argument
once, in ``__post_init__``, with :mod:`detector.validation` (one error type,
:class:`~detector.validation.ArgumentError`, a ``ValueError``; one message format
``<env>: <argument> = <value>: <problem>; allowed: <what>``), and holds the values converted:
floats as ``float``, ints as ``int``, a preset LiDAR name as its
:class:`~pipe_env.lidar.LidarSpec`, a network dict or file as a
:class:`~pipe_env.network.PipeNetwork`, a ``network_config`` dict as a
:class:`~pipe_env.generator.NetworkConfig`.

The field names and defaults are the keyword arguments' (the README's option table is drawn from
these fields by ``docs/generate_tables.py``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, ClassVar

from detector.geometry import Pose
from detector.validation import (
    ArgumentError,
    check_bool,
    check_choice,
    check_int,
    check_number,
    fail,
)
from detector.vocab import DETECTORS
from pipe_env.envs.fidelity import FIDELITIES
from pipe_env.generator import NetworkConfig
from pipe_env.lidar import PRESETS, LidarSpec
from pipe_env.network import PipeNetwork
from primitives.executor import PHYSICS_MODES

#: Largest trigger distance allowed, m (the default, 0.2 m, is where the fast fidelity's
#: detection error models were measured).
MAX_TRIGGER_DISTANCE = 1.0

#: Rendering modes of both environments (``metadata["render_modes"]``).
RENDER_MODES = ("rgb_array", "rgb_array_list", "ansi")


def as_network(value: Any, where: str) -> PipeNetwork | None:
    """``value`` (None, a PipeNetwork, its dict or a file path) as a network.

    Raises:
        ValueError: an unusable value (:class:`ArgumentError`) or file, prefixed by ``where``.
    """
    if value is None or isinstance(value, PipeNetwork):
        return value
    if not isinstance(value, dict | str | Path):
        raise fail("network", value, "a PipeNetwork, a dict or a file path", where=where)
    try:
        return PipeNetwork.from_dict(value) if isinstance(value, dict) else PipeNetwork.load(value)
    except ArgumentError as exc:
        raise exc.within(where) from None
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """The arguments both environments take (see the env classes' docstrings for meanings)."""

    #: The registered id without its namespace, named in argument errors.
    env_name: ClassVar[str] = "PipeNav-v0"

    network_config: NetworkConfig | dict | None = None  # generator settings (NetworkConfig)
    network: PipeNetwork | dict | str | Path | None = None  # a fixed network instead
    detector: str = "improved"  # "improved", "thesis" or "ground_truth"
    fidelity: str = "fast"  # "fast" or "full"
    lidar: str | LidarSpec = "ideal"  # a preset name or a LidarSpec
    misalignment: Pose | None = None  # true sensor pose relative to its mount (full fidelity)
    render_mode: str | None = None
    trigger_distance: float = 0.2  # m, in (0, 1]
    auto_single: bool = True  # take single ways (bends, reducers) without asking
    max_jams: int = 3  # jams that end an episode, >= 1
    scan_image: bool = False  # add the (16, 32) range image to the observation
    reward_invalid: float = -0.5  # a masked action
    reward_jam: float = -2.0  # per jam
    reward_time: float = -0.05  # per decision
    network_pool: int | None = None  # draw from a pool of this many networks, >= 1
    pool_seed: int = 0  # the pool's seed, >= 0
    physics: str = "contact"  # full fidelity: "contact" or "everywhere"

    def __post_init__(self) -> None:
        where = self.env_name
        self._set("detector", check_choice("detector", self.detector, DETECTORS, where))
        self._set("fidelity", check_choice("fidelity", self.fidelity, FIDELITIES, where))
        self._set("physics", check_choice("physics", self.physics, PHYSICS_MODES, where))
        if self.render_mode is not None:
            check_choice("render_mode", self.render_mode, RENDER_MODES, where)
        self._set("network_config", self._network_config())
        self._set("lidar", self._lidar())
        if self.misalignment is not None and not isinstance(self.misalignment, Pose):
            raise fail(
                "misalignment",
                self.misalignment,
                "a Pose (the true sensor pose relative to its nominal mount) or None",
                where=where,
            )
        if self.network_pool is not None:
            self._set("network_pool", check_int("network_pool", self.network_pool, 1, where=where))
        self._set("network", as_network(self.network, where))
        self._set(
            "trigger_distance",
            check_number(
                "trigger_distance",
                self.trigger_distance,
                0.0,
                MAX_TRIGGER_DISTANCE,
                unit="m",
                open_low=True,
                where=where,
            ),
        )
        self._set("auto_single", check_bool("auto_single", self.auto_single, where))
        self._set("max_jams", check_int("max_jams", self.max_jams, 1, where=where))
        self._set("scan_image", check_bool("scan_image", self.scan_image, where))
        for name in ("reward_invalid", "reward_jam", "reward_time"):
            self._set(name, check_number(name, getattr(self, name), where=where))
        self._set("pool_seed", check_int("pool_seed", self.pool_seed, 0, where=where))

    def _set(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)

    def _network_config(self) -> NetworkConfig:
        value = self.network_config
        if value is None:
            return NetworkConfig()
        if isinstance(value, NetworkConfig):
            return value
        if not isinstance(value, dict):
            raise fail(
                "network_config", value, "a NetworkConfig, its dict or None", where=self.env_name
            )
        try:
            return NetworkConfig.from_dict(value)
        except ArgumentError as exc:
            field = exc.field.removeprefix("NetworkConfig.")
            raise fail(
                f"network_config.{field}", exc.value, exc.allowed, exc.problem, self.env_name
            ) from None
        except (TypeError, ValueError) as exc:
            raise fail(
                "network_config", value, "a NetworkConfig dict", str(exc), self.env_name
            ) from None

    def _lidar(self) -> LidarSpec:
        value = self.lidar
        if isinstance(value, str) and value in PRESETS:
            return PRESETS[value]
        if not isinstance(value, LidarSpec):
            raise fail(
                "lidar",
                value,
                f"a preset name ({', '.join(sorted(PRESETS))}) or a LidarSpec",
                where=self.env_name,
            )
        return value

    # typed views of the converted fields
    @property
    def generator(self) -> NetworkConfig:
        """The network generator's settings (``network_config`` converted)."""
        assert isinstance(self.network_config, NetworkConfig)
        return self.network_config

    @property
    def fixed_network(self) -> PipeNetwork | None:
        """The fixed network (``network`` converted), or None to draw one per episode."""
        assert self.network is None or isinstance(self.network, PipeNetwork)
        return self.network

    @property
    def lidar_spec(self) -> LidarSpec:
        """The simulated sensor (``lidar`` converted)."""
        assert isinstance(self.lidar, LidarSpec)
        return self.lidar

    @classmethod
    def argument_names(cls) -> tuple[str, ...]:
        """The keyword arguments, in the order of the fields."""
        return tuple(f.name for f in dataclasses.fields(cls))


@dataclasses.dataclass(frozen=True)
class NavConfig(EnvConfig):
    """PipeNav's arguments: the shared ones and the goal bonus."""

    env_name: ClassVar[str] = "PipeNav-v0"

    reward_goal: float = 10.0  # bonus on reaching the goal, in [0, 1000]

    def __post_init__(self) -> None:
        super().__post_init__()
        where = self.env_name
        self._set(
            "reward_goal", check_number("reward_goal", self.reward_goal, 0.0, 1000.0, where=where)
        )
        n_goals = self.generator.n_goals
        if self.fixed_network is None and n_goals < 1:
            raise fail(
                "network_config.n_goals",
                n_goals,
                "an int >= 1 (PipeNav needs goals)",
                where=where,
            )


@dataclasses.dataclass(frozen=True)
class ExploreConfig(EnvConfig):
    """PipeExplore's arguments: the shared ones and the coverage settings."""

    env_name: ClassVar[str] = "PipeExplore-v0"

    coverage_done: float = 0.98  # covered fraction of the reachable pipe ending it, (0, 1]
    branch_view: float = 0.3  # how far the scans see into pipes leaving the fitting ahead, m

    def __post_init__(self) -> None:
        super().__post_init__()
        where = self.env_name
        self._set(
            "coverage_done",
            check_number("coverage_done", self.coverage_done, 0.0, 1.0, open_low=True, where=where),
        )
        self._set(
            "branch_view", check_number("branch_view", self.branch_view, 0.0, unit="m", where=where)
        )
