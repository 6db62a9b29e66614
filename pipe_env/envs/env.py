"""Gymnasium environments at the Decision Support level (thesis 3.1.1).

The robot senses and proposes, the agent chooses, the robot acts. One ``step`` is one
decision: the environment runs the closed loop (drive, scan, detect, fuse) until a structure is
confirmed within the trigger distance (or the goal is reached), offers the options it found, and
executes the motion-primitive sequence of the option the agent picks.

``pipenav/PipeNav-v0`` (:class:`PipeNavEnv`): reach a goal in a generated network.
``pipenav/PipeExplore-v0`` (:class:`PipeExploreEnv`): cover as much pipe as possible.

Action: ``Discrete(K)``, an index into the options table. Rows ``0..K-2`` hold the detected ways
on (straight on first, then by roll direction); row ``K-1`` is always "back out" (reverse to the
last junction passed, or to the start, and decide again). :meth:`action_masks` marks the rows the
robot would attempt: a detected way on inside the robot's 57-125 mm range turning at most 90 deg,
and back out. **A masked action** is not executed: the robot stays where it is, the same decision
is offered again, the reward is ``reward_invalid + reward_time`` (the penalty plus the cost of a
decision) and ``info["invalid_action"]`` is True.

Observation (a flat ``Dict``, fixed shapes, finite bounds):

- ``options`` (K, 15): per row ``valid``, kind one-hot (straight, reducer, closure, bend,
  junction, back out), ``distance`` (m), ``diameter`` (m), ``cos`` and ``sin`` of the direction,
  ``angle`` (rad), ``confidence``, and ``taken``: how often the robot's own log says it took
  this way from here before (:mod:`pipe_env.envs.way_log`; 0, 1/3, 2/3, 1 for 3 or more; the
  back-out row counts back-outs from here); ``goal_alignment``: cosine between the way's
  outgoing axis and the direction to the goal, both from odometry (0 without a goal);
- ``goal`` (3,): the goal in the robot frame from noisy odometry (m, clipped to +-20; PipeNav);
- ``proprio`` (3,): clamped diameter (m), cos and sin of the robot's roll;
- ``scan`` (16, 32), optional (``scan_image=True``): a low-resolution range image of the last
  scan (full fidelity), normalised by the sensor's maximum range; zeros in fast fidelity.

Reward (PipeNav): ``progress`` (decrease of the along-network distance to the goal, m) +
``goal`` bonus + ``jam`` penalty per jam (of the chosen way, or while driving on to the next
decision) + ``time`` cost per decision; each term is in ``info["reward_terms"]``; a jam's cause
is in ``info["outcome_note"]`` (``drive_jammed_note``, ``auto_jammed_note``). PipeExplore
rewards new pipe length covered by the scans (m).

Options (keyword arguments of ``gymnasium.make``): ``detector`` in ``"improved"``,
``"thesis"``, ``"ground_truth"``; ``fidelity`` ``"fast"`` (kinematic motion, modelled sensing;
for RL iterations) or ``"full"`` (MuJoCo robot, rotating LiDAR, detector, executor); ``lidar``
preset name or :class:`~pipe_env.lidar.LidarSpec`: the simulated sensor in full fidelity, and in
fast fidelity the sensor whose measured error model perturbs the options
(:func:`~pipe_env.envs.sensing_model.error_model_for` of the detector and the sensor);
``network_config`` (a :class:`~pipe_env.generator.NetworkConfig` or its dict);
``network`` (a fixed network, dict or file path, instead of generating one per episode);
``misalignment`` (a Pose: the true sensor pose relative to its nominal mount, full fidelity);
``physics`` (full fidelity: ``"contact"``, physics where contact decides, straight drives away
from fittings kinematic, see :meth:`primitives.executor.Executor.free_straight`; or
``"everywhere"``, contact physics for every motion, the reference);
``network_pool`` (draw episodes
from a fixed, reproducible pool of that many generated networks, seeded by ``pool_seed``; use
another ``pool_seed`` for held-out evaluation); ``trigger_distance`` (stop this far before a
structure's reference point to decide, in (0, 1] m); ``max_jams`` (end the episode after this
many jams, an int >= 1); ``reward_invalid``, ``reward_jam``, ``reward_time`` (finite reward
terms); ``reward_goal`` (PipeNav, in [0, 1000]); ``coverage_done`` (PipeExplore: the covered
fraction of the reachable pipe that ends an episode, in (0, 1]). A bad value raises ValueError
naming the environment, the argument, the value and what is allowed.

Rendering (``render_mode``): ``"ansi"`` returns the options table as text; ``"rgb_array"``
returns an image of the robot in the pipe now (480x360, an isometric view following the robot,
the walls translucent, on a light background); ``"rgb_array_list"`` returns the list of images
since the last ``render()`` call: in full fidelity one every :attr:`frame_interval` simulated
seconds while the robot moves (during ``reset`` and each ``step``) plus one at the end of each,
so a video shows the motion; in fast fidelity (no simulated motion) one per ``reset``/``step``.
To record an mp4, wrap the env in :class:`pipe_env.envs.wrappers.RecordVideo` (Gymnasium's
``RecordVideo``, keeping every motion frame; the stock one keeps one frame per step), with
``render_mode="rgb_array"`` or ``"rgb_array_list"``; it needs the ``video`` extra. Videos play
at ``metadata["render_fps"]`` frames per second. Rendering picks an OpenGL backend on first use
and raises :class:`pipe_env.rendering.RenderingUnavailable` when none works; nothing else needs
one.
"""

