"""The datasheet-conformance tables name tests that exist (docs/reference/conformance-*.md)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_test_a_conformance_table_names_exists():
    defined = set()
    for path in (ROOT / "tests").glob("test_*.py"):
        defined |= set(re.findall(r"^def (test_\w+)", path.read_text(), flags=re.M))
    tables = sorted((ROOT / "docs" / "reference").glob("conformance-*.md"))
    assert len(tables) == 6
    for table in tables:
        named = set(re.findall(r"`(test_\w+)(?:\[[^\]]*\])?`", table.read_text()))
        assert named, table.name
        assert named <= defined, f"{table.name} names missing tests: {sorted(named - defined)}"
