"""Tests of the rotating LiDAR simulator: sensor specs, geometry, noise, modes, errors, storage."""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest

from detector.geometry import Pose, rotation_about
from detector.scan import SCAN_ARRAYS, Scan
from pipe_env import layouts
from pipe_env.lidar import BACKENDS, PRESETS, LidarSpec, RotatingLidar, get_preset
from pipe_env.meshes import circle_segments, polygon_radius
from pipe_env.raycast_analytic import AnalyticBore
from pipe_env.world import build_world

D = 0.1  # pipe diameter of the default test worlds, m
R = 0.5 * D


@pytest.fixture(scope="module")
def straight_world():
    return build_world(layouts.straight(diameter=D, distance=3.0), contact_walls=False)


@pytest.fixture(scope="module")
def closure_world():
    return build_world(layouts.closure(diameter=D, distance=0.6), contact_walls=False)


@pytest.fixture(scope="module")
def pipe60_world():
    return build_world(layouts.straight(diameter=0.06, distance=3.0), contact_walls=False)


#: Slack for the MuJoCo backend's edge guard (2 micro-radians over 2 m) and float32 vertices.
GUARD = 5e-6


def facet_deviation(radius: float) -> float:
    """Largest radial deviation of the faceted ray mesh of a pipe of ``radius`` (m)."""
    n = circle_segments(radius)
    return polygon_radius(radius, n) - radius


