"""The README stays true to the code: its generated tables are current, its Python snippets
run, every ``pipenav``/``make``/``python`` command it shows exists, its links resolve."""

from __future__ import annotations

import importlib.util
import re
import shlex
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
TEXT = README.read_text(encoding="utf-8")


def _generator() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "generate_tables", ROOT / "docs" / "generate_tables.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _blocks(language: str, text: str = TEXT) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", text, re.DOTALL)


def _commands() -> list[str]:
    """Commands in the bash blocks (comments stripped) and in inline code spans."""
    lines = [
        line.split("  #")[0].split(" # ")[0].strip()
        for block in _blocks("bash")
        for line in block.splitlines()
    ]
    prose = re.sub(r"<!-- begin generated.*?<!-- end generated[^>]*>", "", TEXT, flags=re.DOTALL)
    lines += re.findall(r"`((?:pipenav|make|python) [^`]+)`", prose)
    return [line for line in lines if line and "<" not in line]


def test_generated_tables_match_the_code() -> None:
    rendered = _generator().render_readme(TEXT)
    assert rendered == TEXT, "README.md is out of date: run python docs/generate_tables.py --write"


def test_every_feature_and_option_is_described() -> None:
    gen = _generator()
    from pipe_env.envs.observations import OPTION_COLUMNS

    assert all(column.meaning.strip() for column in OPTION_COLUMNS)  # columns carry their own
    for make in gen.TABLES.values():  # a KeyError names anything undescribed
        assert make().startswith("| ")


def test_observation_table_names_every_column_in_order() -> None:
    from pipe_env.envs import OPTION_FEATURES

    section = TEXT.split("<!-- begin generated: observation -->")[1].split("<!-- end")[0]
    names = re.findall(r"^\| (\d+) \| `(\w+)` \|", section, re.MULTILINE)
    assert [(int(i), n) for i, n in names] == list(enumerate(OPTION_FEATURES))


@pytest.mark.parametrize(
    "index",
    [
        # the MaskablePPO snippet imports torch and sb3: over 10 s on a loaded machine
        pytest.param(i, marks=pytest.mark.slow) if "MaskablePPO" in block else i
        for i, block in enumerate(_blocks("python"))
    ],
)
def test_python_snippet_runs(index: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    code = _blocks("python")[index]
    exec(compile(code, f"README.md python block {index}", "exec"), {"__name__": "__readme__"})


def test_commands_exist() -> None:
    from agents.cli import build_parser

    targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.MULTILINE))
    commands = _commands()
    assert any(c.startswith("pipenav ") for c in commands)
    for command in commands:
        words = shlex.split(command)
        if words[0] == "pipenav":
            try:
                build_parser().parse_args(words[1:])
            except SystemExit as exc:  # argparse rejects it
                raise AssertionError(f"README command does not parse: {command}") from exc
        elif words[0] == "make":
            assert set(words[1:]) <= targets, command
        elif words[0] == "python" and words[1] == "-m":
            # a module run: ours must exist; the zoo and MuJoCo's viewer come from packages
            top = words[2].split(".")[0]
            assert top in {"rl_zoo3", "mujoco"} or (ROOT / top).is_dir(), command
        elif words[0] == "python":
            assert (ROOT / words[1]).is_file(), command


def test_links_and_example_scripts_exist() -> None:
    for target in re.findall(r"\]\(([^)#]+)\)", TEXT):
        if not target.startswith("http"):
            assert (ROOT / target).exists(), target
    for script in re.findall(r"`(examples/\w+\.py)`", TEXT):
        assert (ROOT / script).is_file(), script
    assert sorted(p.name for p in (ROOT / "examples").glob("*.py")) == sorted(
        Path(s).name for s in set(re.findall(r"`(examples/\w+\.py)`", TEXT))
    ), "every example is listed in the README"


def test_readme_is_a_guide_not_a_notebook() -> None:
    # the aim is ~250 lines; the ceiling leaves room for short sections, not for history
    assert len(TEXT.splitlines()) <= 300
    for phrase in ("this round", "previous round", OLD_NAME):
        assert phrase not in TEXT


OLD_NAME = "DESIGN" + ".md"  # (spelt so that this file does not contain it)


def test_code_and_docs_cite_the_design_at_its_path() -> None:
    assert (ROOT / "docs" / "design.md").is_file()
    for folder in ("detector", "pipe_env", "primitives", "agents", "tests", "benchmarks"):
        for path in (ROOT / folder).rglob("*.py"):
            assert OLD_NAME not in path.read_text(encoding="utf-8"), path
    assert "docs/design.md" in TEXT


@pytest.mark.parametrize("doc", ["design.md", "detector.md"])
def test_docs_snippets_run_and_links_resolve(doc: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    text = (ROOT / "docs" / doc).read_text(encoding="utf-8")
    for i, code in enumerate(_blocks("python", text)):
        exec(compile(code, f"docs/{doc} python block {i}", "exec"), {"__name__": "__doc__"})
    for target in re.findall(r"\]\(([^)#]+)", text):
        assert (ROOT / "docs" / target).exists(), target
