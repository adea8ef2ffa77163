"""The README stays a short guide and the docs stay readable: README <= 15 KB, no Markdown table
cell over 300 characters, every relative link points at a file."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_the_readme_is_at_most_15_kb() -> None:
    assert (ROOT / "README.md").stat().st_size <= 15 * 1024


def test_no_table_cell_is_over_300_characters() -> None:
    long = [(doc.name, cell[:60]) for doc in DOCS for line in doc.read_text().splitlines()
            if line.startswith("|") for cell in line.strip("|").split(" | ") if len(cell.strip()) > 300]
    assert long == []


def test_relative_links_point_at_files() -> None:
    missing = []
    for doc in DOCS:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", doc.read_text()):
            if "://" in target:
                continue
            if not (doc.parent / target).resolve().exists():
                missing.append((doc.name, target))
    assert missing == []