_PROBES = np.array(
    [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=float
)


def near_wall(bore: AnalyticBore, points: np.ndarray, tol: float) -> np.ndarray:
    """True where a point has both bore and wall within ``tol`` (m): it lies on the exact wall
    within about ``tol`` (probed along the 26 axis, face and corner directions)."""
    probes = _PROBES.copy()
    norms = np.linalg.norm(probes, axis=1)
    probes[norms > 0] /= norms[norms > 0, None]
    s = points[:, None, :] + tol * probes[None]
    inside = bore.contains(s.reshape(-1, 3)).reshape(len(points), len(probes))
    return inside.any(axis=1) & ~inside.all(axis=1)


# ------------------------------------------------------------------------------ specs, presets
def test_presets_follow_the_thesis_tables() -> None:
    ideal, ls02, x4 = PRESETS["ideal"], PRESETS["ls02"], PRESETS["ydlidar_x4"]
    # table 4.2: 0.1-200 cm, 0.1 cm resolution, 180 deg, 0.5 deg
    assert (ideal.min_range, ideal.max_range, ideal.range_resolution) == (0.1, 2.0, 0.001)
    assert ideal.fov == pytest.approx(math.pi) and ideal.n_beams == 361
    assert ideal.is_noiseless
    # table 3.1: LS02 0.1-4 m, 86 deg, 1 deg, 10 Hz; thesis 5.2.2: 2 cm constant error
    assert (ls02.min_range, ls02.max_range, ls02.scan_rate, ls02.bias) == (0.1, 4.0, 10.0, 0.02)
    assert math.degrees(ls02.fov) == pytest.approx(86) and ls02.n_beams == 87
    # table 3.1: X4 0.12-10 m, 0.5 deg, 6-12 Hz, front 180 deg (thesis 4.3)
    assert (x4.min_range, x4.max_range) == (0.12, 10.0) and 6 <= x4.scan_rate <= 12
    assert math.degrees(x4.beam_step) == pytest.approx(0.5) and x4.n_beams == 361
    assert get_preset("ls02") is ls02


def test_beam_angles_are_symmetric_and_a_full_circle_does_not_repeat() -> None:
    spec = LidarSpec(fov=math.radians(90), beam_step=math.radians(1))
    assert spec.n_beams == 91
    assert spec.beam_angles[0] == pytest.approx(-spec.beam_angles[-1])
    assert spec.beam_angles[45] == pytest.approx(0.0, abs=1e-15)
    full = LidarSpec(fov=2 * math.pi, beam_step=math.radians(1))
    assert full.n_beams == 360
    assert full.beam_angles[-1] - full.beam_angles[0] == pytest.approx(math.radians(359))


BAD_SPEC_VALUES = {
    "name": ["", 3],
    "min_range": [-0.1, 101.0, math.nan],
    "max_range": [0.05, 101.0, math.inf],
    "fov": [0.0, 7.0, -1.0],
    "beam_step": [0.0, 4.0],
    "range_resolution": [-0.001, 0.2],
    "noise_sigma": [-0.01, 2.0],
    "noise_sigma_rel": [-0.1, 0.6],
    "bias": [1.5, -1.5, math.nan],
    "dropout": [-0.1, 1.0],
    "angular_jitter": [-0.01, 1.0],
    "max_incidence": [0.0, 2.0],
    "scan_rate": [0.0, -5.0, 2000.0],
}


@pytest.mark.parametrize(
    "field,value", [(f, v) for f, values in BAD_SPEC_VALUES.items() for v in values]
)
def test_bad_spec_field_raises_naming_it(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"LidarSpec\.{field} ="):
        LidarSpec(**{field: value})


def test_every_spec_field_is_validated() -> None:
    assert {f.name for f in fields(LidarSpec)} == set(BAD_SPEC_VALUES)
    with pytest.raises(ValueError, match="LidarSpec.fov"):
        LidarSpec(fov=True)  # a bool is not a number here
    with pytest.raises(ValueError, match="LidarSpec.max_range"):
        PRESETS["ideal"].with_(max_range="2")


def test_unknown_preset_raises(straight_world) -> None:
    with pytest.raises(ValueError, match="preset = 'hokuyo': unknown; allowed: ideal"):
        get_preset("hokuyo")
    with pytest.raises(ValueError, match="preset = .*: unknown; allowed: ideal"):
        RotatingLidar(straight_world, "hokuyo")


@pytest.mark.parametrize(
    "kwargs,name",
    [
        ({"servo_step": 0.0}, "servo_step"),
        ({"servo_step": -0.1}, "servo_step"),
        ({"servo_step": math.nan}, "servo_step"),
        ({"servo_step": 4.0}, "servo_step"),
        ({"servo_range": 0.01}, "servo_range"),
        ({"servo_range": 7.0}, "servo_range"),
        ({"mode": "sweep"}, "mode"),
        ({"servo_settle": -0.1}, "servo_settle"),
        ({"servo_jitter": math.inf}, "servo_jitter"),
        ({"backend": "embree"}, "backend"),
        ({"threads": 0}, "threads"),
        ({"mount": np.eye(4)}, "mount"),
        ({"misalignment": "tilted"}, "misalignment"),
        ({"spec": 42}, "spec"),
    ],
)
def test_bad_lidar_settings_raise_naming_the_field(straight_world, kwargs, name) -> None:
    with pytest.raises(ValueError, match=name):
        RotatingLidar(straight_world, **kwargs)


def test_bad_poses_and_rng_raise_clear_errors(straight_world) -> None:
    lidar = RotatingLidar(straight_world, "ideal", servo_step=math.radians(30))
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="Pose.position must be finite"):
        Pose(np.array([0.0, math.nan, 0.0]), np.eye(3))
    wrong = r"body_pose = .*: a \w+; allowed: a detector.geometry.Pose"
    with pytest.raises(ValueError, match=wrong):
        lidar.scan(np.zeros(3), rng)
    with pytest.raises(ValueError, match=wrong):
        lidar.scan_plane((0, 0, 0), 0.0, rng)
    with pytest.raises(ValueError, match="plane_angle"):
        lidar.scan_plane(Pose.identity(), math.nan, rng)
    with pytest.raises(ValueError, match="rng = 0: a int; allowed: a numpy.random.Generator"):
        lidar.scan(Pose.identity(), 0)
    with pytest.raises(ValueError, match="t0"):
        lidar.scan(Pose.identity(), rng, t0=math.nan)
    moving = RotatingLidar(straight_world, "ideal", servo_step=math.radians(30), mode="continuous")
    with pytest.raises(
        ValueError, match=r"body_pose\(0.0\) = None: a NoneType; allowed: a detector.geometry.Pose"
    ):
        moving.scan(lambda t: None, rng)


