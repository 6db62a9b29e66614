"""Gymnasium environments at the Decision Support level (thesis 3.1.1).

The robot senses and proposes, the agent chooses, the robot acts. One ``step`` is one
decision: the environment runs the closed loop (drive, scan, detect, fuse) until a structure is
confirmed within the trigger distance (or the goal is reached), offers the options it found, and
executes the motion-primitive sequence of the option the agent picks.

``pipenav/PipeNav-v0`` (:class:`PipeNavEnv`): reach a goal in a generated network.
``pipenav/PipeExplore-v0`` (:class:`PipeExploreEnv`): cover as much pipe as possible.
Each class's docstring holds its spaces, rewards, episode end and arguments as tables.

This module owns the decision loop (:class:`DecisionEnv`): the episode, the plant factory,
single ways taken automatically, metrics, rendering and pickling. The parts it is built from
live beside it: the arguments (:mod:`pipe_env.envs.config`), the observation and action types
(:mod:`pipe_env.envs.observations`, :mod:`pipe_env.envs.actions`), the goal and coverage tasks
(:mod:`pipe_env.envs.tasks`), where networks come from (:mod:`pipe_env.envs.sources`), what
agents may know beyond the observation (:mod:`pipe_env.envs.oracle`), and the episode's outcome
accounting (``outcome_log``: :mod:`pipe_env.envs.outcome_log`).

Rendering (``render_mode``): ``"ansi"`` returns the options table as text; ``"rgb_array"``
returns an image of the robot in the pipe now (480x360, an isometric view following the robot,
the walls translucent, on a light background); ``"rgb_array_list"`` returns the list of images
since the last ``render()`` call: in full fidelity one every :attr:`DecisionEnv.frame_interval`
simulated seconds while the robot moves (during ``reset`` and each ``step``) plus one at the end
of each, so a video shows the motion; in fast fidelity (no simulated motion) one per
``reset``/``step``. To record an mp4, wrap the env in :class:`pipe_env.envs.wrappers.RecordVideo`
(Gymnasium's ``RecordVideo``, keeping every motion frame; the stock one keeps one frame per
step), with ``render_mode="rgb_array"`` or ``"rgb_array_list"``; it needs the ``video`` extra.
Videos play at ``metadata["render_fps"]`` frames per second. Rendering picks an OpenGL backend on
first use and raises :class:`pipe_env.rendering.RenderingUnavailable` when none works; nothing
else needs one.
"""

from __future__ import annotations

from typing import Any, ClassVar, Generic, SupportsFloat, TypeVar, cast

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from detector.options import StructureOption, option_errors
from detector.vocab import Kind
from pipe_env.envs.actions import BACK_ROW, K_OPTIONS, OptionAction
from pipe_env.envs.config import (
    MAX_TRIGGER_DISTANCE,
    RENDER_MODES,
    EnvConfig,
    ExploreConfig,
    NavConfig,
    as_network,
)
from pipe_env.envs.fidelity import Fidelity
from pipe_env.envs.observations import (
    GOAL_CLIP,
    MAX_TAKEN,
    OPTION_COLUMNS,
    OPTION_FEATURES,
    SCAN_SHAPE,
    DecisionObservation,
    world_way,
)
from pipe_env.envs.oracle import Oracle
from pipe_env.envs.outcome_log import OutcomeLog
from pipe_env.envs.plant import Decision, KinematicPlant, Plant, PlantOutcome, PlantStatus
from pipe_env.envs.sensing_model import error_model_for
from pipe_env.envs.sources import draw_network, pool_network
from pipe_env.envs.tasks import CoverageTask, GoalTask, Task, reachable_runs
from pipe_env.envs.way_log import WayLog
from pipe_env.network import PipeNetwork
from pipe_env.robot_limits import drivable

