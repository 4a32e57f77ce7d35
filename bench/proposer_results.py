"""Writes the proposer benchmarks' figures into their own section of bench/RESULTS.md.

The section "## Proposers (issue 4)" holds one subsection per benchmark; a rerun
replaces its own subsection and leaves every other section of the file alone.
"""

from __future__ import annotations

import re
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
SECTION = "## Proposers (issue 4)"


def _split(text: str, heading: str, level: int) -> tuple[str, str, str]:
    """(before, the block that starts with ``heading``, after); the block ends at the
    next heading of the same or a higher level."""
    start = text.find(heading + "\n")
    if start < 0:
        return text, "", ""
    body_start = start + len(heading) + 1
    pattern = re.compile(rf"^#{{1,{level}}} ", re.MULTILINE)
    match = pattern.search(text, body_start)
    end = match.start() if match else len(text)
    return text[:start], text[start:end], text[end:]


def write_subsection(subheading: str, body: str, path: Path = RESULTS) -> None:
    """Replace (or add) ``### subheading`` inside the proposers' section."""
    text = path.read_text() if path.exists() else "# Benchmark results\n\n"
    before, section, after = _split(text, SECTION, 2)
    if not section:
        before = before.rstrip("\n") + "\n\n"
        section = SECTION + "\n\n"
    head, old, tail = _split(section, subheading, 3)
    block = f"{subheading}\n\n{body.strip()}\n\n"
    section = head + block + tail if old else section.rstrip("\n") + "\n\n" + block
    path.write_text(before + section.rstrip("\n") + "\n\n" + after.lstrip("\n"))


def write_section(heading: str, body: str, path: Path = RESULTS) -> None:
    """Replace (or append) the top-level ``## heading`` section of its own."""
    text = path.read_text() if path.exists() else "# Benchmark results\n\n"
    before, old, after = _split(text, heading, 2)
    block = f"{heading}\n\n{body.strip()}\n\n"
    if old:
        path.write_text(before + block + after.lstrip("\n"))
    else:
        path.write_text(text.rstrip("\n") + "\n\n" + block)
