"""The data commands of ``pipenav``: recorded sweeps in, simulated sweeps and worlds out.

- ``detect PATH``: runs the detector on recorded sweeps (npz, CSV, rosbag2 folder, ``.mcap``,
  ROS 1 ``.bag``; :func:`detector.io.read_scans`) and, for a sequence of sweeps, the fusion
  (:class:`detector.fusion.StructureTracker`) with the recorded sensor poses, exactly as the
  full-fidelity robot fuses them live; prints the options as the operator console does.
- ``record OUT``: drives the simulated robot (full fidelity: MuJoCo robot, rotating LiDAR,
  stop-and-scan) from the start of a layout or network until the structure ahead is
  confirmed, and writes every sweep to a rosbag2 (or ``.mcap`` / ``.bag`` / ``.npz``), with
  the ground truth and the live detections beside it (``OUT.truth.json``).
- ``export NETWORK``: the pipe walls as a watertight mesh (STL/OBJ/GLB/PLY) and the MuJoCo
  world as MJCF (:mod:`pipe_env.export`), with or without the robot.

:func:`add_commands` registers them on the ``pipenav`` parser.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from detector.atomic import atomic_write_text

EXIT_USAGE = 2
#: The recorder stops once a confirmed structure's reference point is this near, m (the
#: full-fidelity plant's default trigger distance).
TRIGGER_DISTANCE = 0.2


def _print(*args: Any) -> None:
    print(*args, flush=True)


def _error(text: str) -> int:
    _print(f"error: {text}")
    return EXIT_USAGE


# ---------------------------------------------------------------------------- detect
def options_table(title: str, detection: Any, caption: str = "") -> Any:
    """A rich table of a detection's options (the operator console's columns)."""
    from rich.table import Table

    from detector.options import direction_name

    t = Table(title=title, caption=caption or None)
    for col in ("way", "angle", "direction", "distance", "diameter", "confidence"):
        t.add_column(col)
    for o in detection.options:
        t.add_row(
            o.kind,
            f"{math.degrees(o.angle):.0f} deg",
            "-" if o.is_straight_on else direction_name(o.direction),
            f"{o.distance * 100:.1f} cm",
            f"{o.diameter * 1000:.0f} mm",
            f"{o.confidence:.2f}",
        )
    return t


@dataclass
class DetectResult:
    """What ``pipenav detect`` found: one detection per sweep and the fused one."""

    sweeps: list[dict[str, Any]] = field(default_factory=list)
    fused: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"sweeps": self.sweeps, "fused": self.fused}


def detect_sweeps(
    scans: list[Any], clamped_diameter: float | None = None, method: str = "improved"
) -> DetectResult:
    """Detect every sweep and fuse them in order with their believed poses (the last plane's,
    as the live robot does).

    Args:
        scans: the sweeps.
        clamped_diameter: m; default: each sweep's recorded ``metadata["clamped_diameter"]``.
        method: the detector method.
    """
    from detector import StructureTracker, detect

    tracker = StructureTracker()
    out = DetectResult()
    state = None
    for i, scan in enumerate(scans):
        d = (
            clamped_diameter
            if clamped_diameter is not None
            else scan.metadata.get("clamped_diameter")
        )
        if d is None:
            raise ValueError(
                f"sweep {i} has no recorded clamped diameter; give --clamped-diameter (m)"
            )
        det = detect(scan, float(d), method)
        state = tracker.update(det, scan.nominal_positions[-1], scan.nominal_rotations[-1])
        out.sweeps.append(
            {
                "index": i,
                "time_s": float(scan.timestamps[-1]),
                "clamped_diameter_m": float(d),
                "returns": scan.n_valid,
                "no_returns": scan.no_returns,
                "detection": det.to_dict(),
                "track": {
                    "confirmed": state.confirmed,
                    "confidence": state.confidence,
                    "detection": state.detection.to_dict(),
                },
            }
        )
    if state is not None:
        out.fused = {
            "confirmed": state.confirmed,
            "confidence": state.confidence,
            "detection": state.detection.to_dict(),
        }
    return out


def _detect(args: argparse.Namespace) -> int:
    from rich.console import Console

    from detector.io import read_scans

    kwargs: dict[str, Any] = {
        "scan_topic": args.scan_topic,
        "servo_topic": args.servo_topic,
        "servo_joint": args.servo_joint,
        "odom_topic": args.odom_topic,
        "fov": math.radians(args.fov) if args.fov is not None else None,
    }
    if args.lidar is not None:
        from pipe_env.lidar import get_preset

        kwargs["spec"] = get_preset(args.lidar).to_dict()
    try:
        scans = read_scans(args.path, **kwargs)
    except ValueError as exc:
        return _error(str(exc))
    if not scans:
        return _error(f"{args.path}: no sweeps found")
    for name in ("json", "plot"):
        target = getattr(args, name)
        if target is not None and Path(target).is_dir():
            return _error(f"--{name} {target!r} is a folder; give a file name")
    try:
        result = detect_sweeps(scans, args.clamped_diameter, args.method)
    except ValueError as exc:
        return _error(f"{args.path}: {exc}")
    console = Console()
    for s in result.sweeps:
        text = _detection_of(s["detection"]).describe().splitlines()[0]
        track = s["track"]
        mark = "confirmed" if track["confirmed"] else "tentative"
        _print(
            f"sweep {s['index']:3d}  t={s['time_s']:8.2f} s  {s['returns']:6d} returns  "
            f"{text}  | fused: {track['detection']['kind']} ({mark})"
        )
    fused = result.fused
    assert fused is not None
    # one sweep: its own detection; several: the fusion (the tracker's confidences)
    last = _detection_of(result.sweeps[-1]["detection"] if len(scans) == 1 else fused["detection"])
    title = (
        f"structure ahead: {last.kind}"
        + ("" if len(scans) == 1 else f" (fused over {len(scans)} sweeps, ")
        + ("" if len(scans) == 1 else ("confirmed)" if fused["confirmed"] else "not confirmed)"))
    )
    d0 = result.sweeps[-1]["clamped_diameter_m"]
    console.print(options_table(title, last, f"clamped diameter {d0 * 1000:.0f} mm"))
    if args.json:
        atomic_write_text(args.json, json.dumps(result.to_dict(), indent=2, allow_nan=False))
        _print(f"wrote {args.json}")
    if args.plot:
        _plot_scan(scans[-1], last, args.plot)
        _print(f"wrote {args.plot}")
    return 0


def _detection_of(d: dict[str, Any]) -> Any:
    from detector.detection import Detection
    from detector.options import StructureOption

    return Detection(
        d["kind"], [StructureOption.from_dict(o) for o in d["options"]], d["confidence"], {}
    )


def _plot_scan(scan: Any, detection: Any, path: str) -> None:
    """The sweep's returns (sensor frame; side and top views) with the options' reference
    points, written atomically as PNG."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from detector.atomic import atomic_write_bytes

    pts = scan.points("sensor")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, (j, name) in zip(axes, ((1, "y left"), (2, "z up")), strict=True):
        ax.scatter(pts[:, 0], pts[:, j], s=0.5, c="0.3")
        for o in detection.options:
            ax.axvline(o.distance, color="tab:red", lw=1)
        ax.set_xlabel("x forward [m]")
        ax.set_ylabel(f"{name} [m]")
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"{scan.n_valid} returns; {detection.kind}: red lines = reference points")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