__all__ = [
    "GOAL_CLIP",
    "K_OPTIONS",
    "MAX_AUTO_STRUCTURES",
    "MAX_TAKEN",
    "MAX_TRIGGER_DISTANCE",
    "OPTION_COLUMNS",
    "OPTION_FEATURES",
    "SCAN_SHAPE",
    "DecisionEnv",
    "PipeExploreEnv",
    "PipeNavEnv",
    "pool_network",
    "reachable_runs",
]

#: A chain of this many single ways taken automatically truncates the episode.
MAX_AUTO_STRUCTURES = 64

#: An observation: the keys of :class:`~pipe_env.envs.observations.DecisionObservation`.
Observation = dict[str, Any]
ConfigT = TypeVar("ConfigT", bound=EnvConfig)
TaskT = TypeVar("TaskT", bound=Task)


class _FromConfig:
    """A read-only env attribute that is the config field of the same name."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, env: Any, owner: type | None = None) -> Any:
        return self if env is None else getattr(env.config, self.name)

    def __set__(self, env: Any, value: Any) -> None:
        raise AttributeError(
            f"{self.name} is read-only: pass it to the constructor (gymnasium.make(..., "
            f"{self.name}=...)); the environment's settings are its frozen config"
        )


class DecisionEnv(gym.Env[Observation, np.int64], Generic[ConfigT, TaskT]):
    """The decision loop both environments share (see the module docstring and the two
    subclasses' docstrings for the spaces, rewards, episode end and arguments).

    A subclass names its config class and builds its task (:meth:`_make_task`); the network of
    each episode comes from one hook, :meth:`_gen_network`.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 10}

    #: Simulated seconds between the frames collected while the robot moves (full fidelity);
    #: at ``render_fps`` 10 a video plays 5 times faster than the robot drives.
    frame_interval = 0.5

    #: The config class: the keyword arguments and their checks.
    config_class: ClassVar[type[EnvConfig]] = EnvConfig

    # the arguments, read from the config (read-only)
    detector = _FromConfig()
    fidelity = _FromConfig()
    physics = _FromConfig()
    misalignment = _FromConfig()
    trigger_distance = _FromConfig()
    auto_single = _FromConfig()
    max_jams = _FromConfig()
    scan_image = _FromConfig()
    reward_invalid = _FromConfig()
    reward_jam = _FromConfig()
    reward_time = _FromConfig()
    network_pool = _FromConfig()
    pool_seed = _FromConfig()

    def __init__(self, **kwargs: Any) -> None:
        """Keyword arguments: the fields of :attr:`config_class` (see the class docstring)."""
        self.config: ConfigT = self.config_class(**kwargs)  # type: ignore[assignment]
        self.render_mode = self.config.render_mode
        self.observation_type = DecisionObservation(self.config.scan_image)
        self.action_type = OptionAction()
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()
        self.task: TaskT = self._make_task()
        #: what agents may know beyond the observation (:mod:`pipe_env.envs.oracle`)
        self.oracle = Oracle(self)
        self.network: PipeNetwork | None = None
        self.plant: Plant | None = None
        self._decision: Decision | None = None
        self._decision_serial = 0
        self._renderer: Any = None
        self._world_for_render: Any = None
        #: collect frames while the robot moves (``rgb_array_list`` does; so does
        #: :class:`pipe_env.envs.wrappers.RecordVideo` for ``rgb_array``)
        self.collect_frames = self.render_mode == "rgb_array_list"
        self._frames: list[NDArray[np.uint8]] = []
        self._next_frame_time = 0.0
        self._mask_cache: tuple[Any, NDArray[np.bool_]] | None = None
        self._start_counters()

    @property
    def env_name(self) -> str:
        """The registered id without the namespace (named in argument errors)."""
        return self.config.env_name

    @property
    def network_config(self) -> Any:
        """The network generator's settings (a :class:`~pipe_env.generator.NetworkConfig`)."""
        return self.config.generator

    @property
    def fixed_network(self) -> PipeNetwork | None:
        """The fixed network of every episode, or None."""
        return self.config.fixed_network

    @property
    def lidar(self) -> Any:
        """The simulated sensor (a :class:`~pipe_env.lidar.LidarSpec`)."""
        return self.config.lidar_spec

    def _make_task(self) -> TaskT:
        """The episode's task (subclasses build theirs from the config)."""
        raise NotImplementedError

    @property
    def decision(self) -> Decision | None:
        """The decision pending for the agent (None when the episode has ended)."""
        return self._decision

    @decision.setter
    def decision(self, value: Decision | None) -> None:
        self._decision = value
        self._decision_serial += 1

    @property
    def goal_point(self) -> NDArray[np.float64] | None:
        """The task's goal in the world frame (m), None without one."""
        return self.task.goal_point

    @property
    def _plant(self) -> Plant:
        if self.plant is None:
            raise RuntimeError("call reset() before step()")
        return self.plant

    # ----------------------------------------------------------------- episode
    def _gen_network(self) -> PipeNetwork:
        """The next episode's network (MiniGrid's ``_gen_grid``): the fixed one, one of the
        pool or a generated one (:func:`pipe_env.envs.sources.draw_network`), drawn with the
        env's generator. Override to supply networks another way."""
        return draw_network(self.config, self.np_random)

    def _make_plant(self, network: PipeNetwork) -> Plant:
        """The plant factory: the only place that knows the fidelities' classes."""
        cfg = self.config
        if cfg.fidelity == Fidelity.FAST:
            return KinematicPlant(
                network,
                cfg.detector,
                cfg.trigger_distance,
                error_model=error_model_for(cfg.detector, cfg.lidar_spec),
            )
        from pipe_env.envs.plant_full import PhysicalPlant

        # (a cast: PhysicalPlant declares ``world`` as always set, the protocol as optional)
        return cast(
            Plant,
            PhysicalPlant(
                network,
                cfg.detector,
                cfg.trigger_distance,
                lidar=cfg.lidar_spec,
                misalignment=cfg.misalignment,
                scan_image=cfg.scan_image,
                physics=cfg.physics,
            ),
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Observation, dict[str, Any]]:
        super().reset(seed=seed)
        given = (
            as_network(options["network"], self.env_name)
            if options and "network" in options
            else None
        )
        fixed = given is not None or self.fixed_network is not None
        # a generated episode must start with a decision: redraw the rare network whose goal is
        # reached before any (the first structures being single ways taken automatically)
        for _ in range(10):
            self._start_episode(given or self._gen_network())
            if self.decision is not None or fixed:
                break
        if self.decision is None and self.success and fixed:
            which = "options['network']" if given is not None else "network"
            raise ValueError(
                f"{self.env_name}: {which}: the goal is reached inside reset(), before the "
                "first decision (the start drives to it through single ways only); allowed: a "
                "goal beyond the first junction or closure ahead of the start"
            )
        info = self._info(self._reset_events, {})
        self._end_frame()
        return self._observation(), info

    def _start_counters(self) -> None:
        self.jams = 0
        self.decisions = 0
        self.structures = 0
        self.invalid_actions = 0
        self.terminated = False
        self.truncated = False
        self.success = False
        self._waypoints: list[Any] = []
        #: sensor positions where the agent was asked to decide (world frame, m)
        self.decision_points: list[NDArray[np.float64]] = []
        #: detection errors of every decision against ground truth
        self.detection_errors: list[dict[str, float]] = []
        self.way_log = WayLog()
        #: what was sensed at each structure and how each attempted way ended
        #: (:mod:`pipe_env.envs.outcome_log`)
        self.outcome_log = OutcomeLog()
        self._reset_events: dict[str, Any] = {}

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
        plant = self.plant
        plant.reset(np.random.default_rng(self.np_random.integers(2**63)))
        self._frames = []
        if self.collect_frames:
            now = plant.watch_motion(self._on_tick)
            if now is not None:
                self._next_frame_time = now
        self._start_counters()
        self._waypoints = [plant.waypoint()]
        self.task.initialize_episode(network, plant)
        self.decision, self._reset_events = self._advance()
        self.task.sync(plant)

    def step(self, action: Any) -> tuple[Observation, SupportsFloat, bool, bool, dict[str, Any]]:
        plant = self._plant
        # only integers of the action space: int() would turn 0.9, '1', b'1' or True into one
        row = self.action_type.check(action)
        if self.terminated or self.truncated:  # e.g. a goal reached before any decision
            return self._finish_step({}, {"after_termination": True})
        terms: dict[str, float] = {"time": self.config.reward_time}
        events: dict[str, Any] = {"jammed": False, "blocked": False, "invalid_action": False}
        if not self.action_masks()[row]:
            self.invalid_actions += 1
            events["invalid_action"] = True
            terms["invalid"] = self.config.reward_invalid
            return self._finish_step(terms, events)
        self.decisions += 1
        jams_before = self.jams
        assert self.decision is not None
        choice = self.action_type.choice(self.decision.options, row)
        odo = plant.odometry_pose()
        self.way_log.record(odo.position, world_way(choice, odo))
        outcome = self._execute(self.decision, choice)
        self._record(outcome)
        self._after_action(outcome, events)
        if self.jams > jams_before:  # the chosen way, or a drive or single way after it
            terms["jam"] = self.config.reward_jam * (self.jams - jams_before)
        terms.update(self.task.reward_terms(plant, self.success))
        return self._finish_step(terms, events)

    def _after_action(self, outcome: PlantOutcome, events: dict[str, Any]) -> None:
        """Update the episode after the chosen way's ``outcome`` (drive on if it was done)."""
        events["outcome"] = outcome.status
        if outcome.note:
            events["outcome_note"] = outcome.note
        if outcome.status == PlantStatus.JAMMED:
            self.jams += 1
            events["jammed"] = True
            if self.jams >= self.config.max_jams:
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

    def _finish_step(
        self, terms: dict[str, float], events: dict[str, Any]
    ) -> tuple[Observation, SupportsFloat, bool, bool, dict[str, Any]]:
        reward = float(sum(terms.values()))
        info = self._info(events, terms)
        self._end_frame()
        return self._observation(), reward, bool(self.terminated), bool(self.truncated), info

    def _reach_goal(self, events: dict[str, Any]) -> None:
        self.terminated = True
        self.success = True
        self.decision = None
        events["goal_reached"] = True

    def _record(self, outcome: PlantOutcome) -> None:
        if self._waypoints and outcome.path and outcome.path[0] is self._waypoints[-1]:
            self._waypoints.extend(outcome.path[1:])
        else:
            self._waypoints.extend(outcome.path)
        self.task.record(outcome)

    @property
    def path(self) -> NDArray[np.float64]:
        """The driven path so far as (N, 3) world positions, metres."""
        return self._plant.positions([w for w in self._waypoints if w is not None])

    def _advance(self) -> tuple[Decision | None, dict[str, Any]]:
        """Drive to the next decision the agent must take (single ways auto-executed), then
        let the task account for it (coverage may end the episode)."""
        dec, events = self._drive_to_decision()
        if self.task.after_drive(self._plant):
            self.terminated = True
            self.success = True
        return dec, events

    def _drive_to_decision(self) -> tuple[Decision | None, dict[str, Any]]:
        """Drive on until the agent must decide; single ways (a bend or reducer with one
        drivable way) are taken without asking when ``auto_single``."""
        plant = self._plant
        events: dict[str, Any] = {"auto_structures": 0}
        for _ in range(MAX_AUTO_STRUCTURES):
            dec, out = plant.advance(self.task.target)
            self._record(out)
            if out.status == PlantStatus.GOAL:
                self._reach_goal(events)
                return None, events
            assert dec is not None
            # stalled while driving: the robot decides where it is
            if out.status == PlantStatus.JAMMED:
                self.outcome_log.drive_jams += 1
                self._count_jam(events, "drive_jammed", out.note)
            self.structures += 1
            self._after_sensing(dec)
            ways = [o for o in dec.options if drivable(o)]
            if not self._single_way(dec, ways):
                self.decision_points.append(dec.pose.position)
                return dec, events
            done, dec = self._take_single_way(dec, ways[0], events)
            if done:
                return dec, events
        self.truncated = True  # a pathological chain of single ways: stop, it is not an outcome
        events["truncated_auto"] = True
        return None, events

    def _single_way(self, dec: Decision, ways: list[StructureOption]) -> bool:
        """Whether ``dec`` is a single way taken without asking the agent."""
        return (
            self.config.auto_single
            and len(ways) == 1
            and len(dec.options) == 1
            and dec.kind in (Kind.BEND, Kind.REDUCER)
        )

    def _take_single_way(
        self, dec: Decision, way: StructureOption, events: dict[str, Any]
    ) -> tuple[bool, Decision | None]:
        """Execute a single way; (True, the decision to offer) when the drive stops here,
        (False, ``dec``) to drive on."""
        plant = self._plant
        outcome = self._execute(dec, way, auto=True)
        self._record(outcome)
        events["auto_structures"] += 1
        if outcome.status == PlantStatus.GOAL:
            self._reach_goal(events)
            return True, None
        if outcome.status == PlantStatus.DONE:
            return False, dec
        events["auto_" + outcome.status] = True
        plant.decision = dec
        if outcome.status == PlantStatus.JAMMED:
            self._count_jam(events, "auto_jammed", outcome.note)
            if not self.terminated:
                dec = self._sense_again_after_jam()
        self.decision_points.append(dec.pose.position)
        return True, dec

    def _execute(
        self, dec: Decision, choice: StructureOption | str, auto: bool = False
    ) -> PlantOutcome:
        """Have the plant take ``choice`` at ``dec`` and log the attempt."""
        outcome = self._plant.execute(choice, self.task.target)
        self.outcome_log.record_attempt(choice, dec.truth, outcome.status, auto)
        return outcome

    def _sense_again_after_jam(self) -> Decision:
        """The robot backed off the structure that jammed it (on a way the agent chose or
        one the environment took by itself) and decides on fresh sweeps."""
        dec, _ = self._plant.resense()
        self._after_sensing(dec)
        return dec

    def _count_jam(self, events: dict[str, Any], key: str, note: str) -> None:
        self.jams += 1
        events["jammed"] = events[key] = True
        if note:
            events[key + "_note"] = note
        if self.jams >= self.config.max_jams:
            self.terminated = True

    def _after_sensing(self, dec: Decision) -> None:
        """Record detection errors of a decision against ground truth."""
        self.outcome_log.record_sensing(dec.options, dec.kind, dec.truth)
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
        ended = self.decision is None or self.terminated or self.truncated
        mask = self.action_type.mask(None if ended else self.decision.options)  # type: ignore[union-attr]
        self._mask_cache = (key, mask)
        return mask.copy()

    def _observation(self) -> Observation:
        options = self.decision.options if self.decision is not None else []
        return self.observation_type.observe(
            self._plant, options, self.action_masks(), self.way_log, self.goal_point
        )

    def _info(self, events: dict[str, Any], terms: dict[str, float]) -> dict[str, Any]:
        plant = self._plant
        info = {
            "reward_terms": dict(terms),
            "is_success": bool(self.success),
            "jams": int(self.jams),
            "decisions": int(self.decisions),
            "structures": int(self.structures),
            "invalid_actions": int(self.invalid_actions),
            "travelled": float(plant.travelled),
            "sim_time": float(plant.sim_time),
            "fidelity": self.config.fidelity,
            "detector": self.config.detector,
            "detection_error": dict(self.detection_errors[-1]) if self.detection_errors else {},
            "action_mask": self.action_masks().astype(np.int8),
            "odometry_position": plant.odometry_pose().position.copy(),
        }
        info.update(events)
        info.update(self.task.info())
        return info

    # --------------------------------------------------------------- rendering
    def render(self) -> Any:
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
        cfg = self.config
        if self.decision is None:
            state = "goal reached" if self.success else "no decision pending"
            return f"[{cfg.fidelity}/{cfg.detector}] {state}\n"
        dec = self.decision
        plant = self._plant
        lines = [
            f"[{cfg.fidelity}/{cfg.detector}] structure ahead: {dec.kind}"
            f"   clamped {plant.clamped_diameter * 1000:.0f} mm   jams {self.jams}"
        ]
        mask = self.action_masks()
        for i, o in enumerate(dec.options[:BACK_ROW]):
            mark = " " if mask[i] else "x"
            lines.append(f"  [{i}]{mark} {o.describe()}  (confidence {o.confidence:.2f})")
        lines.append(f"  [{BACK_ROW}]  back out to the last junction")
        goal = self.goal_point
        if goal is not None:
            rel = plant.odometry_pose().inverse_transform_points(goal)
            lines.append(f"  goal: {rel[0]:+.2f} m ahead, {rel[1]:+.2f} m left, {rel[2]:+.2f} m up")
        return "\n".join(lines) + "\n"

    def _render_rgb(self) -> NDArray[np.uint8]:
        from pipe_env.rendering import WorldRenderer

        plant = self._plant
        world = plant.world
        if world is None:
            if self._world_for_render is None or self._world_for_render.network is not (
                self.network
            ):
                from pipe_env.world import build_world

                assert self.network is not None
                self._world_for_render = build_world(self.network, contact_walls=False)
                self._renderer = None
            world = self._world_for_render
        if self._renderer is None or self._renderer.world is not world:
            self._renderer = WorldRenderer(world, 480, 360)
        pose = plant.pose()
        bodies = plant.body_positions()  # full fidelity: frame the whole robot
        target = bodies.mean(axis=0) if bodies is not None else pose.position
        cam = self._renderer.camera("iso", target=target, distance=0.9)
        image: NDArray[np.uint8] = self._renderer.render(cam, markers=[(pose.position, 0.03)])
        return image

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._world_for_render = None
        if self.plant is not None:
            self.plant.close()

    def __getstate__(self) -> dict[str, Any]:
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


