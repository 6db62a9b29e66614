"""Structure detection from rotating-LiDAR scans: the thesis algorithms and improved ones.

Works on plain arrays (:class:`detector.scan.Scan`); imports neither MuJoCo nor ``pipe_env``, so
it runs on recorded scans.

- :func:`detect` (full sweeps; ``method="improved"`` or ``"thesis"``) and :func:`detect_planar`
  (one plane, thesis Algorithm 1) return a :class:`Detection`.
- :class:`detector.fusion.StructureTracker` fuses detections while the robot drives.
- :class:`SensorInPipe` is the known sensor pose in the pipe-axis frame.
"""

from detector.api import METHODS, PLANAR_METHODS, detect, detect_planar
from detector.detection import Detection
from detector.ellipse import Ellipse, EllipseFitFailure, fit_ellipse
from detector.fusion import StructureTracker, TrackState
from detector.options import KINDS, StructureOption
from detector.scan import Scan
from detector.transforms import SensorInPipe

__all__ = [
    "KINDS",
    "METHODS",
    "PLANAR_METHODS",
    "Detection",
    "Ellipse",
    "EllipseFitFailure",
    "Scan",
    "SensorInPipe",
    "StructureOption",
    "StructureTracker",
    "TrackState",
    "detect",
    "detect_planar",
    "fit_ellipse",
]
