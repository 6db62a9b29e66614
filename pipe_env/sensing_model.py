"""Fast-fidelity sensing: ground-truth options perturbed by a detector's measured error model.

The ``fast`` fidelity of the environments does not ray-cast or run the detector; it reports the
true options of the structure ahead, perturbed the way a detector errs: gaussian errors on
distance, diameter, angle and direction, a missed way on, a phantom way on, a wrong kind. The
models for ``"improved"`` and ``"thesis"`` are measured (see ``DETECTOR_ERROR_MODELS``'s comments
and ``benchmarks/calibrate_sensing.py``); ``"ground_truth"`` is exact (the oracle ablation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from detector.options import KINDS, StructureOption, option_order


@dataclass(frozen=True)
class DetectionErrorModel:
    """Per-option error statistics of a detector. Metres and radians.

    Attributes:
        name: the detector this model stands for.
        distance_sigma, diameter_sigma, angle_sigma, direction_sigma: gaussian error std.
        miss_rate: probability that a way on (other than the first) is not reported.
        phantom_rate: probability that a structure gets an extra, non-existent way on.
        misclass_rate: probability that the structure's kind is reported wrongly.
        confidence: confidence reported with the options.
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

    def __post_init__(self) -> None:
        for key in ("distance_sigma", "diameter_sigma", "angle_sigma", "direction_sigma"):
            v = getattr(self, key)
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise ValueError(f"DetectionErrorModel.{key} = {v!r} is invalid; allowed [0, 1]")
        for key in ("miss_rate", "phantom_rate", "misclass_rate", "confidence"):
            v = getattr(self, key)
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise ValueError(f"DetectionErrorModel.{key} = {v!r} is invalid; allowed [0, 1]")

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
        out: list[StructureOption] = []
        kind = truth[0].kind
        if coin[n] < self.misclass_rate:
            kind = _confuse(kind, coin[n + 1])
        for i, o in enumerate(truth):
            if i > 0 and coin[i] < self.miss_rate:
                continue
            out.append(self._perturb(o, kind, noise[i]))
        if coin[n + 2] < self.phantom_rate and truth[0].kind not in ("closure", "reducer"):
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

    def _perturb(self, o: StructureOption, kind: str, z: np.ndarray) -> StructureOption:
        if self.exact and kind == o.kind:
            return o
        angle = (
            o.angle + self.angle_sigma * z[2] if o.angle > 1e-6 else abs(self.angle_sigma * z[2])
        )
        return StructureOption(
            kind=kind,
            distance=o.distance + self.distance_sigma * z[0],
            diameter=max(0.0, o.diameter + self.diameter_sigma * z[1]) if o.diameter > 0 else 0.0,
            direction=o.direction + self.direction_sigma * z[3],
            angle=float(np.clip(angle, 0.0, math.pi)),
            confidence=self.confidence,
        )


def _confuse(kind: str, u: float) -> str:
    """A plausible wrong kind (bends and junctions swap; reducers and closures swap)."""
    swap = {"bend": "junction", "junction": "bend", "reducer": "closure", "closure": "reducer"}
    if kind in swap and u < 0.8:
        return swap[kind]
    others = [k for k in KINDS if k not in (kind, "straight")]
    return others[int(u * len(others)) % len(others)]


#: Error models of the fast fidelity, by detector name.
DETECTOR_ERROR_MODELS: dict[str, DetectionErrorModel] = {
    "ground_truth": DetectionErrorModel("ground_truth"),
    # The thesis's own 3D figures (its tables 5.2, 5.3 and 6.1, 40-10 cm window): max errors of
    # 4 cm distance, 1 cm diameter, 2 deg angle and 11 deg direction; a std of about 0.4 x the
    # max error. The bend direction error grew to 28 deg near the bend (5.1.2): miss and
    # misclassification rates reflect its type-1 confusion close to structures.
    "thesis": DetectionErrorModel(
        "thesis",
        distance_sigma=0.016,
        diameter_sigma=0.004,
        angle_sigma=math.radians(0.8),
        direction_sigma=math.radians(4.5),
        miss_rate=0.05,
        phantom_rate=0.02,
        misclass_rate=0.05,
        confidence=0.7,
    ),
    # Placeholder replaced by the calibration of the improved detector (see module docstring).
    "improved": DetectionErrorModel(
        "improved",
        distance_sigma=0.003,
        diameter_sigma=0.001,
        angle_sigma=math.radians(0.3),
        direction_sigma=math.radians(0.6),
        miss_rate=0.005,
        phantom_rate=0.002,
        misclass_rate=0.005,
        confidence=0.95,
    ),
}
