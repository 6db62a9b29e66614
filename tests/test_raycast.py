"""Tests of the ray-casting backends: the exact analytic bore and the MuJoCo sensing model."""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipe_env import layouts
from pipe_env.generator import NetworkConfig, generate_network
from pipe_env.meshes import circle_segments, polygon_radius
from pipe_env.network import PipeNetwork
from pipe_env.raycast_analytic import AnalyticBore, RayHits, solve_depressed_quartic
from pipe_env.raycast_kernels import axial_safe_bands, depressed_quartic_roots
from pipe_env.raycast_mujoco import EDGE_GUARD, MujocoCaster
from pipe_env.world import build_world

_DIRS27 = np.array(
    [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=float
)
_DIRS27[_DIRS27.any(axis=1)] /= np.linalg.norm(_DIRS27[_DIRS27.any(axis=1)], axis=1)[:, None]


def near_wall(bore: AnalyticBore, points: np.ndarray, tol: float) -> np.ndarray:
    """True where both the bore and the wall lie within ``tol`` (m) of a point (probed in 26
    directions): the point is on the exact wall within about ``tol``."""
    s = points[:, None, :] + tol * _DIRS27[None]
    inside = bore.contains(s.reshape(-1, 3)).reshape(len(points), len(_DIRS27))
    return inside.any(axis=1) & ~inside.all(axis=1)


def mesh_tolerance(network: PipeNetwork) -> float:
    """How far the ray meshes may lie from the exact walls (m).

    A faceted circle lies within +-dev of the true one radially. Where two faceted surfaces
    meet (junction and mitre creases) the crease moves by about dev / sin(half the crease
    angle), and a long bend's sweep chords add their own tolerance, hence 1.5 dev; plus the
    edge guard's shift over 3 m and float32 vertex rounding."""
    dev = 0.0
    for r in network.runs:
        radius = 0.5 * r.diameter
        dev = max(dev, polygon_radius(radius, circle_segments(radius)) - radius)
    return 1.5 * dev + EDGE_GUARD * 3.0 + 2e-6


def sample_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1)[:, None]


def interior_points(network: PipeNetwork, n: int, rng: np.random.Generator) -> np.ndarray:
    """Points inside the bore: on the centreline, moved off it by up to 40 % of the radius."""
    pieces = [p for p in network.centreline.pieces if p.length > 1e-6]
    lengths = np.array([p.length for p in pieces])
    out = []
    for k in rng.choice(len(pieces), size=n, p=lengths / lengths.sum()):
        piece = pieces[k]
        s = rng.uniform(0.0, piece.length)
        point, tangent = piece.point_tangent(s)
        side = np.cross(tangent, rng.normal(size=3))
        side /= np.linalg.norm(side)
        out.append(point + side * rng.uniform(0, 0.4) * 0.5 * piece.diameter_at(s))
    return np.array(out)


def check_backends_agree(network: PipeNetwork, origins: np.ndarray, rays_per_origin: int) -> None:
    """Both backends hit every ray (a closed network lets none escape), and each one's hits lie
    on the other's walls within the mesh tolerance."""
    world = build_world(network, contact_walls=False)
    bore = AnalyticBore.from_network(network)
    caster = MujocoCaster(world)
    tol = mesh_tolerance(network)
    rng = np.random.default_rng(1)
    assert bore.contains(origins).all()
    for origin in origins:
        dirs = sample_directions(rays_per_origin, rng)
        hits = bore.cast(origin, dirs, cutoff=50.0)
        assert np.isfinite(hits.dist).all() and (hits.dist > 0).all(), "analytic ray escaped"
        mj, _ = caster.cast(origin[None], dirs[None], 50.0)
        mj = mj[0]
        assert np.isfinite(mj).all(), "MuJoCo ray escaped"
        # MuJoCo hits lie on the exact wall: all within 3 tolerances (a ray can just catch a
        # faceted crease or rim), nearly all within one
        mj_pts = origin + mj[:, None] * dirs
        assert near_wall(bore, mj_pts, 3 * tol).all()
        assert near_wall(bore, mj_pts, tol + 1e-5).mean() > 0.998
        # analytic hits lie on the mesh: cast MuJoCo again from 2 mm before them; at incidences
        # below 70 deg it must stop within the facet tolerance / cos(incidence) of 2 mm
        cos_inc = np.einsum("ij,ij->i", hits.normal, dirs)
        assert (cos_inc > 0).all()
        ok = cos_inc > 0.35
        back, _ = caster.cast(
            (origin + (hits.dist[ok] - 0.002)[:, None] * dirs[ok])[:, None, :],
            dirs[ok][:, None, :],
            1.0,
        )
        on_mesh = np.abs(back[:, 0] - 0.002) <= (tol + 1e-5) / cos_inc[ok]
        assert on_mesh.mean() > 0.995  # the rest: just past a faceted rim or crease
        # and where both hit the same surface the ranges agree
        close = np.abs(mj - hits.dist) <= (tol + 1e-5) / np.maximum(cos_inc, 1e-3)
        assert close.mean() > 0.97


