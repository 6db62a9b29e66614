"""The scan container shared by the simulator and the detector: plain arrays, npz on disk.

A rotating 2D LiDAR measures ``P`` scan planes of ``B`` beams. Each plane contains the sensor's
forward (x) axis and is rotated about it by its servo (plane) angle ``alpha``; a beam at angle
``beta`` within the plane points along (sensor frame, x forward, y left, z up)::

    d(alpha, beta) = (cos beta, sin beta cos alpha, sin beta sin alpha)

so plane angle 0 is the horizontal plane (beta > 0 to the left) and plane angle pi/2 the
vertical one (beta > 0 upwards). Units: metres, radians, seconds.

"No return" (out of range, dropout, no surface) is ``inf`` in ``ranges`` and ``False`` in
``valid`` once a :class:`Scan` is built. What it is built from may use the other conventions of
REP 117 and of LiDAR SDKs: a beam is a return only where ``valid`` is True and its range is
finite, above 0 and within the spec's ``[min_range, max_range]`` (``MAX_RANGE_LIMIT`` when the
spec gives no ``max_range``). Every other beam (NaN, +-inf, 0.0, negative, too near, too far,
flagged invalid) becomes ``inf``/``False``, counted by reason in :attr:`Scan.no_returns`.

This module lives in ``detector`` (not ``pipe_env``) so recorded scans can be loaded and
detected without the simulator.
"""

from __future__ import annotations

import json
import math
import numbers
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from detector.atomic import atomic_open
from detector.validation import fail

#: The arrays of a scan, as :meth:`Scan.save` stores them (the npz's keys besides the
#: format version, the spec and the metadata).
SCAN_ARRAYS = (
    "ranges",
    "valid",
    "beam_angles",
    "plane_angles",
    "timestamps",
    "positions",
    "rotations",
    "nominal_positions",
    "nominal_rotations",
)


class ScanReadError(ValueError):
    """A recording that cannot be read as scans; the message names the file, the topic or
    row, and what was expected."""


SCAN_FORMAT_VERSION = 1

#: Farthest range (m) a scan without a ``max_range`` in its spec keeps as a return (the
#: farthest a ``LidarSpec`` allows is 100 m; beyond a kilometre a return is no pipe wall).
MAX_RANGE_LIMIT = 1000.0
#: Largest ``max |R^T R - I|`` of a rotation matrix in a scan (its determinant must be +1
#: within the same tolerance).
ROTATION_TOL = 1e-6
#: Beam and plane angles must lie in ``[-ANGLE_LIMIT, ANGLE_LIMIT]`` radians.
ANGLE_LIMIT = 2.0 * math.pi
#: Reasons a beam is no return, in the order they are judged (:attr:`Scan.no_returns`).
NO_RETURN_REASONS: tuple[str, ...] = (
    "flagged",  # valid was False
    "nan",
    "inf",  # +inf or -inf
    "zero",  # 0.0, the "no return" of many LiDAR SDKs
    "below_min_range",  # negative, or below the spec's min_range
    "above_max_range",  # beyond the spec's max_range (or MAX_RANGE_LIMIT)
)

#: Entries of ``Scan.spec`` the detector reads (the ``LidarSpec`` fields of the same names),
#: with their unit and the values allowed: ``">= 0"`` a finite number >= 0, ``"finite"`` any
#: finite number, ``"> 0"`` a number > 0 (``inf``: unlimited), ``"(0, pi/2]"`` an angle above 0
#: up to a right angle (radians: 80 degrees given as ``80`` is refused).
SPEC_NUMBERS: dict[str, tuple[str, str]] = {
    "noise_sigma": ("m", ">= 0"),
    "noise_sigma_rel": ("", ">= 0"),
    "range_resolution": ("m", ">= 0"),
    "angular_jitter": ("rad", ">= 0"),
    "bias": ("m", "finite"),
    "min_range": ("m", ">= 0"),
    "max_range": ("m", "> 0"),
    "max_incidence": ("rad", "(0, pi/2]"),
}