from __future__ import annotations

import math
import numbers
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from detector.geometry import Pose, clamp, norm3
from detector.options import KINDS, StructureOption, option_errors, option_vector
from detector.vocab import Kind
from pipe_env.envs.fidelity import FIDELITIES, Fidelity
from pipe_env.envs.plant import (
    BACK_OUT,
    Decision,
    EdgeState,
    KinematicPlant,
    Outcome,
    Plant,
    PlantStatus,
    goal_edge_position,
)
from pipe_env.envs.sensing_model import DETECTORS, error_model_for
from pipe_env.envs.way_log import WayLog
from pipe_env.generator import NetworkConfig, generate_network
from pipe_env.network import PipeNetwork
from pipe_env.robot_limits import MAX_TURN, drivable
from pipe_env.routing import (
    EdgePosition,
    edge_geodesic,
    edge_length,
    edge_position,
    locate,
    route,
    turn_angle,
)

K_OPTIONS = 6
OPTION_FEATURES = (
    "valid",
    "straight",
    "reducer",
    "closure",
    "bend",
    "junction",
    "back_out",
    "distance",
    "diameter",
    "cos_direction",
    "sin_direction",
    "angle",
    "confidence",
    "taken",
    "goal_alignment",
)
SCAN_SHAPE = (16, 32)
GOAL_CLIP = 20.0
MAX_AUTO_STRUCTURES = 64

_LOW = np.array([0, 0, 0, 0, 0, 0, 0, -1.0, 0.0, -1, -1, 0.0, 0.0, 0.0, -1], dtype=np.float32)
_HIGH = np.array([1, 1, 1, 1, 1, 1, 1, 5.0, 0.3, 1, 1, math.pi, 1.0, 1.0, 1], dtype=np.float32)
#: ``taken`` saturates at this many times (see :mod:`pipe_env.envs.way_log`).
MAX_TAKEN = 3


#: Largest trigger distance allowed, m (the default, 0.2 m, is where the fast fidelity's
#: detection error models were measured).
MAX_TRIGGER_DISTANCE = 1.0


def _as_network(value: PipeNetwork | dict | str | Path | None) -> PipeNetwork | None:
    if value is None or isinstance(value, PipeNetwork):
        return value
    if isinstance(value, dict):
        return PipeNetwork.from_dict(value)
    if isinstance(value, (str, Path)):
        return PipeNetwork.load(value)
    raise ValueError(f"network={value!r} is not allowed; use a PipeNetwork, a dict or a file path")