# ----------------------------------------------------------------------------- quartic solver
def test_quartic_solver_matches_numpy_roots() -> None:
    rng = np.random.default_rng(0)
    roots = rng.normal(size=(3000, 4)) * rng.choice([0.01, 1.0, 30.0], size=(3000, 1))
    roots -= roots.mean(axis=1, keepdims=True)  # depressed: the roots sum to zero
    coeffs = np.array([np.poly(r) for r in roots])
    got = np.sort(solve_depressed_quartic(coeffs[:, 2], coeffs[:, 3], coeffs[:, 4]), axis=1)
    scale = np.abs(roots).max(axis=1, keepdims=True)
    assert np.isfinite(got).all()
    assert (np.abs(got - np.sort(roots, axis=1)) / scale).max() < 1e-8
    # random coefficients: the number of real roots matches, residuals vanish
    p, q, s = rng.normal(size=(3, 2000))
    q[:500] = 0.0  # biquadratic: rays in a torus's mid-plane
    got = solve_depressed_quartic(p, q, s)
    want = np.array(
        [np.sum(np.abs(np.roots([1, 0, a, b, c]).imag) < 1e-9) for a, b, c in zip(p, q, s)]
    )
    assert (np.isfinite(got).sum(axis=1) == want).all()
    x = got
    residual = np.abs((x * x + p[:, None]) * x * x + q[:, None] * x + s[:, None])
    assert np.nanmax(residual) < 1e-10


def test_compiled_quartic_matches_the_vectorised_solver() -> None:
    """The kernels' scalar quartic gives the numpy solver's real roots (count and values)."""
    rng = np.random.default_rng(7)
    p, q, s = rng.normal(size=(3, 3000)) * rng.choice([0.01, 1.0, 30.0], size=(3, 3000))
    q[:400] = 0.0  # biquadratic
    want = np.sort(solve_depressed_quartic(p, q, s), axis=1)
    for i in range(len(p)):
        n, *roots = depressed_quartic_roots(p[i], q[i], s[i])
        got = np.array(roots)
        assert n == np.isfinite(want[i]).sum()
        np.testing.assert_allclose(got[:n], want[i, :n], rtol=0, atol=1e-12)
        assert np.isnan(got[n:]).all()


# ------------------------------------------------------------ compiled kernels versus numpy
#: The worlds the compiled backend is checked in against the numpy reference.
COMPARED_LAYOUTS = ("t_junction", "long_bend", "reducer", "cross_junction", "closure")


def assert_same_hits(a: RayHits, b: RayHits, label: str, at_rims: bool = False) -> None:
    """Same misses (inf) and outside starts (0), hits within 1e-9 m, and (nearly always) the
    same element and normal.

    ``at_rims``: the rays are aimed at the rims where two elements' walls meet; there both
    walls end within rounding of each other and either element is right."""
    assert (np.isfinite(a.dist) == np.isfinite(b.dist)).all(), f"{label}: misses differ"
    assert ((a.dist == 0) == (b.dist == 0)).all(), f"{label}: outside starts differ"
    hit = np.isfinite(a.dist)
    err = np.abs(a.dist[hit] - b.dist[hit])
    assert err.max(initial=0.0) <= 1e-9, f"{label}: hits differ by {err.max():.3g} m"
    assert ((a.element >= 0) == (b.element >= 0)).all(), f"{label}: hit or not differs"
    same = (a.element == b.element) & (np.abs(a.normal - b.normal).max(axis=1) <= 1e-7)
    if not at_rims:
        assert same.mean() > 0.999, f"{label}: surfaces differ on {np.sum(~same)} rays"


