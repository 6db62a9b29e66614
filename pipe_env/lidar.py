"""The rotating 2D LiDAR of thesis chapter 3.2: sensor models, presets and the simulator.

A 2D LiDAR scans a plane that contains the front module's forward axis; a servo rotates that
plane about the forward axis (thesis 3.2.2: 2 deg steps over 180 deg, position control). Beam and
plane geometry are defined in :mod:`detector.scan`.

Ray casting backends (``RotatingLidar(..., backend=...)``):

- ``"mujoco"`` (the default of :class:`RotatingLidar` itself): ``mujoco.mj_multiRay`` against
  the world's wall meshes (geom group ``world.wall_group``), batched, on a sensing-only copy of
  those meshes (:mod:`pipe_env.raycast_mujoco`). The meshes are faceted, so ranges carry the
  tessellation error of :mod:`pipe_env.meshes` (a fraction of a millimetre radially).
- ``"analytic"`` (the default of the closed loop: the full-fidelity plant,
  :class:`pipe_env.envs.plant_full.PhysicalPlant`, argument ``lidar_backend``): exact intersection
  with the network's cylinders, cones, planes and tori (:mod:`pipe_env.raycast_analytic`),
  compiled per ray (numba), one origin per plane.

Poses:

- ``body_pose`` (argument of :meth:`RotatingLidar.scan`): world pose of the robot's front module
  (or of any carrier), x forward;
- ``mount``: the sensor frame relative to the body as designed (nominal);
- ``misalignment``: the error of the real sensor relative to its nominal mount (offset and tilt).
  Rays are cast from ``body * mount * misalignment``; the scan records both that truth and the
  nominal ``body * mount`` that the robot believes.

Measurement model, applied per beam in this order to the true distance ``r`` of a hit:
``r + bias + N(0, sigma^2 + (sigma_rel * r)^2)``, quantised to ``range_resolution``, then lost if
the *measured* value lies outside ``[min_range, max_range]``, on a dropout (probability
``dropout``) or when the beam meets the surface at an incidence above ``max_incidence``. Angular
jitter perturbs the cast direction within the scan plane (the sensor's encoder), the servo
jitter perturbs a whole plane about the forward axis (the servo's position error); the reported
angles stay nominal. No return is ``inf`` with ``valid == False``, never a fake distance.

Modes: ``"stop_and_scan"`` (the thesis: the carrier stands still during a sweep; each plane
takes ``1 / scan_rate`` plus ``servo_settle``) and ``"continuous"`` (the servo turns at
``servo_step * scan_rate`` while the carrier moves: pass a callable ``t -> body pose`` and each
plane is cast from the pose at its own timestamp, which distorts the cloud as on hardware; the
motion during one plane's in-plane sweep is neglected).

Randomness: all noise comes from the ``numpy.random.Generator`` passed to :meth:`scan`, with a
fixed number of draws per scan, so the same seed gives the same bytes.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from detector.geometry import Pose
from detector.scan import Scan, beam_directions
from detector.validation import check_choice, check_int, check_number, fail
from pipe_env.world import PipeWorld

MODES = ("stop_and_scan", "continuous")
BACKENDS = ("mujoco", "analytic")
#: Rays are cast this far beyond ``max_range + |bias|`` so that noise can still reach max_range.
_CUTOFF_MARGIN = 0.05


@dataclass(frozen=True)
class LidarSpec:
    """A 2D LiDAR's limits and noise. Lengths in metres, angles in radians, rates in hertz.

    Attributes:
        name: preset name or a label.
        min_range, max_range: measured ranges outside this interval are lost.
        fov: in-plane field of view, centred on the forward axis.
        beam_step: angle between beams in the plane.
        range_resolution: quantisation step of reported ranges (0: none).
        noise_sigma: standard deviation of gaussian range noise, absolute.
        noise_sigma_rel: standard deviation relative to the range (0.01 = 1 %).
        bias: constant offset added to every range (the thesis saw 2 cm on the LS02).
        dropout: probability that a return is lost.
        angular_jitter: standard deviation of the actual in-plane beam angle around the nominal.
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
                raise fail(f"LidarSpec.{name}", getattr(self, name), allowed)

        need(isinstance(self.name, str) and self.name != "", "name", "a non-empty string")
        for f in fields(self):
            if f.name != "name":
                v = getattr(self, f.name)
                ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
                need(ok, f.name, "a finite number")
                object.__setattr__(self, f.name, float(v))
        need(0.0 <= self.min_range <= 100.0, "min_range", "[0, 100] m")
        need(self.min_range < self.max_range <= 100.0, "max_range", "(min_range, 100] m")
        need(0.0 < self.fov <= 2 * math.pi, "fov", "(0, 2 pi] rad")
        need(0.0 < self.beam_step <= self.fov, "beam_step", "(0, fov] rad")
        need(self.fov / self.beam_step <= 100_000, "beam_step", "at most 100000 beams per plane")
        need(0.0 <= self.range_resolution <= 0.1, "range_resolution", "[0, 0.1] m")
        need(0.0 <= self.noise_sigma <= 1.0, "noise_sigma", "[0, 1] m")
        need(0.0 <= self.noise_sigma_rel <= 0.5, "noise_sigma_rel", "[0, 0.5]")
        need(abs(self.bias) <= 1.0, "bias", "[-1, 1] m")
        need(0.0 <= self.dropout < 1.0, "dropout", "[0, 1)")
        need(0.0 <= self.angular_jitter <= math.radians(10), "angular_jitter", "[0, 10 deg] rad")
        need(0.0 < self.max_incidence <= math.pi / 2, "max_incidence", "(0, pi/2] rad")
        need(0.0 < self.scan_rate <= 1000.0, "scan_rate", "(0, 1000] Hz")

    @property
    def n_beams(self) -> int:
        """Beams per plane; a full circle does not repeat its first beam."""
        n = int(round(self.fov / self.beam_step))
        return n if self.fov >= 2 * math.pi - 1e-9 else n + 1

    @property
    def beam_angles(self) -> NDArray[np.float64]:
        """(B,) in-plane beam angles, radians, symmetric about forward."""
        half = 0.5 * (self.n_beams - 1) * self.beam_step
        return -half + self.beam_step * np.arange(self.n_beams, dtype=np.float64)

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