class PipeNavEnv(DecisionEnv[NavConfig, GoalTask]):
    """Reach a goal in a generated pipe network: ``pipenav/PipeNav-v0``.

    ## Description

    The robot starts in a generated network (or a given one) and must reach the network's
    first goal. Each step is one decision at a structure ahead: the environment drives the
    robot on (sensing, detecting and taking single ways by itself) until the agent must choose
    among the detected ways on, or back out.

    ## Action space

    ``Discrete(6)`` (:mod:`pipe_env.envs.actions`):

    | action | meaning |
    |---|---|
    | 0-4 | the detected way in that row (straight on first, then by roll direction) |
    | 5 | back out: reverse to the last junction passed (or the start) and decide again |

    ``action_masks()`` (and ``info["action_mask"]``) allows a detected way inside the robot's
    57-125 mm range turning at most 90 deg, and backing out. A masked action is not executed:
    the robot stays, the same decision is offered again, ``info["invalid_action"]`` is True.
    Anything but an integer of the space (a float, a bool, a string) raises ``ValueError``.

    ## Observation space

    A ``Dict`` (:mod:`pipe_env.envs.observations`):

    | key | shape | meaning |
    |---|---|---|
    | ``options`` | (6, 15) | one row per action; columns below |
    | ``goal`` | (3,) | the goal in the robot frame from noisy odometry, m, clipped to +-20 |
    | ``proprio`` | (3,) | clamped diameter (m), cos and sin of the robot's roll |
    | ``scan`` | (16, 32) | with ``scan_image=True``: the last sweep's ranges / max range |

    | column | name | range | meaning |
    |---|---|---|---|
    | 0 | ``valid`` | [0, 1] | 1 if the action mask allows this row |
    | 1-5 | ``straight``, ``reducer``, ``closure``, ``bend``, ``junction`` | [0, 1] | kind one-hot |
    | 6 | ``back_out`` | [0, 1] | 1 on the back-out row |
    | 7 | ``distance`` | [-1, 5] | to the structure's reference point along the pipe, m |
    | 8 | ``diameter`` | [0, 0.3] | inner diameter of the outgoing pipe, m |
    | 9, 10 | ``cos_direction``, ``sin_direction`` | [-1, 1] | roll of the outgoing axis |
    | 11 | ``angle`` | [0, pi] | deflection from straight on, rad |
    | 12 | ``confidence`` | [0, 1] | the detector's confidence |
    | 13 | ``taken`` | [0, 1] | ways taken from here before (0, 1/3, 2/3, 1 for 3 or more) |
    | 14 | ``goal_alignment`` | [-1, 1] | cos between the way and the direction to the goal |

    ## Rewards

    The sum of the terms in ``info["reward_terms"]`` (:class:`~pipe_env.envs.tasks.GoalTask`):

    | term | when | value |
    |---|---|---|
    | ``progress`` | every executed action | decrease of the along-network distance to the goal, m |
    | ``goal`` | the goal is reached | ``reward_goal`` |
    | ``jam`` | per jam of the chosen way or on the way to the next decision | ``reward_jam`` |
    | ``time`` | every decision | ``reward_time`` |
    | ``invalid`` | a masked action (instead of the other terms but ``time``) | ``reward_invalid`` |

    ## Starting state

    The robot at the network's start pose, driven to the first decision (a generated network
    whose goal is reached before any decision is drawn again).

    ## Episode end

    | ends | when |
    |---|---|
    | terminated, success | the goal is reached |
    | terminated | ``max_jams`` jams |
    | truncated | 64 decisions (the registered ``max_episode_steps``), or 64 single ways in a row |

    ## Arguments

    Keyword arguments of ``gymnasium.make`` (:class:`~pipe_env.envs.config.NavConfig`); a bad
    value raises ``ValueError`` (``PipeNav-v0: <argument> = <value>: <problem>; allowed: ...``).

    | argument | default | meaning |
    |---|---|---|
    | ``network_config`` | None | ``NetworkConfig`` (or its dict) of the generated networks |
    | ``network`` | None | a fixed network (``PipeNetwork``, dict or JSON/YAML path) |
    | ``network_pool`` | None | draw episodes from a reproducible pool of this many networks |
    | ``pool_seed`` | 0 | seed of that pool (another one for held-out evaluation) |
    | ``detector`` | ``"improved"`` | ``improved``, ``thesis`` or ``ground_truth`` |
    | ``fidelity`` | ``"fast"`` | ``fast`` (kinematic, modelled sensing) or ``full`` (MuJoCo) |
    | ``lidar`` | ``"ideal"`` | sensor preset or a ``LidarSpec`` (fast: its error model) |
    | ``misalignment`` | None | true sensor pose relative to its mount (full fidelity) |
    | ``physics`` | ``"contact"`` | full fidelity: ``contact`` or ``everywhere`` (the reference) |
    | ``render_mode`` | None | ``rgb_array``, ``rgb_array_list`` or ``ansi`` |
    | ``trigger_distance`` | 0.2 | stop this far before a structure to decide, m, in (0, 1] |
    | ``auto_single`` | True | take a single way (a bend or reducer) without asking |
    | ``max_jams`` | 3 | end the episode after this many jams (>= 1) |
    | ``scan_image`` | False | add the ``scan`` range image |
    | ``reward_goal`` | 10.0 | the goal bonus, in [0, 1000] |
    | ``reward_jam`` | -2.0 | per jam |
    | ``reward_time`` | -0.05 | per decision |
    | ``reward_invalid`` | -0.5 | per masked action |
    """

    config_class = NavConfig

    reward_goal = _FromConfig()

    def _make_task(self) -> GoalTask:
        return GoalTask(self.config.reward_goal)

    @property
    def goal(self) -> NDArray[np.float64] | None:
        """The episode's goal point in the world frame, m."""
        return self.task.goal

    @property
    def shortest_route(self) -> float:
        """Length of the shortest route from the start to the goal, m."""
        return self.task.shortest_route


