"""docs/architecture.md names every plant-side class in one table, with its module (issue
43): a class added or removed under tspend/plants/ without the table following fails here."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _classes_in_code() -> set[tuple[str, str]]:
    out = set()
    plants = ROOT / "tspend" / "plants"
    for path in sorted(plants.rglob("*.py")):
        tree = ast.parse(path.read_text())
        module = path.relative_to(plants).as_posix()
        out |= {(node.name, module) for node in tree.body
                if isinstance(node, ast.ClassDef) and not node.name.startswith("_")}
    return out


def _classes_in_table() -> set[tuple[str, str]]:
    text = (ROOT / "docs" / "architecture.md").read_text()
    section = text.split("## Plant-side classes", 1)[1].split("\n## ", 1)[0]
    out = set()
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not cells[0].startswith("`"):
            continue
        module = cells[1].strip("`")
        out |= {(name, module) for name in re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", cells[0])}
        assert cells[2], f"{cells[0]}: no job given"
    return out


def test_every_plant_side_class_is_in_the_table_and_nothing_else():
    code, table = _classes_in_code(), _classes_in_table()
    assert not code - table, f"not in docs/architecture.md's table: {sorted(code - table)}"
    assert not table - code, f"in the table but not in tspend/plants/: {sorted(table - code)}"