def seam_rays(
    network: PipeNetwork, rng: np.random.Generator, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays that meet the seams between elements: from interior points to points on the rims
    of the ports (where a run meets a fitting) and through the port planes' interiors, and
    rays grazing along a seam: in a port plane, or moved off it by 0.1 nm to 0.1 um.

    Returns origins (n, 3), directions (n, 3) and which rays lie exactly in a port plane."""
    ports = [p for g in network.geometry.values() for p in g.ports]
    origins, dirs, exact = [], [], []
    while len(origins) < n:
        port = ports[rng.integers(len(ports))]
        side = np.cross(port.axis, rng.normal(size=3))
        side /= np.linalg.norm(side)
        kind = rng.integers(3)
        if kind == 0:  # at the rim
            target = port.position + side * port.radius
        else:  # through the port plane's interior
            target = port.position + side * port.radius * rng.uniform(0.0, 0.95)
        shift = 0.0
        if kind == 2:  # in the port plane, starting inside on the seam: graze along it
            shift = float(rng.choice([0.0, -1e-10, 1e-10, -1e-7, 1e-7]))
            start = port.position - side * port.radius * rng.uniform(0.0, 0.9)
            start, target = start + shift * port.axis, target + shift * port.axis
        else:
            start = port.position + port.axis * rng.uniform(-1.2, 1.2) * port.radius
            start += np.cross(port.axis, rng.normal(size=3)) * 0.3 * port.radius
        d = target - start
        if np.linalg.norm(d) < 1e-6:
            continue
        origins.append(start)
        dirs.append(d / np.linalg.norm(d))
        exact.append(kind == 2 and shift == 0.0)
    return np.array(origins), np.array(dirs), np.array(exact)


def assert_same_seam_hits(bore: AnalyticBore, network: PipeNetwork, seed: int, n: int) -> None:
    """Rays at the seams hit where the numpy reference hits them.

    A ray exactly in a seam plane starts on both elements' boundary planes and runs along
    them: rounding alone decides whether its start is inside one, the other or neither
    element, and the two paths round differently (the reference works relative to the first
    ray's origin), so those rays are not compared; rays 0.1 nm off the plane are."""
    origins, dirs, exact = seam_rays(network, np.random.default_rng(seed), n)
    o, d = origins[~exact], dirs[~exact]
    assert_same_hits(bore.cast(o, d), bore.cast_numpy(o, d), "seams", at_rims=True)


@pytest.mark.parametrize("name", COMPARED_LAYOUTS)
def test_compiled_backend_matches_numpy_reference(name: str) -> None:
    """The compiled kernels give the numpy path's hits on many random rays: one origin and
    one origin per ray, with and without a cutoff, and rays grazing the seams."""
    net = layouts.make_layout(name)
    bore = AnalyticBore.from_network(net)
    rng = np.random.default_rng(11)
    for origin in interior_points(net, 6, rng):
        dirs = sample_directions(3000, rng)
        for cutoff in (np.inf, 0.35):
            assert_same_hits(
                bore.cast(origin, dirs, cutoff),
                bore.cast_numpy(origin, dirs, cutoff),
                f"{name} one origin, cutoff {cutoff}",
            )
    origins = interior_points(net, 4000, rng)
    dirs = sample_directions(4000, rng)
    assert_same_hits(
        bore.cast(origins, dirs), bore.cast_numpy(origins, dirs), f"{name} per-ray origins"
    )
    assert_same_seam_hits(bore, net, 13, 4000)
    # rays from outside the bore (inside walls, beyond the ends) report 0 on both
    outside = origins + rng.normal(size=origins.shape) * 0.2
    assert_same_hits(bore.cast(outside, dirs), bore.cast_numpy(outside, dirs), f"{name} outside")


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), planar=st.booleans())
def test_compiled_backend_matches_numpy_on_generated_networks(seed: int, planar: bool) -> None:
    net = generate_network(NetworkConfig(n_fittings=6, planar=planar), np.random.default_rng(seed))
    bore = AnalyticBore.from_network(net)
    rng = np.random.default_rng(seed)
    origins = interior_points(net, 1500, rng)
    dirs = sample_directions(1500, rng)
    assert_same_hits(bore.cast(origins, dirs), bore.cast_numpy(origins, dirs), "generated")
    assert_same_seam_hits(bore, net, seed, 1500)