# ---------------------------------------------------------------------------- record
@dataclass
class Recording:
    """A recorded drive: the sweeps (each with its ``metadata["clamped_diameter"]``) and, per
    sweep, the ground truth and the live detection and fused state."""

    scans: list[Any]
    sweeps: list[dict[str, Any]]
    fused: dict[str, Any] | None
    network: Any
    info: dict[str, Any]


def record_drive(
    network: Any,
    *,
    lidar: str = "ydlidar_x4",
    seed: int = 0,
    method: str = "improved",
    scan_interval: float = 0.05,
    max_distance: float = 2.0,
    backend: str = "analytic",
) -> Recording:
    """Drive the simulated robot from the network's start, sweeping every ``scan_interval`` m
    (stop and scan), detecting and fusing live as the full-fidelity plant does, until a
    structure is confirmed within ``TRIGGER_DISTANCE`` or ``max_distance`` m are driven."""
    import numpy as np

    from detector import StructureTracker, detect
    from primitives.executor import Executor

    ex = Executor.for_network(network, lidar=lidar, backend=backend)
    start = network.start_pose
    ex.place(start, float(network.inner_diameter_at(start.position)))
    tracker = StructureTracker()
    scans: list[Any] = []
    sweeps: list[dict[str, Any]] = []
    last: dict[str, Any] = {}

    def on_scan(scan: Any, state: Any) -> str:
        d = float(state.clamped_diameter)
        scan = replace(scan, metadata={**scan.metadata, "clamped_diameter": d})
        det = detect(scan, d, method)
        track = tracker.update(det, scan.nominal_positions[-1], scan.nominal_rotations[-1])
        pose = ex.robot.sensor_pose()
        truth = network.structures_ahead(pose)
        scans.append(scan)
        last["track"] = track
        sweeps.append(
            {
                "index": len(sweeps),
                "time_s": float(scan.timestamps[-1]),
                "clamped_diameter_m": d,
                "true_sensor_position_m": pose.position.tolist(),
                "truth": [o.to_dict() for o in truth],
                "detection": det.to_dict(),
                "track": {
                    "confirmed": track.confirmed,
                    "confidence": track.confidence,
                    "detection": track.detection.to_dict(),
                },
            }
        )
        if track.confirmed and track.detection.options:
            if min(o.distance for o in track.detection.options) <= TRIGGER_DISTANCE + 0.5 * (
                scan_interval
            ):
                return "stop"
        return "continue"

    outcome = ex.drive_until(
        on_scan, max_distance, scan_interval=scan_interval, rng=np.random.default_rng(seed)
    )
    track = last.get("track")
    fused = None
    if track is not None:
        fused = {
            "confirmed": track.confirmed,
            "confidence": track.confidence,
            "detection": track.detection.to_dict(),
        }
    info = {
        "lidar": lidar,
        "seed": seed,
        "method": method,
        "scan_interval_m": scan_interval,
        "backend": backend,
        "outcome": outcome.status,
        "reason": outcome.reason,
    }
    return Recording(scans, sweeps, fused, network, info)


