"""The layout of ``benchmarks/``: every script is a module with its own help, listed in the index,
and none patches ``sys.path``."""

from __future__ import annotations

import importlib
import os
import re
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
#: Modules that are not scripts: the shared helpers, and the modules a script of the comparison
#: folder is split into (its stages, its settings, its pages).
NOT_SCRIPTS = {
    "benchmarks.common",
    *(f"benchmarks.comparison.model_comparison_{part}" for part in (
        "build", "conditioning", "metrics", "publish", "results", "runs", "sections", "settings",
        "train",
    )),
    "benchmarks.comparison.zoo_training_curve",
    "benchmarks.paper.study",
}  # fmt: skip


def _modules() -> list[str]:
    paths = sorted(p for p in BENCHMARKS.rglob("*.py") if p.name != "__init__.py")
    return [".".join(p.relative_to(BENCHMARKS.parent).with_suffix("").parts) for p in paths]


SCRIPTS = [m for m in _modules() if m not in NOT_SCRIPTS]


def test_no_script_patches_sys_path():
    for path in [*BENCHMARKS.rglob("*.py"), *BENCHMARKS.rglob("*.md")]:
        assert "sys.path" not in path.read_text(), path


def test_every_folder_is_a_package():
    for folder in [BENCHMARKS, *(p for p in BENCHMARKS.iterdir() if p.is_dir())]:
        if folder.name != "__pycache__":
            assert (folder / "__init__.py").is_file(), folder


def test_the_index_lists_every_script():
    index = (BENCHMARKS / "README.md").read_text()
    listed = set(re.findall(r"^\| \[\w+\]\((\w+/\w+)\.py\)", index, flags=re.MULTILINE))
    assert listed == {m.removeprefix("benchmarks.").replace(".", "/") for m in _modules()} - {
        "common"
    }


@pytest.fixture
def environ():
    """``os.environ`` as it was before the test (a script sets defaults such as ``MUJOCO_GL``
    when it is imported)."""
    saved = os.environ.copy()
    yield
    os.environ.clear()
    os.environ.update(saved)


@pytest.mark.parametrize("module", SCRIPTS)
def test_a_script_prints_its_help_with_its_module_name(module, environ, monkeypatch, capsys):
    script = importlib.import_module(module)
    monkeypatch.setattr(sys, "argv", [module, "--help"])
    with pytest.raises(SystemExit) as exit_:
        script.main()
    assert exit_.value.code == 0
    usage = capsys.readouterr().out
    assert re.match(rf"usage: python -m {re.escape(module)}\s", usage)
