"""Helpers shared by subcommands: the common flags, the configuration and the input they name."""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.base.frames import parse_frames
from litevloc.config import load_config
from litevloc.config.schema import LiteVLocConfig
from litevloc.hw.streams.base import StreamSource


def add_frames_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="take part of the input: a Python slice over frame indices")


def add_json_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="write a machine-readable summary here")


def add_config_args(p: argparse.ArgumentParser, required: bool = False) -> None:
    p.add_argument("--config", default=None, required=required, help="preset name (see `litevloc info`) or YAML file")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one config value, e.g. --set replay.rate=2 (repeatable)")


def frames_of(args: argparse.Namespace) -> slice:
    try:
        return parse_frames(getattr(args, "frames", None))
    except ValueError as exc:
        from litevloc.cli.main import UserError

        raise UserError(str(exc)) from exc


def config_of(args: argparse.Namespace) -> LiteVLocConfig:
    return load_config(getattr(args, "config", None), getattr(args, "overrides", []))


def source_of(args: argparse.Namespace, cfg: LiteVLocConfig) -> StreamSource:
    """`args.src` opened strictly, limited to `--frames`, with the config's RGB-D calibration."""
    from litevloc.runtime.sources import open_source

    return open_source(args.src, frames_of(args), strict=True, rgbd_calibration=cfg.rgbd_calibration)
