"""The rotating 2D LiDAR of thesis chapter 3.2: sensor models, presets and the simulator.

A 2D LiDAR scans a plane that contains the front module's forward axis; a servo rotates that
plane about the forward axis (thesis: 2 deg steps over 180 deg, position control). Each plane is
cast with ``mujoco.mj_multiRay`` against the world's ray meshes only (``world.wall_group``).

Geometry of a scan is defined in :mod:`detector.scan`. Poses:

- ``body_pose`` (argument of :meth:`RotatingLidar.scan`): world pose of the robot's front module
  (or of any carrier), x forward;
- ``mount``: the sensor frame relative to the body as designed (nominal);
- ``misalignment``: the error of the real sensor relative to its nominal mount (offset and tilt).
  Rays are cast from ``body * mount * misalignment``; the scan records both that truth and the
  nominal ``body * mount`` that the robot believes.

Measurement model, applied per beam in this order to the true distance ``r`` of a hit:
``r + bias + N(0, sigma^2 + (sigma_rel * r)^2)``, quantised to ``range_resolution``, then lost if
outside ``[min_range, max_range]``, on a dropout (probability ``dropout``) or when the beam meets
the surface at an incidence above ``max_incidence``. Angular jitter perturbs the cast direction
while the reported beam angle stays nominal. No return is ``inf`` with ``valid == False``.

Modes: ``"stop_and_scan"`` (the thesis: the carrier stands still during a sweep) and
``"continuous"`` (the servo turns while the carrier moves: pass a callable ``t -> body pose`` and
each plane is cast from the pose at its own timestamp, which distorts the cloud as on hardware).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from detector.scan import Scan, beam_directions
from pipe_env.geometry import Pose
from pipe_env.world import PipeWorld

MODES = ("stop_and_scan", "continuous")


@dataclass(frozen=True)
class LidarSpec:
    """A 2D LiDAR's limits and noise. Lengths in metres, angles in radians, rates in hertz.

    Attributes:
        name: preset name or a label.
        min_range, max_range: returns outside this interval are lost.
        fov: in-plane field of view, centred on the forward axis.
        beam_step: angle between beams in the plane.
        range_resolution: quantisation step of reported ranges (0: none).
        noise_sigma: standard deviation of gaussian range noise, absolute.
        noise_sigma_rel: standard deviation relative to the range (0.01 = 1 %).
        bias: constant offset added to every range (the thesis saw 2 cm on the LS02).
        dropout: probability that a return is lost.
        angular_jitter: standard deviation of the actual beam direction around the nominal one.
        max_incidence: returns are lost when the beam meets the surface at a larger angle from
            its normal (pi/2: never).
        scan_rate: in-plane sweeps per second; one plane takes ``1 / scan_rate`` seconds.
    """

    name: str = "custom"
    min_range: float = 0.1
    max_range: float = 2.0
    fov: float = math.pi
    beam_step: float = math.radians(0.5)
    range_resolution: float = 0.001
    noise_sigma: float = 0.0
    noise_sigma_rel: float = 0.0
    bias: float = 0.0
    dropout: float = 0.0
    angular_jitter: float = 0.0
    max_incidence: float = math.pi / 2
    scan_rate: float = 10.0

    def __post_init__(self) -> None:
        def need(ok: bool, name: str, allowed: str) -> None:
            if not ok:
                raise ValueError(
                    f"LidarSpec.{name} = {getattr(self, name)!r} is invalid; allowed: {allowed}"
                )

        for f in fields(self):
            if f.name != "name":
                v = getattr(self, f.name)
                need(isinstance(v, (int, float)) and math.isfinite(v), f.name, "a finite number")
        need(0.0 <= self.min_range < self.max_range, "min_range", "0 <= min_range < max_range")
        need(self.max_range <= 100.0, "max_range", "(min_range, 100] m")
        need(0.0 < self.fov <= 2 * math.pi, "fov", "(0, 2 pi] rad")
        need(0.0 < self.beam_step <= self.fov, "beam_step", "(0, fov] rad")
        need(0.0 <= self.range_resolution <= 0.1, "range_resolution", "[0, 0.1] m")
        need(0.0 <= self.noise_sigma <= 1.0, "noise_sigma", "[0, 1] m")
        need(0.0 <= self.noise_sigma_rel <= 0.5, "noise_sigma_rel", "[0, 0.5]")
        need(abs(self.bias) <= 1.0, "bias", "[-1, 1] m")
        need(0.0 <= self.dropout < 1.0, "dropout", "[0, 1)")
        need(0.0 <= self.angular_jitter <= math.radians(10), "angular_jitter", "[0, 10 deg]")
        need(0.0 < self.max_incidence <= math.pi / 2, "max_incidence", "(0, pi/2] rad")
        need(0.0 < self.scan_rate <= 1000.0, "scan_rate", "(0, 1000] Hz")

    @property
    def n_beams(self) -> int:
        return int(round(self.fov / self.beam_step)) + 1

    @property
    def beam_angles(self) -> NDArray[np.float64]:
        """(B,) in-plane beam angles, radians, symmetric about forward."""
        half = 0.5 * (self.n_beams - 1) * self.beam_step
        return np.linspace(-half, half, self.n_beams)

    @property
    def is_noiseless(self) -> bool:
        return (
            self.noise_sigma == 0
            and self.noise_sigma_rel == 0
            and self.bias == 0
            and self.dropout == 0
            and self.angular_jitter == 0
        )

    def with_(self, **changes: Any) -> LidarSpec:
        """A copy with some fields changed (validated)."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