# ------------------------------------------------------------------------- geometry, backends
@pytest.mark.parametrize("backend", BACKENDS)
def test_ideal_ranges_match_the_analytic_cylinder(straight_world, backend: str) -> None:
    """Every return of a noiseless sweep lies on the pipe wall.

    Points are compared radially (distance from the pipe axis): along a ray a radial error
    grows as 1/sin(beam angle) at grazing incidence, but radially the measured point is off by
    at most half the range resolution (the quantisation acts along the ray, of which only the
    radial component counts) plus the faceting of the mesh (MuJoCo backend: the polygon's
    facets lie within +-facet_deviation of the true circle; analytic backend: exact).
    """
    spec = PRESETS["ideal"]
    lidar = RotatingLidar(straight_world, spec, backend=backend)
    offset = np.array([0.0, 0.004, -0.003])  # off-axis: no symmetric coincidences
    for position in (np.zeros(3), offset):
        scan = lidar.scan(Pose(position, np.eye(3)), np.random.default_rng(0))
        assert scan.ranges.shape == (90, 361)
        pts = scan.points("world")
        side = pts[:, 0] < 2.9  # the end wall at 3 m is beyond the 2 m range anyway
        assert side.all()
        radial = np.hypot(pts[:, 1], pts[:, 2])
        facets = facet_deviation(R) if backend == "mujoco" else 0.0
        assert np.abs(radial - R).max() <= 0.5 * spec.range_resolution + facets + GUARD
        # every beam whose wall point lies within [min, max] range returns (no leaks, no holes)
        d = scan.directions()
        lateral = np.hypot(d[..., 1], d[..., 2])
        with np.errstate(divide="ignore"):
            expected = np.where(lateral > 0, R / lateral, np.inf)  # on-axis sensor
        if not position.any():
            inside = (expected > spec.min_range + 0.002) & (expected < spec.max_range - 0.002)
            assert scan.valid[inside].all()
            assert not scan.valid[expected < spec.min_range - 0.002].any()
            along = 0.5 * spec.range_resolution + (facets + GUARD) / lateral[inside]
            assert (np.abs(scan.ranges[inside] - expected[inside]) <= along).all()


def test_backends_agree_on_a_sweep_near_a_junction() -> None:
    net = layouts.t_junction(diameter=D, distance=0.3)
    world = build_world(net, contact_walls=False)
    pose = net.start_pose.translated(0.1)
    scans = [
        RotatingLidar(world, "ideal", backend=b).scan(pose, np.random.default_rng(0))
        for b in BACKENDS
    ]
    mj, an = scans
    assert (mj.valid == an.valid).mean() > 0.998
    # ranges differ at grazing incidence (facets) and at the rims of the branch hole, but every
    # MuJoCo point lies on the exact wall within the facet tolerance plus the quantisation
    bore = AnalyticBore.from_network(net)
    pts = mj.points("world")
    assert near_wall(bore, pts, facet_deviation(R) + 0.0005 + GUARD).all()
    both = mj.valid & an.valid
    assert np.median(np.abs(mj.ranges[both] - an.ranges[both])) <= 0.0005


# ------------------------------------------------------------------------------ thesis 5.1.1
def test_ls02_in_a_60mm_pipe_sees_only_a_few_points_per_side(pipe60_world) -> None:
    """Thesis 5.1.1: centred in a straight 6 cm pipe the LS02 gets about 12 points on each side
    of the wall per plane; its 10 cm minimum range removes the rest (the near wall)."""
    spec = PRESETS["ls02"]
    lidar = RotatingLidar(pipe60_world, spec, backend="analytic")
    scan = lidar.scan(Pose.identity(), np.random.default_rng(7))
    beta = scan.beam_angles
    left = (scan.valid & (beta > 0.01)).sum(axis=1)
    right = (scan.valid & (beta < -0.01)).sum(axis=1)
    assert 8 <= left.mean() <= 16 and 8 <= right.mean() <= 16
    assert left.max() <= 20 and right.max() <= 20
    assert scan.valid.sum(axis=1).max() <= 0.5 * spec.n_beams
    assert (scan.ranges[scan.valid] >= spec.min_range).all()
    # the near wall (true distance < 10 cm - bias, beams beyond ~25 deg) returns nothing
    near_beams = np.abs(beta) > math.asin(0.03 / (spec.min_range - spec.bias - 0.01))
    assert near_beams.sum() > 30
    assert not scan.valid[:, near_beams].any()
    pts = scan.points("sensor")
    assert (pts[:, 0] > 0.07).all()


