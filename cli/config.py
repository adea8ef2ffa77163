"""`litevloc config show [PREFIX] [--config P] [--set KEY=VALUE] [--flat]`: the effective settings as
the nested tree of sections, each with its value, unit, allowed range, where the value came from
(default / the YAML file / override) and its description."""

from __future__ import annotations

import argparse

from litevloc.cli.common import add_config_args
from litevloc.config.describe import Setting, load_with_origins, walk
from litevloc.config.render import render_text, render_tree


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="show the effective settings with their descriptions and origins")
    csub = p.add_subparsers(dest="config_command", metavar="SUBCOMMAND")
    csub.required = True
    s = csub.add_parser("show", help="the settings tree: name = value unit [origin] range description")
    s.add_argument("prefix", nargs="?", default="", help="only keys starting with this, e.g. mapping.keyframes")
    s.add_argument("--changed", action="store_true", help="only the settings that differ from the code default")
    s.add_argument("--flat", action="store_true", help="one line per setting with its dotted key, no tree")
    add_config_args(s)
    s.set_defaults(func=show)


def show(args: argparse.Namespace) -> int:
    from litevloc.cli.main import UserError

    prefix = args.prefix.rstrip(".")
    items = walk(load_with_origins(args.config, args.overrides))
    rows = [r for r in items if isinstance(r, Setting) and (not prefix or r.key == prefix
                                                            or r.key.startswith(prefix + "."))]
    if args.changed:
        rows = [r for r in rows if r.value != r.default]
    if not rows and args.prefix:
        raise UserError(f"no setting starts with {args.prefix!r} (see `litevloc config show`)")
    keep = {r.key for r in rows}
    print(render_text(rows) if args.flat else render_tree([r for r in items if not isinstance(r, Setting)
                                                           or r.key in keep]), end="")
    return 0
