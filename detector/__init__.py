"""Structure detection from rotating-LiDAR scans: the thesis algorithms and improved ones.

Works on plain arrays (:class:`detector.scan.Scan`); imports neither MuJoCo nor ``pipe_env``, so
it runs on recorded scans.
"""

from detector.options import KINDS, StructureOption
from detector.scan import Scan

__all__ = ["KINDS", "Scan", "StructureOption"]