def test_ls02_sees_no_outliers_of_a_sharp_bend_in_a_60mm_pipe() -> None:
    """Thesis 5.1.1: a sharp bend cannot be detected in a 6 cm pipe, as there are little to no
    outlying points (points beyond the pipe radius); in the 20 cm pipe of thesis 5.2.2 the
    same sensor sees the bend clearly."""

    def outliers_per_plane(diameter: float, distance: float) -> float:
        net = layouts.mitre_bend(diameter=diameter, angle=math.pi / 2, distance=distance)
        world = build_world(net, contact_walls=False)
        lidar = RotatingLidar(world, "ls02", backend="analytic")
        scan = lidar.scan(net.start_pose, np.random.default_rng(3))
        # the detector knows the constant bias (thesis 5.2.2) and removes it
        r = np.where(scan.valid, scan.ranges - scan.spec["bias"], np.nan)
        pts = (scan.directions() * r[..., None])[scan.valid] + net.start_pose.position
        radius = np.hypot(pts[:, 1], pts[:, 2])
        return float((radius > 0.5 * diameter + 0.005).sum() / scan.n_planes)

    assert outliers_per_plane(0.06, 0.2) < 1.5
    assert outliers_per_plane(0.2, 0.2) > 10.0


# ----------------------------------------------------------------------------------- noise
def _noise_setup(straight_world, spec: LidarSpec):
    lidar = RotatingLidar(straight_world, spec, backend="analytic")
    truth = RotatingLidar(
        straight_world,
        spec.with_(
            noise_sigma=0,
            noise_sigma_rel=0,
            bias=0,
            dropout=0,
            angular_jitter=0,
            range_resolution=0,
            min_range=0.0,
            max_range=10.0,
        ),
        backend="analytic",
    )
    pose = Pose(np.array([0.0, 0.003, 0.002]), np.eye(3))
    true = truth.scan(pose, np.random.default_rng(0)).ranges
    return lidar, pose, true


def test_range_noise_bias_and_sigmas_match_the_spec(straight_world) -> None:
    spec = LidarSpec(
        min_range=0.05,
        max_range=2.0,
        range_resolution=0.0,
        noise_sigma=0.003,
        noise_sigma_rel=0.01,
        bias=0.02,
    )
    lidar, pose, true = _noise_setup(straight_world, spec)
    err, dist = [], []
    for seed in range(4):
        scan = lidar.scan(pose, np.random.default_rng(seed))
        ok = scan.valid & (true > 0.15) & (true < 1.5)
        err.append(scan.ranges[ok] - true[ok])
        dist.append(true[ok])
    e, r = np.concatenate(err), np.concatenate(dist)
    assert len(e) > 20_000
    sigma = np.sqrt(spec.noise_sigma**2 + (spec.noise_sigma_rel * r) ** 2)
    z = (e - spec.bias) / sigma
    assert abs(z.mean()) < 0.03  # mean error = bias
    assert abs(z.std() - 1.0) < 0.02
    # both parts of sigma: the variance grows with r^2 as sigma_abs^2 + (sigma_rel r)^2
    a = np.column_stack([np.ones_like(r), r**2])
    coef, *_ = np.linalg.lstsq(a, (e - spec.bias) ** 2, rcond=None)
    assert math.sqrt(max(coef[0], 0)) == pytest.approx(spec.noise_sigma, rel=0.15)
    assert math.sqrt(coef[1]) == pytest.approx(spec.noise_sigma_rel, rel=0.05)


