"""Fast-fidelity sensing: ground-truth options perturbed by a detector's measured error model.

The ``fast`` fidelity of the environments does not ray-cast or run the detector; it reports the
true options of the structure ahead, perturbed the way a detector errs: gaussian errors on
distance, diameter, angle and direction, a missed way on, a phantom way on, a wrong kind. The
models for ``"improved"`` and ``"thesis"`` are measured per LiDAR preset by
``benchmarks/calibrate_sensing.py`` (the real detector on ray-cast scans, swept and fused over
the approach as the full fidelity does, rescans included, compared with ground truth at the
decision point) and stored
in ``pipe_env/data/sensing_models.json``; :func:`error_model_for` picks the entry of a detector
and a sensor. ``"ground_truth"`` is exact (the oracle ablation).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from importlib import resources
from typing import Any

import numpy as np

from detector.geometry import clamp
from detector.options import KINDS, StructureOption, option_order
from detector.validation import check_number, fail
from detector.vocab import DETECTORS, Kind, Method

_WHERE = "DetectionErrorModel"
_SIGMAS = ("distance_sigma", "diameter_sigma", "angle_sigma", "direction_sigma")


@dataclass(frozen=True)
class DetectionErrorModel:
    """Per-option error statistics of a detector. Metres and radians.

    Attributes:
        name: the detector this model stands for.
        distance_sigma, diameter_sigma, angle_sigma, direction_sigma: gaussian error std of
            an ordinary estimate.
        gross_rate: probability that a way on's estimate is a gross error (beyond the thesis
            requirements: 2 cm, 5 mm, 5 deg, 5 deg); detectors fail that way rather than with
            wide gaussian tails.
        gross_distance_sigma, gross_diameter_sigma, gross_angle_sigma, gross_direction_sigma:
            error std of a gross estimate.
        miss_rate: probability that a way on (other than the first) is not reported.
        phantom_rate: probability that a structure gets an extra, non-existent way on.
        misclass_rate: probability that the structure's kind is reported wrongly.
        confidence: confidence reported with the options.
        lower_bound_rate: probability that a long bend's way (``bend_radius > 0``) reads a
            lower bound of its angle (seen short of its arc's end): the angle read short by
            ``|N(0, lower_bound_sigma)|`` and the reference point nearer with it (the arc's
            start and radius kept), before the ordinary or gross error.
        lower_bound_sigma: std of that shortfall, rad.
    """

    name: str
    distance_sigma: float = 0.0
    diameter_sigma: float = 0.0
    angle_sigma: float = 0.0
    direction_sigma: float = 0.0
    miss_rate: float = 0.0
    phantom_rate: float = 0.0
    misclass_rate: float = 0.0
    confidence: float = 1.0
    gross_rate: float = 0.0
    gross_distance_sigma: float = 0.0
    gross_diameter_sigma: float = 0.0
    gross_angle_sigma: float = 0.0
    gross_direction_sigma: float = 0.0
    lower_bound_rate: float = 0.0
    lower_bound_sigma: float = 0.0

    def __post_init__(self) -> None:
        for key in _SIGMAS + tuple(f"gross_{k}" for k in _SIGMAS) + ("lower_bound_sigma",):
            check_number(f"{_WHERE}.{key}", getattr(self, key), 0.0, math.pi, "m or rad")
        for key in (
            "miss_rate",
            "phantom_rate",
            "misclass_rate",
            "confidence",
            "gross_rate",
            "lower_bound_rate",
        ):
            check_number(f"{_WHERE}.{key}", getattr(self, key), 0.0, 1.0)

    @property
    def exact(self) -> bool:
        return all(
            getattr(self, k) == 0.0
            for k in (
                "distance_sigma",
                "diameter_sigma",
                "angle_sigma",
                "direction_sigma",
                "miss_rate",
                "phantom_rate",
                "misclass_rate",
                "gross_rate",
                "lower_bound_rate",
            )
        )

    def apply(
        self, truth: list[StructureOption], rng: np.random.Generator
    ) -> list[StructureOption]:
        """Perturb the true options of one structure. Draws a fixed number of random numbers
        per option so that a seed fixes the result."""
        if not truth:
            return []
        n = len(truth)
        noise = rng.normal(size=(n, 4))
        coin = rng.random(size=(n + 3,))
        gross = rng.random(size=n) < self.gross_rate
        # (drawn only by models that have lower bounds: the others' seeded draws stay as they
        # were before the field existed)
        shortfall = np.zeros(n)
        if self.lower_bound_rate > 0.0:
            short = rng.random(size=n) < self.lower_bound_rate
            shortfall = np.where(short, np.abs(rng.normal(0.0, self.lower_bound_sigma, n)), 0.0)
        out: list[StructureOption] = []
        kind = truth[0].kind
        if coin[n] < self.misclass_rate:
            kind = _confuse(kind, coin[n + 1])
        for i, o in enumerate(truth):
            if i > 0 and coin[i] < self.miss_rate:
                continue
            read = o if o.bend_radius <= 0.0 else _read_short(o, float(shortfall[i]))
            out.append(self._perturb(read, kind, noise[i], bool(gross[i])))
        if coin[n + 2] < self.phantom_rate and truth[0].kind not in (Kind.CLOSURE, Kind.REDUCER):
            ref = out[-1]
            phantom_dir = ref.direction + math.pi / 2 + rng.normal(0.0, 0.3)
            out.append(
                replace(
                    ref,
                    direction=phantom_dir,
                    angle=min(ref.angle + 0.2, math.pi),
                    confidence=0.5 * self.confidence,
                )
            )
        out.sort(key=option_order)
        return out

    def _perturb(
        self, o: StructureOption, kind: str, z: np.ndarray, gross: bool
    ) -> StructureOption:
        if self.exact and kind == o.kind:
            return o
        prefix = "gross_" if gross else ""
        s_dist, s_diam, s_angle, s_dir = (getattr(self, prefix + k) for k in _SIGMAS)
        angle = o.angle + s_angle * z[2] if o.angle > 1e-6 else abs(s_angle * z[2])
        return StructureOption(
            kind=kind,
            distance=o.distance + s_dist * z[0],
            diameter=max(0.0, o.diameter + s_diam * z[1]) if o.diameter > 0 else 0.0,
            direction=o.direction + s_dir * z[3],
            angle=clamp(angle, 0.0, math.pi),
            confidence=self.confidence,
            bend_radius=o.bend_radius if kind == Kind.BEND else 0.0,
        )


#: A long bend read as a lower bound keeps at least this angle, rad.
MIN_LOWER_BOUND_ANGLE = math.radians(5.0)


def _read_short(o: StructureOption, shortfall: float) -> StructureOption:
    """The long bend ``o`` read ``shortfall`` rad short of its angle (a lower bound, at least
    :data:`MIN_LOWER_BOUND_ANGLE`), its reference point nearer with it: the arc's start
    (``distance - R tan(angle / 2)``) and radius stay."""
    if shortfall <= 0.0:
        return o
    angle = max(o.angle - shortfall, min(o.angle, MIN_LOWER_BOUND_ANGLE))
    nearer = o.bend_radius * (math.tan(0.5 * o.angle) - math.tan(0.5 * angle))
    return replace(o, angle=angle, distance=o.distance - nearer)


def _confuse(kind: str, u: float) -> str:
    """A plausible wrong kind (bends and junctions swap; reducers and closures swap)."""
    swap = {"bend": "junction", "junction": "bend", "reducer": "closure", "closure": "reducer"}
    if kind in swap and u < 0.8:
        return swap[kind]
    others = [k for k in KINDS if k not in (kind, "straight")]
    return others[int(u * len(others)) % len(others)]


#: Used only when no calibrated entry exists for a sensor (a custom LidarSpec whose name is not
#: a preset): the thesis's own 3D figures (its tables 5.2, 5.3 and 6.1, 40-10 cm window): max
#: errors of 4 cm distance, 1 cm diameter, 2 deg angle and 11 deg direction, a std of about
#: 0.4 x the max error; miss and misclassification rates reflect its type-1 confusion close to
#: structures (5.1.2).
THESIS_LITERATURE_MODEL = DetectionErrorModel(
    "thesis/literature",
    distance_sigma=0.016,
    diameter_sigma=0.004,
    angle_sigma=math.radians(0.8),
    direction_sigma=math.radians(4.5),
    miss_rate=0.05,
    phantom_rate=0.02,
    misclass_rate=0.05,
    confidence=0.7,
)


@lru_cache(maxsize=1)
def calibrated_models() -> dict[str, DetectionErrorModel]:
    """The calibrated models by ``"detector/preset"`` (empty if the data file is missing)."""
    source = resources.files("pipe_env").joinpath(SENSING_MODELS_FILE)
    try:
        text = source.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    return parse_models(text, str(source))


#: The packaged calibrated models, relative to the ``pipe_env`` package.
SENSING_MODELS_FILE = "data/sensing_models.json"


def parse_models(text: str, source: str) -> dict[str, DetectionErrorModel]:
    """The models of a sensing-models JSON document; a corrupt one is a ``ValueError`` naming
    ``source`` and saying how to regenerate it."""
    fix = "regenerate it with benchmarks/calibrate_sensing.py --write or reinstall pipenav"
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        where = f" at line {exc.lineno}" if isinstance(exc, json.JSONDecodeError) else ""
        raise ValueError(
            f"{source}: the sensing models file is corrupt (not JSON{where}); {fix}"
        ) from None
    models = doc.get("models") if isinstance(doc, dict) else None
    if not isinstance(models, dict):
        raise ValueError(f"{source}: the sensing models file has no 'models' mapping; {fix}")
    names = {f.name for f in fields(DetectionErrorModel)}
    out: dict[str, DetectionErrorModel] = {}
    for key, entry in models.items():
        try:
            if not isinstance(entry, dict):
                raise TypeError(type(entry).__name__)
            out[key] = DetectionErrorModel(**{k: v for k, v in entry.items() if k in names})
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"{source}: models.{key} is not a valid sensing model ({exc}); {fix}"
            ) from None
    return out


def error_model_for(detector: str, lidar: Any = "ideal") -> DetectionErrorModel:
    """The fast fidelity's error model of ``detector`` with the sensor ``lidar``.

    Args:
        detector: one of :data:`DETECTORS`.
        lidar: a preset name or a ``LidarSpec`` (its ``name`` selects the calibrated entry).
    """
    if detector not in DETECTORS:
        raise fail("detector", detector, ", ".join(DETECTORS), where="error_model_for")
    if detector == Method.GROUND_TRUTH:
        return DetectionErrorModel("ground_truth")
    preset = lidar if isinstance(lidar, str) else str(getattr(lidar, "name", "ideal"))
    models = calibrated_models()
    if f"{detector}/{preset}" in models:
        return models[f"{detector}/{preset}"]
    if detector == Method.THESIS:
        return THESIS_LITERATURE_MODEL
    if f"{detector}/ideal" in models:
        return models[f"{detector}/ideal"]
    raise ValueError(
        f"no calibrated sensing model for detector={detector!r}; run "
        "benchmarks/calibrate_sensing.py --write"
    )
