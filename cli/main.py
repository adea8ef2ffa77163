"""`litevloc` command line: one console script, one module per subcommand.

Each module in `COMMANDS` defines `register(subparsers)` which adds its parser and sets
`func` (called with the parsed args; returns an exit code). Every LiteVLoc domain error
derives from `litevloc.base.errors.LiteVLocError` (`ConfigError`, `StreamError`,
`MapFormatError`, `ModelError`, ...): it is caught here, with `FileNotFoundError`, and
printed as one line, exit 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from litevloc.base.errors import LiteVLocError

# Subcommand modules (litevloc.cli.<name>), in help order.
COMMANDS = ("info", "demo", "run", "convert", "replay", "record", "sim", "models", "map", "localize", "bench",
            "calib", "plan", "goal", "config")


class UserError(LiteVLocError):
    """An error the user can fix (bad path, bad argument); printed without a traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="litevloc",
        description="LiteVLoc: map-lite visual localization runtime for image-goal navigation",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"litevloc.cli.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.func(args) or 0)
    except (LiteVLocError, FileNotFoundError) as exc:
        print(f"litevloc {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"litevloc {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
