"""The procedural generator: every seed validates and compiles; same seed, same network."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipe_env.generator import NetworkConfig, NetworkGenerationError, generate_network
from pipe_env.routing import route
from pipe_env.world import build_world

configs = st.builds(
    NetworkConfig,
    n_fittings=st.integers(1, 14),
    planar=st.booleans(),
    allow_loops=st.booleans(),
    branch_same_diameter=st.floats(0.0, 1.0),
)


@settings(max_examples=300)
@given(seed=st.integers(0, 2**32 - 1), config=configs)
def test_generated_networks_validate_and_reach_their_goal(seed: int, config: NetworkConfig) -> None:
    net = generate_network(config, np.random.default_rng(seed))
    net.validate()
    kinds = [f.kind for f in net.fittings]
    assert sum(k != "closure" for k in kinds) >= 1
    assert len(net.goals) == config.n_goals
    assert net.start_pose is not None
    for goal in net.goals:
        assert route(net, net.start_pose, goal) is not None
    d = net.to_dict()
    assert type(net).from_dict(d).to_dict() == d


@settings(max_examples=25)
@given(seed=st.integers(0, 2**32 - 1), config=configs)
def test_generated_networks_compile(seed: int, config: NetworkConfig) -> None:
    net = generate_network(config, np.random.default_rng(seed))
    world = build_world(net)
    assert world.model.ngeom > len(net.fittings)
    assert world.triangle_count > 0


@pytest.mark.slow
@settings(max_examples=300)
@given(seed=st.integers(0, 2**32 - 1), config=configs)
def test_hundreds_of_generated_networks_compile(seed: int, config: NetworkConfig) -> None:
    build_world(generate_network(config, np.random.default_rng(seed)))


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=20)
def test_same_seed_same_network(seed: int) -> None:
    cfg = NetworkConfig(n_fittings=10, planar=False, allow_loops=True)
    a = generate_network(cfg, np.random.default_rng(seed)).to_dict()
    b = generate_network(cfg, np.random.default_rng(seed)).to_dict()
    assert a == b


def test_different_seeds_differ() -> None:
    cfg = NetworkConfig()
    nets = {str(generate_network(cfg, np.random.default_rng(s)).to_dict()) for s in range(5)}
    assert len(nets) == 5


def test_loops_are_generated_when_allowed() -> None:
    cfg = NetworkConfig(
        n_fittings=12, allow_loops=True, loop_probability=1.0, kind_weights={"tee": 1.0}
    )
    net = generate_network(cfg, np.random.default_rng(3))
    # a tree has runs = fittings - 1; every loop adds one run
    assert len(net.runs) > len(net.fittings) - 1


def test_max_extent_bounds_the_network() -> None:
    net = generate_network(NetworkConfig(n_fittings=6, max_extent=2.5), np.random.default_rng(2))
    pts = np.array([f.position for f in net.fittings])
    assert np.all(np.ptp(pts, axis=0) <= 2.5 + 1e-9)


def test_planar_networks_stay_horizontal() -> None:
    net = generate_network(NetworkConfig(n_fittings=12, planar=True), np.random.default_rng(4))
    assert np.allclose([f.position[2] for f in net.fittings], 0.0, atol=1e-9)


def test_three_d_networks_leave_the_plane() -> None:
    zs = []
    for seed in range(5):
        net = generate_network(
            NetworkConfig(n_fittings=10, planar=False), np.random.default_rng(seed)
        )
        zs.append(np.ptp([f.position[2] for f in net.fittings]))
    assert max(zs) > 0.2


def test_mix_and_diameters_follow_the_config() -> None:
    cfg = NetworkConfig(
        n_fittings=10, kind_weights={"mitre_bend": 1.0}, diameter_range=(0.06, 0.07), n_goals=0
    )  # (bends only: the start drives to the one closure without a decision, so no goal)
    net = generate_network(cfg, np.random.default_rng(0))
    assert {f.kind for f in net.fittings} == {"bend", "closure"}
    assert all(f.style == "mitre" for f in net.fittings if f.kind == "bend")
    assert all(0.06 <= r.diameter <= 0.07 for r in net.runs)


def test_bounded_retries_then_clear_error() -> None:
    cfg = NetworkConfig(n_fittings=40, max_extent=2.0, max_retries=3)
    with pytest.raises(NetworkGenerationError, match=r"n_fittings=40 in 3 attempts"):
        generate_network(cfg, np.random.default_rng(0))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"n_fittings": 0},
            r"NetworkConfig.n_fittings = 0 is invalid; allowed: an integer in \[1, 200\]",
        ),
        ({"kind_weights": {"spiral": 1.0}}, r"kind_weights = \['spiral'\] is invalid"),
        ({"diameter_range": (0.1, 0.05)}, r"diameter_range = \(0.1, 0.05\) is invalid"),
        ({"bend_angle_range": (10.0, 90.0)}, r"bend_angle_range .* 30 <= lo <= hi <= 90 deg"),
        ({"run_length_range": (0.01, 1.0)}, r"run_length_range"),
    ],
)
def test_config_errors_name_the_field(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        NetworkConfig(**kwargs)


def test_config_round_trip() -> None:
    cfg = NetworkConfig(n_fittings=5, planar=False)
    assert NetworkConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="no keys"):
        NetworkConfig.from_dict({"size": 3})


def test_rng_must_be_a_generator() -> None:
    with pytest.raises(ValueError, match="numpy.random.Generator"):
        generate_network(NetworkConfig(), 42)  # type: ignore[arg-type]
