"""`litevloc config show [PREFIX] [--config P] [--set KEY=VALUE]`: the effective settings, each
with its description and where its value came from (default / the YAML file / override)."""

from __future__ import annotations

import argparse

from litevloc.cli.common import add_config_args
from litevloc.config.describe import load_with_origins, render_text, settings


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="show the effective settings with their descriptions and origins")
    csub = p.add_subparsers(dest="config_command", metavar="SUBCOMMAND")
    csub.required = True
    s = csub.add_parser("show", help="every effective setting: key = value [origin] description")
    s.add_argument("prefix", nargs="?", default="", help="only keys starting with this, e.g. mapping.keyframes")
    s.add_argument("--changed", action="store_true", help="only the settings that differ from the code default")
    add_config_args(s)
    s.set_defaults(func=show)


def show(args: argparse.Namespace) -> int:
    from litevloc.cli.main import UserError

    rows = settings(load_with_origins(args.config, args.overrides))
    rows = [r for r in rows if r.key == args.prefix or r.key.startswith(args.prefix.rstrip(".") + ".")
            or not args.prefix]
    if args.changed:
        rows = [r for r in rows if r.value != r.default]
    if not rows and args.prefix:
        raise UserError(f"no setting starts with {args.prefix!r} (see `litevloc config show`)")
    print(render_text(rows), end="")
    return 0
