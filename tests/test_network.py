"""The network model: serialisation round trips and validation errors that name what is wrong."""

from __future__ import annotations

import copy
import json
import math
from typing import Any

import numpy as np
import pytest

from pipe_env import layouts
from pipe_env.network import PipeNetwork


def hand_written() -> dict[str, Any]:
    """A small network as a user would write it: entry, mitre bend, tee, two closures."""
    return {
        "version": 1,
        "name": "hand",
        "fittings": [
            {"id": "in", "kind": "closure", "position": [0, 0, 0]},
            {"id": "b", "kind": "bend", "position": [1.5, 0, 0], "style": "mitre"},
            {"id": "t", "kind": "tee", "position": [1.5, 1.0, 0]},
            {"id": "e1", "kind": "closure", "position": [1.5, 2.0, 0]},
            {"id": "e2", "kind": "closure", "position": [2.5, 1.0, 0]},
        ],
        "runs": [
            {"id": "r0", "a": "in", "b": "b", "diameter": 0.1},
            {"id": "r1", "a": "b", "b": "t", "diameter": 0.1},
            {"id": "r2", "a": "t", "b": "e1", "diameter": 0.1},
            {"id": "r3", "a": "t", "b": "e2", "diameter": 0.08},
        ],
        "start": {"position": [0.6, 0, 0], "forward": [1, 0, 0]},
        "goals": [[2.3, 1.0, 0.0]],
    }


def test_hand_written_network_validates_and_round_trips(tmp_path) -> None:
    net = PipeNetwork.from_dict(hand_written())
    assert len(net.fittings) == 5 and len(net.runs) == 4
    d = net.to_dict()
    assert d["version"] == 1
    again = PipeNetwork.from_dict(json.loads(json.dumps(d)))
    assert again.to_dict() == d
    assert PipeNetwork.from_yaml(net.to_yaml()).to_dict() == d
    for suffix in (".json", ".yaml"):
        path = tmp_path / f"net{suffix}"
        net.save(path)
        assert PipeNetwork.load(path).to_dict() == d


def test_ground_truth_on_hand_written_network() -> None:
    net = PipeNetwork.from_dict(hand_written())
    (opt,) = net.structures_ahead(net.start_pose, 2.0)
    assert opt.kind == "bend"
    assert opt.distance == pytest.approx(0.9)
    assert opt.angle == pytest.approx(math.pi / 2)
    assert opt.direction == pytest.approx(0.0)  # left
    assert net.structures_ahead(net.start_pose, 0.5) == []


def broken(path: str, value: Any) -> dict[str, Any]:
    d = copy.deepcopy(hand_written())
    target: Any = d
    keys = path.split(".")
    for k in keys[:-1]:
        target = target[int(k)] if k.isdigit() else target[k]
    last = keys[-1]
    if value is _DELETE:
        del target[int(last) if last.isdigit() else last]
    else:
        target[int(last) if last.isdigit() else last] = value
    return d


