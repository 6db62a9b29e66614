"""``--write-docs`` of the benchmark scripts this package's docs depend on: each writes its
stamped section of ``docs/benchmarks.md`` (here into a temporary copy) with what it printed."""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

import benchmarks.report as report

ROOT = Path(__file__).resolve().parent.parent


def _script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def docs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    path = tmp_path / "benchmarks.md"
    monkeypatch.setattr(report, "write_section", functools.partial(report.write_section, path=path))
    return path


def test_bench_world_writes_its_section(
    docs: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["bench_world.py", "--fittings", "3", "--seeds", "1", "--write-docs"]
    monkeypatch.setattr(sys, "argv", argv)
    _script("bench_world").main()
    text = docs.read_text()
    assert "<!-- begin world -->" in text and "<!-- end world -->" in text
    assert "_commit " in text and "threads:" in text
    assert "`python benchmarks/bench_world.py --fittings 3 --seeds 1`" in text
    assert "| build_world |" in text
    assert "| build_world |" in capsys.readouterr().out


def test_bench_primitives_writes_its_section(docs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    argv = ["bench_primitives.py", "--skip-tolerance", "--skip-speed", "--write-docs"]
    monkeypatch.setattr(sys, "argv", argv)
    _script("bench_primitives").main()
    text = docs.read_text()
    assert "<!-- begin primitives -->" in text
    assert "`python benchmarks/bench_primitives.py --skip-tolerance --skip-speed`" in text


def test_without_the_flag_nothing_is_written(docs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["bench_primitives.py", "--skip-tolerance", "--skip-speed"])
    _script("bench_primitives").main()
    assert not docs.exists()