class _ArgumentCheck:
    """Checks the keyword arguments of ``gymnasium.make`` for one environment id.

    Every error is a ValueError of the form ``"<env>: <name>=<value> is not allowed; use
    <what is allowed>"``. Booleans are not accepted where numbers are expected.
    """

    def __init__(self, env: str) -> None:
        self.env = env

    def fail(self, name: str, value: Any, allowed: str) -> ValueError:
        """The error for argument ``name`` given ``value`` (``allowed``: what may be given)."""
        shown = repr(value)
        shown = shown if len(shown) <= 100 else shown[:97] + "..."
        return ValueError(f"{self.env}: {name}={shown} is not allowed; use {allowed}")

    def number(
        self,
        name: str,
        value: Any,
        lo: float = -math.inf,
        hi: float = math.inf,
        lo_open: bool = False,
        allowed: str = "a finite number",
    ) -> float:
        """``value`` as a finite float in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
        ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
        try:
            v = float(value) if ok else math.nan
        except OverflowError:  # an int too large for a float
            v = math.nan
        if not (math.isfinite(v) and (lo < v if lo_open else lo <= v) and v <= hi):
            raise self.fail(name, value, allowed)
        return v

    def integer(self, name: str, value: Any, minimum: int) -> int:
        """``value`` as an int >= ``minimum``."""
        ok = isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
        if not (ok and int(value) >= minimum):
            raise self.fail(name, value, f"an int >= {minimum}")
        return int(value)

    def flag(self, name: str, value: Any) -> bool:
        """``value`` as a bool (True or False only)."""
        if not isinstance(value, (bool, np.bool_)):
            raise self.fail(name, value, "True or False")
        return bool(value)

    def choice(self, name: str, value: Any, allowed: tuple[Any, ...] | list[Any]) -> Any:
        """``value``, one of ``allowed``."""
        if not isinstance(value, str) or value not in allowed:
            raise self.fail(name, value, f"one of {tuple(allowed)}")
        return value


class _DecisionEnv(gym.Env):
    """Shared machinery of the two environments (see module docstring)."""

    metadata = {"render_modes": ["rgb_array", "rgb_array_list", "ansi"], "render_fps": 10}

    #: Simulated seconds between the frames collected while the robot moves (full fidelity);
    #: at ``render_fps`` 10 a video plays 5 times faster than the robot drives.
    frame_interval = 0.5

    #: The registered id without the namespace (named in argument errors).
    env_name = "PipeNav-v0"

    def __init__(
        self,
        network_config: NetworkConfig | dict | None = None,
        network: PipeNetwork | dict | str | None = None,
        detector: str = "improved",
        fidelity: str = "fast",
        lidar: Any = "ideal",
        misalignment: Pose | None = None,
        render_mode: str | None = None,
        trigger_distance: float = 0.2,
        auto_single: bool = True,
        max_jams: int = 3,
        scan_image: bool = False,
        reward_invalid: float = -0.5,
        reward_jam: float = -2.0,
        reward_time: float = -0.05,
        network_pool: int | None = None,
        pool_seed: int = 0,
        physics: str = "contact",
    ) -> None:
        from pipe_env.lidar import PRESETS, LidarSpec
        from primitives.executor import PHYSICS_MODES

        check = _ArgumentCheck(self.env_name)
        self.detector = check.choice("detector", detector, DETECTORS)
        self.fidelity = check.choice("fidelity", fidelity, FIDELITIES)
        self.physics = check.choice("physics", physics, PHYSICS_MODES)
        if render_mode is not None:
            check.choice("render_mode", render_mode, self.metadata["render_modes"])
        if isinstance(network_config, dict):
            try:
                network_config = NetworkConfig.from_dict(network_config)
            except (TypeError, ValueError) as exc:
                raise check.fail(
                    "network_config", network_config, f"a valid NetworkConfig dict ({exc})"
                ) from None
        elif network_config is not None and not isinstance(network_config, NetworkConfig):
            raise check.fail("network_config", network_config, "a NetworkConfig, its dict or None")
        if isinstance(lidar, str) and lidar in PRESETS:
            lidar = PRESETS[lidar]
        if not isinstance(lidar, LidarSpec):
            raise check.fail(
                "lidar", lidar, f"a preset name in {tuple(sorted(PRESETS))} or a LidarSpec"
            )
        if misalignment is not None and not isinstance(misalignment, Pose):
            raise check.fail(
                "misalignment",
                misalignment,
                "a Pose (the true sensor pose relative to its nominal mount) or None",
            )
        if network_pool is not None:
            network_pool = check.integer("network_pool", network_pool, 1)
        try:
            self.fixed_network = _as_network(network)
        except ValueError as exc:
            raise ValueError(f"{self.env_name}: {exc}") from None
        self.network_config = network_config or NetworkConfig()
        self.lidar = lidar
        self.misalignment = misalignment
        self.render_mode = render_mode
        self.trigger_distance = check.number(
            "trigger_distance",
            trigger_distance,
            0.0,
            MAX_TRIGGER_DISTANCE,
            lo_open=True,
            allowed=f"a number in (0, {MAX_TRIGGER_DISTANCE:g}] m",
        )
        self.auto_single = check.flag("auto_single", auto_single)
        self.max_jams = check.integer("max_jams", max_jams, 1)
        self.scan_image = check.flag("scan_image", scan_image)
        self.reward_invalid = check.number("reward_invalid", reward_invalid)
        self.reward_jam = check.number("reward_jam", reward_jam)
        self.reward_time = check.number("reward_time", reward_time)
        self.network_pool = network_pool
        self.pool_seed = check.integer("pool_seed", pool_seed, 0)
        obs = {
            "options": spaces.Box(
                np.tile(_LOW, (K_OPTIONS, 1)), np.tile(_HIGH, (K_OPTIONS, 1)), dtype=np.float32
            ),
            "goal": spaces.Box(-GOAL_CLIP, GOAL_CLIP, (3,), dtype=np.float32),
            "proprio": spaces.Box(
                np.array([0.0, -1, -1], np.float32),
                np.array([0.3, 1, 1], np.float32),
                dtype=np.float32,
            ),
        }
        if self.scan_image:
            obs["scan"] = spaces.Box(0.0, 1.0, SCAN_SHAPE, dtype=np.float32)
        self.observation_space = spaces.Dict(obs)
        self.action_space = spaces.Discrete(K_OPTIONS)
        self.network: PipeNetwork | None = None
        self.plant: Plant | None = None
        self._decision: Decision | None = None
        self._decision_serial = 0
        self._renderer: Any = None
        self._world_for_render: Any = None
        #: collect frames while the robot moves (``rgb_array_list`` does; so does
        #: :class:`pipe_env.envs.wrappers.RecordVideo` for ``rgb_array``)
        self.collect_frames = render_mode == "rgb_array_list"
        self._frames: list[NDArray[np.uint8]] = []
        self._next_frame_time = 0.0
        self._mask_cache: tuple[Any, NDArray[np.bool_]] | None = None

    @property
    def decision(self) -> Decision | None:
        """The decision pending for the agent (None when the episode has ended)."""
        return self._decision

    @decision.setter
    def decision(self, value: Decision | None) -> None:
        self._decision = value
        self._decision_serial += 1

    # ----------------------------------------------------------------- episode
    def _new_network(self) -> PipeNetwork:
        if self.fixed_network is not None:
            return self.fixed_network
        if self.network_pool is None:
            return generate_network(self.network_config, self.np_random)
        # a pool of networks, network i generated from seed (pool_seed, i) on first use: episodes
        # sample from a fixed, reproducible set (held-out sets use another pool_seed)
        i = int(self.np_random.integers(self.network_pool))
        return pool_network(self.network_config, self.pool_seed, i)

    def _make_plant(self, network: PipeNetwork) -> Plant:
        """The plant factory: the only place that knows the fidelities' classes."""
        if self.fidelity == Fidelity.FAST:
            return KinematicPlant(
                network,
                self.detector,
                self.trigger_distance,
                error_model=error_model_for(self.detector, self.lidar),
            )
        from pipe_env.envs.plant_full import PhysicalPlant

        return PhysicalPlant(
            network,
            self.detector,
            self.trigger_distance,
            lidar=self.lidar,
            misalignment=self.misalignment,
            scan_image=self.scan_image,
            physics=self.physics,
        )

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        given = _as_network(options["network"]) if options and "network" in options else None
        # a generated episode must start with a decision: redraw the rare network whose goal is
        # reached before any (the first structures being single ways taken automatically)
        for _ in range(10):
            self._start_episode(given or self._new_network())
            if self.decision is not None or given is not None or self.fixed_network is not None:
                break
        if self.decision is None and self.success and (given or self.fixed_network) is not None:
            which = "options['network']" if given is not None else "network"
            raise ValueError(
                f"{self.env_name}: {which}: the goal is reached inside reset(), before the "
                "first decision (the start drives to it through single ways only); allowed: a "
                "goal beyond the first junction or closure ahead of the start"
            )
        info = self._info(self._reset_events, {})
        self._end_frame()
        return self._observation(), info

    def _start_episode(self, network: PipeNetwork) -> None:
        self.network = network
        if self._world_for_render is not None and self._world_for_render.network is not (
            self.network
        ):
            self.close()
        if self.plant is None or self.plant.network is not network:
            # a plant (in full fidelity its compiled MuJoCo model) is built once per network
            # and reset between episodes on it
            if self.plant is not None:
                self.plant.close()
            self.plant = self._make_plant(self.network)
        self.plant.reset(np.random.default_rng(self.np_random.integers(2**63)))
        self._frames = []
        executor = getattr(self.plant, "executor", None)
        if self.collect_frames and executor is not None:
            self._next_frame_time = executor.time
            executor.on_tick = self._on_tick
        self.jams = 0
        self.decisions = 0
        self.structures = 0
        self.invalid_actions = 0
        self.terminated = False
        self.truncated = False
        self.success = False
        self._waypoints: list[Any] = [self.plant.waypoint()]
        self.decision_points: list[NDArray[np.float64]] = []
        self.detection_errors: list[dict[str, float]] = []
        self.way_log = WayLog()
        self._episode_reset()
        self.decision, self._reset_events = self._advance()
        self._sync_progress()

    def _sync_progress(self) -> None:
        """Hook: take the progress baseline after the reset's drive to the first decision."""

    def _episode_reset(self) -> None:
        """Hook for subclasses (goal, coverage)."""

    def step(self, action: int):
        if self.plant is None:
            raise RuntimeError("call reset() before step()")
        # only integers of the action space: int() would turn 0.9, '1', b'1' or True into one
        if isinstance(action, np.ndarray) and action.shape == () and action.dtype.kind in "iu":
            action = action.item()
        if (
            isinstance(action, (bool, np.bool_))
            or not isinstance(action, (numbers.Integral, np.integer))
            or not 0 <= int(action) < K_OPTIONS
        ):
            raise ValueError(
                f"action {action!r} ({type(action).__name__}) is not allowed; allowed: an "
                f"integer (Python or numpy) in Discrete({K_OPTIONS}), 0..{K_OPTIONS - 1}"
            )
        action = int(action)
        if self.terminated or self.truncated:  # e.g. a goal reached before any decision
            return self._finish_step({}, {"after_termination": True})
        mask = self.action_masks()
        terms: dict[str, float] = {"time": self.reward_time}
        events: dict[str, Any] = {"jammed": False, "blocked": False, "invalid_action": False}
        if not mask[action]:
            self.invalid_actions += 1
            events["invalid_action"] = True
            terms["invalid"] = self.reward_invalid
            return self._finish_step(terms, events)
        self.decisions += 1
        jams_before = self.jams
        assert self.decision is not None
        choice: StructureOption | str = (
            BACK_OUT if action == K_OPTIONS - 1 else self.decision.options[action]
        )
        odo = self.plant.odometry_pose()
        self.way_log.record(odo.position, self._world_way(choice, odo))
        outcome = self.plant.execute(choice, self._goal_target())
        self._record(outcome)
        events["outcome"] = outcome.status
        if outcome.note:
            events["outcome_note"] = outcome.note
        if outcome.status == PlantStatus.JAMMED:
            self.jams += 1
            events["jammed"] = True
            if self.jams >= self.max_jams:
                self.terminated = True
            else:
                self.decision = self._sense_again_after_jam()
        elif outcome.status == PlantStatus.BLOCKED:
            events["blocked"] = True
        elif outcome.status == PlantStatus.GOAL:
            self._reach_goal(events)
        else:
            self.decision, adv = self._advance()
            events.update(adv)
        if self.jams > jams_before:  # the chosen way, or a drive or single way after it
            terms["jam"] = self.reward_jam * (self.jams - jams_before)
        terms.update(self._progress_terms())
        return self._finish_step(terms, events)

    def _finish_step(self, terms: dict[str, float], events: dict[str, Any]):
        reward = float(sum(terms.values()))
        info = self._info(events, terms)
        self._end_frame()
        return self._observation(), reward, bool(self.terminated), bool(self.truncated), info

    def _reach_goal(self, events: dict[str, Any]) -> None:
        self.terminated = True
        self.success = True
        self.decision = None
        events["goal_reached"] = True

    @staticmethod
    def _world_way(choice: StructureOption | str, odo: Pose) -> NDArray[np.float64] | None:
        """A chosen way as a world direction from the odometry heading (None: back out)."""
        return None if isinstance(choice, str) else odo.rotation @ option_vector(choice)

    def _record(self, outcome: Outcome) -> None:
        if self._waypoints and outcome.path and outcome.path[0] is self._waypoints[-1]:
            self._waypoints.extend(outcome.path[1:])
        else:
            self._waypoints.extend(outcome.path)

    @property
    def path(self) -> NDArray[np.float64]:
        """The driven path so far as (N, 3) world positions, metres."""
        return self.plant.positions([w for w in self._waypoints if w is not None])

    def _advance(self) -> tuple[Decision | None, dict[str, Any]]:
        """Drive to the next decision the agent must take (single ways auto-executed)."""
        events: dict[str, Any] = {"auto_structures": 0}
        for _ in range(MAX_AUTO_STRUCTURES):
            dec, out = self.plant.advance(self._goal_target())
            self._record(out)
            if out.status == PlantStatus.GOAL:
                self._reach_goal(events)
                return None, events
            assert dec is not None
            # stalled while driving: the robot decides where it is
            if out.status == PlantStatus.JAMMED:
                self._count_jam(events, "drive_jammed", out.note)
            self.structures += 1
            self._after_sensing(dec)
            ways = [o for o in dec.options if drivable(o)]
            single = (
                self.auto_single
                and len(ways) == 1
                and len(dec.options) == 1
                and dec.kind in (Kind.BEND, Kind.REDUCER)
            )
            if not single:
                self.decision_points.append(dec.pose.position)
                return dec, events
            outcome = self.plant.execute(ways[0], self._goal_target())
            self._record(outcome)
            events["auto_structures"] += 1
            if outcome.status == PlantStatus.GOAL:
                self._reach_goal(events)
                return None, events
            if outcome.status != PlantStatus.DONE:
                events["auto_" + outcome.status] = True
                self.plant.decision = dec
                if outcome.status == PlantStatus.JAMMED:
                    self._count_jam(events, "auto_jammed", outcome.note)
                    if not self.terminated:
                        dec = self._sense_again_after_jam()
                self.decision_points.append(dec.pose.position)
                return dec, events
        self.truncated = True  # a pathological chain of single ways: stop, it is not an outcome
        events["truncated_auto"] = True
        return None, events

    def _sense_again_after_jam(self) -> Decision:
        """The robot backed off the structure that jammed it (on a way the agent chose or
        one the environment took by itself) and decides on fresh sweeps."""
        dec, _ = self.plant.resense()
        self._after_sensing(dec)
        return dec

    def _count_jam(self, events: dict[str, Any], key: str, note: str) -> None:
        self.jams += 1
        events["jammed"] = events[key] = True
        if note:
            events[key + "_note"] = note
        if self.jams >= self.max_jams:
            self.terminated = True

    def _after_sensing(self, dec: Decision) -> None:
        """Record detection errors of a decision against ground truth."""
        if not dec.options or not dec.truth:
            return
        kind_ok = dec.kind == dec.truth[0].kind
        errs = {
            "kind_correct": float(kind_ok),
            "n_options": len(dec.options),
            "n_true": len(dec.truth),
        }
        errs.update(option_errors(dec.options, dec.truth))
        errs.setdefault("direction", 0.0)
        self.detection_errors.append(errs)

    # ------------------------------------------------------------ observation
    def action_masks(self) -> NDArray[np.bool_]:
        """Which actions the robot would attempt now (MaskablePPO reads this on the env)."""
        key = (self._decision_serial, self.terminated, self.truncated)
        if self._mask_cache is not None and self._mask_cache[0] == key:
            return self._mask_cache[1].copy()
        mask = self._compute_mask()
        self._mask_cache = (key, mask)
        return mask.copy()

    def _compute_mask(self) -> NDArray[np.bool_]:
        mask = np.zeros(K_OPTIONS, dtype=bool)
        if self.decision is None or self.terminated or self.truncated:
            mask[K_OPTIONS - 1] = True  # nothing to choose; backing out is always possible
            return mask
        for i, o in enumerate(self.decision.options[: K_OPTIONS - 1]):
            mask[i] = drivable(o)
        mask[K_OPTIONS - 1] = True
        return mask

    def _options_table(self) -> NDArray[np.float32]:
        table = np.zeros((K_OPTIONS, len(OPTION_FEATURES)), dtype=np.float32)
        mask = self.action_masks()
        odo = self.plant.odometry_pose()
        goal = self._goal_point()
        to_goal = None
        if goal is not None:
            rel = goal - odo.position
            norm = norm3(rel)
            to_goal = rel / norm if norm > 1e-9 else None
            if to_goal is not None:  # backing out heads the other way
                table[K_OPTIONS - 1, 14] = clamp(-float(odo.forward @ to_goal), -1.0, 1.0)
        options = self.decision.options[: K_OPTIONS - 1] if self.decision is not None else []
        ways = [self._world_way(o, odo) for o in options]
        taken = self.way_log.counts(odo.position, [*ways, None])
        table[K_OPTIONS - 1, 13] = min(taken[-1], MAX_TAKEN) / MAX_TAKEN
        for i, o in enumerate(options):
            row = [0.0] * len(OPTION_FEATURES)
            row[0] = float(mask[i])
            row[1 + KINDS.index(o.kind)] = 1.0
            row[7] = clamp(o.distance, _LOW[7], _HIGH[7])
            row[8] = clamp(o.diameter, 0.0, _HIGH[8])
            row[9], row[10] = math.cos(o.direction), math.sin(o.direction)
            row[11] = clamp(o.angle, 0.0, math.pi)
            row[12] = clamp(o.confidence, 0.0, 1.0)
            row[13] = min(taken[i], MAX_TAKEN) / MAX_TAKEN
            if to_goal is not None:
                row[14] = clamp(float(ways[i] @ to_goal), -1.0, 1.0)
            table[i] = row
        back = table[K_OPTIONS - 1]
        back[0] = float(mask[K_OPTIONS - 1])
        back[6] = 1.0
        back[9] = 1.0
        back[11] = math.pi
        back[12] = 1.0
        return table

    def _goal_point(self) -> NDArray[np.float64] | None:
        return None

    def _goal_target(self) -> Any:
        """What the plant drives towards: the goal point (or its cached edge position)."""
        return self._goal_point()

    def _observation(self) -> dict[str, NDArray[np.float32]]:
        pose = self.plant.odometry_pose()
        roll = _roll_of(pose)
        obs = {
            "options": self._options_table(),
            "goal": np.zeros(3, dtype=np.float32),
            "proprio": np.array(
                [clamp(self.plant.clamped_diameter, 0.0, 0.3), math.cos(roll), math.sin(roll)],
                dtype=np.float32,
            ),
        }
        goal = self._goal_point()
        if goal is not None:
            rel = pose.rotation.T @ (goal - pose.position)
            obs["goal"] = np.clip(rel, -GOAL_CLIP, GOAL_CLIP).astype(np.float32)
        if self.scan_image:
            img = self.plant.scan_image
            obs["scan"] = (
                np.zeros(SCAN_SHAPE, np.float32) if img is None else np.asarray(img, np.float32)
            )
        return obs

    def _info(self, events: dict[str, Any], terms: dict[str, float]) -> dict[str, Any]:
        info = {
            "reward_terms": dict(terms),
            "is_success": bool(self.success),
            "jams": int(self.jams),
            "decisions": int(self.decisions),
            "structures": int(self.structures),
            "invalid_actions": int(self.invalid_actions),
            "travelled": float(self.plant.travelled),
            "sim_time": float(self.plant.sim_time),
            "fidelity": self.fidelity,
            "detector": self.detector,
            "detection_error": dict(self.detection_errors[-1]) if self.detection_errors else {},
            "action_mask": self.action_masks().astype(np.int8),
            "odometry_position": self.plant.odometry_pose().position.copy(),
        }
        info.update({k: v for k, v in events.items()})
        return info

    def _progress_measure(self) -> float:
        return 0.0

    def _progress_terms(self) -> dict[str, float]:
        return {}

    # --------------------------------------------------------------- rendering
    def render(self):
        if self.render_mode == "ansi":
            return self.options_text()
        if self.render_mode == "rgb_array":
            return self._render_rgb()
        if self.render_mode == "rgb_array_list":
            return self.take_frames()
        return None

    def take_frames(self) -> list[NDArray[np.uint8]]:
        """The frames collected since the last call (see module docstring), oldest first."""
        frames, self._frames = self._frames, []
        return frames

    def _on_tick(self, time: float) -> None:
        """Executor hook: one frame every :attr:`frame_interval` simulated seconds (s)."""
        if time + 1e-9 >= self._next_frame_time:
            self._frames.append(self._render_rgb())
            self._next_frame_time = time + self.frame_interval

    def _end_frame(self) -> None:
        if self.collect_frames and self.plant is not None:
            self._frames.append(self._render_rgb())

    def options_text(self) -> str:
        """The options table as an operator would read it."""
        lines = []
        if self.decision is None:
            state = "goal reached" if self.success else "no decision pending"
            return f"[{self.fidelity}/{self.detector}] {state}\n"
        dec = self.decision
        lines.append(
            f"[{self.fidelity}/{self.detector}] structure ahead: {dec.kind}"
            f"   clamped {self.plant.clamped_diameter * 1000:.0f} mm   jams {self.jams}"
        )
        mask = self.action_masks()
        for i, o in enumerate(dec.options[: K_OPTIONS - 1]):
            mark = " " if mask[i] else "x"
            lines.append(f"  [{i}]{mark} {o.describe()}  (confidence {o.confidence:.2f})")
        lines.append(f"  [{K_OPTIONS - 1}]  back out to the last junction")
        goal = self._goal_point()
        if goal is not None:
            rel = self.plant.odometry_pose().inverse_transform_points(goal)
            lines.append(f"  goal: {rel[0]:+.2f} m ahead, {rel[1]:+.2f} m left, {rel[2]:+.2f} m up")
        return "\n".join(lines) + "\n"

    def _render_rgb(self) -> NDArray[np.uint8]:
        from pipe_env.rendering import WorldRenderer

        world = self.plant.world
        if world is None:
            if self._world_for_render is None or self._world_for_render.network is not (
                self.network
            ):
                from pipe_env.world import build_world

                self._world_for_render = build_world(self.network, contact_walls=False)
                self._renderer = None
            world = self._world_for_render
        if self._renderer is None or self._renderer.world is not world:
            self._renderer = WorldRenderer(world, 480, 360)
        pose = self.plant.pose()
        robot = getattr(self.plant, "robot", None)  # full fidelity: frame the whole robot
        target = (
            world.data.xpos[robot.body_ids].mean(axis=0) if robot is not None else pose.position
        )
        cam = self._renderer.camera("iso", target=target, distance=0.9)
        return self._renderer.render(cam, markers=[(pose.position, 0.03)])

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._world_for_render = None
        if self.plant is not None:
            self.plant.close()

    def __getstate__(self) -> dict:
        """Picklable state; the renderer is dropped (rebuilt on the next render).

        Raises:
            TypeError: at full fidelity once an episode has started: the plant holds a live
                MuJoCo simulation (model, data and sensors), which cannot be pickled. Vector
                environments do not need it: subprocess workers build their environments
                from the constructor arguments.
        """
        if self.plant is not None and self.plant.world is not None:
            raise TypeError(
                f"{self.env_name}: a fidelity='full' environment holds a live MuJoCo simulation "
                "after reset() and cannot be pickled mid-episode; pickle it before reset(), or "
                "build it again from its constructor arguments (as subprocess vector "
                "environments do)"
            )
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_world_for_render"] = None
        return state