def beam_directions(plane_angles: NDArray, beam_angles: NDArray) -> NDArray[np.float64]:
    """(P, B, 3) unit beam directions in the sensor frame (see module docstring)."""
    a = np.asarray(plane_angles, dtype=float)[:, None]
    b = np.asarray(beam_angles, dtype=float)[None, :]
    sb = np.sin(b)
    return np.stack(np.broadcast_arrays(np.cos(b), sb * np.cos(a), sb * np.sin(a)), axis=-1).astype(
        float
    )


@dataclass(frozen=True, eq=False)
class Scan:
    """One LiDAR sweep: ``P`` planes x ``B`` beams.

    Attributes:
        ranges: (P, B) measured ranges, metres; ``inf`` where there is no return.
        valid: (P, B) True where a return was measured.
        beam_angles: (B,) beam angle within the plane, radians (0 = forward).
        plane_angles: (P,) servo angle of each plane about the forward axis, radians.
        timestamps: (P,) time each plane was measured, seconds.
        positions: (P, 3) world position of the sensor origin at each plane (truth), metres.
        rotations: (P, 3, 3) world-from-sensor rotation at each plane (truth). The sensor frame
            is the mount frame before the servo rotation: x forward, y left, z up.
        nominal_positions, nominal_rotations: the same as the robot believes them (odometry and
            the nominal mount, without misalignment). The detector may use these; it never sees
            the truth.
        spec: the sensor description (a ``LidarSpec`` as a dict), for the detector's limits.
        metadata: free-form extras (seed, mode, ...).
    """

    ranges: NDArray[np.float64]
    valid: NDArray[np.bool_]
    beam_angles: NDArray[np.float64]
    plane_angles: NDArray[np.float64]
    timestamps: NDArray[np.float64]
    positions: NDArray[np.float64]
    rotations: NDArray[np.float64]
    nominal_positions: NDArray[np.float64]
    nominal_rotations: NDArray[np.float64]
    spec: dict[str, Any] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        r = np.asarray(self.ranges, dtype=float)
        if r.ndim != 2:
            raise fail("ranges.shape", r.shape, "(planes, beams)", "not 2-D", where="Scan")
        p, b = r.shape
        shapes = {
            "valid": (p, b),
            "beam_angles": (b,),
            "plane_angles": (p,),
            "timestamps": (p,),
            "positions": (p, 3),
            "rotations": (p, 3, 3),
            "nominal_positions": (p, 3),
            "nominal_rotations": (p, 3, 3),
        }
        for name, shape in shapes.items():
            arr = np.asarray(getattr(self, name), dtype=bool if name == "valid" else float)
            if arr.shape != shape:
                raise fail(f"{name}.shape", arr.shape, str(shape), "wrong shape", where="Scan")
            if name != "valid" and not np.all(np.isfinite(arr)):
                k = _first(~np.isfinite(arr))
                raise fail(
                    f"{name}[{', '.join(map(str, k))}]",
                    float(arr[k]),
                    "finite numbers",
                    "not finite",
                    where="Scan",
                )
            object.__setattr__(self, name, arr)
        _check_spec(self.spec)
        for name in ("beam_angles", "plane_angles"):
            arr = getattr(self, name)
            bad = np.abs(arr) > ANGLE_LIMIT
            if np.any(bad):
                k = _first(bad)
                raise fail(
                    f"{name}[{k[0]}]",
                    float(arr[k]),
                    "angles in [-2 pi, 2 pi] (rad)",
                    "out of range",
                    where="Scan",
                )
        for name in ("rotations", "nominal_rotations"):
            _check_rotations(name, getattr(self, name))
        r, valid, counts = _returns(r, self.valid, self.spec)
        object.__setattr__(self, "valid", valid)
        object.__setattr__(self, "_no_returns", counts)
        object.__setattr__(self, "ranges", r)

    @property
    def no_returns(self) -> dict[str, int]:
        """Beams without a return, counted by reason (:data:`NO_RETURN_REASONS`; each beam
        counts once, under the first reason that applies)."""
        return dict(self._no_returns)  # type: ignore[attr-defined]

    def diagnostics(self) -> dict[str, Any]:
        """Counts for people and logs: beams, returns and the no returns by reason."""
        return {
            "n_beams": int(self.ranges.size),
            "n_returns": self.n_valid,
            "no_returns": self.no_returns,
        }

    @property
    def n_planes(self) -> int:
        return int(self.ranges.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.ranges.shape[1])

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.valid))

    def directions(self) -> NDArray[np.float64]:
        """(P, B, 3) nominal beam directions in the sensor frame."""
        return beam_directions(self.plane_angles, self.beam_angles)

    def points(self, frame: str = "sensor", valid_only: bool = True) -> NDArray[np.float64]:
        """Measured points, metres.

        Args:
            frame: ``"sensor"``: each plane's points in the sensor frame at that plane's time;
                ``"world"``: through the true per-plane poses; ``"nominal"``: all planes in the
                sensor frame of the *last* plane using the believed (nominal) poses, which
                compensates the robot's own motion during a continuous sweep.
            valid_only: return (N, 3) valid points only; else (P, B, 3) with NaN where invalid.
        """
        local = self.directions() * np.where(self.valid, self.ranges, np.nan)[..., None]
        if frame == "sensor":
            out = local
        elif frame == "world":
            out = np.einsum("pij,pbj->pbi", self.rotations, local) + self.positions[:, None, :]
        elif frame == "nominal":
            world = (
                np.einsum("pij,pbj->pbi", self.nominal_rotations, local)
                + self.nominal_positions[:, None, :]
            )
            r_last, p_last = self.nominal_rotations[-1], self.nominal_positions[-1]
            out = (world - p_last) @ r_last
        else:
            raise ValueError(f"frame must be 'sensor', 'world' or 'nominal', got {frame!r}")
        return out[self.valid] if valid_only else out

    def plane(self, index: int) -> Scan:
        """A single-plane scan (for the 2D algorithm)."""
        if not -self.n_planes <= index < self.n_planes:
            raise ValueError(
                f"plane index must be in [-{self.n_planes}, {self.n_planes - 1}] for a scan of "
                f"{self.n_planes} planes, got {index}"
            )
        sl = slice(index, index + 1) if index != -1 else slice(-1, None)
        return Scan(
            self.ranges[sl],
            self.valid[sl],
            self.beam_angles,
            self.plane_angles[sl],
            self.timestamps[sl],
            self.positions[sl],
            self.rotations[sl],
            self.nominal_positions[sl],
            self.nominal_rotations[sl],
            dict(self.spec),
            dict(self.metadata),
        )

    # ---------------------------------------------------------------- storage
    def save(self, path: str | Path) -> None:
        """Write an ``.npz`` file (arrays plus the spec and metadata as JSON), atomically;
        ``.npz`` is appended to a name without it (as numpy does)."""
        target = Path(path)
        if target.suffix != ".npz":
            target = target.with_name(target.name + ".npz")
        with atomic_open(target, "wb") as handle:
            self._savez(handle)

    def _savez(self, handle: Any) -> None:
        np.savez_compressed(
            handle,
            format_version=np.array(SCAN_FORMAT_VERSION),
            ranges=self.ranges,
            valid=self.valid,
            beam_angles=self.beam_angles,
            plane_angles=self.plane_angles,
            timestamps=self.timestamps,
            positions=self.positions,
            rotations=self.rotations,
            nominal_positions=self.nominal_positions,
            nominal_rotations=self.nominal_rotations,
            spec=np.array(json.dumps(self.spec)),
            metadata=np.array(json.dumps(self.metadata, default=_json_default)),
        )

    @classmethod
    def load(cls, path: str | Path) -> Scan:
        """Read a scan written by :meth:`save`.

        Raises:
            ScanReadError: (a ``ValueError``) naming the file, for a missing, corrupt or
                foreign file; the scan's own checks name the field they reject.
        """
        try:
            return cls._load(path)
        except FileNotFoundError:
            raise ScanReadError(f"{path}: no such scan file") from None
        except ScanReadError:
            raise
        except ValueError as exc:  # the scan's own checks, or a malformed array
            raise ScanReadError(f"{path}: {exc}") from None
        except (OSError, EOFError, KeyError, TypeError, zipfile.BadZipFile, zlib.error) as exc:
            raise ScanReadError(
                f"{path}: not a readable pipenav scan file ({type(exc).__name__}: {exc}); "
                "expected an .npz written by Scan.save"
            ) from None

    @classmethod
    def _load(cls, path: str | Path) -> Scan:
        with np.load(Path(path), allow_pickle=False) as z:
            version = int(z["format_version"])
            if version != SCAN_FORMAT_VERSION:
                raise ScanReadError(
                    f"scan file {path} has format_version {version}; this reads "
                    f"{SCAN_FORMAT_VERSION}"
                )
            arrays = {k: z[k] for k in SCAN_ARRAYS}
            spec = json.loads(str(z["spec"]))
            meta = json.loads(str(z["metadata"]))
        return cls(**arrays, spec=spec, metadata=meta)


