"""The package's shape, read from its source: pipeline stages import only leftwards, no cycles,
no oversized files.

Stages (``docs/architecture.md``): envs -> data -> models -> classifiers -> planning -> training
-> run -> oracle / diagnose -> benchmark -> metrics / report -> cli. ``vp2.utils``, ``vp2.spec`` and ``vp2._quiet`` are shared
by every stage and import no stage. Imports inside functions count: a lazy import is still a
dependency, and so is an import named as a string (``"vp2.models.simulator:SimulatorModel"`` handed
to ``importlib``, a registry of factory paths). The size rule holds for ``benchmarks/`` too.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
from benchmarks.checks.architecture_figures import strongly_connected

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "vp2"
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

STAGES: dict[str, int] = {
    "envs": 0,
    "data": 1,
    "models": 2,
    "classifiers": 3,
    "planning": 4,
    "training": 5,
    "run": 6,
    "oracle": 7,
    "diagnose": 7,
    "benchmark": 8,
    "metrics": 9,
    "report": 9,
    "cli": 10,
}
SHARED = {"utils", "spec", "_quiet"}
MAX_LINES = 500
#: A string literal that names a vp2 module, optionally with ``:attribute``: an import by name.
NAMED_IMPORT = re.compile(r"vp2(\.[A-Za-z_]\w*)+(:[A-Za-z_][\w.]*)?")


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def imported_modules(name: str, path: Path, known: set[str]) -> set[str]:
    """The vp2 modules ``name`` imports: ``from a.b import c`` counts ``a.b.c`` when that is a
    module, else ``a.b``."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
              and NAMED_IMPORT.fullmatch(node.value)):
            module, _, attr = node.value.partition(":")
            targets = [f"{module}.{attr.split('.')[0]}" if attr else module]
        else:
            continue
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target.startswith("vp2") and target != name:
                found.add(target)
    return found


def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {name: imported_modules(name, path, known) for name, path in mods.items()}


def stage(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def test_stages_cover_every_subpackage():
    top = {stage(m) for m in modules()} - {None}
    assert top <= set(STAGES) | SHARED, f"new top-level module(s) without a stage: {top - set(STAGES) - SHARED}"


def test_no_backward_imports():
    bad = []
    for mod, deps in graph().items():
        s = stage(mod)
        for dep in deps:
            d = stage(dep)
            if d is None:  # `vp2` itself (registers the envs): envs-level
                d = "envs"
            if d in SHARED:
                continue
            if s in SHARED:
                bad.append(f"{mod} (shared) imports {dep}")
            elif s is not None and STAGES[d] > STAGES[s]:
                bad.append(f"{mod} ({s}) imports {dep} ({d}), a later stage")
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    cycles = strongly_connected(graph())
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_no_oversized_source_files():
    big = {m: n for m, p in modules().items() if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not big, f"over {MAX_LINES} lines: {big}"


def test_no_oversized_benchmark_scripts():
    """The size rule holds for ``benchmarks/`` too: every script and module of it."""
    paths = sorted(BENCHMARKS.rglob("*.py"))
    assert len(paths) > 10, f"no benchmark scripts found under {BENCHMARKS}"
    big = {str(p.relative_to(BENCHMARKS.parent)): n for p in paths
           if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not big, f"over {MAX_LINES} lines: {big}"


def test_the_checker_sees_a_backward_import(tmp_path):
    """The import reader must resolve what the rules are about; a planted backward import and a
    planted cycle are found."""
    known = {"vp2.envs.base", "vp2.benchmark.runner", "vp2.envs", "vp2.benchmark"}
    f = tmp_path / "base.py"
    f.write_text("def f():\n    from vp2.benchmark.runner import run_benchmark\n")
    assert imported_modules("vp2.envs.base", f, known) == {"vp2.benchmark.runner"}
    g = tmp_path / "__init__.py"
    g.write_text("from . import base\nfrom .base import thing\n")
    assert imported_modules("vp2.envs", g, known) == {"vp2.envs.base"}


def test_the_checker_sees_an_import_named_as_a_string(tmp_path):
    """A module or factory path in a string (a registry, ``importlib.import_module``) is an
    import; prose that mentions a module is not."""
    known = {"vp2.envs.base", "vp2.benchmark.runner", "vp2.envs", "vp2.benchmark"}
    f = tmp_path / "base.py"
    f.write_text('FACTORIES = {"x": "vp2.benchmark.runner:run_benchmark"}\n'
                 'import importlib\nimportlib.import_module("vp2.benchmark")\n'
                 '"""See vp2.benchmark.runner for the loop."""\n')
    assert imported_modules("vp2.envs.base", f, known) == {"vp2.benchmark.runner", "vp2.benchmark"}


@pytest.mark.parametrize("mod", ["vp2.run.config", "vp2.run.model_spec"])
def test_light_modules_do_not_import_torch(mod):
    """Reading a run's config (and resolving ``--model`` strings) must not load torch."""
    import subprocess
    import sys

    assert mod in modules(), f"{mod} moved: update this test"
    code = f"import sys, {mod}; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
