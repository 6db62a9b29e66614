"""Loaders name the file and what was wrong: Scan.load on corrupt files, training configs."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from agents.train import TrainConfig
from detector.scan import Scan, ScanReadError

DATA = Path(__file__).resolve().parents[1] / "examples" / "data" / "tee_100mm_ydlidar_x4.npz"


def test_a_good_scan_still_loads() -> None:
    scan = Scan.load(DATA)
    assert scan.ranges.ndim == 2


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(cut=st.integers(0, 30_000), flips=st.lists(st.integers(0, 30_000), max_size=8))
def test_a_corrupt_scan_file_is_an_error_naming_it(
    tmp_path: Path, cut: int, flips: list[int]
) -> None:
    raw = bytearray(DATA.read_bytes())
    raw = raw[: min(cut, len(raw))] if cut < len(raw) else raw
    for i in flips:
        if i < len(raw):
            raw[i] ^= 0x5A
    path = tmp_path / "broken.npz"
    path.write_bytes(bytes(raw))
    try:
        Scan.load(path)
    except ScanReadError as exc:
        assert str(path) in str(exc)


def test_missing_and_foreign_files(tmp_path: Path) -> None:
    with pytest.raises(ScanReadError, match="no such scan file"):
        Scan.load(tmp_path / "missing.npz")
    foreign = tmp_path / "plain.npz"
    np.savez(foreign, a=np.zeros(3))
    with pytest.raises(ScanReadError, match="plain.npz"):
        Scan.load(foreign)
    text = tmp_path / "text.npz"
    text.write_text("ranges,valid\n1,2\n")
    with pytest.raises(ScanReadError, match="text.npz"):
        Scan.load(text)
    with zipfile.ZipFile(tmp_path / "zip.npz", "w") as z:
        z.writestr("ranges.npy", b"not an array")
    with pytest.raises(ScanReadError, match="zip.npz"):
        Scan.load(tmp_path / "zip.npz")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("max_minutes: soon\n", "max_minutes"),
        ("seed: -1\n", "seed"),
        ("n_envs: [1]\n", "n_envs"),
        ("ppo: [1, 2]\n", "ppo"),
        ("totl_timesteps: 5\n", "unknown keys"),
        ("a: [unclosed\n", "not valid YAML"),
        ("- a list\n", "must be a mapping"),
    ],
)
def test_training_config_errors_name_the_file_and_field(
    tmp_path: Path, text: str, match: str
) -> None:
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as info:
        TrainConfig.from_yaml(path)
    assert str(path) in str(info.value)


def test_missing_training_config(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no such training config"):
        TrainConfig.from_yaml(tmp_path / "nope.yaml")