def write_recording(rec: Recording, out: str | Path) -> tuple[Path, Path]:
    """Write the sweeps (format by ``out``: a folder name for rosbag2, ``.mcap``: rosbag2 in
    MCAP storage, ``.bag``: ROS 1, ``.npz``) and ``<out>.truth.json`` beside them."""
    from detector.io import write_npz, write_rosbag

    target = Path(out)
    if target.suffix == ".npz":
        write_npz(rec.scans, target)
    elif target.suffix == ".mcap":
        target = target.with_suffix("")
        write_rosbag(rec.scans, target, storage="mcap")
    else:
        write_rosbag(rec.scans, target)
    truth = target.with_name(target.name + ".truth.json")
    doc = {
        "network": rec.network.to_dict(),
        **rec.info,
        "sweeps": rec.sweeps,
        "fused": rec.fused,
    }
    atomic_write_text(truth, json.dumps(doc, indent=2, allow_nan=False))
    return target, truth


def _network_from(args: argparse.Namespace) -> Any:
    from pipe_env.layouts import make_layout
    from pipe_env.network import PipeNetwork

    if args.network:
        return PipeNetwork.load(args.network)
    params = json.loads(args.params)
    if not isinstance(params, dict):
        raise ValueError(f"--params must be a JSON object, got {args.params!r}")
    return make_layout(args.layout, **params)


