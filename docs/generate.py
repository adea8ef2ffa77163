"""Regenerate the documentation that the code can write: docs/parameters.md (every setting,
from the settings declarations and presets) and docs/cli.md (every command, from the parsers).

    python docs/generate.py          # rewrite them
    python docs/generate.py --check  # exit 1 when a committed file is stale (the tests do this)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from litevloc.cli.reference import render_cli_reference
from litevloc.config import preset_names
from litevloc.config.describe import load_with_origins
from litevloc.config.render import render_markdown

DOCS = Path(__file__).resolve().parent


def generated() -> dict[Path, str]:
    """{file: its generated text}."""
    return {DOCS / "parameters.md": render_markdown({p: load_with_origins(p) for p in preset_names()}),
            DOCS / "cli.md": render_cli_reference()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check that the committed files are current")
    args = ap.parse_args()
    stale = []
    for path, text in generated().items():
        if path.exists() and path.read_text() == text:
            continue
        stale.append(path.name)
        if not args.check:
            path.write_text(text)
            print(f"wrote {path}")
    if args.check and stale:
        print(f"stale: {', '.join(stale)} (run `python docs/generate.py`)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
