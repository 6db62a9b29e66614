"""``pipenav record``, ``detect`` and ``export``: a drive recorded as a rosbag2 replays through
``detect`` to the live fused detection; the exported STL is watertight and the MJCF loads."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
import trimesh

from agents.cli import build_parser, main
from detector.io import read_scans


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "drive"
    assert main(["record", str(out), "--layout", "t_junction", "--seed", "2"]) == 0
    return out, json.loads(out.with_name("drive.truth.json").read_text())


def test_recorded_bag_replays_to_the_live_fused_detection(recorded, tmp_path, capsys):
    bag, truth = recorded
    scans = read_scans(bag)
    assert len(scans) == len(truth["sweeps"]) >= 3
    # several sweeps while driving: the sensor moved between them
    xs = [s["true_sensor_position_m"][0] for s in truth["sweeps"]]
    assert np.ptp(xs) > 0.05
    assert truth["fused"]["confirmed"] and truth["fused"]["detection"]["kind"] == "junction"
    out = tmp_path / "det.json"
    assert main(["detect", str(bag), "--json", str(out), "--plot", str(tmp_path / "d.png")]) == 0
    printed = capsys.readouterr().out
    assert "structure ahead: junction" in printed and "confirmed" in printed
    got = json.loads(out.read_text())
    # (the poses travel as quaternions: rotations come back within 1e-16, and an angle near 0
    # through acos within 1e-7)
    _close(got["fused"], truth["fused"])
    for live, replay in zip(truth["sweeps"], got["sweeps"], strict=True):
        _close(replay["detection"]["options"], live["detection"]["options"])
        _close(replay["track"], live["track"])
        assert replay["clamped_diameter_m"] == live["clamped_diameter_m"]
    assert (tmp_path / "d.png").stat().st_size > 1000


def _close(a, b, tol: float = 1e-6) -> None:
    """Equal JSON documents, numbers within ``tol``."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (a, b)
        for k in a:
            _close(a[k], b[k], tol)
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), (a, b)
        for x, y in zip(a, b, strict=True):
            _close(x, y, tol)
    elif isinstance(a, float) and not isinstance(b, bool):
        assert b == pytest.approx(a, abs=tol)
    else:
        assert a == b


def test_detect_needs_a_clamped_diameter(tmp_path, capsys):
    from detector_scans import scan_layout

    from detector.io import write_csv

    write_csv([scan_layout("closure", 0.4)[0]], tmp_path / "s.csv")
    assert main(["detect", str(tmp_path / "s.csv")]) == 2
    assert "has no recorded clamped diameter; give --clamped-diameter" in capsys.readouterr().out
    assert main(["detect", str(tmp_path / "s.csv"), "--clamped-diameter", "0.1"]) == 0
    assert main(["detect", str(tmp_path / "missing.bag")]) == 2
    assert "missing.bag: no such file or folder" in capsys.readouterr().out


def test_export_stl_is_watertight_and_mjcf_loads(tmp_path, capsys):
    stl, obj, xml, robot = (tmp_path / n for n in ("w.stl", "w.obj", "w.xml", "r.xml"))
    args = ["export", "--layout", "y_junction", "--stl", str(stl), "--obj", str(obj)]
    assert main([*args, "--mjcf", str(xml)]) == 0
    assert "watertight" in capsys.readouterr().out
    for path in (stl, obj):
        mesh = trimesh.load(path, force="mesh")
        assert mesh.is_watertight and mesh.volume > 0
    model = mujoco.MjModel.from_xml_path(str(xml))
    assert model.nmesh > 0 and model.ngeom > model.nmesh
    assert main(["export", "--layout", "closure", "--mjcf", str(robot), "--robot"]) == 0
    model = mujoco.MjModel.from_xml_path(str(robot))
    assert model.nkey == 1 and model.nmocap > 0
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    start = data.qpos[:3].copy()
    assert np.linalg.norm(start) > 0.0  # (the robot at the network's start)
    for _ in range(200):  # clamped: it stays there under gravity
        mujoco.mj_step(model, data)
    assert np.linalg.norm(data.qpos[:3] - start) < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8))
def test_generated_networks_export_watertight(tmp_path, seed):
    from pipe_env.export import export_mesh
    from pipe_env.generator import NetworkConfig, generate_network

    net = generate_network(NetworkConfig.from_dict({"n_fittings": 8}), np.random.default_rng(seed))
    path = export_mesh(net, tmp_path / "w.stl")
    mesh = trimesh.load(path, force="mesh")
    assert mesh.is_watertight and mesh.volume > 0


def test_export_errors(tmp_path, capsys):
    assert main(["export", "--layout", "closure"]) == 2
    assert "give at least one of --stl" in capsys.readouterr().out
    assert main(["export", "--layout", "closure", "--stl", str(tmp_path / "w.obj")]) == 2
    assert "expected a .stl file name" in capsys.readouterr().out


def test_every_option_has_help_with_its_default():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name in ("detect", "record", "export"):
        parser = sub.choices[name]
        for action in parser._actions:
            if action.dest == "help":
                continue
            assert action.help, (name, action.dest)
            if action.option_strings:
                assert "default" in action.help, (name, action.dest)