_DELETE = object()


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("runs.3.b", "nowhere", r"^runs\[3\] \(id 'r3'\).b = 'nowhere': not a fitting .*dangling"),
        (
            "runs.0.diameter",
            0.3,
            r"^runs\[0\] \(id 'r0'\).diameter = 0.3: out of range; allowed: 0.02 to 0.25 \(m\)",
        ),
        (
            "runs.3.diameter",
            0.12,
            r"^runs\[3\] \(id 'r3'\).diameter = 0.12: branch wider than the run through",
        ),
        (
            "fittings.1.kind",
            "tee",
            r"^fittings\[1\] \(id 'b'\).kind = 'tee': joined by 2 run.*a tee joins exactly 3",
        ),
        (
            "fittings.1.kind",
            "elbow",
            r"^fittings\[1\] \(id 'b'\).kind = 'elbow': unknown; allowed: bend, closure",
        ),
        (
            "fittings.1.style",
            "curly",
            r"^fittings\[1\] \(id 'b'\).style = 'curly': unknown; allowed: mitre, long",
        ),
        (
            "fittings.1.position",
            [1.5, 0, 0.6],
            r"^fittings\[1\] \(id 'b'\).position = .*: deflection 101.02 deg out of range",
        ),
        (
            "fittings.4.position",
            [1.58, 1.0, 0],
            r"^runs\[3\] \(id 'r3'\) = 0.08: too short for its fittings",
        ),
        (
            "fittings.4.position",
            [2.5, 1.3, 0],
            r"^runs\[3\] \(id 'r3'\).b = 'e2': branch at 73.30 deg to the run through",
        ),
        ("version", 2, r"^version = 2: unsupported; allowed: 1 \(this pipenav reads version 1\)"),
        ("colour", "red", r"^colour = 'red': unknown key; allowed:"),
        (
            "start.position",
            [0.6, 0.2, 0],
            r"^start.position = .*from the nearest centreline; allowed: inside the bore",
        ),
        ("goals", [[5, 5, 5]], r"^goals\[0\] = \[5.0, 5.0, 5.0\]: .*; allowed: inside the bore"),
        (
            "fittings.0.position",
            [0, "x", 0],
            r"^fittings\[0\] \(id 'in'\).position = \[0, 'x', 0\]: not a list of numbers",
        ),
    ],
)
def test_validation_errors_name_element_value_and_range(
    path: str, value: Any, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        PipeNetwork.from_dict(broken(path, value))


def test_long_bend_radius_out_of_range() -> None:
    d = hand_written()
    d["fittings"][1].update(style="long", bend_radius=0.5)
    with pytest.raises(
        ValueError,
        match=r"^fittings\[1\] \(id 'b'\).bend_radius = 0.5: 5.00 D, out of range; allowed: 1 to 3",
    ):
        PipeNetwork.from_dict(d)


def test_intersecting_runs_are_rejected() -> None:
    d = hand_written()
    # a second branch from a new tee that crosses run r0
    d["fittings"] += [
        {"id": "t2", "kind": "tee", "position": [0.8, -0.5, 0]},
        {"id": "x1", "kind": "closure", "position": [0.2, -0.5, 0]},
        {"id": "x2", "kind": "closure", "position": [1.4, -0.5, 0]},
        {"id": "x3", "kind": "closure", "position": [0.8, 0.6, 0]},
    ]
    d["runs"] += [
        {"id": "s1", "a": "t2", "b": "x1", "diameter": 0.1},
        {"id": "s2", "a": "t2", "b": "x2", "diameter": 0.1},
        {"id": "s3", "a": "t2", "b": "x3", "diameter": 0.1},
    ]
    with pytest.raises(
        ValueError, match=r"^runs\[0\] \(id 'r0'\) = .*: intersects runs\[6\] \(id 's3'\)"
    ):
        PipeNetwork.from_dict(d)


def test_missing_and_unknown_element_keys() -> None:
    with pytest.raises(ValueError, match=r"^runs\[0\].diameter = None: missing"):
        PipeNetwork.from_dict(broken("runs.0.diameter", _DELETE))
    with pytest.raises(ValueError, match=r"^fittings\[1\].radius = 3: unknown key"):
        PipeNetwork.from_dict(broken("fittings.1.radius", 3))


def test_reducer_rules() -> None:
    net = layouts.reducer(0.1, 0.06, 0.1)
    d = net.to_dict()
    d["fittings"][1]["taper_length"] = 0.001
    with pytest.raises(
        ValueError, match=r"^fittings\[1\] \(id 's'\).taper_length = 0.001: out of range"
    ):
        PipeNetwork.from_dict(d)
    d["fittings"][1]["taper_length"] = 0.01
    with pytest.raises(
        ValueError,
        match=r"^fittings\[1\] \(id 's'\).taper_length = 0.01: taper half-angle 63.4 deg",
    ):
        PipeNetwork.from_dict(d)
    d = net.to_dict()
    d["runs"][1]["diameter"] = 0.1
    with pytest.raises(
        ValueError, match=r"^runs\[1\] \(id '.*'\).diameter = 0.1: joins equal diameters"
    ):
        PipeNetwork.from_dict(d)


def test_centreline_queries_on_a_bend() -> None:
    net = layouts.long_bend(diameter=0.1, angle=math.pi / 2, radius_factor=2.0, distance=0.5)
    cl = net.centreline
    # total length: incoming straight + tangent legs replaced by the arc + outlet
    arc = 0.2 * math.pi / 2
    tangent = 0.2
    p = cl.nearest(np.array([0.0, 0.0, 0.0]))  # the corner point lies off the centreline
    assert p.distance == pytest.approx(0.2 * (math.sqrt(2) - 1), abs=1e-9)
    assert net.inner_diameter_at([0.3, 0.0, 0.0]) == pytest.approx(0.1)
    start = net.start_pose.position
    out_end = net.position("out0")
    expected = (0.5 - tangent) + arc + (0.6 + 0.025)
    assert net.geodesic_distance(start, out_end) == pytest.approx(expected, abs=1e-9)
    path = cl.path_between(start, out_end)
    assert path.length == pytest.approx(expected, abs=1e-9)
    mid = path.pose_at((0.5 - tangent) + arc / 2)
    r = np.linalg.norm(mid.position - np.array([-tangent, 0.2, 0.0]))
    assert r == pytest.approx(0.2, abs=1e-9)  # on the arc
    assert np.allclose(mid.forward, [math.sqrt(0.5), math.sqrt(0.5), 0], atol=1e-9)


def test_inner_diameter_in_a_reducer_taper() -> None:
    net = layouts.reducer(0.1, 0.06, taper_length=0.2)
    assert net.inner_diameter_at([0.1, 0, 0]) == pytest.approx(0.08)
    assert net.inner_diameter_at([0.05, 0, 0]) == pytest.approx(0.09)
    assert net.inner_diameter_at([0.5, 0, 0]) == pytest.approx(0.06)


def test_cross_needs_one_diameter_per_run_through() -> None:
    net = layouts.cross_junction(0.1, 0.08)
    d = net.to_dict()
    d["runs"][3]["diameter"] = 0.07  # one side branch narrower than its opposite
    with pytest.raises(
        ValueError,
        match=r"^runs\[3\] \(id 'r_out2'\).diameter = 0.07: differs from run 'r_out1' on the run",
    ):
        PipeNetwork.from_dict(d)


def test_from_dict_type_errors_are_named() -> None:
    d = hand_written()
    d["goals"] = 5
    with pytest.raises(ValueError, match=r"^goals = 5: not a list; allowed: a list"):
        PipeNetwork.from_dict(d)
    d = hand_written()
    d["fittings"][1].update(style="long", bend_radius="x")
    with pytest.raises(
        ValueError, match=r"^fittings\[1\] \(id 'b'\).bend_radius = 'x': not a number"
    ):
        PipeNetwork.from_dict(d)
    with pytest.raises(ValueError, match=r"^runs = \[\]: empty; allowed: at least one run"):
        PipeNetwork.from_dict({"version": 1, "fittings": [], "runs": []})


def test_edge_positions_inside_a_long_bend_round_trip() -> None:
    from pipe_env.routing import edge_path, edge_position

    net = layouts.long_bend(0.1, math.pi / 2, radius_factor=3.0)
    arc = next(p for p in net.centreline.pieces if p.kind == "arc")
    for frac in (0.05, 0.25, 0.45, 0.55, 0.95):
        p, _ = arc.point_tangent(frac * arc.length)
        ep = edge_position(net, net.centreline.nearest(p))
        q, _ = edge_path(net, ep.run_id).point_tangent(ep.s)
        assert np.linalg.norm(q - p) < 1e-9, frac


def test_load_names_the_file_and_the_element_by_path_and_id(tmp_path) -> None:
    import pickle

    from pipe_env.network_io import NetworkSpecError

    path = tmp_path / "net.yaml"
    path.write_text(json.dumps(broken("runs.0.diameter", 0.3)))  # JSON is YAML too
    with pytest.raises(NetworkSpecError) as err:
        PipeNetwork.load(path)
    message = str(err.value)
    assert message.startswith(f"{path}: runs[0] (id 'r0').diameter = 0.3: out of range")
    assert err.value.field == "runs[0] (id 'r0').diameter" and err.value.where == str(path)
    again = pickle.loads(pickle.dumps(err.value))
    assert type(again) is NetworkSpecError and str(again) == message


def test_validate_names_fittings_by_path_and_id() -> None:
    net = PipeNetwork.from_dict(broken("fittings.1.style", "curly"), validate=False)
    with pytest.raises(ValueError, match=r"^fittings\[1\] \(id 'b'\).style = 'curly': unknown"):
        net.validate()
    far = net.with_goals([[5000.0, 0, 0]])
    with pytest.raises(ValueError, match=r"^goals\[0\] = \[5000.0, 0.0, 0.0\]: outside the"):
        far.validate()
