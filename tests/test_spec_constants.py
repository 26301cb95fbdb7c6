"""Every SPEC number is defined once, in ``vp2/spec.py``: nowhere else in the package does a
name of that constant get its literal value (a module constant, a default argument, a CLI
default). Docstrings and comments may mention the numbers; they are not read here."""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest

from vp2 import spec

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "vp2"

# (what, name pattern, value): a NAME (or a "--flag") matching the pattern given this value.
RULES: list[tuple[str, str, object]] = [
    ("NUM_SAMPLES", r"\w*samples\w*|max_batch_size", spec.NUM_SAMPLES),
    ("LARGE_NUM_SAMPLES", r"\w*samples\w*|max_batch_size", spec.LARGE_NUM_SAMPLES),
    ("MAIN_JOB_NUM_SAMPLES", r"model_samples|main\w*samples", spec.MAIN_JOB_NUM_SAMPLES),
    ("GAMMA", r"\w*gamma\w*", spec.GAMMA),
    ("BETA", r"\w*beta\w*", spec.BETA),
    ("NUM_ITERATIONS", r"\w*iterations\w*", spec.NUM_ITERATIONS),
    ("NUM_CONTROL_STEPS", r"num_steps|\w*control_steps\w*", spec.NUM_CONTROL_STEPS),
    ("NUM_CONTEXT", r"num_context\w*", spec.NUM_CONTEXT),
    ("NUM_FUTURE", r"num_future\w*|horizon", spec.NUM_FUTURE),
    ("MIN_SEEDS", r"\w*min_seeds\w*", spec.MIN_SEEDS),
    ("ROBODESK_PIXEL_WEIGHT", r"\w*pixel_weight\w*", spec.ROBODESK_PIXEL_WEIGHT),
    ("TABLETOP_PIXEL_WEIGHT", r"\w*pixel_weight\w*", spec.TABLETOP_PIXEL_WEIGHT),
    ("ROBODESK_CLASSIFIER_WEIGHT", r"\w*classifier_weight\w*", spec.ROBODESK_CLASSIFIER_WEIGHT),
    ("ENSEMBLE_DISAGREEMENT_WEIGHT", r"lam|\w*disagreement\w*", spec.ENSEMBLE_DISAGREEMENT_WEIGHT),
]
SIGMA_LITERALS = {env: tuple(s) for env, s in spec.SIGMA.items()}


def code_only(text: str) -> str:
    """The source with comments and strings blanked (same lines and columns), except
    ``"--flag"`` strings, which stay."""
    lines = text.splitlines(keepends=True)
    chars = [list(line) for line in lines]
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type == tokenize.STRING and tok.string.strip("'\"rbfu").startswith("--"):
            continue
        if tok.type not in (tokenize.COMMENT, tokenize.STRING):
            continue
        (srow, scol), (erow, ecol) = tok.start, tok.end
        for row in range(srow, erow + 1):
            line = chars[row - 1]
            lo = scol if row == srow else 0
            hi = ecol if row == erow else len(line)
            for i in range(lo, hi):
                if line[i] != "\n":
                    line[i] = " "
    return "".join("".join(line) for line in chars)


def literal(value: object) -> str:
    if isinstance(value, float):
        text = repr(value)
        return re.escape(text[:-2] if text.endswith(".0") else text) + r"(?:\.0*)?"
    return re.escape(str(value))


def violations(text: str) -> list[str]:
    code = code_only(text)
    found = []
    for what, names, value in RULES:
        num = literal(value)
        assign = rf"\b(?:{names})\b\s*(?::[^=\n]*?)?=\s*{num}(?![\w.*])"
        flag_names = names.replace(r"\w", r"[\w-]").replace("_", "[-_]")
        flag = rf'["\x27]--(?:{flag_names})["\x27][^)]*?\bdefault\s*=\s*{num}(?![\w.*])'
        for pattern in (assign, flag):
            for m in re.finditer(pattern, code, re.IGNORECASE | re.DOTALL):
                line = code.count("\n", 0, m.start()) + 1
                found.append(f"{what} ({value}) at line {line}: {m.group(0)[:60]!r}")
    for env, sigma in SIGMA_LITERALS.items():
        tup = r"\(\s*" + r"\s*,\s*".join(literal(v) for v in sigma) + r"\s*,?\s*\)"
        for m in re.finditer(tup, code):
            line = code.count("\n", 0, m.start()) + 1
            found.append(f"SIGMA[{env}] at line {line}")
    return found


def package_files() -> list[Path]:
    return [p for p in sorted(PACKAGE.rglob("*.py")) if p.name != "spec.py" or p.parent != PACKAGE]


@pytest.mark.parametrize("path", package_files(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_spec_numbers_are_not_written_again(path):
    assert violations(path.read_text()) == []


def test_the_check_finds_a_second_definition():
    planted = (
        "def mppi(num_samples: int = 200, gamma: float = 0.05):\n"
        "    '''uses num_samples = 200 (docstrings are fine)'''\n"
        "    # NUM_SAMPLES = 200 in a comment is fine\n"
        "p.add_argument('--model-samples', type=int, default=50)\n"
        "SIGMA = (0.5, 0.5, 0.5, 0.1, 0.1)\n"
        "MIN_SEEDS = 3\n"
    )
    found = violations(planted)
    assert [f.split(" ")[0] for f in found] == [
        "NUM_SAMPLES", "MAIN_JOB_NUM_SAMPLES", "GAMMA", "MIN_SEEDS", "SIGMA[robodesk]"
    ]
    assert violations("from vp2.spec import NUM_SAMPLES\nnum_samples = NUM_SAMPLES\n") == []
    assert [f.split(" ")[0] for f in violations("def cost(lam: float = 0.01): ...\n")] == [
        "ENSEMBLE_DISAGREEMENT_WEIGHT"
    ]
