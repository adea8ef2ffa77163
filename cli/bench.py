"""`litevloc bench NAME ...`: benchmarks as a command group.

Each name in `BENCHES` is a module `litevloc.cli.bench_<name>` defining
`register(subparsers)` (adds its parser, sets `func`), like the top-level commands.
Add `bench reloc` by writing `bench_reloc.py` and appending "reloc" here.
"""

from __future__ import annotations

import argparse
import importlib

BENCHES = ("fusion", "reloc")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks: accuracy and speed tables, JSON with --json")
    bsub = p.add_subparsers(dest="bench", metavar="BENCH")
    bsub.required = True
    for name in BENCHES:
        importlib.import_module(f"litevloc.cli.bench_{name}").register(bsub)