#: Sensor presets. Figures from thesis table 4.2 (ideal) and table 3.1 with the manufacturers'
#: datasheets it cites ([24] LeiShen LS02, [25] EAI YDLIDAR X4).
PRESETS: dict[str, LidarSpec] = {
    # thesis table 4.2 "ideal Lidar": 0.1-200 cm, 0.1 cm resolution, 180 deg FoV, 0.5 deg steps
    "ideal": LidarSpec(
        name="ideal",
        min_range=0.1,
        max_range=2.0,
        fov=math.pi,
        beam_step=math.radians(0.5),
        range_resolution=0.001,
        scan_rate=10.0,
    ),
    # LS02 solid-state 2D LiDAR (thesis table 3.1, datasheet [24]): range 0.1-4 m, accuracy
    # < 0.5 % below 2 m, 86 deg scanning angle, 1 deg resolution, 10 Hz. Thesis 5.2.2 measured a
    # constant 2 cm error on the real unit, modelled as bias; the 5 mm quantisation and 1 % noise
    # reflect the coarse returns seen in thesis figure 5.8.
    "ls02": LidarSpec(
        name="ls02",
        min_range=0.1,
        max_range=4.0,
        fov=math.radians(86),
        beam_step=math.radians(1),
        range_resolution=0.005,
        noise_sigma=0.002,
        noise_sigma_rel=0.005,
        bias=0.02,
        dropout=0.02,
        angular_jitter=math.radians(0.2),
        max_incidence=math.radians(80),
        scan_rate=10.0,
    ),
    # YDLIDAR X4 (thesis table 3.1, datasheet [25]): range 0.12-10 m, accuracy < 0.5 mm below
    # 2 m and < 1.5 % beyond (the thesis lists < 3 % of distance), 0.48-0.52 deg resolution,
    # 6-12 Hz, 360 deg restricted to the front 180 deg in the thesis (4.3). Range resolution
    # below 1 % of distance; modelled as 0.5 mm quantisation, 1.5 mm plus 0.5 % gaussian noise.
    "ydlidar_x4": LidarSpec(
        name="ydlidar_x4",
        min_range=0.12,
        max_range=10.0,
        fov=math.pi,
        beam_step=math.radians(0.5),
        range_resolution=0.0005,
        noise_sigma=0.0015,
        noise_sigma_rel=0.005,
        dropout=0.01,
        angular_jitter=math.radians(0.1),
        max_incidence=math.radians(85),
        scan_rate=7.0,
    ),
}


def get_preset(name: str) -> LidarSpec:
    """The preset called ``name``; raises ValueError listing the presets if unknown."""
    if name not in PRESETS:
        raise ValueError(f"unknown LiDAR preset {name!r}; allowed: {sorted(PRESETS)}")
    return PRESETS[name]


def _rot_x(angle: float) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


