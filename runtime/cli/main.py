"""`litevloc` command line: one console script, one module per subcommand.

Each module in `COMMANDS` defines `register(subparsers)` which adds its parser and sets
`func` (called with the parsed args; returns an exit code). Errors that a user can fix
(`ConfigError`, `StreamError`, ...) are caught here and printed as one line, exit 2.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import sys
from collections.abc import Sequence

# Subcommand modules (litevloc.runtime.cli.<name>), in help order.
COMMANDS = ("info", "demo", "run", "convert", "replay", "record", "sim", "models", "map", "localize", "bench",
            "calib", "plan", "goal")


class UserError(Exception):
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
        importlib.import_module(f"litevloc.runtime.cli.{name}").register(sub)
    return parser


def _user_errors() -> tuple[type[BaseException], ...]:
    from litevloc.config import ConfigError
    from litevloc.hw.messages import StreamError
    from litevloc.pipelines.geometry import GeometryError

    errors: list[type[BaseException]] = [UserError, ConfigError, StreamError, GeometryError, FileNotFoundError]
    try:
        from litevloc.models.registry import ModelError

        errors.append(ModelError)
    except ImportError:
        pass
    try:
        from litevloc.hw.sim.render import RenderError
        from litevloc.hw.sim.textures import TextureError
        from litevloc.hw.sim.trajectory import PlanningError

        errors += [RenderError, TextureError, PlanningError]
    except ImportError:
        pass
    for mod, name in (("litevloc.runtime.bus", "BusError"), ("litevloc.runtime.service", "ServiceError")):
        with contextlib.suppress(ImportError, AttributeError):
            errors.append(getattr(importlib.import_module(mod), name))
    try:
        from litevloc.pipelines.topomap.io import MapFormatError

        errors.append(MapFormatError)
    except ImportError:
        pass
    return tuple(errors)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.func(args) or 0)
    except _user_errors() as exc:
        print(f"litevloc {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"litevloc {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