@pytest.mark.parametrize("name", COMPARED_LAYOUTS)
def test_safe_bands_are_out_of_every_other_pieces_reach(name: str) -> None:
    """Wall points of a quadric within its safe band lie outside every other piece's
    bounding sphere (which is what lets a ray leaving there stop), and the straight runs
    have a band (so the shortcut is taken)."""
    bore = AnalyticBore.from_network(layouts.make_layout(name))
    table, kind = bore._table, bore._kind
    bands = axial_safe_bands(table, kind)
    rng = np.random.default_rng(14)
    runs = [k for k in range(len(table)) if bore.elements[bore._element[k]].startswith("run:")]
    assert all(bands[k, 0] < bands[k, 1] for k in runs)
    for k in np.flatnonzero(bands[:, 0] <= bands[:, 1]):
        p, u, r0, slope = table[k, 0:3], table[k, 3:6], table[k, 6], table[k, 7]
        s = rng.uniform(bands[k, 0], bands[k, 1], 2000)
        side = np.cross(u, rng.normal(size=(2000, 3)))
        side /= np.linalg.norm(side, axis=1)[:, None]
        wall = p + s[:, None] * u + (r0 + slope * s)[:, None] * side
        for j in range(len(table)):
            if j != k:
                gap = np.linalg.norm(wall - table[j, 16:19], axis=1) - table[j, 19]
                assert gap.min() > 0.0


def test_cast_groups_equals_cast_with_repeated_origins() -> None:
    """A sweep cast as groups (one origin per plane) gives the per-ray cast's bytes."""
    net = layouts.long_bend(diameter=0.08, distance=0.3)
    bore = AnalyticBore.from_network(net)
    rng = np.random.default_rng(12)
    origins = interior_points(net, 7, rng)
    dirs = np.stack([sample_directions(50, rng) for _ in origins])
    grouped = bore.cast_groups(origins, dirs, 1.5, normals=True)
    flat = bore.cast(np.repeat(origins, 50, axis=0), dirs.reshape(-1, 3), 1.5, normals=True)
    assert grouped.dist.tobytes() == flat.dist.tobytes()
    assert grouped.normal.tobytes() == flat.normal.tobytes()
    assert (grouped.element == flat.element).all()
    empty = bore.cast_groups(origins[:0], dirs[:0], 1.0)
    assert empty.dist.shape == (0,) and empty.normal.shape == (0, 3)


def test_cast_rejects_bad_shapes_and_cutoffs() -> None:
    bore = AnalyticBore.from_network(layouts.straight())
    dirs = sample_directions(4, np.random.default_rng(0))
    with pytest.raises(ValueError, match="cutoff"):
        bore.cast(np.zeros(3), dirs, cutoff=0.0)
    with pytest.raises(ValueError, match="origins"):
        bore.cast(np.zeros((3, 3)), dirs)
    with pytest.raises(ValueError, match="origins"):
        bore.cast_groups(np.zeros((2, 3)), dirs[None])
    with pytest.raises(ValueError, match="cutoff"):
        bore.cast_groups(np.zeros((1, 3)), dirs[None], cutoff=-1.0)


# ------------------------------------------------------------------------------ analytic bore
def test_straight_pipe_is_exact_with_outward_normals() -> None:
    net = layouts.straight(diameter=0.1, distance=3.0)
    bore = AnalyticBore.from_network(net)
    rng = np.random.default_rng(2)
    origin = np.array([0.3, 0.01, -0.02])
    dirs = sample_directions(5000, rng)
    hits = bore.cast(origin, dirs)
    pts = origin + hits.dist[:, None] * dirs
    entry_wall = -0.6 - 0.025  # the entry cap's inner face (layouts.BEHIND + its leg)
    side = (pts[:, 0] > entry_wall + 1e-9) & (pts[:, 0] < 3.0 - 1e-9)
    np.testing.assert_allclose(np.hypot(pts[side, 1], pts[side, 2]), 0.05, atol=1e-12)
    radial = pts[side] * [0, 1, 1]
    np.testing.assert_allclose(hits.normal[side], radial / 0.05, atol=1e-9)
    ends = ~side
    assert ends.any()
    np.testing.assert_allclose(np.abs(hits.normal[ends, 0]), 1.0)
    assert set(hits.element[ends]) == {
        bore.elements.index(f"fitting:{f}") for f in ("entry", "end")
    }
    # points on the centreline are inside, just outside the wall is not
    assert bore.contains(np.array([[0.5, 0, 0], [0.5, 0.0499, 0]])).all()
    assert not bore.contains(np.array([[0.5, 0.0501, 0], [3.001, 0, 0]])).any()