#: Pool networks generated in this process, shared by its environments (an evaluation builds
#: several envs on the same pool): (config, pool_seed, index) -> network.
_POOL_CACHE: dict[tuple[str, int, int], PipeNetwork] = {}
_POOL_CACHE_SIZE = 4096


def pool_network(config: NetworkConfig, pool_seed: int, index: int) -> PipeNetwork:
    """Network ``index`` of the pool ``pool_seed`` (the same for every process and run)."""
    key = (repr(config), int(pool_seed), int(index))
    net = _POOL_CACHE.get(key)
    if net is None:
        net = generate_network(config, np.random.default_rng([pool_seed, index]))
        if len(_POOL_CACHE) >= _POOL_CACHE_SIZE:
            _POOL_CACHE.pop(next(iter(_POOL_CACHE)))
        _POOL_CACHE[key] = net
    return net


def _roll_of(pose: Pose) -> float:
    """Roll of a pose about its forward axis relative to the roll-zero frame."""
    from detector.geometry import frame_from_forward

    ref = frame_from_forward(pose.forward)
    return math.atan2(float(pose.up @ ref[:, 1]) * -1.0, float(pose.up @ ref[:, 2]))


class PipeNavEnv(_DecisionEnv):
    """Reach a goal in a generated pipe network (see module docstring)."""

    def __init__(self, *args: Any, reward_goal: float = 10.0, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.reward_goal = _ArgumentCheck(self.env_name).number(
            "reward_goal", reward_goal, 0.0, 1000.0, allowed="a number in [0, 1000]"
        )
        if self.fixed_network is None and self.network_config.n_goals < 1:
            raise ValueError(
                f"{self.env_name}: network_config.n_goals={self.network_config.n_goals!r} is "
                "not allowed; use an int >= 1 (PipeNav needs goals)"
            )

    def _episode_reset(self) -> None:
        assert self.network is not None
        if not self.network.goals:
            raise ValueError("PipeNav needs a network with at least one goal")
        self.goal = np.asarray(self.network.goals[0], dtype=float)
        self.goal_edge = goal_edge_position(self.network, self.goal)
        start = self.network.start_pose
        assert start is not None
        r = route(self.network, start, self.goal)
        self.shortest_route = float(r.length) if r is not None else float("nan")
        self._last_distance = self._progress_measure()

    def _goal_point(self) -> NDArray[np.float64] | None:
        return getattr(self, "goal", None)

    def _sync_progress(self) -> None:
        self._last_distance = self._progress_measure()

    def _goal_target(self) -> Any:
        return self.goal_edge

    def _progress_measure(self) -> float:
        return edge_geodesic(self.network, self.plant.edge_position(), self.goal_edge)

    def _progress_terms(self) -> dict[str, float]:
        now = self._progress_measure()
        terms = {"progress": float(self._last_distance - now)}
        self._last_distance = now
        if self.success:
            terms["goal"] = self.reward_goal
        return terms

    def _info(self, events: dict[str, Any], terms: dict[str, float]) -> dict[str, Any]:
        info = super()._info(events, terms)
        info["shortest_route"] = self.shortest_route
        info["distance_to_goal"] = (
            float(self._last_distance) if hasattr(self, "_last_distance") else float("nan")
        )
        return info


class PipeExploreEnv(_DecisionEnv):
    """Inspect as much of the network as possible; reward = new pipe length covered (m).

    Args (besides the shared ones of the module docstring):
        coverage_done: covered fraction of the reachable pipe that ends the episode with
            success, in (0, 1].
        branch_view: how far the scans see into each pipe leaving the fitting ahead, m (>= 0).
    """

    env_name = "PipeExplore-v0"

    def __init__(
        self, *args: Any, coverage_done: float = 0.98, branch_view: float = 0.3, **kwargs: Any
    ) -> None:
        super().__init__(*args, **kwargs)
        check = _ArgumentCheck(self.env_name)
        self.coverage_done = check.number(
            "coverage_done", coverage_done, 0.0, 1.0, lo_open=True, allowed="a number in (0, 1]"
        )
        self.branch_view = check.number(
            "branch_view", branch_view, 0.0, allowed="a finite number >= 0 m"
        )

    def _episode_reset(self) -> None:
        assert self.network is not None
        self.covered: dict[str, list[tuple[float, float]]] = {}
        self.reachable_length, self.reachable_runs = reachable_runs(self.network)
        self._covered_total = 0.0
        # the robot was put in through the pipe behind it: that part counts as inspected
        st = self.plant.state
        r = self.network.run_by_id[st.run_id]
        behind = 0.0 if st.towards == r.b else edge_length(self.network, r.id)
        self._cover(r.id, min(st.s, behind), max(st.s, behind))
        self._cover_from_here()

    def _sync_progress(self) -> None:
        self._last_cover = self._covered_total

    def _cover_from_here(self) -> None:
        """The scans see the pipe between the robot and the fitting ahead, and a short way
        (``branch_view`` m) into each pipe leaving that fitting."""
        st = self.plant.state
        r = self.network.run_by_id[st.run_id]
        end = edge_length(self.network, r.id) if st.towards == r.b else 0.0
        self._cover(r.id, min(st.s, end), max(st.s, end))
        for other in self.network.runs_at[st.towards]:
            if other.id == r.id:
                continue
            length = edge_length(self.network, other.id)
            view = min(self.branch_view, length)
            if other.a == st.towards:
                self._cover(other.id, 0.0, view)
            else:
                self._cover(other.id, length - view, length)

    def _record(self, outcome: Outcome) -> None:
        super()._record(outcome)
        if outcome.status == PlantStatus.BACK_OUT:
            return  # reversing over pipe already seen
        # (the kinematic plant's path holds edge states; the physical plant's, sensor
        # positions along the driven path, m)
        waypoints = [
            w
            if isinstance(w, EdgeState)
            else edge_position(self.network, self.network.centreline.nearest(w))
            for w in outcome.path
        ]
        for a, b in zip(waypoints[:-1], waypoints[1:]):
            if a.run_id == b.run_id:
                self._cover(a.run_id, min(a.s, b.s), max(a.s, b.s))
                continue
            crossing = self._crossing(a, b)
            if crossing is None:  # (not neighbouring runs: nothing known in between)
                continue
            # through a fitting: to its centre on one run, from it on the next
            left, entered = crossing
            ra = self.network.run_by_id[a.run_id]
            end_a = edge_length(self.network, ra.id) if left == ra.b else 0.0
            self._cover(ra.id, min(a.s, end_a), max(a.s, end_a))
            rb = self.network.run_by_id[b.run_id]
            start_b = edge_length(self.network, rb.id) if entered == rb.b else 0.0
            self._cover(rb.id, min(b.s, start_b), max(b.s, start_b))

    def _crossing(
        self, a: EdgeState | EdgePosition, b: EdgeState | EdgePosition
    ) -> tuple[str, str] | None:
        """The fittings through which a path leaves ``a``'s run and enters ``b``'s: from the
        headings of edge states, else the fitting the two runs share (``None``: none)."""
        ra, rb = self.network.run_by_id[a.run_id], self.network.run_by_id[b.run_id]
        if isinstance(a, EdgeState) and isinstance(b, EdgeState):
            return a.towards, (rb.a if b.towards == rb.b else rb.b)
        shared = [n for n in (ra.a, ra.b) if n in (rb.a, rb.b)]
        return (shared[0], shared[0]) if shared else None

    def _cover(self, run_id: str, a: float, b: float) -> None:
        spans = self.covered.setdefault(run_id, [])
        spans.append((a, b))
        spans.sort()
        merged: list[tuple[float, float]] = []
        for lo, hi in spans:
            if merged and lo <= merged[-1][1] + 1e-9:
                merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
            else:
                merged.append((lo, hi))
        self.covered[run_id] = merged
        self._covered_total = sum(
            hi - lo
            for run in sorted(self.covered)
            if run in self.reachable_runs
            for lo, hi in self.covered[run]
        )

    def _advance(self) -> tuple[Decision | None, dict[str, Any]]:
        dec, events = super()._advance()
        self._cover_from_here()
        if self._covered_total >= self.coverage_done * self.reachable_length:
            self.terminated = True
            self.success = True
        return dec, events

    def _progress_measure(self) -> float:
        return self._covered_total

    def _progress_terms(self) -> dict[str, float]:
        new = self._covered_total - self._last_cover
        self._last_cover = self._covered_total
        return {"coverage": float(new)}

    def _info(self, events: dict[str, Any], terms: dict[str, float]) -> dict[str, Any]:
        info = super()._info(events, terms)
        total = getattr(self, "reachable_length", float("nan"))
        info["covered"] = float(getattr(self, "_covered_total", 0.0))
        info["coverage"] = info["covered"] / total if total else 0.0
        return info


def reachable_runs(network: PipeNetwork, max_turn: float = MAX_TURN) -> tuple[float, set[str]]:
    """Runs a forward-driving robot can reach from the start, and their centreline length (m)."""
    start = network.start_pose
    assert start is not None
    ep, towards = locate(network, start)
    seen_runs = {ep.run_id}
    frontier = [(towards, ep.run_id)]
    seen = set(frontier)
    while frontier:
        node, run_in = frontier.pop()
        for r in network.runs_at[node]:
            if r.id == run_in or turn_angle(network, node, run_in, r.id) > max_turn:
                continue
            state = (r.other(node), r.id)
            seen_runs.add(r.id)
            if state not in seen:
                seen.add(state)
                frontier.append(state)
    # summed in a fixed order: set order varies between processes (hash seeds)
    return float(sum(edge_length(network, r) for r in sorted(seen_runs))), seen_runs
