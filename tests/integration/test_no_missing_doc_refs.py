"""Every document the code and docs cite is in the repository (issue 14).

The design document the early code cited by section number was never committed, so a
reader could not follow those references. They now name docs/protocol.md, docs/safety.md,
broker/README.md or a module; this test keeps it that way for tracked .py and .md files.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# The design document cited by section ("DESIGN" + " §3", also without the space) or by file name (".md").
MISSING_DOC = re.compile(r"\bDESIGN\s*(?:§|\.md\b)")


def _tracked_sources() -> list[Path]:
    out = subprocess.run(
        ["git", "ls-files", "-z", "--", "*.py", "*.md"],
        cwd=ROOT, capture_output=True, check=True, timeout=30,
    ).stdout.decode()
    return [ROOT / name for name in out.split("\0") if name]


def find_missing_doc_refs(paths: list[Path]) -> list[str]:
    hits = []
    for path in paths:
        if not path.is_file():  # deleted in the work tree, not yet in the index
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if MISSING_DOC.search(line):
                name = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name
                hits.append(f"{name}:{number}: {line.strip()}")
    return hits


def test_pattern_catches_the_old_spellings(tmp_path: Path) -> None:
    sample = tmp_path / "sample.md"
    sample.write_text("ok\nsee " + "DESIGN" + " §3\n" + "DESIGN" + ".md\nDESIGNER notes\n", encoding="utf-8")
    assert [hit.split(":")[1] for hit in find_missing_doc_refs([sample])] == ["2", "3"]


def test_no_reference_to_a_document_outside_the_repository() -> None:
    paths = _tracked_sources()
    assert any(p.name == "protocol.md" for p in paths)  # the listing really covers the docs
    hits = find_missing_doc_refs(paths)
    assert not hits, "cite a file in the repository instead:\n" + "\n".join(hits)
