"""Recorded scans in and out (detector.io): round trips through rosbag2 (SQLite and MCAP), ROS 1
bags, CSV and npz give the detection of the original sweep; sweeps are cut where the servo
reverses; JointState servos, TF poses and a mounting offset; errors that name the file, the
topic and what was expected."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from detector_scans import scan_layout
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from detector import detect
from detector.io import (
    ScanReadError,
    matrix_to_quat,
    quat_to_matrix,
    read_scans,
    scan_from_laserscans,
    sweep_cuts,
    write_csv,
    write_npz,
    write_rosbag,
)
from detector.scan import Scan


@pytest.fixture(scope="module")
def x4_sweep():
    """A simulated YDLidar X4 sweep 30 cm before a tee (noise, dropouts, 0.5 mm steps)."""
    return scan_layout("t_junction", 0.3, sensor="ydlidar_x4", seed=3)


def _same_detection(a, b) -> None:
    """The same detection (the diagnostics hold timings). A LaserScan holds float32; the
    reader restores the spec's beam angles and range grid, so a simulated sweep comes back
    bit for bit."""
    assert (a.kind, a.options, a.confidence) == (b.kind, b.options, b.confidence)


@pytest.mark.parametrize("name", ["bag2", "bag2.mcap", "ros1.bag", "scans.csv", "scans.npz"])
def test_round_trip_detects_as_the_original(tmp_path, x4_sweep, name):
    scan, truth, d = x4_sweep
    path = tmp_path / name
    if name.endswith(".csv"):
        write_csv([scan], path)
    elif name.endswith(".npz"):
        write_npz([scan], path)
    elif name.endswith(".mcap"):
        path = tmp_path / "bag2_mcap"
        write_rosbag([scan], path, storage="mcap")
        path = next(path.glob("*.mcap"))  # (the storage file alone reads too)
    else:
        write_rosbag([scan], path)
    (got,) = read_scans(path)
    assert (got.valid == scan.valid).all()
    assert got.spec == scan.spec
    assert np.allclose(got.ranges[got.valid], scan.ranges[scan.valid], atol=1e-6, rtol=0)
    assert np.allclose(got.plane_angles, scan.plane_angles, atol=1e-12)
    assert np.allclose(got.beam_angles, scan.beam_angles, atol=1e-6)
    assert np.allclose(got.nominal_positions, scan.nominal_positions, atol=1e-12)
    assert np.allclose(got.nominal_rotations, scan.nominal_rotations, atol=1e-12)
    assert np.array_equal(got.ranges, scan.ranges)
    assert np.array_equal(got.beam_angles, scan.beam_angles)
    for method in ("improved", "thesis"):
        _same_detection(detect(got, d, method), detect(scan, d, method))
    assert detect(got, d).kind == "junction"


def test_zero_no_returns_in_a_bag_detect_as_inf(tmp_path, x4_sweep):
    scan, _, d = x4_sweep
    zeros = np.where(scan.valid, scan.ranges, 0.0)
    as_zero = dataclasses.replace(scan, ranges=zeros, valid=np.ones(zeros.shape, bool))
    write_csv([as_zero], tmp_path / "z.csv")
    (got,) = read_scans(tmp_path / "z.csv")
    assert got.no_returns["zero"] == 0  # (written as inf: the scan had none left)
    # a CSV with 0.0 and NaN for no return, as SDKs write it
    text = (tmp_path / "z.csv").read_text().replace(",inf,", ",0.0,", 500).replace(",inf,", ",nan,")
    (tmp_path / "z0.csv").write_text(text)
    (got0,) = read_scans(tmp_path / "z0.csv")
    assert got0.no_returns["zero"] == 500 and got0.no_returns["nan"] > 0
    assert (got0.valid == scan.valid).all()
    _same_detection(detect(got0, d), detect(scan, d))


def test_several_sweeps_cut_where_the_servo_reverses(tmp_path, x4_sweep):
    scan, _, d = x4_sweep
    back = dataclasses.replace(  # the servo sweeping back: planes in reverse order, later
        scan,
        ranges=scan.ranges[::-1],
        valid=scan.valid[::-1],
        plane_angles=scan.plane_angles[::-1],
        timestamps=scan.timestamps + scan.timestamps[-1] + 0.1,
        positions=scan.positions[::-1],
        rotations=scan.rotations[::-1],
        nominal_positions=scan.nominal_positions[::-1],
        nominal_rotations=scan.nominal_rotations[::-1],
    )
    again = dataclasses.replace(scan, timestamps=back.timestamps + back.timestamps[-1] + 0.1)
    write_rosbag([scan, back, again], tmp_path / "three")
    got = read_scans(tmp_path / "three")
    assert [s.n_planes for s in got] == [scan.n_planes] * 3
    assert got[1].plane_angles[0] == pytest.approx(scan.plane_angles[-1])
    assert got[2].plane_angles[0] == pytest.approx(0.0)
    assert [detect(s, d).kind for s in got] == ["junction"] * 3
    # (the CSV without a sweep column cuts them the same way)
    write_csv([scan, back, again], tmp_path / "three.csv")
    text = (tmp_path / "three.csv").read_text().splitlines()
    body = [",".join(row.split(",")[1:]) for row in text if not row.startswith("#")]
    (tmp_path / "nosweep.csv").write_text("\n".join(body))
    assert [s.n_planes for s in read_scans(tmp_path / "nosweep.csv")] == [scan.n_planes] * 3


def test_sweep_cuts():
    a = [0.0, 0.1, 0.2, 0.3, 0.2, 0.1, 0.0, 0.0, 0.1]
    assert sweep_cuts(a) == [slice(0, 4), slice(4, 7), slice(7, 9)]
    assert sweep_cuts([0.0, 1.0, 2.0, 3.0], servo_range=1.5) == [slice(0, 2), slice(2, 4)]


def _laserscan(ts, stamp_ns: int, ranges: np.ndarray, frame="laser"):
    t = ts.types
    return t["sensor_msgs/msg/LaserScan"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
            frame_id=frame,
        ),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=0.5,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.1,
        range_max=4.0,
        ranges=ranges.astype(np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def test_jointstate_servo_tf_poses_and_a_mount(tmp_path):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    path = tmp_path / "robot_bag"
    yaw = 0.3
    q_yaw = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    with Writer(path, version=9) as w:
        c_scan = w.add_connection("/lidar/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        c_js = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        for k in range(6):
            ns = 10**9 + k * 10**8

            def stamp(n=ns):
                return t["builtin_interfaces/msg/Time"](sec=n // 10**9, nanosec=n % 10**9)

            js = t["sensor_msgs/msg/JointState"](
                header=t["std_msgs/msg/Header"](stamp=stamp(), frame_id=""),
                name=["wheel", "servo"],
                position=np.array([5.0, 0.1 * k]),
                velocity=np.zeros(2),
                effort=np.zeros(2),
            )
            tf = t["geometry_msgs/msg/TransformStamped"](
                header=t["std_msgs/msg/Header"](stamp=stamp(), frame_id="odom"),
                child_frame_id="base_link",
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=0.01 * k, y=0.0, z=0.0),
                    rotation=t["geometry_msgs/msg/Quaternion"](
                        x=q_yaw[1], y=q_yaw[2], z=q_yaw[3], w=q_yaw[0]
                    ),
                ),
            )
            w.write(c_js, ns, ts.serialize_cdr(js, "sensor_msgs/msg/JointState"))
            w.write(
                c_tf,
                ns,
                ts.serialize_cdr(
                    t["tf2_msgs/msg/TFMessage"](transforms=[tf]), "tf2_msgs/msg/TFMessage"
                ),
            )
            if k >= 1:  # scans halfway between servo readings
                r = np.array([0.5, 0.0, np.inf, np.nan, 5.0])
                w.write(
                    c_scan,
                    ns + 5 * 10**7,
                    ts.serialize_cdr(
                        _laserscan(ts, ns + 5 * 10**7, r), "sensor_msgs/msg/LaserScan"
                    ),
                )
    with pytest.raises(
        ScanReadError,
        match=r"robot_bag: topic '/joint_states' is a JointState of joints \['wheel', 'servo'\]; "
        "name the servo joint",
    ):
        read_scans(path)
    mount = (np.array([0.2, 0.0, 0.05]), np.eye(3))
    (scan,) = read_scans(path, servo_joint="servo", mount=mount)
    assert scan.n_planes == 4 and scan.n_beams == 5  # (the last scan: after the servo's)
    assert np.allclose(scan.plane_angles, [0.15, 0.25, 0.35, 0.45])
    assert np.allclose(scan.beam_angles, [-1.0, -0.5, 0.0, 0.5, 1.0])
    # 0.0, inf, NaN and 5 m (beyond range_max 4 m) are no returns
    assert scan.valid.sum() == 4 and scan.no_returns["above_max_range"] == 4
    assert scan.spec == {"min_range": pytest.approx(0.1), "max_range": 4.0}
    rot = quat_to_matrix(q_yaw)
    expect = np.array([0.015, 0.0, 0.0]) + rot @ mount[0]
    assert np.allclose(scan.nominal_positions[0], expect)
    assert np.allclose(scan.nominal_rotations[0], rot)


def test_quaternions_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        r = quat_to_matrix(q)
        assert np.allclose(quat_to_matrix(matrix_to_quat(r)), r, atol=1e-12)


def test_from_laserscans_live():
    ts = get_typestore(Stores.ROS2_HUMBLE)
    msgs = [_laserscan(ts, 10**9 + k, np.array([0.5, 0.6, 0.0, 0.7, 0.8])) for k in range(3)]
    scan = scan_from_laserscans(msgs, [0.0, 0.5, 1.0], fov=1.2)
    assert scan.n_beams == 3 and np.allclose(scan.beam_angles, [-0.5, 0.0, 0.5])
    assert scan.no_returns["zero"] == 3
    with pytest.raises(ScanReadError, match="expected one plane angle per LaserScan, got 2"):
        scan_from_laserscans(msgs, [0.0, 0.5])


def test_errors_name_the_file_the_topic_and_what_was_expected(tmp_path, x4_sweep):
    scan, _, _ = x4_sweep
    write_rosbag([scan], tmp_path / "bag")
    with pytest.raises(
        ScanReadError,
        match=r"bag: topic '/nope' \(scan\) is not in the bag; expected one of "
        r"sensor_msgs/msg/LaserScan: \['/scan'\]",
    ):
        read_scans(tmp_path / "bag", scan_topic="/nope")
    with pytest.raises(
        ScanReadError,
        match=r"bag: topic '/odom' \(servo\) holds nav_msgs/msg/Odometry; expected "
        r"std_msgs/msg/Float64 or sensor_msgs/msg/JointState",
    ):
        read_scans(tmp_path / "bag", servo_topic="/odom")
    bad = tmp_path / "broken.npz"
    bad.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(ScanReadError, match=r"broken\.npz: not a scan npz"):
        read_scans(bad)
    csv = tmp_path / "bad.csv"
    csv.write_text("plane_angle,beam_angle,range,time\n0,0.1,0.5,0\n0,zero,0.5,0\n")
    with pytest.raises(
        ScanReadError, match=r"bad\.csv: row 3, column 'beam_angle': expected a number, got 'zero'"
    ):
        read_scans(csv)
    csv.write_text("plane_angle,range,time\n0,0.5,0\n")
    with pytest.raises(ScanReadError, match=r"bad\.csv: missing column\(s\) \['beam_angle'\]"):
        read_scans(csv)
    with pytest.raises(ScanReadError, match=r"nothing\.bag: no such file"):
        read_scans(tmp_path / "nothing.bag")
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(
        ScanReadError, match=r"x\.txt: unknown format '\.txt'; expected \.npz, \.csv"
    ):
        read_scans(tmp_path / "x.txt")


def test_write_rosbag_replaces_an_existing_bag(tmp_path, x4_sweep):
    scan, _, _ = x4_sweep
    write_rosbag([scan], tmp_path / "bag")
    late = dataclasses.replace(scan.plane(0), timestamps=scan.timestamps[-1:] + 1.0)
    write_rosbag([scan, late], tmp_path / "bag")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # (no temporary left)
    assert len(read_scans(tmp_path / "bag", min_planes=1)) == 2


def test_real_data_doc_snippets_run(monkeypatch):
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(root)
    text = (root / "docs" / "real-data.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.DOTALL)
    assert blocks
    for i, code in enumerate(blocks):
        exec(compile(code, f"docs/real-data.md python block {i}", "exec"), {"__name__": "__doc__"})


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_corrupt_recordings_raise_scan_read_errors_naming_the_file(tmp_path_factory, data):
    # a valid npz, CSV and bag, then bytes cut, flipped or replaced: a ScanReadError (a
    # ValueError naming the file) or scans, never a raw zipfile/csv/sqlite/rosbags error
    folder = tmp_path_factory.mktemp("corrupt")
    scan = _tiny_scan()
    kind = data.draw(st.sampled_from(["npz", "csv", "bag"]))
    path = folder / f"rec.{kind}"
    {"npz": write_npz, "csv": write_csv, "bag": write_rosbag}[kind]([scan], path)
    raw = bytearray(path.read_bytes())
    how = data.draw(st.sampled_from(["cut", "flip", "garbage"]))
    if how == "cut":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif how == "flip":
        for i in data.draw(st.lists(st.integers(0, len(raw) - 1), min_size=1, max_size=8)):
            raw[i] ^= 0xFF
    else:
        raw = bytearray(data.draw(st.binary(max_size=200)))
    path.write_bytes(bytes(raw))
    try:
        got = read_scans(path)
    except ScanReadError as exc:
        assert str(path) in str(exc)
    else:
        assert all(isinstance(s, Scan) for s in got)


def _tiny_scan() -> Scan:
    p, b = 4, 7
    ranges = np.full((p, b), 0.4)
    ranges[1, 2] = np.inf
    return Scan(
        ranges=ranges,
        valid=np.isfinite(ranges),
        beam_angles=np.linspace(-1.0, 1.0, b),
        plane_angles=np.linspace(0.0, 1.5, p),
        timestamps=np.arange(p, dtype=float),
        positions=np.zeros((p, 3)),
        rotations=np.tile(np.eye(3), (p, 1, 1)),
        nominal_positions=np.zeros((p, 3)),
        nominal_rotations=np.tile(np.eye(3), (p, 1, 1)),
        spec={"min_range": 0.1, "max_range": 2.0},
    )