def _record(args: argparse.Namespace) -> int:
    try:
        network = _network_from(args)
    except (ValueError, OSError, json.JSONDecodeError) as exc:
        return _error(str(exc))
    if Path(args.out).is_file() and Path(args.out).suffix not in (".npz", ".bag"):
        return _error(f"OUT {args.out!r} is a file; a rosbag2 is a folder")
    rec = record_drive(
        network,
        lidar=args.lidar,
        seed=args.seed,
        method=args.method,
        scan_interval=args.scan_interval,
        max_distance=args.max_distance,
        backend=args.backend,
    )
    target, truth = write_recording(rec, args.out)
    fused = rec.fused or {}
    kind = fused.get("detection", {}).get("kind", "-")
    _print(
        f"recorded {len(rec.scans)} sweeps ({rec.info['outcome']}: {rec.info['reason']}); "
        f"live fused detection: {kind} ({'confirmed' if fused.get('confirmed') else 'tentative'})"
    )
    _print(f"wrote {target} and {truth}")
    return 0


# ---------------------------------------------------------------------------- export
def _export(args: argparse.Namespace) -> int:
    from pipe_env.export import MESH_FORMATS, export_mesh, export_mjcf, mesh_report

    if not any((args.stl, args.obj, args.glb, args.mjcf)):
        return _error("nothing to write; give at least one of --stl, --obj, --glb, --mjcf")
    try:
        network = _network_from(args)
        network.validate()
    except (ValueError, OSError, json.JSONDecodeError) as exc:
        return _error(str(exc))
    for option, suffix in (("stl", ".stl"), ("obj", ".obj"), ("glb", ".glb")):
        path = getattr(args, option)
        if path is None:
            continue
        if Path(path).suffix.lower() != suffix:
            return _error(f"--{option} {path!r}: expected a {suffix} file name")
        assert suffix in MESH_FORMATS
        export_mesh(network, path)
        rep = mesh_report(path)
        _print(
            f"wrote {path}: {rep['triangles']} triangles, "
            f"{'watertight' if rep['watertight'] else 'NOT watertight'}"
        )
    if args.mjcf:
        if args.robot:
            from primitives.executor import Executor

            ex = Executor.for_network(network, lidar=None)
            start = network.start_pose
            ex.place(start, float(network.inner_diameter_at(start.position)))
            d = ex.world.data
            key = {
                "qpos": d.qpos,
                "qvel": d.qvel,
                "mocap_pos": d.mocap_pos,
                "mocap_quat": d.mocap_quat,
            }
            export_mjcf(ex.world, args.mjcf, keyframe=key)
        else:
            export_mjcf(network, args.mjcf, contact_walls=not args.no_contact_walls)
        _print(f"wrote {args.mjcf} (open it with: python -m mujoco.viewer --mjcf {args.mjcf})")
    return 0


# ---------------------------------------------------------------------------- parsers
def add_detector_options(p: argparse.ArgumentParser, json_what: str | None = None) -> None:
    """Add ``--method`` (the detector method) and, if ``json_what`` says what is written,
    ``--json`` (a JSON file to write it to) to ``p``."""
    from detector.api import METHODS
    from detector.vocab import Method

    p.add_argument(
        "--method",
        default=Method.IMPROVED.value,
        choices=sorted(METHODS),
        help="detector method (default: %(default)s)",
    )
    if json_what is not None:
        p.add_argument(
            "--json", default=None, help=f"write {json_what} as JSON here (default: none)"
        )


