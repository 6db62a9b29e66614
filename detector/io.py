"""Recorded scans in and out: our npz, a CSV layout, and ROS bags (rosbag2, MCAP, ROS 1).

This module owns the ways from recorded data to :class:`~detector.scan.Scan` (and back, for
replaying simulated sweeps into a ROS stack). Like the rest of :mod:`detector` it needs neither
MuJoCo nor the simulator; ROS bags are read and written with the pure-Python ``rosbags``
library (no ROS install).

- :func:`read_scans` reads any of the formats into a list of sweeps;
- :func:`write_rosbag`, :func:`write_csv` and :func:`write_npz` write them;
- :func:`scan_from_laserscans` builds one sweep from
  ``sensor_msgs/LaserScan`` messages and their servo angles, for live use.

Sensor poses (see the user document on real data): every pose is the *sensor frame before the
servo rotation* (x forward along the pipe, y left, z up; REP 103) in the odometry (world)
frame. The servo angle is the rotation of the scan plane about the sensor's x axis (0: the
LaserScan plane is the horizontal x-y plane, beams at positive angles to the left; +pi/2: the
vertical x-z plane, positive beams upwards). An odometry pose is of the robot's base; the
``mount`` (base to sensor frame) is composed onto it.

No returns follow REP 117 and the SDKs: NaN, +-inf, 0.0 and ranges outside the message's
``[range_min, range_max]`` are no returns; :class:`~detector.scan.Scan` counts them.

CSV layout (one row per beam; ``#`` lines are comments; an optional ``# spec: {json}`` line
gives the sensor description)::

    sweep,plane_angle,beam_angle,range,time[,x,y,z,qw,qx,qy,qz]

``sweep`` (integer, optional: without it the sweeps are cut where the servo reverses),
``plane_angle`` (servo angle, rad), ``beam_angle`` (rad), ``range`` (m; ``inf``, ``nan`` or
``0`` for no return), ``time`` (s, one per plane); the optional pose columns give the sensor
position (m) and orientation (unit quaternion, world from sensor) at that plane. A plane is
the run of consecutive rows with the same ``sweep``, ``plane_angle`` and ``time``.
"""

from __future__ import annotations

import contextlib
import csv
import io as _io
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from detector.atomic import atomic_open, atomic_write_text
from detector.scan import SCAN_ARRAYS, Scan, ScanReadError

__all__ = [
    "BagTopics",
    "ScanReadError",
    "read_scans",
    "scan_from_laserscans",
    "sweep_cuts",
    "write_csv",
    "write_npz",
    "write_rosbag",
]

LASERSCAN = "sensor_msgs/msg/LaserScan"
FLOAT64 = "std_msgs/msg/Float64"
JOINTSTATE = "sensor_msgs/msg/JointState"
ODOMETRY = "nav_msgs/msg/Odometry"
TFMESSAGE = "tf2_msgs/msg/TFMessage"
#: Message types a servo angle may come in (radians).
SERVO_TYPES = (FLOAT64, JOINTSTATE)
#: Topics :func:`write_rosbag` writes (and :func:`read_scans` prefers when several match).
DEFAULT_TOPICS = {
    "scan": "/scan",
    "servo": "/servo_angle",
    "odom": "/odom",
    "truth": "/ground_truth/odom",
    "spec": "/lidar_spec",
    "clamp": "/clamped_diameter",
}
STRING = "std_msgs/msg/String"
#: The CSV columns (the pose columns are optional).
CSV_COLUMNS = ("sweep", "plane_angle", "beam_angle", "range", "time")
CSV_POSE_COLUMNS = ("x", "y", "z", "qw", "qx", "qy", "qz")
#: Format version of a multi-sweep npz written by :func:`write_npz`.
NPZ_SWEEPS_VERSION = 1


@dataclass(frozen=True)
class BagTopics:
    """Topics of a bag as :func:`read_scans` resolved them (``None``: not in the bag)."""

    scan: str
    servo: str
    odom: str | None
    truth: str | None