def test_quantisation_and_min_max_range(straight_world) -> None:
    spec = LidarSpec(min_range=0.1, max_range=0.6, range_resolution=0.005, noise_sigma=0.002)
    lidar, pose, true = _noise_setup(straight_world, spec)
    scan = lidar.scan(pose, np.random.default_rng(1))
    r = scan.ranges[scan.valid]
    steps = r / spec.range_resolution
    assert np.abs(steps - np.round(steps)).max() < 1e-9
    assert r.min() >= spec.min_range and r.max() <= spec.max_range
    clean = RotatingLidar(straight_world, spec.with_(noise_sigma=0.0), backend="analytic")
    q = clean.scan(pose, np.random.default_rng(1))
    both = q.valid
    assert np.abs(q.ranges[both] - true[both]).max() <= 0.5 * spec.range_resolution + 1e-12
    # no return is inf with valid False, never a fake distance
    assert np.isinf(scan.ranges[~scan.valid]).all()
    assert (~scan.valid[true > 0.7]).all()


def test_dropout_rate_matches_the_spec(straight_world) -> None:
    spec = LidarSpec(dropout=0.2, range_resolution=0.0)
    lidar, pose, true = _noise_setup(straight_world, spec)
    candidates = (true > 0.12) & (true < 1.9)
    lost = []
    for seed in range(3):
        scan = lidar.scan(pose, np.random.default_rng(seed))
        lost.append(~scan.valid[candidates])
    rate = np.concatenate(lost).mean()
    n = candidates.sum() * 3
    assert abs(rate - 0.2) < 4 * math.sqrt(0.2 * 0.8 / n)


def test_angular_jitter_statistics(straight_world) -> None:
    """On the pipe axis a beam at in-plane angle b meets the wall at R / sin(b), so the measured
    range reveals the actual beam angle; its spread is the angular jitter."""
    sigma = math.radians(0.5)
    spec = LidarSpec(range_resolution=0.0, angular_jitter=sigma, min_range=0.01)
    lidar = RotatingLidar(straight_world, spec, backend="analytic")
    beta = spec.beam_angles
    sel = (np.abs(beta) > math.radians(20)) & (np.abs(beta) < math.radians(70))
    dev = []
    for seed in range(3):
        scan = lidar.scan(Pose.identity(), np.random.default_rng(seed))
        actual = np.arcsin(np.clip(R / scan.ranges[:, sel], -1, 1))
        dev.append(((actual - np.abs(beta[sel])) * np.sign(beta[sel])).ravel())
    d = np.concatenate(dev)
    assert abs(d.mean()) < 0.05 * sigma
    assert d.std() == pytest.approx(sigma, rel=0.05)


def test_servo_jitter_turns_whole_planes(straight_world) -> None:
    """The servo error is one draw per plane: each plane equals a noiseless plane cast at the
    perturbed angle (the draw order is: servo error, then range noise, then dropouts)."""
    jitter = math.radians(3)
    spec = LidarSpec(range_resolution=0.0)
    pose = Pose(np.array([0.0, 0.02, 0.0]), np.eye(3))  # off-axis: angle changes the ranges
    lidar = RotatingLidar(
        straight_world, spec, servo_step=math.radians(20), servo_jitter=jitter, backend="analytic"
    )
    scan = lidar.scan(pose, np.random.default_rng(5))
    errors = jitter * np.random.default_rng(5).standard_normal(lidar.n_planes)
    plain = RotatingLidar(straight_world, spec, backend="analytic")
    for k, a in enumerate(lidar.plane_angles):
        ref = plain.scan_plane(pose, float(a + errors[k]), np.random.default_rng(0))
        np.testing.assert_allclose(scan.ranges[k], ref.ranges[0], rtol=0, atol=1e-12)
    assert scan.plane_angles == pytest.approx(lidar.plane_angles)  # reported nominal


@pytest.mark.parametrize("backend", BACKENDS)
def test_same_seed_same_bytes_different_seed_differs(straight_world, backend: str) -> None:
    lidar = RotatingLidar(straight_world, "ydlidar_x4", servo_step=math.radians(6), backend=backend)
    pose = Pose(np.array([0.2, 0.001, 0.0]), np.eye(3))
    a = lidar.scan(pose, np.random.default_rng(11))
    b = lidar.scan(pose, np.random.default_rng(11))
    c = lidar.scan(pose, np.random.default_rng(12))
    assert a.ranges.tobytes() == b.ranges.tobytes() and a.valid.tobytes() == b.valid.tobytes()
    assert a.ranges.tobytes() != c.ranges.tobytes()
    ideal = RotatingLidar(straight_world, "ideal", servo_step=math.radians(6), backend=backend)
    assert (
        ideal.scan(pose, np.random.default_rng(1)).ranges.tobytes()
        == ideal.scan(pose, np.random.default_rng(2)).ranges.tobytes()
    )