def add_commands(sub: Any) -> None:
    """Register ``detect``, ``record`` and ``export`` on the ``pipenav`` subparsers."""
    from pipe_env.layouts import LAYOUTS
    from pipe_env.lidar import BACKENDS, PRESETS

    de = sub.add_parser("detect", help="detect structures in recorded sweeps")
    de.add_argument("path", help="npz, CSV, rosbag2 folder, .mcap or ROS 1 .bag")
    de.add_argument(
        "--clamped-diameter",
        type=float,
        default=None,
        help="inner diameter of the pipe the robot is clamped in, m (default: the recorded "
        "/clamped_diameter)",
    )
    add_detector_options(de, json_what="every sweep's detection and the fusion")
    de.add_argument(
        "--plot", default=None, help="write a PNG of the last sweep here (default: none)"
    )
    de.add_argument("--scan-topic", default=None, help="LaserScan topic (default: the only one)")
    de.add_argument(
        "--servo-topic", default=None, help="servo angle topic, rad (default: the only one)"
    )
    de.add_argument(
        "--servo-joint",
        default=None,
        help="joint of a JointState servo topic (default: the only one)",
    )
    de.add_argument(
        "--odom-topic", default=None, help="Odometry or TF topic (default: the only one)"
    )
    de.add_argument(
        "--fov", type=float, default=None, help="keep beams within +-fov/2, deg (default: all)"
    )
    de.add_argument(
        "--lidar",
        default=None,
        choices=sorted(PRESETS),
        help="sensor preset for the noise model (default: the recorded spec)",
    )
    de.set_defaults(func=_detect)

    def network_options(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--layout",
            default="t_junction",
            choices=sorted(LAYOUTS),
            help="canonical layout when no network file is given (default: %(default)s)",
        )
        p.add_argument(
            "--params", default="{}", help="layout parameters as JSON (default: %(default)s)"
        )

    re_ = sub.add_parser(
        "record",
        help="record simulated sweeps while driving into a rosbag2 or npz",
    )
    re_.add_argument("out", help="rosbag2 folder, .mcap, ROS 1 .bag or .npz")
    re_.add_argument(
        "--network",
        default=None,
        help="a network file (.json/.yaml) instead of a layout (default: none)",
    )
    network_options(re_)
    re_.add_argument(
        "--lidar",
        default="ydlidar_x4",
        choices=sorted(PRESETS),
        help="LiDAR preset (default: %(default)s)",
    )
    re_.add_argument(
        "--seed", type=int, default=0, help="seed of the sensor noise (default: %(default)s)"
    )
    add_detector_options(re_)
    re_.add_argument(
        "--scan-interval",
        type=float,
        default=0.05,
        help="metres driven between sweeps (default: %(default)s)",
    )
    re_.add_argument(
        "--max-distance", type=float, default=2.0, help="longest drive, m (default: %(default)s)"
    )
    re_.add_argument(
        "--backend",
        default="analytic",
        choices=BACKENDS,
        help="ray casting backend (default: %(default)s)",
    )
    re_.set_defaults(func=_record)

    ex = sub.add_parser("export", help="a network's walls as a mesh and its world as MJCF")
    ex.add_argument(
        "network", nargs="?", default=None, help="network file (.json/.yaml); default: --layout"
    )
    network_options(ex)
    ex.add_argument("--stl", default=None, help="write the walls as STL here (default: none)")
    ex.add_argument("--obj", default=None, help="write the walls as OBJ here (default: none)")
    ex.add_argument("--glb", default=None, help="write the walls as GLB here (default: none)")
    ex.add_argument(
        "--mjcf", default=None, help="write the MuJoCo world as MJCF here (default: none)"
    )
    ex.add_argument(
        "--robot",
        action="store_true",
        help="MJCF: with the robot clamped at the start (default: without)",
    )
    ex.add_argument(
        "--no-contact-walls",
        action="store_true",
        help="MJCF without the robot: walls for rays only (default: with contact walls)",
    )
    ex.set_defaults(func=_export)