def test_cutoff_culls_without_changing_nearer_hits() -> None:
    net = layouts.t_junction(diameter=0.1, distance=0.4)
    bore = AnalyticBore.from_network(net)
    dirs = sample_directions(4000, np.random.default_rng(3))
    full = bore.cast(net.start_pose.position, dirs)
    cut = bore.cast(net.start_pose.position, dirs, cutoff=0.3)
    near = full.dist <= 0.3
    np.testing.assert_array_equal(cut.dist[near], full.dist[near])
    assert np.isinf(cut.dist[~near]).all() and (cut.element[~near] == -1).all()


def test_many_origins_equal_one_origin_at_a_time() -> None:
    net = layouts.long_bend(diameter=0.08, distance=0.3)
    bore = AnalyticBore.from_network(net)
    rng = np.random.default_rng(4)
    origins = interior_points(net, 5, rng)
    dirs = sample_directions(300, rng)
    together = bore.cast(np.repeat(origins, len(dirs), axis=0), np.tile(dirs, (5, 1)))
    for k, origin in enumerate(origins):
        alone = bore.cast(origin, dirs)
        sl = slice(k * len(dirs), (k + 1) * len(dirs))
        np.testing.assert_allclose(together.dist[sl], alone.dist, rtol=0, atol=1e-12)
        np.testing.assert_allclose(together.normal[sl], alone.normal, atol=1e-9)


def test_rays_from_outside_the_bore_report_zero() -> None:
    net = layouts.straight()
    bore = AnalyticBore.from_network(net)
    hits = bore.cast(np.array([0.5, 0.2, 0.0]), sample_directions(50, np.random.default_rng(0)))
    assert (hits.dist == 0.0).all()


# ------------------------------------------------------------------ analytic versus MuJoCo
@pytest.mark.parametrize("name", sorted(layouts.LAYOUTS))
def test_backends_agree_on_every_layout(name: str) -> None:
    net = layouts.make_layout(name)
    start = net.start_pose
    origins = np.array(
        [
            start.position,  # on the axis: the symmetric case where meshes leak without a guard
            start.translated(0.25).position + [0.0, 0.01, -0.006],
            start.translated(0.45).position + [0.0, -0.008, 0.004],
        ]
    )
    origins = origins[AnalyticBore.from_network(net).contains(origins)]
    check_backends_agree(net, origins, 1500)


@pytest.mark.parametrize("seed", [0, 1])
def test_backends_agree_on_generated_networks(seed: int) -> None:
    config = NetworkConfig(n_fittings=5, planar=False)
    net = generate_network(config, np.random.default_rng(seed))
    origins = interior_points(net, 4, np.random.default_rng(seed + 100))
    check_backends_agree(net, origins, 800)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2, 12))
def test_backends_agree_on_many_generated_networks(seed: int) -> None:
    config = NetworkConfig(n_fittings=10, planar=seed % 2 == 0, allow_loops=seed % 3 == 0)
    net = generate_network(config, np.random.default_rng(seed))
    origins = interior_points(net, 10, np.random.default_rng(seed + 100))
    check_backends_agree(net, origins, 2000)


# ---------------------------------------------------------------------- MuJoCo sensing model
def test_sensing_model_keeps_the_hits_of_the_world_model() -> None:
    """The sensing-only model (no contact walls, bore-facing faces only) returns the same hits
    as the full world model for rays from inside the bore, with fewer geoms and triangles; two
    threads return the same bytes as one."""
    net = layouts.t_junction(diameter=0.1, distance=0.4)
    world = build_world(net)
    full = MujocoCaster(world, inner_only=False, sensing_only=False)
    lean = MujocoCaster(world)
    twin = MujocoCaster(world, threads=2)
    assert lean.model.ngeom < world.model.ngeom and lean.model.nmeshface < world.triangle_count
    assert lean.model.ngeom == len(world.wall_geoms)
    rng = np.random.default_rng(5)
    origins = interior_points(net, 6, rng)
    dirs = np.stack([sample_directions(500, rng) for _ in origins])
    a, na = full.cast(origins, dirs, 5.0, normals=True)
    b, nb = lean.cast(origins, dirs, 5.0, normals=True)
    c, _ = twin.cast(origins, dirs, 5.0)
    # float32 vertices are re-centred per mesh, so hits move by nanometres; a ray that just
    # catches a dropped ring face at a crease may move by a fraction of a millimetre
    diff = np.abs(a - b)
    assert (diff <= 1e-6).mean() > 0.99 and diff.max() < 1e-3
    assert (np.abs(na - nb).max(axis=-1) <= 1e-3).mean() > 0.99
    assert c.tobytes() == b.tobytes()
    assert (np.einsum("pbi,pbi->pb", nb, dirs) > 0).all()  # normals point into the wall
    # one origin, split over two threads
    one = np.repeat(origins[:1], 1, axis=0)
    c1, _ = twin.cast(one, dirs[:1], 5.0)
    b1, _ = lean.cast(one, dirs[:1], 5.0)
    assert c1.tobytes() == b1.tobytes()