def _returns(
    ranges: NDArray[np.float64], valid: NDArray[np.bool_], spec: Mapping[str, Any] | None
) -> tuple[NDArray[np.float64], NDArray[np.bool_], dict[str, int]]:
    """``(ranges, valid, counts)``: ``inf``/``False`` at every beam that is no return (module
    docstring), and how many beams each reason of :data:`NO_RETURN_REASONS` took."""
    lo = spec_value(spec, "min_range", 0.0)
    hi = min(spec_value(spec, "max_range", MAX_RANGE_LIMIT), MAX_RANGE_LIMIT)
    with np.errstate(invalid="ignore"):
        masks = (
            ~valid,
            np.isnan(ranges),
            np.isinf(ranges),
            ranges == 0.0,
            ranges < lo,
            ranges > hi,
        )
    left = np.ones(ranges.shape, dtype=bool)
    counts: dict[str, int] = {}
    for reason, mask in zip(NO_RETURN_REASONS, masks, strict=True):
        hit = mask & left
        counts[reason] = int(np.count_nonzero(hit))
        left &= ~hit
    if bool(left.all()):
        return ranges, left, counts
    return np.where(left, ranges, np.inf), left, counts


def _check_rotations(name: str, rot: NDArray[np.float64]) -> None:
    """Reject ``rot`` (P, 3, 3) unless every matrix is a proper rotation within
    :data:`ROTATION_TOL`."""
    if rot.shape[0] == 0:
        return
    ortho = np.abs(np.einsum("pki,pkj->pij", rot, rot) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = (ortho > ROTATION_TOL) | (np.abs(det - 1.0) > ROTATION_TOL)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise fail(
            f"{name}[{k}]",
            rot[k].tolist(),
            f"a proper rotation matrix (R^T R = I and det R = +1 within {ROTATION_TOL:g})",
            f"not a rotation (max |R^T R - I| = {float(ortho[k]):.3g}, "
            f"det R = {float(det[k]):.6g})",
            where="Scan",
        )


def _first(mask: NDArray[np.bool_]) -> tuple[int, ...]:
    """Index (as a tuple of ints) of the first True element of ``mask``."""
    return tuple(int(i) for i in np.unravel_index(int(np.argmax(mask)), mask.shape))


def _spec_number_problem(value: Any, rule: str) -> str | None:
    """What is wrong with ``value`` as a :data:`SPEC_NUMBERS` entry of ``rule`` (``">= 0"``,
    ``"finite"``, ``"> 0"``, where inf is allowed, or ``"(0, pi/2]"``), or ``None``."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return "not a number"
    v = float(value)
    if math.isnan(v) or (math.isinf(v) and rule != "> 0"):
        return "not finite"
    if (rule == ">= 0" and v < 0.0) or (rule == "> 0" and v <= 0.0):
        return "out of range"
    if rule == "(0, pi/2]" and not 0.0 < v <= 0.5 * math.pi:
        return "out of range"
    return None


def _check_spec(spec: Any) -> None:
    """Reject a ``Scan.spec`` that is not a dictionary, or whose entries in
    :data:`SPEC_NUMBERS` are not numbers in their allowed range."""
    if spec is None:
        return
    if not isinstance(spec, Mapping):
        raise fail("spec", spec, "a dict (a LidarSpec as a dict)", "not a dict", where="Scan")
    for key, (unit, rule) in SPEC_NUMBERS.items():
        if key not in spec:
            continue
        problem = _spec_number_problem(spec[key], rule)
        if problem is not None:
            u = f" ({unit})" if unit else ""
            allowed = {
                ">= 0": f"a finite number >= 0{u}",
                "finite": f"a finite number{u}",
                "> 0": f"a number > 0{u}, inf: unlimited",
                "(0, pi/2]": f"above 0 to pi/2{u}",
            }[rule]
            raise fail(f"spec[{key!r}]", spec[key], allowed, problem, where="Scan")
    if "min_range" in spec and "max_range" in spec:
        if not float(spec["min_range"]) < float(spec["max_range"]):
            raise fail(
                "spec['min_range']",
                spec["min_range"],
                f"below spec['max_range'] = {spec['max_range']!r} (m)",
                "not below max_range",
                where="Scan",
            )


def spec_value(spec: Mapping[str, Any] | None, key: str, default: float) -> float:
    """The number ``spec[key]`` (checked by :class:`Scan`), or ``default`` when absent."""
    if not spec:
        return default
    return float(spec.get(key, default))


def corrected_ranges(ranges: NDArray[np.float64], bias: float) -> NDArray[np.float64]:
    """Measured ranges (m) without the sensor's constant ``bias`` (m), clamped at 0 m."""
    return np.maximum(ranges - bias, 0.0)


def radial_noise(
    spec: Mapping[str, Any] | None,
    ranges: NDArray[np.float64],
    sin_beta: NDArray[np.float64],
    cos_beta: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Standard deviation of each return's range and of its distance across the pipe axis.

    The sensor model of ``spec`` (:data:`SPEC_NUMBERS`): gaussian range noise ``noise_sigma``
    (m) and ``noise_sigma_rel`` x range, and quantisation to ``range_resolution`` (m), a
    uniform error of variance ``resolution^2 / 12``; the range error moves a return across
    the axis by ``|sin beta|`` of it; the beam-angle jitter ``angular_jitter`` (rad) moves it
    by ``range x jitter x |cos beta|``.

    Args:
        spec: the scan's sensor description (``Scan.spec``); absent entries count as 0.
        ranges: (N,) corrected ranges (:func:`corrected_ranges`), metres.
        sin_beta, cos_beta: (N,) ``|sin|`` and ``|cos|`` of each return's beam angle.

    Returns:
        ``(sigma_range, sigma_radial)``, both (N,) metres.
    """
    sig = spec_value(spec, "noise_sigma", 0.0)
    sig_rel = spec_value(spec, "noise_sigma_rel", 0.0)
    res = spec_value(spec, "range_resolution", 0.0)
    jitter = spec_value(spec, "angular_jitter", 0.0)
    if sig_rel != 0.0:
        sigma_range = np.sqrt(sig**2 + (sig_rel * ranges) ** 2 + (res**2) / 12.0)
    else:  # (the same numbers, without the per-return terms that vanish)
        sigma_range = np.full(ranges.size, math.sqrt(sig**2 + (res**2) / 12.0))
    sigma_r = sigma_range * sin_beta
    if jitter != 0.0:
        sigma_r += ranges * jitter * cos_beta
    return sigma_range, sigma_r


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot store {type(value).__name__} in scan metadata")
