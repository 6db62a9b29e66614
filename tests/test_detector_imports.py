"""The detector runs on recorded scans: it must import neither MuJoCo nor pipe_env."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_detector_runs_with_mujoco_and_pipe_env_blocked(tmp_path):
    code = textwrap.dedent(
        """
        import sys, importlib.abc, math

        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("mujoco", "pipe_env"):
                    raise ImportError(f"blocked import of {name}")
                return None

        sys.meta_path.insert(0, Block())
        import numpy as np
        import detector
        from detector import detect, detect_planar
        from detector.fusion import StructureTracker
        from detector.scan import Scan

        beams = np.linspace(-math.pi / 2, math.pi / 2, 181)
        planes = np.arange(45) * (math.pi / 45)
        sb = np.abs(np.sin(beams))
        r = np.where(sb > 1e-9, 0.05 / np.maximum(sb, 1e-12), np.inf)
        r = np.minimum(r, 0.3 / np.cos(beams))  # an end wall 30 cm ahead
        r = np.tile(r, (45, 1))
        r[(r > 2.0) | (r < 0.1)] = np.inf
        p = len(planes)
        scan = Scan(r, np.isfinite(r), beams, planes, np.zeros(p), np.zeros((p, 3)),
                    np.tile(np.eye(3), (p, 1, 1)), np.zeros((p, 3)), np.tile(np.eye(3), (p, 1, 1)))
        path = sys.argv[1]
        scan.save(path)
        scan = Scan.load(path)
        det = detect(scan, 0.1)
        assert det.kind == "closure", det.describe()
        assert abs(det.options[0].distance - 0.3) < 0.005
        detect(scan, 0.1, "thesis")
        detect_planar(scan.plane(0), 0.1)
        StructureTracker().update(det, np.zeros(3), np.eye(3))
        assert not any(m.split(".")[0] in ("mujoco", "pipe_env") for m in sys.modules)
        print("ok")
        """
    )
    res = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "scan.npz")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith("ok")
