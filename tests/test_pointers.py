"""Every pointer in the code resolves inside the repository (issue 39: the code cited a
DESIGN.md that was never in it): a file under docs/ or bench/ that code, tests or docs
name exists, and a section of docs/method.md named in quotes is one of its headings."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [
    *(ROOT / "client").rglob("*.py"),
    *(ROOT / "service").rglob("*.py"),
    *(ROOT / "workers").rglob("*.py"),
    *(ROOT / "bench").rglob("*.py"),
    *(ROOT / "tests").rglob("*.py"),
    *(ROOT / "examples").rglob("*.yaml"),
    *(ROOT / "examples").rglob("*.py"),
    *(ROOT / "service" / "adservice" / "static" / "js").glob("*.js"),
    *(ROOT / "docs").glob("*.md"),
    ROOT / "bench" / "RESULTS.md",
    ROOT / "README.md",
]
FILE = re.compile(r"(?<![\w/.])((?:docs|bench|examples)/[\w/.-]+\.(?:md|py|yaml))")
SECTION = re.compile(r'docs/method\.md,\s+#?\s*"([^"]+)"|"([^"]+)" in docs/method\.md')


def test_files_named_in_the_code_and_docs_exist() -> None:
    missing = {
        f"{source.relative_to(ROOT)}: {name}"
        for source in SOURCES
        for name in FILE.findall(source.read_text())
        if not (ROOT / name).exists()
    }
    assert missing == set()
    assert not [s for s in SOURCES if "DESIGN" + ".md" in s.read_text() and s != Path(__file__)]


def test_sections_of_the_method_named_in_the_code_are_its_headings() -> None:
    headings = set(re.findall(r"^#+ (.+)$", (ROOT / "docs" / "method.md").read_text(), re.M))
    named = {a or b for source in SOURCES for a, b in SECTION.findall(source.read_text())}
    assert len(named) >= 3
    assert named <= headings, named - headings