# ------------------------------------------------------------------------ rotations
def quat_to_matrix(q: Sequence[float]) -> NDArray[np.float64]:
    """(3, 3) rotation of the quaternion ``q = (w, x, y, z)`` (normalised here)."""
    w, x, y, z = np.asarray(q, dtype=float) / float(np.linalg.norm(q))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(r: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit quaternion ``(w, x, y, z)`` (w >= 0) of the rotation matrix ``r``."""
    m = np.asarray(r, dtype=float)
    t = float(np.trace(m))
    if t > 0.0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    out = np.array(q)
    out /= np.linalg.norm(out)
    return out if out[0] >= 0.0 else -out


def _slerp(q0: NDArray, q1: NDArray, f: float) -> NDArray[np.float64]:
    if np.dot(q0, q1) < 0.0:
        q1 = -q1
    d = min(1.0, float(np.dot(q0, q1)))
    if d > 0.9995:
        q = q0 + f * (q1 - q0)
    else:
        th = math.acos(d)
        q = (math.sin((1 - f) * th) * q0 + math.sin(f * th) * q1) / math.sin(th)
    return q / np.linalg.norm(q)


def _interp_poses(
    t: NDArray[np.float64], times: NDArray[np.float64], pos: NDArray, quat: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Positions (linear) and rotations (slerp) at the times ``t`` (clamped to the ends)."""
    out_p = np.stack([np.interp(t, times, pos[:, i]) for i in range(3)], axis=-1)
    out_r = np.empty((t.size, 3, 3))
    for n, tn in enumerate(t):
        k = int(np.searchsorted(times, tn, side="right")) - 1
        if k < 0 or times.size == 1:
            q = quat[0]
        elif k >= times.size - 1 or times[k] == tn:
            q = quat[min(k, times.size - 1)]
        else:
            q = _slerp(quat[k], quat[k + 1], (tn - times[k]) / (times[k + 1] - times[k]))
        out_r[n] = quat_to_matrix(q)
    return out_p, out_r


def _mount(mount: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(position (3,), rotation (3, 3))`` of the sensor frame in the base frame."""
    if mount is None:
        return np.zeros(3), np.eye(3)
    try:
        p, r = mount
        p = np.asarray(p, dtype=float).reshape(3)
        r = np.asarray(r, dtype=float).reshape(3, 3)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"mount must be (position (3,) m, rotation (3, 3)) of the sensor in the base frame, "
            f"got {mount!r}"
        ) from exc
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(r))):
        raise ValueError(f"mount must be finite, got {mount!r}")
    return p, r


# ------------------------------------------------------------------------ sweeps
def sweep_cuts(angles: ArrayLike, servo_range: float | None = None) -> list[slice]:
    """Split a sequence of servo angles (rad) into sweeps: a new sweep starts where the servo
    reverses (or jumps back) or, with ``servo_range`` (rad), where the angles since the start
    of the sweep would span more than it. Where the servo dwells at its turning point (the
    same angle twice), the first reading ends the sweep and the next begins the new one."""
    a = np.asarray(angles, dtype=float)
    if a.size == 0:
        return []
    cuts = [0]
    direction = 0.0
    dwell = 0  # first index of the run of equal angles ending at i - 1
    for i in range(1, a.size):
        step = a[i] - a[i - 1]
        if step == 0.0:
            continue
        reverse = direction != 0.0 and math.copysign(1.0, step) != direction
        too_far = servo_range is not None and abs(a[i] - a[cuts[-1]]) > servo_range + 1e-9
        if reverse or too_far:
            # after a dwell the new sweep starts at its second reading (and this step is its
            # first); else at this reading, its direction still unknown
            dwelt = reverse and dwell + 1 < i
            cuts.append(dwell + 1 if dwelt else i)
            direction = math.copysign(1.0, step) if dwelt else 0.0
        else:
            direction = math.copysign(1.0, step)
        dwell = i
    cuts.append(a.size)
    return [slice(cuts[k], cuts[k + 1]) for k in range(len(cuts) - 1)]


def scan_from_laserscans(
    messages: Sequence[Any],
    plane_angles: Sequence[float] | NDArray[np.float64],
    *,
    timestamps: ArrayLike | None = None,
    positions: Any = None,
    rotations: Any = None,
    true_positions: Any = None,
    true_rotations: Any = None,
    spec: Mapping[str, Any] | None = None,
    fov: float | None = None,
    metadata: Mapping[str, Any] | None = None,
    source: str = "LaserScan messages",
) -> Scan:
    """One sweep from ``sensor_msgs/LaserScan`` messages, one per plane.

    Args:
        messages: the LaserScans (anything with ``angle_min``, ``angle_increment``,
            ``range_min``, ``range_max``, ``ranges`` and ``header.stamp``), all with the same
            beams.
        plane_angles: (P,) servo angle of each message, radians (module docstring).
        timestamps: (P,) seconds; default: the messages' header stamps.
        positions, rotations: (P, 3) m and (P, 3, 3) sensor poses the robot believes (world
            from sensor, before the servo rotation); default: the identity (a still sensor).
        true_positions, true_rotations: the true poses where known (simulation); default: the
            believed ones.
        spec: the sensor description (``LidarSpec`` fields); the messages' ``range_min`` and
            ``range_max`` override its limits.
        fov: keep only beams with ``|angle| <= fov / 2`` (e.g. the front half of a 360 degree
            sensor), radians; default: all.
        metadata: extras stored in the scan.
        source: names the data in error messages (a file and topic).
    """
    n = len(messages)
    if n == 0:
        raise ScanReadError(f"{source}: expected at least one LaserScan, got none")
    if len(plane_angles) != n:
        raise ScanReadError(
            f"{source}: expected one plane angle per LaserScan, got {len(plane_angles)} angles "
            f"for {n} messages"
        )
    first = messages[0]
    n_b = len(first.ranges)
    key = (float(first.angle_min), float(first.angle_increment), n_b)
    for k, m in enumerate(messages):
        if (float(m.angle_min), float(m.angle_increment), len(m.ranges)) != key:
            raise ScanReadError(
                f"{source}: LaserScan {k} of the sweep has angle_min {float(m.angle_min):g}, "
                f"angle_increment {float(m.angle_increment):g} and {len(m.ranges)} ranges; "
                f"expected the first one's {key[0]:g}, {key[1]:g} and {key[2]}"
            )
    beams = key[0] + key[1] * np.arange(n_b, dtype=np.float64)
    keep = np.ones(n_b, dtype=bool) if fov is None else np.abs(beams) <= 0.5 * fov + 1e-9
    if not keep.any():
        raise ScanReadError(f"{source}: no beam lies within the field of view {fov!r} rad")
    ranges = np.array([np.asarray(m.ranges, dtype=float) for m in messages])[:, keep]
    lo = max(float(m.range_min) for m in messages)
    hi = min(float(m.range_max) for m in messages)
    spec_d = dict(spec or {})
    if math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi:
        for name, value in (("min_range", lo), ("max_range", hi)):
            given = spec_d.get(name)
            # (a LaserScan holds float32: keep the spec's own number when it is the same one)
            same = isinstance(given, (int, float)) and np.float32(given) == np.float32(value)
            if not same:
                spec_d[name] = value
    if timestamps is None:
        timestamps = [_stamp(m.header.stamp) for m in messages]
    t = np.asarray(timestamps, dtype=float)
    pos = np.zeros((n, 3)) if positions is None else np.asarray(positions, dtype=float)
    rot = np.tile(np.eye(3), (n, 1, 1)) if rotations is None else np.asarray(rotations, float)
    tpos = pos if true_positions is None else np.asarray(true_positions, dtype=float)
    trot = rot if true_rotations is None else np.asarray(true_rotations, dtype=float)
    beams, ranges = _restore_float64(beams, ranges, spec_d, keep)
    if "min_range" in spec_d and "max_range" in spec_d:
        # a return within the message's float32 limits stays one when the limits are read as
        # the spec's float64 numbers (0.12 m in float32 is 0.1199999973 m)
        lo32, hi32 = np.float32(spec_d["min_range"]), np.float32(spec_d["max_range"])
        with np.errstate(invalid="ignore"):
            r32 = ranges.astype(np.float32)
            inside = np.isfinite(r32) & (r32 > 0) & (r32 >= lo32) & (r32 <= hi32)
        lims = float(spec_d["min_range"]), float(spec_d["max_range"])
        ranges = np.where(inside, np.clip(ranges, *lims), ranges)
    meta = {"source": source, **dict(metadata or {})}
    try:
        return Scan(
            ranges=ranges,
            valid=np.ones(ranges.shape, dtype=bool),
            beam_angles=beams,
            plane_angles=np.asarray(plane_angles, dtype=float),
            timestamps=t,
            positions=tpos,
            rotations=trot,
            nominal_positions=pos,
            nominal_rotations=rot,
            spec=spec_d,
            metadata=meta,
        )
    except ValueError as exc:
        raise ScanReadError(f"{source}: {exc}") from exc


def _restore_float64(
    beams: NDArray[np.float64],
    ranges: NDArray[np.float64],
    spec: Mapping[str, Any],
    keep: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Undo a LaserScan's float32 rounding where the spec says what the numbers were: beam
    angles that are the spec's (``fov``, ``beam_step``: a ``LidarSpec``'s beams) and ranges on
    its ``range_resolution`` grid (a sensor reporting whole millimetres), each to within the
    float32 rounding. ``beams`` are all the message's, ``ranges`` the kept ones."""
    fov, step = spec.get("fov"), spec.get("beam_step")
    if isinstance(fov, (int, float)) and isinstance(step, (int, float)) and step > 0:
        n = int(round(fov / step)) + (0 if fov >= 2 * math.pi - 1e-9 else 1)
        if n == beams.size:
            exact = -0.5 * (n - 1) * step + step * np.arange(n, dtype=np.float64)
            if np.all(np.abs(exact - beams) <= 1e-6):
                beams = exact
    res = spec.get("range_resolution")
    if isinstance(res, (int, float)) and res > 0:
        with np.errstate(invalid="ignore", over="ignore"):
            snapped = np.round(ranges / res) * res
            near = np.abs(snapped - ranges) <= 4.0 * float(np.finfo(np.float32).eps) * ranges
        ranges = np.where(np.isfinite(ranges) & near, snapped, ranges)
    return beams[keep], ranges


def _stamp(stamp: Any) -> float:
    # (the same rounding as a bag time in ns: stamps and bag times compare equal)
    return 1e-9 * (int(stamp.sec) * 10**9 + int(stamp.nanosec))


# ------------------------------------------------------------------------ reading
def read_scans(
    path: str | os.PathLike[str],
    *,
    scan_topic: str | None = None,
    servo_topic: str | None = None,
    servo_joint: str | None = None,
    odom_topic: str | None = None,
    truth_topic: str | None = None,
    tf_child: str | None = None,
    mount: Any = None,
    spec: Mapping[str, Any] | None = None,
    fov: float | None = None,
    servo_range: float | None = None,
    min_planes: int = 2,
) -> list[Scan]:
    """Every sweep recorded in ``path``, in time order.

    Formats (by the path): ``.npz`` (a :meth:`Scan.save` file or :func:`write_npz`'s
    sweeps), ``.csv`` (module docstring), a rosbag2 folder, ``.mcap`` or ``.db3`` (rosbag2
    storage files) and ``.bag`` (ROS 1).

    Bags hold ``sensor_msgs/msg/LaserScan`` on ``scan_topic`` and the servo angle (radians) on
    ``servo_topic`` as ``std_msgs/msg/Float64`` (timed by the bag's receive time) or
    ``sensor_msgs/msg/JointState`` (joint ``servo_joint``; timed by its header); optionally
    ``nav_msgs/msg/Odometry`` on ``odom_topic`` (the robot's believed base pose) or a
    ``tf2_msgs/msg/TFMessage`` topic (the transform whose child frame is ``tf_child``, else
    the first of each message), and on
    ``truth_topic`` the true sensor pose (simulation only). A topic left ``None`` is the one
    topic of its type (``DEFAULT_TOPICS`` among several). A ``std_msgs/msg/String`` on
    ``/lidar_spec`` (written by :func:`write_rosbag`) gives the sensor description as JSON;
    a ``std_msgs/msg/Float64`` on ``/clamped_diameter`` (m) the clamp encoders' reading,
    stored in each sweep's ``metadata["clamped_diameter"]`` (the last one before its end).
    Each LaserScan gets the servo angle at its header stamp, interpolated (one before the
    first or after the last servo reading is dropped); sweeps are cut
    where the servo reverses or jumps back (or exceeds ``servo_range``).

    Args:
        mount: ``(position, rotation)`` of the sensor frame in the odometry's base frame
            (default: the identity).
        spec: the sensor description (``LidarSpec`` fields as a dict) stored in each scan.
        fov: keep only beams within ``+-fov / 2`` rad.
        min_planes: sweeps with fewer planes (a partial sweep at the ends) are dropped.

    Raises:
        ScanReadError: (a ``ValueError``) naming the file, the topic and what was expected.
    """
    p = Path(path)
    if not p.exists():
        raise ScanReadError(f"{p}: no such file or folder")
    suffix = p.suffix.lower()
    if p.is_file() and suffix == ".npz":
        return _read_npz(p)
    if p.is_file() and suffix == ".csv":
        return _read_csv(p, spec=spec, fov=fov, servo_range=servo_range, min_planes=min_planes)
    if p.is_dir() or suffix in (".mcap", ".db3", ".bag"):
        return _read_bag(
            p,
            scan_topic=scan_topic,
            servo_topic=servo_topic,
            servo_joint=servo_joint,
            odom_topic=odom_topic,
            truth_topic=truth_topic,
            tf_child=tf_child,
            mount=mount,
            spec=spec,
            fov=fov,
            servo_range=servo_range,
            min_planes=min_planes,
        )
    raise ScanReadError(
        f"{p}: unknown format {suffix or '(no suffix)'!r}; expected .npz, .csv, a rosbag2 "
        "folder, .mcap, .db3 or .bag"
    )


def _read_npz(p: Path) -> list[Scan]:
    try:
        with np.load(p, allow_pickle=False) as z:
            if "n_sweeps" not in z.files:
                return [Scan.load(p)]
            version = int(z["sweeps_version"])
            if version != NPZ_SWEEPS_VERSION:
                raise ScanReadError(
                    f"{p}: sweeps_version {version}; this reads {NPZ_SWEEPS_VERSION}"
                )
            out = []
            for i in range(int(z["n_sweeps"])):
                arrays = {k: z[f"{i}/{k}"] for k in SCAN_ARRAYS}
                spec = json.loads(str(z[f"{i}/spec"]))
                meta = json.loads(str(z[f"{i}/metadata"]))
                out.append(Scan(**arrays, spec=spec, metadata=meta))
            return out
    except ScanReadError:
        raise
    except Exception as e:  # (zipfile, zlib, numpy, JSON: any broken file, named)
        raise ScanReadError(
            f"{p}: not a scan npz (expected the arrays {', '.join(SCAN_ARRAYS)}, the spec and "
            f"the metadata): {type(e).__name__}: {e}"
        ) from e


def _csv_lines(p: Path, spec: Mapping[str, Any] | None) -> tuple[dict[str, Any], list[str]]:
    """The spec (a ``# spec:`` comment's, under the given ``spec``) and the non-comment,
    non-blank lines of the CSV file ``p``."""
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ScanReadError(f"{p}: cannot be read as UTF-8 text ({e})") from e
    spec_d = dict(spec or {})
    lines = []
    for line in text.splitlines():
        if line.startswith("#"):
            body = line[1:].strip()
            if body.startswith("spec:"):
                try:
                    spec_d = {**json.loads(body[5:]), **spec_d}
                except json.JSONDecodeError as e:
                    raise ScanReadError(f"{p}: the '# spec:' line is not JSON ({e})") from e
            continue
        if line.strip():
            lines.append(line)
    return spec_d, lines


def _csv_columns(p: Path, lines: list[str]) -> dict[str, NDArray[np.float64]]:
    """The known columns of the CSV ``lines`` as arrays (one value per row), checked: the
    required columns present, every cell a number, the plane, beam, time and pose columns
    finite."""
    try:
        rows = list(csv.reader(lines))
    except csv.Error as e:
        raise ScanReadError(f"{p}: not CSV text ({e})") from e
    if not rows:
        raise ScanReadError(f"{p}: no header row; expected the columns {','.join(CSV_COLUMNS)}")
    header = [h.strip() for h in rows[0]]
    need = [c for c in CSV_COLUMNS if c != "sweep" and c not in header]
    if need:
        raise ScanReadError(
            f"{p}: missing column(s) {need}; expected {','.join(CSV_COLUMNS)} (sweep optional)"
            f"[,{','.join(CSV_POSE_COLUMNS)}], got {header}"
        )
    cols = [c for c in (*CSV_COLUMNS, *CSV_POSE_COLUMNS) if c in header]
    idx = {c: header.index(c) for c in cols}
    data = np.empty((len(rows) - 1, len(cols)))
    for n, row in enumerate(rows[1:]):
        for j, c in enumerate(cols):
            try:
                data[n, j] = float(row[idx[c]])
            except (IndexError, ValueError):
                value = row[idx[c]] if idx[c] < len(row) else "(missing)"
                raise ScanReadError(
                    f"{p}: row {n + 2}, column {c!r}: expected a number, got {value!r}"
                ) from None
    if data.shape[0] == 0:
        raise ScanReadError(f"{p}: no data rows")
    col = {c: data[:, j] for j, c in enumerate(cols)}
    has_pose = all(c in col for c in CSV_POSE_COLUMNS)
    for c in ("plane_angle", "beam_angle", "time", *(CSV_POSE_COLUMNS if has_pose else ())):
        bad = ~np.isfinite(col[c])
        if bad.any():
            n_bad = int(np.argmax(bad))
            raise ScanReadError(f"{p}: row {n_bad + 2}, column {c!r}: expected a finite number")
    return col


def _csv_planes(
    p: Path, col: Mapping[str, NDArray[np.float64]], sweep: NDArray[np.float64]
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The first row of each plane (a run of rows with the same sweep, plane angle and time)
    and the beam angles every plane must share."""
    key = np.stack([sweep, col["plane_angle"], col["time"]], axis=1)
    new_plane = np.r_[True, np.any(key[1:] != key[:-1], axis=1)]
    starts = np.flatnonzero(new_plane)
    ends = np.r_[starts[1:], sweep.size]
    n_b = int(ends[0] - starts[0])
    beams = col["beam_angle"][starts[0] : ends[0]]
    for s, stop in zip(starts, ends, strict=True):
        if stop - s != n_b or not np.array_equal(col["beam_angle"][s:stop], beams):
            raise ScanReadError(
                f"{p}: the plane starting at row {s + 2} has {stop - s} beams; expected the "
                f"same {n_b} beam angles as the first plane"
            )
    return starts, beams


def _csv_poses(
    col: Mapping[str, NDArray[np.float64]], starts: NDArray[np.intp]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per plane: sensor position (m) and rotation (world from sensor); the identity without
    the pose columns."""
    if not all(c in col for c in CSV_POSE_COLUMNS):
        return np.zeros((starts.size, 3)), np.tile(np.eye(3), (starts.size, 1, 1))
    pos = np.stack([col[c][starts] for c in ("x", "y", "z")], axis=1)
    quat = np.stack([col[c][starts] for c in ("qw", "qx", "qy", "qz")], axis=1)
    return pos, np.array([quat_to_matrix(q) for q in quat])


def _read_csv(
    p: Path,
    *,
    spec: Mapping[str, Any] | None,
    fov: float | None,
    servo_range: float | None,
    min_planes: int,
) -> list[Scan]:
    spec_d, lines = _csv_lines(p, spec)
    col = _csv_columns(p, lines)
    sweep = col.get("sweep", np.zeros(col["range"].size))
    starts, beams = _csv_planes(p, col, sweep)
    ranges = col["range"].reshape(-1, beams.size)
    plane_sweep = sweep[starts]
    plane_angle = col["plane_angle"][starts]
    times = col["time"][starts]
    pos, rot = _csv_poses(col, starts)
    if "sweep" in col:
        bounds = np.flatnonzero(np.r_[True, plane_sweep[1:] != plane_sweep[:-1], True])
        groups = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    else:
        groups = sweep_cuts(plane_angle, servo_range)
    keep = np.ones(beams.size, dtype=bool) if fov is None else np.abs(beams) <= 0.5 * fov + 1e-9
    out = []
    for g in groups:
        if g.stop - g.start < min_planes and len(groups) > 1:
            continue
        r = ranges[g][:, keep]
        try:
            out.append(
                Scan(
                    ranges=r,
                    valid=np.ones(r.shape, dtype=bool),
                    beam_angles=beams[keep],
                    plane_angles=plane_angle[g],
                    timestamps=times[g],
                    positions=pos[g],
                    rotations=rot[g],
                    nominal_positions=pos[g],
                    nominal_rotations=rot[g],
                    spec=spec_d,
                    metadata={"source": str(p)},
                )
            )
        except ValueError as e:
            raise ScanReadError(f"{p}: sweep starting at plane {g.start}: {e}") from e
    return out


def _pick_topic(
    p: Path, topics: Mapping[str, Any], types: Sequence[str], asked: str | None, role: str
) -> str | None:
    """The topic of ``role``: ``asked`` (checked), else the one topic of the types, else the
    default name among several; ``None`` when the bag has none."""
    found = sorted(t for t, info in topics.items() if info.msgtype in types)
    what = " or ".join(types)
    if asked is not None:
        if asked not in topics:
            raise ScanReadError(
                f"{p}: topic {asked!r} ({role}) is not in the bag; expected one of {what}: "
                f"{found or 'none in this bag'} (all topics: {sorted(topics)})"
            )
        if topics[asked].msgtype not in types:
            raise ScanReadError(
                f"{p}: topic {asked!r} ({role}) holds {topics[asked].msgtype}; expected {what}"
            )
        return asked
    if len(found) == 1:
        return found[0]
    if DEFAULT_TOPICS.get(role) in found:
        return DEFAULT_TOPICS[role]
    if len(found) > 1:
        raise ScanReadError(
            f"{p}: several {what} topics {found}; name the {role} topic ({role}_topic)"
        )
    return None


@dataclass
class _BagChoice:
    """The topics :func:`_read_bag` reads (``None``: absent)."""

    scan: str
    servo: str
    odom: str | None
    truth: str | None
    spec: str | None
    clamp: str | None

    def wanted(self) -> set[str]:
        return {
            t
            for t in (self.scan, self.servo, self.odom, self.truth, self.spec, self.clamp)
            if t is not None
        }


@dataclass
class _BagRecords:
    """What :func:`_read_bag` collects from the messages, each list as ``(time s, ...)``."""

    scans: list[tuple[float, Any]] = field(default_factory=list)
    servo: list[tuple[float, float]] = field(default_factory=list)
    odom: list[tuple[float, NDArray, NDArray]] = field(default_factory=list)
    truth: list[tuple[float, NDArray, NDArray]] = field(default_factory=list)
    clamp: list[tuple[float, float]] = field(default_factory=list)
    spec: dict[str, Any] = field(default_factory=dict)


def _bag_choice(
    p: Path,
    topics: Mapping[str, Any],
    scan_topic: str | None,
    servo_topic: str | None,
    odom_topic: str | None,
    truth_topic: str | None,
) -> _BagChoice:
    """The topics to read: asked for (checked) or found by type (see :func:`read_scans`)."""
    s_topic = _pick_topic(p, topics, (LASERSCAN,), scan_topic, "scan")
    if s_topic is None:
        raise ScanReadError(f"{p}: no {LASERSCAN} topic; the bag has {_describe(topics)}")
    v_topic = _pick_topic(p, topics, SERVO_TYPES, servo_topic, "servo")
    if v_topic is None:
        raise ScanReadError(
            f"{p}: no servo angle topic ({' or '.join(SERVO_TYPES)}, radians); the bag "
            f"has {_describe(topics)}"
        )
    o_topic = _pick_topic(p, topics, (ODOMETRY, TFMESSAGE), odom_topic, "odom")
    t_topic = truth_topic
    if t_topic is None and DEFAULT_TOPICS["truth"] in topics:
        t_topic = DEFAULT_TOPICS["truth"]
    if t_topic is not None:
        t_topic = _pick_topic(p, topics, (ODOMETRY,), t_topic, "truth")
    if o_topic == t_topic:
        o_topic = _pick_topic(
            p, {k: v for k, v in topics.items() if k != t_topic}, (ODOMETRY,), None, "odom"
        )

    def optional(name: str, msgtype: str) -> str | None:
        topic = DEFAULT_TOPICS[name]
        return topic if topic in topics and topics[topic].msgtype == msgtype else None

    return _BagChoice(
        s_topic, v_topic, o_topic, t_topic, optional("spec", STRING), optional("clamp", FLOAT64)
    )


def _bag_record(
    p: Path,
    ch: _BagChoice,
    rec: _BagRecords,
    topic: str,
    msg: Any,
    t_bag: float,
    servo_joint: str | None,
    tf_child: str | None,
) -> None:
    """File one deserialised message of ``topic`` (received at ``t_bag``, s) into ``rec``."""
    if topic == ch.scan:
        st = _stamp(msg.header.stamp)
        rec.scans.append((st if st > 0.0 else t_bag, msg))
    elif topic == ch.servo:
        rec.servo.append(_servo_value(p, ch.servo, msg, t_bag, servo_joint))
    elif topic == ch.clamp:
        rec.clamp.append((t_bag, float(msg.data)))
    elif topic == ch.spec:
        try:
            rec.spec = dict(json.loads(msg.data))
        except (json.JSONDecodeError, TypeError, ValueError) as e:
            raise ScanReadError(
                f"{p}: topic {ch.spec!r}: expected the sensor spec as a JSON object, got "
                f"{msg.data[:80]!r}"
            ) from e
    elif topic in (ch.odom, ch.truth):
        pose = _pose_of(msg, t_bag, tf_child)
        if pose is not None:
            (rec.odom if topic == ch.odom else rec.truth).append(pose)


def _bag_records(
    p: Path,
    *,
    scan_topic: str | None,
    servo_topic: str | None,
    servo_joint: str | None,
    odom_topic: str | None,
    truth_topic: str | None,
    tf_child: str | None,
) -> tuple[_BagChoice, _BagRecords]:
    """The chosen topics of the bag ``p`` and their messages."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if p.suffix == ".bag" else Stores.ROS2_HUMBLE)
    rec = _BagRecords()
    try:
        with AnyReader([p], default_typestore=store) as reader:
            ch = _bag_choice(p, reader.topics, scan_topic, servo_topic, odom_topic, truth_topic)
            wanted = ch.wanted()
            conns = [c for c in reader.connections if c.topic in wanted]
            for conn, t_bag, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                _bag_record(p, ch, rec, conn.topic, msg, 1e-9 * t_bag, servo_joint, tf_child)
    except ScanReadError:
        raise
    except Exception as e:  # (rosbags, sqlite3, mcap, struct: any broken bag, named)
        raise ScanReadError(f"{p}: cannot be read as a ROS bag ({type(e).__name__}: {e})") from e
    if not rec.scans:
        raise ScanReadError(f"{p}: topic {ch.scan!r} holds no LaserScan messages")
    if not rec.servo:
        raise ScanReadError(f"{p}: topic {ch.servo!r} holds no servo angles")
    return ch, rec


def _plane_angles(
    p: Path, ch: _BagChoice, rec: _BagRecords
) -> tuple[list[tuple[float, Any]], NDArray[np.float64], NDArray[np.float64]]:
    """The LaserScans within the servo readings' time span, in time order, with their times
    (s) and servo angles (rad, interpolated at each scan's time)."""
    scans_raw = sorted(rec.scans, key=lambda x: x[0])
    servo = sorted(rec.servo)
    sv_t = np.array([t for t, _ in servo])
    sv_a = np.array([a for _, a in servo])
    # a LaserScan outside the servo readings' time span has no known plane: it is dropped
    scans_raw = [(t, m) for t, m in scans_raw if sv_t[0] <= t <= sv_t[-1]]
    if not scans_raw:
        raise ScanReadError(
            f"{p}: no LaserScan on {ch.scan!r} lies within the servo readings on {ch.servo!r} "
            f"({sv_t[0]:.3f} to {sv_t[-1]:.3f} s); expected both recorded together"
        )
    t_scan = np.array([t for t, _ in scans_raw])
    angles = np.interp(t_scan, sv_t, sv_a)
    # (a servo reading at a scan's own stamp is its angle exactly; np.interp may round it)
    at = np.clip(np.searchsorted(sv_t, t_scan), 0, sv_t.size - 1)
    angles = np.where(sv_t[at] == t_scan, sv_a[at], angles)
    return scans_raw, t_scan, angles


def _read_bag(
    p: Path,
    *,
    scan_topic: str | None,
    servo_topic: str | None,
    servo_joint: str | None,
    odom_topic: str | None,
    truth_topic: str | None,
    tf_child: str | None,
    mount: Any,
    spec: Mapping[str, Any] | None,
    fov: float | None,
    servo_range: float | None,
    min_planes: int,
) -> list[Scan]:
    mount_p, mount_r = _mount(mount)
    ch, rec = _bag_records(
        p,
        scan_topic=scan_topic,
        servo_topic=servo_topic,
        servo_joint=servo_joint,
        odom_topic=odom_topic,
        truth_topic=truth_topic,
        tf_child=tf_child,
    )
    scans_raw, t_scan, angles = _plane_angles(p, ch, rec)
    believed = _poses_at(t_scan, rec.odom, mount_p, mount_r)
    true = _poses_at(t_scan, rec.truth, np.zeros(3), np.eye(3)) if rec.truth else believed
    out = []
    clamp = sorted(rec.clamp)
    cuts = sweep_cuts(angles, servo_range)
    for g in cuts:
        if g.stop - g.start < min_planes and len(cuts) > 1:
            continue
        extra: dict[str, Any] = {}
        # the clamped diameter read last before the sweep ended (the encoders at this stop)
        before = [d for t, d in clamp if t <= t_scan[g.stop - 1] + 1e-9]
        if before:
            extra["clamped_diameter"] = before[-1]
        out.append(
            scan_from_laserscans(
                [m for _, m in scans_raw[g]],
                angles[g],
                timestamps=t_scan[g],
                positions=believed[0][g],
                rotations=believed[1][g],
                true_positions=true[0][g],
                true_rotations=true[1][g],
                spec={**rec.spec, **dict(spec or {})},
                fov=fov,
                metadata={"topics": [ch.scan, ch.servo, ch.odom, ch.truth], **extra},
                source=f"{p} topic {ch.scan!r}",
            )
        )
    return out


def _describe(topics: Mapping[str, Any]) -> str:
    return ", ".join(f"{t} ({i.msgtype})" for t, i in sorted(topics.items())) or "no topics"


def _servo_value(p: Path, topic: str, msg: Any, t_bag: float, joint: str | None) -> tuple:
    if hasattr(msg, "position") and hasattr(msg, "name"):  # JointState
        names = list(msg.name)
        if joint is None:
            if len(names) != 1:
                raise ScanReadError(
                    f"{p}: topic {topic!r} is a JointState of joints {names}; name the servo "
                    "joint (servo_joint)"
                )
            k = 0
        elif joint in names:
            k = names.index(joint)
        else:
            raise ScanReadError(f"{p}: topic {topic!r} has no joint {joint!r}; it has {names}")
        st = _stamp(msg.header.stamp)
        return (st if st > 0.0 else t_bag, float(msg.position[k]))
    value = float(msg.data)
    if not math.isfinite(value):
        raise ScanReadError(f"{p}: topic {topic!r}: expected finite servo angles, got {value}")
    return (t_bag, value)


def _pose_of(
    msg: Any, t_bag: float, tf_child: str | None = None
) -> tuple[float, NDArray, NDArray] | None:
    if hasattr(msg, "transforms"):  # TFMessage: the transform to tf_child (else its first)
        found = [t for t in msg.transforms if tf_child is None or t.child_frame_id == tf_child]
        if not found:
            return None
        tf = found[0]
        st = _stamp(tf.header.stamp)
        tr, q = tf.transform.translation, tf.transform.rotation
    else:  # Odometry
        st = _stamp(msg.header.stamp)
        tr, q = msg.pose.pose.position, msg.pose.pose.orientation
    return (
        st if st > 0.0 else t_bag,
        np.array([tr.x, tr.y, tr.z], dtype=float),
        np.array([q.w, q.x, q.y, q.z], dtype=float),
    )


def _poses_at(
    t: NDArray[np.float64],
    poses: list[tuple[float, NDArray, NDArray]],
    mount_p: NDArray[np.float64],
    mount_r: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World-from-sensor poses at ``t``: the base poses (interpolated) composed with the
    mount; the mount alone without poses."""
    if not poses:
        return np.tile(mount_p, (t.size, 1)), np.tile(mount_r, (t.size, 1, 1))
    poses = sorted(poses, key=lambda x: x[0])
    times = np.array([x[0] for x in poses])
    pos, rot = _interp_poses(
        t, times, np.array([x[1] for x in poses]), np.array([x[2] for x in poses])
    )
    return pos + rot @ mount_p, rot @ mount_r


# ------------------------------------------------------------------------ writing
@contextlib.contextmanager
def _atomic_path(target: Path) -> Iterator[Path]:
    """A fresh temporary path beside ``target`` for a writer that needs a path (a bag folder
    or file); on a clean exit it replaces ``target`` (a folder is renamed into place, an old
    one moved aside first), else it is removed."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    tmp = tmp_dir / target.name
    try:
        yield tmp
        for f in [tmp] if tmp.is_file() else sorted(tmp.rglob("*")):
            if f.is_file():
                with open(f, "rb") as h:
                    os.fsync(h.fileno())
        old = None
        if target.is_dir():
            old = tmp_dir / ".old"
            os.replace(target, old)
        os.replace(tmp, target)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def write_rosbag(
    scans: Sequence[Scan],
    path: str | os.PathLike[str],
    *,
    storage: str = "sqlite3",
    scan_topic: str = DEFAULT_TOPICS["scan"],
    servo_topic: str = DEFAULT_TOPICS["servo"],
    odom_topic: str = DEFAULT_TOPICS["odom"],
    truth_topic: str | None = DEFAULT_TOPICS["truth"],
    frame_id: str = "laser",
    odom_frame: str = "odom",
    t_offset: float = 0.0,
) -> Path:
    """Write sweeps as a ROS bag (the inverse of :func:`read_scans`), atomically.

    Each plane becomes a ``sensor_msgs/msg/LaserScan`` on ``scan_topic`` (no returns as
    ``+inf``; ``range_min``/``range_max`` from the spec), its servo angle a
    ``std_msgs/msg/Float64`` on ``servo_topic`` at the same time, the believed (nominal) sensor
    pose a ``nav_msgs/msg/Odometry`` on ``odom_topic`` and, with ``truth_topic``, the true one;
    the spec as JSON on ``/lidar_spec`` and a sweep's ``metadata["clamped_diameter"]`` (m) on
    ``/clamped_diameter`` at its first plane.
    Bag times equal the header stamps: the planes' timestamps plus ``t_offset`` s (ROS time
    must be >= 0).

    Args:
        path: a folder for rosbag2 (``storage`` ``"sqlite3"`` or ``"mcap"``), or a ``.bag``
            file for ROS 1. An existing bag at ``path`` is replaced.

    Returns:
        The path written.
    """
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    target = Path(path)
    ros1 = target.suffix == ".bag"
    if storage not in ("sqlite3", "mcap"):
        raise ValueError(f"storage must be 'sqlite3' or 'mcap', got {storage!r}")
    if not scans:
        raise ValueError(f"{target}: no scans to write")
    t_min = min(float(s.timestamps.min()) for s in scans) + t_offset
    if t_min < 0.0:
        raise ValueError(f"{target}: scan times + t_offset must be >= 0 s, got {t_min} s")
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    ty = store.types
    header_kw: dict[str, Any] = {"seq": 0} if ros1 else {}
    time_t = ty["builtin_interfaces/msg/Time"]

    def header(t: float, frame: str) -> Any:
        ns = _ns(t)
        return ty["std_msgs/msg/Header"](
            **header_kw, stamp=time_t(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame
        )

    def odometry(t: float, pos: NDArray, rot: NDArray) -> Any:
        q = matrix_to_quat(rot)
        pose = ty["geometry_msgs/msg/Pose"](
            position=ty["geometry_msgs/msg/Point"](x=pos[0], y=pos[1], z=pos[2]),
            orientation=ty["geometry_msgs/msg/Quaternion"](x=q[1], y=q[2], z=q[3], w=q[0]),
        )
        zero3 = ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        return ty[ODOMETRY](
            header=header(t, odom_frame),
            child_frame_id=frame_id,
            pose=ty["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=ty["geometry_msgs/msg/TwistWithCovariance"](
                twist=ty["geometry_msgs/msg/Twist"](linear=zero3, angular=zero3),
                covariance=np.zeros(36),
            ),
        )

    ser = store.serialize_ros1 if ros1 else store.serialize_cdr
    with _atomic_path(target) as tmp:
        if ros1:
            writer: Any = Writer1(tmp)
        else:
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            writer = Writer2(tmp, version=9, storage_plugin=plugin)
        with writer:
            c_scan = writer.add_connection(scan_topic, LASERSCAN, typestore=store)
            c_servo = writer.add_connection(servo_topic, FLOAT64, typestore=store)
            c_odom = writer.add_connection(odom_topic, ODOMETRY, typestore=store)
            c_truth = (
                writer.add_connection(truth_topic, ODOMETRY, typestore=store)
                if truth_topic
                else None
            )
            c_clamp = None
            if any("clamped_diameter" in sc.metadata for sc in scans):
                c_clamp = writer.add_connection(DEFAULT_TOPICS["clamp"], FLOAT64, typestore=store)
            c_spec = writer.add_connection(DEFAULT_TOPICS["spec"], STRING, typestore=store)
            text = json.dumps(scans[0].spec, default=_plain)
            writer.write(c_spec, _ns(t_min), ser(ty[STRING](data=text), STRING))
            for scan in scans:
                if c_clamp is not None and "clamped_diameter" in scan.metadata:
                    d = float(scan.metadata["clamped_diameter"])
                    t0 = _ns(float(scan.timestamps[0]) + t_offset)
                    writer.write(c_clamp, t0, ser(ty[FLOAT64](data=d), FLOAT64))
                beams = scan.beam_angles
                inc = float(beams[1] - beams[0]) if beams.size > 1 else 0.0
                lo = float(scan.spec.get("min_range", 0.0))
                hi = float(scan.spec.get("max_range", 1000.0))
                period = float(np.median(np.diff(scan.timestamps))) if scan.n_planes > 1 else 0.0
                for k in range(scan.n_planes):
                    t = float(scan.timestamps[k]) + t_offset
                    ns = _ns(t)
                    msg = ty[LASERSCAN](
                        header=header(t, frame_id),
                        angle_min=float(beams[0]),
                        angle_max=float(beams[-1]),
                        angle_increment=inc,
                        time_increment=0.0,
                        scan_time=period,
                        range_min=lo,
                        range_max=hi,
                        ranges=np.where(scan.valid[k], scan.ranges[k], np.inf).astype(np.float32),
                        intensities=np.zeros(0, dtype=np.float32),
                    )
                    writer.write(
                        c_servo, ns, ser(ty[FLOAT64](data=float(scan.plane_angles[k])), FLOAT64)
                    )
                    writer.write(
                        c_odom,
                        ns,
                        ser(
                            odometry(t, scan.nominal_positions[k], scan.nominal_rotations[k]),
                            ODOMETRY,
                        ),
                    )
                    if c_truth is not None:
                        writer.write(
                            c_truth,
                            ns,
                            ser(odometry(t, scan.positions[k], scan.rotations[k]), ODOMETRY),
                        )
                    writer.write(c_scan, ns, ser(msg, LASERSCAN))
    return target


def write_npz(scans: Sequence[Scan], path: str | os.PathLike[str]) -> Path:
    """Write sweeps to one ``.npz`` (atomically); :func:`read_scans` reads it back."""
    target = Path(path)
    arrays: dict[str, Any] = {
        "sweeps_version": np.array(NPZ_SWEEPS_VERSION),
        "n_sweeps": np.array(len(scans)),
    }
    for i, s in enumerate(scans):
        for k in SCAN_ARRAYS:
            arrays[f"{i}/{k}"] = getattr(s, k)
        arrays[f"{i}/spec"] = np.array(json.dumps(s.spec))
        arrays[f"{i}/metadata"] = np.array(json.dumps(s.metadata, default=_plain))
    with atomic_open(target, "wb") as handle:
        np.savez_compressed(handle, **arrays)
    return target


def write_csv(scans: Sequence[Scan], path: str | os.PathLike[str], poses: bool = True) -> Path:
    """Write sweeps in the CSV layout of the module docstring (atomically): one row per beam,
    no returns as ``inf``, the believed (nominal) sensor poses when ``poses``, the first
    sweep's spec on a ``# spec:`` line."""
    target = Path(path)
    buf = _io.StringIO()
    buf.write("# pipenav scans: one row per beam; angles rad, ranges m, times s\n")
    if scans:
        buf.write(f"# spec: {json.dumps(scans[0].spec, default=_plain)}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*CSV_COLUMNS, *(CSV_POSE_COLUMNS if poses else ())])
    for i, s in enumerate(scans):
        for k in range(s.n_planes):
            extra: list[str] = []
            if poses:
                q = matrix_to_quat(s.nominal_rotations[k])
                extra = [repr(float(v)) for v in (*s.nominal_positions[k], *q)]
            a, t = repr(float(s.plane_angles[k])), repr(float(s.timestamps[k]))
            for b in range(s.n_beams):
                r = float(s.ranges[k, b]) if s.valid[k, b] else math.inf
                w.writerow([i, a, repr(float(s.beam_angles[b])), repr(r), t, *extra])
    atomic_write_text(target, buf.getvalue())
    return target


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)