class RotatingLidar:
    """A 2D LiDAR on a servo that turns its scan plane about the forward axis.

    Args:
        world: the world whose ray meshes are scanned.
        spec: sensor model (a :class:`LidarSpec` or a preset name).
        servo_step: plane angle increment, radians (thesis: 2 deg).
        servo_range: total servo sweep, radians (thesis: 180 deg; planes at 0, step, ... < range).
        mode: ``"stop_and_scan"`` or ``"continuous"``.
        mount: nominal sensor pose in the body frame.
        misalignment: true sensor pose relative to the nominal one.
        servo_settle: stop-and-scan time to move and settle between planes, seconds.
    """

    def __init__(
        self,
        world: PipeWorld,
        spec: LidarSpec | str = "ideal",
        servo_step: float = math.radians(2.0),
        servo_range: float = math.pi,
        mode: str = "stop_and_scan",
        mount: Pose | None = None,
        misalignment: Pose | None = None,
        servo_settle: float = 0.02,
    ) -> None:
        self.world = world
        self.spec = get_preset(spec) if isinstance(spec, str) else spec
        if not isinstance(self.spec, LidarSpec):
            raise ValueError(f"spec must be a LidarSpec or a preset name, got {spec!r}")
        if not (math.isfinite(servo_step) and 0.0 < servo_step <= math.pi):
            raise ValueError(f"servo_step = {servo_step!r} rad is invalid; allowed (0, pi]")
        if not (math.isfinite(servo_range) and servo_step <= servo_range <= 2 * math.pi):
            raise ValueError(
                f"servo_range = {servo_range!r} rad is invalid; allowed [servo_step, 2 pi]"
            )
        if mode not in MODES:
            raise ValueError(f"mode = {mode!r} is invalid; allowed: {MODES}")
        if not (math.isfinite(servo_settle) and 0.0 <= servo_settle <= 10.0):
            raise ValueError(f"servo_settle = {servo_settle!r} s is invalid; allowed [0, 10]")
        self.servo_step = float(servo_step)
        self.servo_range = float(servo_range)
        self.mode = mode
        self.mount = mount if mount is not None else Pose.identity()
        self.misalignment = misalignment if misalignment is not None else Pose.identity()
        self.servo_settle = float(servo_settle)
        n_planes = max(1, int(math.floor(self.servo_range / self.servo_step + 1e-9)))
        self.plane_angles = np.arange(n_planes) * self.servo_step
        self.beam_angles = self.spec.beam_angles
        self._local_dirs = beam_directions(self.plane_angles, self.beam_angles)  # (P, B, 3)
        n_rays = n_planes * self.spec.n_beams
        self._geomid = np.zeros(n_rays, dtype=np.int32)
        self._dist = np.zeros(n_rays, dtype=float)
        self._normal = np.zeros(3 * n_rays, dtype=float)
        self._vec = np.zeros(3 * n_rays, dtype=float)
        self._geomgroup = world.ray_geomgroup

    # ------------------------------------------------------------------ timing
    @property
    def n_planes(self) -> int:
        return int(len(self.plane_angles))

    @property
    def plane_period(self) -> float:
        """Seconds from one plane to the next."""
        settle = self.servo_settle if self.mode == "stop_and_scan" else 0.0
        return 1.0 / self.spec.scan_rate + settle

    @property
    def sweep_duration(self) -> float:
        """Seconds for a full servo sweep."""
        return self.n_planes * self.plane_period

    # ---------------------------------------------------------------- scanning
    def scan(
        self,
        body_pose: Pose | Callable[[float], Pose],
        rng: np.random.Generator,
        t0: float = 0.0,
    ) -> Scan:
        """A full servo sweep.

        Args:
            body_pose: the carrier's world pose, or (continuous mode) a function of time giving
                it; stop-and-scan with a function uses its value at ``t0``.
            rng: source of all measurement noise.
            t0: time of the first plane, seconds.
        """
        times = t0 + np.arange(self.n_planes) * self.plane_period
        if callable(body_pose):
            if self.mode == "continuous":
                bodies = [_checked(body_pose(float(t)), "body_pose(t)") for t in times]
            else:
                bodies = [_checked(body_pose(float(t0)), "body_pose(t0)")] * self.n_planes
        else:
            bodies = [_checked(body_pose, "body_pose")] * self.n_planes
        return self._cast(np.arange(self.n_planes), bodies, times, rng)

    def scan_plane(
        self, body_pose: Pose, plane_angle: float, rng: np.random.Generator, t0: float = 0.0
    ) -> Scan:
        """One plane at servo angle ``plane_angle`` (radians), for the 2D algorithm."""
        _checked(body_pose, "body_pose")
        if not math.isfinite(plane_angle):
            raise ValueError(f"plane_angle must be finite, got {plane_angle!r}")
        dirs = beam_directions(np.array([plane_angle]), self.beam_angles)
        return self._cast_dirs(dirs, np.array([plane_angle]), [body_pose], np.array([t0]), rng)

    def _cast(
        self, planes: NDArray, bodies: list[Pose], times: NDArray, rng: np.random.Generator
    ) -> Scan:
        return self._cast_dirs(
            self._local_dirs[planes], self.plane_angles[planes], bodies, times, rng
        )

    def _cast_dirs(
        self,
        local_dirs: NDArray,
        plane_angles: NDArray,
        bodies: list[Pose],
        times: NDArray,
        rng: np.random.Generator,
    ) -> Scan:
        spec = self.spec
        n_p, n_b = local_dirs.shape[:2]
        n = n_p * n_b
        nominal = [b.compose(self.mount) for b in bodies]
        true = [p.compose(self.misalignment) for p in nominal]
        # draw every random number up front, a fixed count per ray, so a seed fixes the scan
        jitter = rng.normal(0.0, 1.0, size=(2, n_p, n_b)) if spec.angular_jitter > 0 else None
        noise = rng.normal(0.0, 1.0, size=(n_p, n_b))
        drop = rng.random(size=(n_p, n_b))
        dirs = local_dirs
        if jitter is not None:
            dirs = _jittered(
                local_dirs, plane_angles, self.beam_angles, jitter, spec.angular_jitter
            )
        vec = self._vec[: 3 * n].reshape(n_p, n_b, 3)
        for k in range(n_p):
            vec[k] = dirs[k] @ true[k].rotation.T
        dist = self._dist[:n]
        geomid = self._geomid[:n]
        want_normals = spec.max_incidence < math.pi / 2
        normal = self._normal[: 3 * n]
        m, d = self.world.model, self.world.data
        cutoff = spec.max_range + abs(spec.bias) + 0.05
        same_origin = all(np.array_equal(t.position, true[0].position) for t in true)
        if same_origin:
            mujoco.mj_multiRay(
                m,
                d,
                true[0].position,
                self._vec[: 3 * n],
                self._geomgroup,
                1,
                -1,
                geomid,
                dist,
                normal if want_normals else None,
                n,
                cutoff,
            )
        else:
            for k in range(n_p):
                sl = slice(k * n_b, (k + 1) * n_b)
                mujoco.mj_multiRay(
                    m,
                    d,
                    true[k].position,
                    self._vec[3 * sl.start : 3 * sl.stop],
                    self._geomgroup,
                    1,
                    -1,
                    geomid[sl],
                    dist[sl],
                    normal[3 * sl.start : 3 * sl.stop] if want_normals else None,
                    n_b,
                    cutoff,
                )
        true_r = dist.reshape(n_p, n_b)
        hit = true_r >= 0.0
        r = np.where(hit, true_r, 0.0)
        sigma = np.sqrt(spec.noise_sigma**2 + (spec.noise_sigma_rel * r) ** 2)
        meas = r + spec.bias + sigma * noise
        if spec.range_resolution > 0:
            meas = np.round(meas / spec.range_resolution) * spec.range_resolution
        valid = hit & (meas >= spec.min_range) & (meas <= spec.max_range) & (drop >= spec.dropout)
        if want_normals:
            cos_inc = -np.einsum("pbi,pbi->pb", normal.reshape(n_p, n_b, 3), vec)
            valid &= cos_inc >= math.cos(spec.max_incidence)
        ranges = np.where(valid, meas, np.inf)
        meta = {
            "mode": self.mode,
            "servo_step": self.servo_step,
            "servo_range": self.servo_range,
            "n_planes": int(n_p),
        }
        return Scan(
            ranges=ranges,
            valid=valid,
            beam_angles=self.beam_angles.copy(),
            plane_angles=np.asarray(plane_angles, dtype=float).copy(),
            timestamps=np.asarray(times, dtype=float),
            positions=np.array([t.position for t in true]),
            rotations=np.array([t.rotation for t in true]),
            nominal_positions=np.array([p.position for p in nominal]),
            nominal_rotations=np.array([p.rotation for p in nominal]),
            spec=spec.to_dict(),
            metadata=meta,
        )


def _checked(pose: Any, name: str) -> Pose:
    if not isinstance(pose, Pose):
        raise ValueError(f"{name} must be a pipe_env.geometry.Pose, got {type(pose).__name__}")
    return pose


def _jittered(
    local_dirs: NDArray,
    plane_angles: NDArray,
    beam_angles: NDArray,
    unit_noise: NDArray,
    sigma: float,
) -> NDArray:
    """Beam directions with the in-plane and plane angles perturbed by ``sigma`` * noise."""
    a = np.asarray(plane_angles)[:, None] + sigma * unit_noise[0]
    b = np.asarray(beam_angles)[None, :] + sigma * unit_noise[1]
    sb = np.sin(b)
    return np.stack([np.cos(b), sb * np.cos(a), sb * np.sin(a)], axis=-1)