# ----------------------------------------------------------------------------- misalignment
@pytest.mark.parametrize("backend", BACKENDS)
def test_misalignment_moves_points_exactly_as_the_transform_predicts(
    straight_world, backend: str
) -> None:
    offset = np.array([0.01, 0.006, -0.004])
    tilt = rotation_about([0.0, 0.0, 1.0], math.radians(3)) @ rotation_about(
        [0.0, 1.0, 0.0], math.radians(-2)
    )
    misalignment = Pose(offset, tilt)
    mount = Pose(np.array([0.05, 0.0, 0.0]), np.eye(3))
    body = Pose(np.array([0.1, 0.0, 0.0]), np.eye(3))
    spec = PRESETS["ideal"].with_(range_resolution=0.0)
    step = math.radians(10)
    tilted = RotatingLidar(
        straight_world,
        spec,
        servo_step=step,
        mount=mount,
        misalignment=misalignment,
        backend=backend,
    )
    scan = tilted.scan(body, np.random.default_rng(0))
    truth = body.compose(mount).compose(misalignment)
    nominal = body.compose(mount)
    # rays leave from the true pose: identical to a perfectly mounted sensor placed there
    direct = RotatingLidar(straight_world, spec, servo_step=step, backend=backend).scan(
        truth, np.random.default_rng(0)
    )
    assert scan.ranges.tobytes() == direct.ranges.tobytes()
    np.testing.assert_allclose(scan.positions, np.tile(truth.position, (scan.n_planes, 1)))
    np.testing.assert_allclose(scan.nominal_positions[0], nominal.position)
    # true world points lie on the wall
    world = scan.points("world")
    tol = facet_deviation(R) + GUARD if backend == "mujoco" else 1e-9
    assert np.abs(np.hypot(world[:, 1], world[:, 2]) - R).max() <= tol
    # the believed points are the true ones moved by nominal * misalignment^-1 * nominal^-1
    believed = nominal.transform_points(scan.points("sensor"))
    predicted = nominal.compose(misalignment.inverse()).transform_points(
        nominal.inverse_transform_points(world)
    )
    np.testing.assert_allclose(believed, predicted, atol=1e-12)
    # and they are off the wall by about the misalignment (the robot would see a bent pipe)
    assert np.abs(np.hypot(believed[:, 1], believed[:, 2]) - R).max() > 0.004
    # sensor-frame points: the scan's own frame is the true sensor frame
    np.testing.assert_allclose(
        scan.points("sensor"), truth.inverse_transform_points(world), atol=1e-12
    )