#: Sensor presets. Sources: thesis table 4.2 (the simulated "ideal Lidar"), thesis table 3.1 with
#: the manufacturers' data it cites ([24] LeiShen LS02, [25] EAI YDLIDAR X4 data sheet), and the
#: thesis's own measurements (5.2.2). Figures no source gives are marked "assumed".
PRESETS: dict[str, LidarSpec] = {
    # thesis table 4.2 "ideal Lidar": detection range 0.1-200 cm, range resolution 0.1 cm,
    # field of view 180 deg, angle resolution 0.5-1 deg (0.5 deg used). Noiseless.
    # scan_rate: assumed (the Gazebo sensor's rate is not given).
    "ideal": LidarSpec(
        name="ideal",
        min_range=0.1,
        max_range=2.0,
        fov=math.pi,
        beam_step=math.radians(0.5),
        range_resolution=0.001,
        scan_rate=10.0,
    ),
    # LeiShen LS02 solid-state 2D LiDAR, thesis table 3.1 after [24]: detection range 0.1-4 m,
    # scanning angle 86 deg, angle resolution 1 deg, scan frequency 10 Hz; detection accuracy
    # "< 0.5 (for range < 2 m)". The table's unit column says mm, but 0.5 mm is not credible for
    # a sensor whose unit the thesis measured with a constant 2 cm error (5.2.2) and found
    # unusable in small pipes (5.1.1, 6); it is read here as 0.5 % of the distance (1 sigma).
    # bias 2 cm: thesis 5.2.2 ("a constant measurement error of 2 cm").
    # Assumed (no source): 2 mm absolute noise, 5 mm output resolution, 2 % dropouts, 0.2 deg
    # beam jitter, returns lost beyond 80 deg incidence.
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
    # EAI YDLIDAR X4, thesis table 3.1 after [25]: range 0.12 to > 10 m, angle resolution
    # 0.48-0.52 deg (0.5 used), scan frequency 6-12 Hz (7 Hz, the data sheet's typical value),
    # 360 deg restricted to the front 180 deg as in thesis 4.3. Detection accuracy "< 3 % of
    # distance" (table 3.1), modelled as 1 % of distance at 1 sigma. The X4 data sheet gives a
    # range resolution of < 0.5 mm below 2 m (and < 1 % of the distance beyond): 0.5 mm
    # quantisation. Assumed: 1 % dropouts, 0.1 deg beam jitter, returns lost beyond 85 deg.
    "ydlidar_x4": LidarSpec(
        name="ydlidar_x4",
        min_range=0.12,
        max_range=10.0,
        fov=math.pi,
        beam_step=math.radians(0.5),
        range_resolution=0.0005,
        noise_sigma=0.0,
        noise_sigma_rel=0.01,
        dropout=0.01,
        angular_jitter=math.radians(0.1),
        max_incidence=math.radians(85),
        scan_rate=7.0,
    ),
}