class PipeExploreEnv(DecisionEnv[ExploreConfig, CoverageTask]):
    """Inspect as much of the network as possible: ``pipenav/PipeExplore-v0``.

    ## Description

    The robot starts in a generated network (or a given one) and should see as much of the
    pipe it can reach as it can. The scans see the pipe between the robot and the fitting ahead
    and ``branch_view`` m into each pipe leaving that fitting; the pipe it was put in through
    counts as seen.

    ## Action space

    As PipeNav's: ``Discrete(6)``, rows 0-4 the detected ways on, row 5 backs out, with
    ``action_masks()`` and strict checking (:mod:`pipe_env.envs.actions`).

    ## Observation space

    As PipeNav's (:mod:`pipe_env.envs.observations`): ``options`` (6, 15), ``goal`` (3,) (zeros:
    no goal), ``proprio`` (3,), and ``scan`` (16, 32) with ``scan_image=True``; the options
    columns are ``valid``, the kind one-hot ``straight``, ``reducer``, ``closure``, ``bend``,
    ``junction``, ``back_out``, ``distance``, ``diameter``, ``cos_direction``,
    ``sin_direction``, ``angle``, ``confidence``, ``taken`` and ``goal_alignment`` (0).

    ## Rewards

    The sum of the terms in ``info["reward_terms"]`` (:class:`~pipe_env.envs.tasks.CoverageTask`):

    | term | when | value |
    |---|---|---|
    | ``coverage`` | every executed action | new pipe length covered by the scans, m |
    | ``jam`` | per jam of the chosen way or on the way to the next decision | ``reward_jam`` |
    | ``time`` | every decision | ``reward_time`` |
    | ``invalid`` | a masked action (instead of the other terms but ``time``) | ``reward_invalid`` |

    ``info["covered"]`` (m) and ``info["coverage"]`` (fraction of the reachable pipe) report it.

    ## Starting state

    The robot at the network's start pose, driven to the first decision.

    ## Episode end

    | ends | when |
    |---|---|
    | terminated, success | the covered fraction of the reachable pipe reaches ``coverage_done`` |
    | terminated | ``max_jams`` jams |
    | truncated | 128 decisions (the registered ``max_episode_steps``), or 64 single ways in a row |

    ## Arguments

    Keyword arguments of ``gymnasium.make`` (:class:`~pipe_env.envs.config.ExploreConfig`):
    PipeNav's (``network_config``, ``network``, ``network_pool``, ``pool_seed``,
    ``detector``, ``fidelity``, ``lidar``, ``misalignment``, ``physics``, ``render_mode``,
    ``trigger_distance``, ``auto_single``, ``max_jams``, ``scan_image``, ``reward_jam``,
    ``reward_time``, ``reward_invalid``) but ``reward_goal``, and:

    | argument | default | meaning |
    |---|---|---|
    | ``coverage_done`` | 0.98 | covered fraction of the reachable pipe ending it, in (0, 1] |
    | ``branch_view`` | 0.3 | how far the scans see into pipes leaving the fitting ahead, m |
    """

    config_class = ExploreConfig

    coverage_done = _FromConfig()
    branch_view = _FromConfig()

    def _make_task(self) -> CoverageTask:
        return CoverageTask(self.config.coverage_done, self.config.branch_view)

    @property
    def covered(self) -> dict[str, list[tuple[float, float]]]:
        """Covered spans (m along the run) per run id."""
        return self.task.covered

    @property
    def reachable_length(self) -> float:
        """Centreline length of the pipe the robot can reach, m."""
        return self.task.reachable_length
