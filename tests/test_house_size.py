"""What a newcomer reads stays short (issue 29): the repository by aggregate, each module
under about 400 lines (one module of 1,209 lines held seven aggregates), and a README
that opens with the two commands and fits a minute's reading, its detail in docs/."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REPOSITORY = ROOT / "service" / "adservice" / "repository"


def test_each_repository_module_holds_one_aggregate_in_under_400_lines() -> None:
    sizes = {path.name: len(path.read_text().splitlines()) for path in REPOSITORY.glob("*.py")}
    assert len(sizes) >= 8, sizes  # studies, trials, tell, leases, artifacts, tokens, ...
    assert not {name: n for name, n in sizes.items() if n > 400}
    assert not list((ROOT / "service" / "adservice").glob("repository*.py"))


def test_the_readme_opens_with_the_two_commands_and_stays_short() -> None:
    text = (ROOT / "README.md").read_text()
    first_block = re.search(r"```\w*\n(.*?)```", text, re.S)
    assert first_block is not None and text.index("```") < 40  # before any prose
    assert [line.split()[:2] for line in first_block.group(1).splitlines()] == [
        ["make", "demo"],
        ["make", "test"],
    ]
    assert len(text.splitlines()) <= 120
    headings = re.findall(r"^## (.+)$", text, re.M)
    assert headings[:3] == ["Quick start", "Commands", "Docs"]
    for link in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (ROOT / link).exists(), link
