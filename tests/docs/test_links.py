"""The documentation holds together: every relative link in README.md, docs/ and benchmarks/README.md
names a file that exists and, with ``#anchor``, a heading of that page; no heading names a
session or an issue (docs describe the present; dated findings live in docs/findings/)."""

from __future__ import annotations

import functools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", ROOT / "benchmarks" / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")


def prose_lines(path: Path):
    """``(number, line)`` of a Markdown page outside fenced code blocks."""
    fenced = False
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced:
            yield number, line


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: link text kept, lower case, punctuation dropped."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


@functools.cache
def anchors(path: Path) -> frozenset[str]:
    """The anchors of a page's headings (a repeated heading gets ``-1``, ``-2``, ...)."""
    count: dict[str, int] = {}
    found = set()
    for _, line in prose_lines(path):
        if m := HEADING.match(line):
            s = slug(m.group(2))
            found.add(f"{s}-{count[s]}" if s in count else s)
            count[s] = count.get(s, 0) + 1
    return frozenset(found)


def broken_links(page: Path) -> list[str]:
    bad = []
    for number, line in prose_lines(page):
        for m in LINK.finditer(re.sub(r"`[^`]*`", "", line)):
            target = m.group(1)
            if re.match(r"^[a-z]+:", target):  # http:, mailto:, ...
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page.resolve()
            if not dest.exists():
                bad.append(f"{page.relative_to(ROOT)}:{number}: no file {target}")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                bad.append(f"{page.relative_to(ROOT)}:{number}: no heading #{anchor} in {path}")
    return bad


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    assert broken_links(page) == []


def test_the_checker_finds_a_broken_file_and_anchor(tmp_path):
    page = tmp_path / "a.md"
    (tmp_path / "b.md").write_text("# Real heading\n## Twice\n## Twice\n")
    page.write_text("[x](b.md#real-heading) [y](b.md#gone) [z](c.md) [v](b.md#twice-1)\n"
                    "```\n[w](d.md)\n```\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        assert broken_links(page) == ["a.md:1: no heading #gone in b.md", "a.md:1: no file c.md"]
    finally:
        ROOT = saved


def test_no_heading_names_a_session_or_an_issue():
    bad = [f"{page.relative_to(ROOT)}:{n}: {line}" for page in PAGES
           for n, line in prose_lines(page)
           if HEADING.match(line) and re.search(r"\b(session|issue)s?\b", line, re.IGNORECASE)]
    assert bad == []


def test_the_readme_defines_the_benchmark_inside_the_repository():
    readme = (ROOT / "README.md").read_text()
    assert "docs/protocol.md" in readme
    assert "../shared" not in readme and "SPEC.md" not in readme