def get_preset(name: str) -> LidarSpec:
    """The preset called ``name``; raises ValueError listing the presets if unknown."""
    if not isinstance(name, str) or name not in PRESETS:
        raise fail("preset", name, ", ".join(sorted(PRESETS)), "unknown")
    return PRESETS[name]


class RotatingLidar:
    """A 2D LiDAR on a servo that turns its scan plane about the forward axis.

    Args:
        world: the world whose walls are scanned.
        spec: sensor model (a :class:`LidarSpec` or a preset name).
        servo_step: plane angle increment, radians (thesis: 2 deg).
        servo_range: total servo sweep, radians (thesis: 180 deg; planes at 0, step, ... < range).
        mode: ``"stop_and_scan"`` or ``"continuous"``.
        mount: nominal sensor pose in the body frame.
        misalignment: true sensor pose relative to the nominal one.
        servo_settle: stop-and-scan time to move and settle between planes, seconds.
        servo_jitter: standard deviation of the servo's position error, radians (one draw per
            plane; the plane is cast at the perturbed angle and reported at the nominal one).
        backend: ``"mujoco"`` (``mj_multiRay`` on the meshes) or ``"analytic"`` (exact).
        threads: MuJoCo backend only: split each batch over this many threads.
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
        servo_jitter: float = 0.0,
        backend: str = "mujoco",
        threads: int = 1,
    ) -> None:
        if not isinstance(world, PipeWorld):
            raise fail("world", world, "a PipeWorld", f"a {type(world).__name__}")
        if isinstance(spec, str):
            spec = get_preset(spec)
        if not isinstance(spec, LidarSpec):
            raise fail("spec", spec, "a LidarSpec or a preset name", f"a {type(spec).__name__}")
        _need_number(servo_step, "servo_step", 0.0, math.pi, "rad", low_open=True)
        _need_number(servo_range, "servo_range", servo_step, 2 * math.pi, "rad")
        check_choice("mode", mode, MODES)
        _need_number(servo_settle, "servo_settle", 0.0, 10.0, "s")
        _need_number(servo_jitter, "servo_jitter", 0.0, math.radians(10), "rad")
        check_choice("backend", backend, BACKENDS)
        check_int("threads", threads, low=1)
        self.world = world
        self.spec = spec
        self.servo_step = float(servo_step)
        self.servo_range = float(servo_range)
        self.mode = mode
        self.mount = _checked(mount, "mount") if mount is not None else Pose.identity()
        self.misalignment = (
            _checked(misalignment, "misalignment") if misalignment is not None else Pose.identity()
        )
        self.servo_settle = float(servo_settle)
        self.servo_jitter = float(servo_jitter)
        self.backend = backend
        n_planes = max(1, int(math.floor(self.servo_range / self.servo_step + 1e-9)))
        self.plane_angles = np.arange(n_planes) * self.servo_step
        self.beam_angles = spec.beam_angles
        self._local_dirs = beam_directions(self.plane_angles, self.beam_angles)  # (P, B, 3)
        self._cutoff = spec.max_range + abs(spec.bias) + _CUTOFF_MARGIN
        if backend == "mujoco":
            from pipe_env.raycast_mujoco import MujocoCaster

            self._caster: Any = MujocoCaster(world, threads=threads)
        else:
            from pipe_env.raycast_analytic import AnalyticBore

            self._caster = AnalyticBore.from_network(world.network)

    # ------------------------------------------------------------------ timing
    @property
    def n_planes(self) -> int:
        return int(len(self.plane_angles))

    @property
    def n_beams(self) -> int:
        return int(len(self.beam_angles))

    @property
    def cutoff(self) -> float:
        """Distance up to which rays are cast, metres (max range + |bias| + a margin)."""
        return self._cutoff

    @property
    def local_directions(self) -> NDArray[np.float64]:
        """(P, B, 3) nominal beam directions of a sweep in the sensor frame."""
        return self._local_dirs.copy()

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
    def close(self) -> None:
        """Release the ray caster's worker threads (the MuJoCo backend with ``threads > 1``);
        casting again after this runs on one thread."""
        close = getattr(self._caster, "close", None)
        if close is not None:
            close()

    def scan(
        self,
        body_pose: Pose | Callable[[float], Pose],
        rng: np.random.Generator,
        t0: float = 0.0,
    ) -> Scan:
        """A full servo sweep.

        Args:
            body_pose: the carrier's world pose, or (continuous mode) a function of time in
                seconds giving it; stop-and-scan with a function uses its value at ``t0``.
            rng: source of all measurement noise.
            t0: time of the first plane, seconds.
        """
        _need_rng(rng)
        _need_number(t0, "t0", -1e9, 1e9, "s")
        times = t0 + np.arange(self.n_planes) * self.plane_period
        if callable(body_pose) and not isinstance(body_pose, Pose):
            if self.mode == "continuous":
                bodies = [_checked(body_pose(float(t)), f"body_pose({float(t)})") for t in times]
            else:
                bodies = [_checked(body_pose(float(t0)), f"body_pose({float(t0)})")] * len(times)
        else:
            bodies = [_checked(body_pose, "body_pose")] * self.n_planes
        return self._cast(self._local_dirs, self.plane_angles, bodies, times, rng)

    def scan_plane(
        self, body_pose: Pose, plane_angle: float, rng: np.random.Generator, t0: float = 0.0
    ) -> Scan:
        """One plane at servo angle ``plane_angle`` (radians), for the 2D algorithm."""
        body = _checked(body_pose, "body_pose")
        _need_rng(rng)
        _need_number(plane_angle, "plane_angle", -2 * math.pi, 2 * math.pi, "rad")
        _need_number(t0, "t0", -1e9, 1e9, "s")
        angles = np.array([float(plane_angle)])
        dirs = beam_directions(angles, self.beam_angles)
        return self._cast(dirs, angles, [body], np.array([float(t0)]), rng)

    def _cast(
        self,
        local_dirs: NDArray,
        plane_angles: NDArray,
        bodies: list[Pose],
        times: NDArray,
        rng: np.random.Generator,
    ) -> Scan:
        spec = self.spec
        n_p, n_b = local_dirs.shape[:2]
        composed: dict[int, tuple[Pose, Pose]] = {}
        for body in bodies:  # stop-and-scan repeats one body pose: compose it once
            if id(body) not in composed:
                nom = body.compose(self.mount)
                composed[id(body)] = (nom, nom.compose(self.misalignment))
        nominal = [composed[id(b)][0] for b in bodies]
        true = [composed[id(b)][1] for b in bodies]
        # every random number is drawn up front, a fixed count per scan, so a seed fixes it
        beam_noise = rng.standard_normal((n_p, n_b)) if spec.angular_jitter > 0 else None
        servo_noise = rng.standard_normal(n_p) if self.servo_jitter > 0 else None
        noise = rng.standard_normal((n_p, n_b))
        drop = rng.random((n_p, n_b))
        dirs = local_dirs
        if beam_noise is not None or servo_noise is not None:
            a = np.asarray(plane_angles, dtype=float)
            if servo_noise is not None:
                a = a + self.servo_jitter * servo_noise
            b = self.beam_angles[None, :]
            if beam_noise is not None:
                b = b + spec.angular_jitter * beam_noise
            # the plane angle's sine and cosine once per plane (the same values per beam)
            sb = np.sin(b)
            dirs = np.empty((n_p, n_b, 3))
            dirs[..., 0] = np.cos(b)
            np.multiply(sb, np.cos(a)[:, None], out=dirs[..., 1])
            np.multiply(sb, np.sin(a)[:, None], out=dirs[..., 2])
        rot = np.array([t.rotation for t in true])
        pos = np.array([t.position for t in true])
        world_dirs = np.empty((n_p, n_b, 3))
        _rotate_into(rot, np.ascontiguousarray(dirs, dtype=float), world_dirs)
        want_normals = spec.max_incidence < math.pi / 2
        true_r, normals = self._raycast(pos, world_dirs, want_normals)
        ranges = np.empty((n_p, n_b))
        valid = np.empty((n_p, n_b), dtype=bool)
        _measure(
            np.ascontiguousarray(true_r, dtype=float),
            noise,
            drop,
            world_dirs,
            np.ascontiguousarray(normals, dtype=float) if normals is not None else world_dirs,
            normals is not None,
            spec.noise_sigma**2,
            spec.noise_sigma_rel,
            spec.bias,
            spec.range_resolution,
            spec.min_range,
            spec.max_range,
            spec.dropout,
            math.cos(spec.max_incidence),
            ranges,
            valid,
        )
        meta = {
            "mode": self.mode,
            "backend": self.backend,
            "servo_step": self.servo_step,
            "servo_range": self.servo_range,
            "servo_jitter": self.servo_jitter,
            "n_planes": int(n_p),
        }
        return Scan(
            ranges=ranges,
            valid=valid,
            beam_angles=self.beam_angles.copy(),
            plane_angles=np.asarray(plane_angles, dtype=float).copy(),
            timestamps=np.asarray(times, dtype=float).copy(),
            positions=pos,
            rotations=rot,
            nominal_positions=np.array([p.position for p in nominal]),
            nominal_rotations=np.array([p.rotation for p in nominal]),
            spec=spec.to_dict(),
            metadata=meta,
        )

    def _raycast(
        self, origins: NDArray, dirs: NDArray, normals: bool
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """(P, B) true distances (inf: no wall within the cutoff) and optionally normals."""
        if self.backend == "mujoco":
            return self._caster.cast(origins, dirs, self._cutoff, normals)
        n_p, n_b = dirs.shape[:2]
        hits = self._caster.cast_groups(origins, dirs, self._cutoff, normals)
        # a ray starting outside the bore reports 0: no measurement
        dist = hits.dist.reshape(n_p, n_b)
        dist[dist <= 0.0] = np.inf
        return dist, hits.normal.reshape(n_p, n_b, 3) if normals else None


@numba.njit(cache=True)
def _rotate_into(rot: NDArray, dirs: NDArray, out: NDArray) -> None:
    """``out`` (P, B, 3): the directions ``dirs`` (P, B, 3) rotated by the (P, 3, 3) per-plane
    rotations (compiled: one pass, no temporaries)."""
    for p in range(dirs.shape[0]):
        for b in range(dirs.shape[1]):
            x, y, z = dirs[p, b, 0], dirs[p, b, 1], dirs[p, b, 2]
            for i in range(3):
                out[p, b, i] = rot[p, i, 0] * x + rot[p, i, 1] * y + rot[p, i, 2] * z


@numba.njit(cache=True)
def _measure(
    true_r: NDArray,
    noise: NDArray,
    drop: NDArray,
    dirs: NDArray,
    normals: NDArray,
    use_normals: bool,
    sigma2: float,
    sigma_rel: float,
    bias: float,
    resolution: float,
    min_range: float,
    max_range: float,
    dropout: float,
    cos_max_incidence: float,
    ranges: NDArray,
    valid: NDArray,
) -> None:
    """The measurement model of the module docstring, beam by beam: from true distances
    ``true_r`` (P, B) (inf: no hit), gaussian ``noise`` and uniform ``drop`` draws, the beams'
    world directions and (if ``use_normals``) the walls' normals, write the reported ``ranges``
    (inf where lost) and ``valid``. Units: metres; ``sigma2`` is the absolute variance, m^2."""
    for p in range(true_r.shape[0]):
        for b in range(true_r.shape[1]):
            r = true_r[p, b]
            hit = math.isfinite(r)
            if not hit:
                r = 0.0
            rel = sigma_rel * r
            meas = r + bias + math.sqrt(sigma2 + rel * rel) * noise[p, b]
            if resolution > 0:
                meas = np.rint(meas / resolution) * resolution
            ok = hit and meas >= min_range and meas <= max_range and drop[p, b] >= dropout
            if ok and use_normals:
                cos_inc = (
                    normals[p, b, 0] * dirs[p, b, 0]
                    + normals[p, b, 1] * dirs[p, b, 1]
                    + normals[p, b, 2] * dirs[p, b, 2]
                )
                ok = cos_inc >= cos_max_incidence
            valid[p, b] = ok
            ranges[p, b] = meas if ok else math.inf


def _need_number(
    value: Any, name: str, lo: float, hi: float, unit: str, low_open: bool = False
) -> None:
    check_number(name, value, lo, hi, unit, open_low=low_open)


def _need_rng(rng: Any) -> None:
    if not isinstance(rng, np.random.Generator):
        raise fail("rng", rng, "a numpy.random.Generator", f"a {type(rng).__name__}")


def _checked(pose: Any, name: str) -> Pose:
    if not isinstance(pose, Pose):
        raise fail(name, pose, "a detector.geometry.Pose", f"a {type(pose).__name__}")
    return pose
