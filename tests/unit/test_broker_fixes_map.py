"""broker/FIXES.md maps every hardened fix to the tests that prove it: each fix has a "Tests:" line, and every test
it names exists (a renamed or deleted test would otherwise leave the map pointing at nothing)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIXES = ROOT / "broker" / "FIXES.md"
REFERENCE = re.compile(r"`(tests/[\w/]+\.py)::(\w+)")


def _sections(text: str) -> dict[str, str]:
    body = text[text.index("## The fixes"): text.index("## Gaps")]
    parts = re.split(r"(?m)^### ", body)[1:]
    return {part.split("\n", 1)[0]: part for part in parts}


def _test_names(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    return {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
            and node.name.startswith("test_")}


def test_every_fix_names_tests_and_every_named_test_exists() -> None:
    sections = _sections(FIXES.read_text())
    assert len(sections) >= 31
    missing = []
    for title, text in sections.items():
        named = REFERENCE.findall(text)
        assert "**Tests:**" in text and named, f"fix {title!r} names no test"
        for file, test in named:
            path = ROOT / file
            if not path.exists() or test not in _test_names(path):
                missing.append(f"{title}: {file}::{test}")
    assert not missing, "FIXES.md names tests that do not exist:\n" + "\n".join(missing)


def test_the_check_notices_a_test_that_is_gone(tmp_path: Path) -> None:
    module = tmp_path / "test_x.py"
    module.write_text("def test_kept():\n    pass\n")
    assert _test_names(module) == {"test_kept"}
    assert REFERENCE.findall("* **Tests:** `tests/x/test_x.py::test_gone`") == [("tests/x/test_x.py", "test_gone")]