# ---------------------------------------------------------------------------- continuous mode
def test_continuous_mode_follows_the_trajectory_and_distorts_predictably(closure_world) -> None:
    """Driving towards an end wall at 2 cm/s, each plane is cast from the pose at its time: the
    forward beam shortens by v * t, world points stay on the true wall, and the cloud differs
    from a stop-and-scan sweep exactly by the motion."""
    v = 0.02
    start = -0.6  # the closure layout puts the end wall at x = 0

    def trajectory(t: float) -> Pose:
        return Pose(np.array([start + v * t, 0.0, 0.0]), np.eye(3))

    spec = PRESETS["ideal"].with_(range_resolution=0.0)
    step = math.radians(10)
    moving = RotatingLidar(
        closure_world, spec, servo_step=step, mode="continuous", backend="analytic"
    )
    scan = moving.scan(trajectory, np.random.default_rng(0), t0=1.0)
    times = scan.timestamps
    assert np.all(np.diff(times) > 0)
    np.testing.assert_allclose(np.diff(times), 1.0 / spec.scan_rate)
    assert times[0] == 1.0
    np.testing.assert_allclose(scan.positions[:, 0], start + v * times)
    forward = scan.ranges[:, spec.n_beams // 2]
    np.testing.assert_allclose(forward, -(start + v * times), atol=1e-9)
    # end-wall points in the world are all on the plane x = 0
    pts = scan.points("world", valid_only=False)
    end = np.abs(pts[..., 0]) < 1e-6
    assert end.sum() > scan.n_planes
    # versus stop-and-scan from the first pose: sensor-frame points of the end wall shift by the
    # travelled distance along x; side-wall points in a straight pipe do not change
    still = RotatingLidar(closure_world, spec, servo_step=step, backend="analytic").scan(
        trajectory(1.0), np.random.default_rng(0)
    )
    p_move = scan.points("sensor", valid_only=False)
    p_still = still.points("sensor", valid_only=False)
    moved = v * (times - times[0])
    on_wall_both = end & (np.abs(still.points("world", valid_only=False)[..., 0]) < 1e-6)
    for k in range(1, scan.n_planes):
        sel = on_wall_both[k]
        if sel.any():
            np.testing.assert_allclose(p_still[k, sel, 0] - p_move[k, sel, 0], moved[k], atol=1e-9)
    side = (np.abs(pts[..., 0]) > 0.2) & np.isfinite(p_still[..., 0])
    np.testing.assert_allclose(np.hypot(p_move[side][:, 1], p_move[side][:, 2]), R, atol=1e-9)
    # motion compensation with the believed poses: all planes in the last plane's frame
    comp = scan.points("nominal")
    last = trajectory(times[-1])
    np.testing.assert_allclose(comp, last.inverse_transform_points(scan.points("world")), atol=1e-9)


def test_stop_and_scan_with_a_trajectory_uses_the_pose_at_t0(closure_world) -> None:
    lidar = RotatingLidar(closure_world, "ideal", servo_step=math.radians(30))

    def trajectory(t: float) -> Pose:
        return Pose(np.array([-0.6 + 0.05 * t, 0.0, 0.0]), np.eye(3))

    scan = lidar.scan(trajectory, np.random.default_rng(0), t0=2.0)
    np.testing.assert_allclose(scan.positions[:, 0], -0.5)
    assert lidar.sweep_duration == pytest.approx(6 * (0.1 + 0.02))
    np.testing.assert_allclose(np.diff(scan.timestamps), 0.12)


def test_scan_plane_is_one_plane_of_the_sweep(straight_world) -> None:
    lidar = RotatingLidar(straight_world, "ideal", backend="analytic")
    pose = Pose(np.array([0.1, 0.01, 0.0]), np.eye(3))
    sweep = lidar.scan(pose, np.random.default_rng(0))
    plane = lidar.scan_plane(pose, float(lidar.plane_angles[45]), np.random.default_rng(0))
    assert plane.ranges.shape == (1, 361)
    np.testing.assert_array_equal(plane.ranges[0], sweep.ranges[45])
    np.testing.assert_array_equal(sweep.plane(45).ranges, plane.ranges)


# ------------------------------------------------------------------------------------ storage
def test_scan_npz_round_trip(tmp_path, closure_world) -> None:
    lidar = RotatingLidar(
        closure_world,
        "ls02",
        servo_step=math.radians(12),
        mode="continuous",
        misalignment=Pose(np.array([0.0, 0.002, 0.0]), rotation_about([1, 0, 0], 0.01)),
    )
    scan = lidar.scan(
        lambda t: Pose(np.array([-0.6 + 0.01 * t, 0.0, 0.0]), np.eye(3)), np.random.default_rng(4)
    )
    path = tmp_path / "scan.npz"
    scan.save(path)
    back = Scan.load(path)
    for name in SCAN_ARRAYS:
        assert getattr(back, name).tobytes() == getattr(scan, name).tobytes(), name
    assert back.spec == scan.spec and back.metadata == scan.metadata
    for frame in ("sensor", "world", "nominal"):
        np.testing.assert_array_equal(back.points(frame), scan.points(frame))
        np.testing.assert_array_equal(
            back.points(frame, valid_only=False), scan.points(frame, valid_only=False)
        )
    assert LidarSpec(**back.spec) == lidar.spec
