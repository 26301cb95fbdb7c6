"""The README's oracle table (Known limits) says what the shipped asset holds."""

from __future__ import annotations

import re
from pathlib import Path

from vp2.oracle.shipped import load_shipped_oracle

README = Path(__file__).resolve().parents[2] / "README.md"
#: The README's column order.
COLUMNS = ("robodesk/push_red", "robodesk/push_green", "robodesk/push_blue",
           "robodesk/open_slide", "robodesk/open_drawer", "robodesk/flat_block_off_table",
           "robodesk/upright_block_off_table", "tabletop/push_large_cube",
           "tabletop/push_small_cube", "tabletop/push_cylinder", "tabletop/push_sphere")


def _readme_rows() -> dict[str, list[str]]:
    rows = {}
    for line in README.read_text().splitlines():
        match = re.match(r"\s*\| `([\w-]+)`[^|]*\| #0–#\d \|(.*)\|\s*$", line)
        if match:
            rows[match.group(1)] = [c.strip() for c in match.group(2).split("|")]
    return rows


def test_the_readme_oracle_table_is_the_shipped_one():
    shipped = load_shipped_oracle()
    rows = _readme_rows()
    assert shipped is not None and set(rows) == {t.name for t in shipped.tables}
    for table in shipped.tables:
        expected = [f"{table.tasks[c].successes}/{table.tasks[c].trials}" for c in COLUMNS]
        assert rows[table.name] == expected, table.name