def test_mujoco_caster_rejects_bad_settings() -> None:
    world = build_world(layouts.straight(), contact_walls=False)
    with pytest.raises(ValueError, match="threads"):
        MujocoCaster(world, threads=0)
    with pytest.raises(ValueError, match="inner_only"):
        MujocoCaster(world, inner_only=True, sensing_only=False)


def test_casters_pickle_and_cast_the_same() -> None:
    """Subprocess vector envs pickle their sensors: both backends survive a round trip."""
    import pickle

    net = layouts.reducer()
    world = build_world(net, contact_walls=False)
    dirs = sample_directions(200, np.random.default_rng(6))
    origin = net.start_pose.position
    caster = MujocoCaster(world, threads=2)
    again = pickle.loads(pickle.dumps(caster))
    assert again.cast(origin[None], dirs[None], 5.0)[0].tobytes() == (
        caster.cast(origin[None], dirs[None], 5.0)[0].tobytes()
    )
    bore = AnalyticBore.from_network(net)
    bore2 = pickle.loads(pickle.dumps(bore))
    assert bore2.cast(origin, dirs).dist.tobytes() == bore.cast(origin, dirs).dist.tobytes()


@settings(max_examples=25, deadline=None)
@given(
    name=st.sampled_from(sorted(layouts.LAYOUTS)),
    diameter=st.floats(0.03, 0.2),
    seed=st.integers(0, 2**32 - 1),
)
def test_analytic_hits_are_where_rays_leave_the_bore(name: str, diameter: float, seed: int) -> None:
    """Just before each hit the ray is inside the bore and just after it is outside; for every
    layout, diameter and interior origin, and no ray escapes."""
    # a reducer narrows to 60 % (its default outlet could equal a drawn inlet: no reducer)
    params = (
        {"diameter_in": diameter, "diameter_out": max(0.02, 0.6 * diameter)}
        if name == "reducer"
        else {"diameter": diameter}
    )
    net = layouts.make_layout(name, **params)
    bore = AnalyticBore.from_network(net)
    rng = np.random.default_rng(seed)
    origins = interior_points(net, 3, rng)
    for origin in origins:
        dirs = sample_directions(400, rng)
        hits = bore.cast(origin, dirs)
        assert np.isfinite(hits.dist).all() and (hits.dist > 0).all()
        eps = 1e-7
        before = origin + (hits.dist - eps)[:, None] * dirs
        after = origin + (hits.dist + eps)[:, None] * dirs
        assert bore.contains(before).all()
        assert not bore.contains(after).any()
        np.testing.assert_allclose(np.linalg.norm(hits.normal, axis=1), 1.0, atol=1e-9)


# ------------------------------------------------------------------------------- benchmark
def test_bench_lidar_prints_embree_beside_the_backend_and_writes_its_section(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``bench_lidar.py --write-docs`` prints both worlds' rates with Embree's and the ratio,
    and writes the same table as the stamped 'lidar' section (here into a temporary file)."""
    pytest.importorskip("embreex")
    import benchmarks.report as report

    path = tmp_path / "benchmarks.md"
    monkeypatch.setattr(report, "write_section", functools.partial(report.write_section, path=path))
    monkeypatch.setattr(sys, "argv", ["bench_lidar.py", "--repeat", "1", "--write-docs"])
    root = Path(__file__).resolve().parent.parent
    spec = importlib.util.spec_from_file_location("bench_lidar", root / "benchmarks/bench_lidar.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main()
    out = capsys.readouterr().out
    for row in ("analytic backend (compiled kernels)", "Embree (embreex), 1 thread"):
        assert row in out
    assert out.count("analytic backend / Embree = ") == 2
    text = path.read_text()
    assert "<!-- begin lidar -->" in text
    assert "`python benchmarks/bench_lidar.py --repeat 1`" in text
    assert "| Embree (embreex), 1 thread, same meshes |" in text
