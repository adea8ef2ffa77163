"""`litevloc run --config CFG`: the onboard service (until SIGINT/SIGTERM or end of a recording)."""

from __future__ import annotations

import argparse
import json
import logging
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from litevloc.cli.common import add_config_args, add_json_arg, config_of, frames_of
from litevloc.cli.main import UserError
from litevloc.runtime.tools.outputs import write_json

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the onboard localization service")
    add_config_args(p, required=True)
    add_service_args(p)
    p.add_argument("--source", type=Path, default=None, help="replay this recording instead of the configured driver")
    p.add_argument("--rate", type=float, default=None,
                   help="real-time factor for --source (default: config replay.rate)")
    add_json_arg(p)
    p.set_defaults(func=run)


def add_service_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", type=Path, default=None,
                   help="map folder, or zenoh:NAME[@VERSION] fetched from the map service first (default: the "
                        "config's `map`)")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="e.g. tcp/127.0.0.1:7447")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT")
    p.add_argument("--namespace", default=None, help="key-expression prefix, e.g. robot1")
    add_view_args(p)
    p.add_argument("--fault", action="append", default=[], metavar="KIND@START:DURATION",
                   help="inject a fault (tests/benchmarks), e.g. camera_dropout@10:5; see runtime/service/faults.py")


def add_view_args(p: argparse.ArgumentParser) -> None:
    """`--view` / `--view-save FILE` (the live Rerun view, runtime/service/view.py; off by default)."""
    p.add_argument("--view", action="store_true",
                   help="show the live view: spawn the Rerun viewer and stream to it (needs rerun-sdk and a display)")
    p.add_argument("--view-save", type=Path, default=None, metavar="FILE.rrd",
                   help="save the live view's stream to this .rrd file (open it later with `rerun FILE.rrd`)")


def make_view(args: argparse.Namespace, topomap: Any = None, T_base_camera: Any = None) -> Any:
    """A `runtime.service.view.LiveView` for --view / --view-save, else None (rerun is then never imported)."""
    if not getattr(args, "view", False) and getattr(args, "view_save", None) is None:
        return None
    from litevloc.runtime.service.view import LiveView, ViewError

    try:
        return LiveView(save=args.view_save, spawn=args.view, topomap=topomap, T_base_camera=T_base_camera)
    except ViewError as exc:
        raise UserError(str(exc)) from exc


def open_configured_source(cfg: Any, path: Path | None, frames: slice = slice(None)) -> Any:
    """--source (limited to `frames`), else the config's source (`source.kind`, opened through
    `runtime.sources.SOURCE_KINDS`: a recording, dataset, sim URI, or a camera)."""
    from litevloc.base.frames import parse_frames
    from litevloc.runtime.sources import SourceUse, open_source, source_kind

    if path is not None:
        return open_source(path, frames, strict=cfg.source.strict, rgbd_calibration=cfg.rgbd_calibration)
    kind = source_kind(cfg.source.kind)
    if kind.needs_path and not cfg.source.path:
        raise UserError(f"config source.kind is {cfg.source.kind!r} but source.path is empty; give --source")
    return kind.open(cfg, parse_frames(cfg.source.frames or None), SourceUse.SERVICE)


def follow_map(cfg: Any, uri: str, fetched: Any, app: Any) -> ExitStack | None:
    """A map follower for `--map zenoh:NAME` (no @VERSION, `fleet.follow_latest`) on a robot session
    of its own: announced versions are fetched and switched to while the service runs; closing the
    stack closes the follower, then the session. None when the map is pinned or not followed."""
    from litevloc.runtime.maps.app import parse_map_uri, robot_session
    from litevloc.runtime.maps.follow import MapFollower

    parsed = parse_map_uri(uri)
    if parsed is None or parsed[1] is not None or not cfg.fleet.follow_latest or fetched.offline:
        return None
    stack = ExitStack()
    session = stack.enter_context(robot_session(cfg.zenoh))
    stack.callback(MapFollower(session, fetched.name, fetched.version, cfg.fleet, app.request_map_switch).close)
    return stack


def run_service(args: argparse.Namespace, source_path: Path | None, rate: float | None, record: bool = True) -> dict:
    from litevloc.runtime.service.app import build_app, with_endpoints

    cfg = with_endpoints(config_of(args), args.listen, args.connect, args.namespace)
    src = open_configured_source(cfg, source_path, frames_of(args))  # first: a missing camera is the first error
    map_path = args.map or (Path(cfg.map) if cfg.map else None)
    if map_path is None:
        raise UserError("no map: give --map MAP or set `map:` in the config")
    fetched = None
    if str(map_path).startswith("zenoh:"):
        from litevloc.runtime.maps.app import resolve_map

        fetched = resolve_map(str(map_path), cfg.zenoh, cfg.fleet)
        assert fetched is not None
        map_path = fetched.path
    faults = None
    if getattr(args, "fault", None):
        from litevloc.runtime.service.faults import FaultInjector, FaultSpecError

        try:
            faults = FaultInjector(args.fault)  # parsed before the (slow) model loading
        except FaultSpecError as exc:
            raise UserError(str(exc)) from exc
    view_spawn = bool(getattr(args, "view", False))
    view_save: Path | None = getattr(args, "view_save", None)
    try:
        from litevloc.runtime.sources import service_messages

        msgs = service_messages(src, reader_process=cfg.runtime.recording_process and cfg.runtime.mode != "sequential")
        app = build_app(cfg, map_path, msgs, cfg.replay.rate if rate is None else rate,
                        record=record, view_spawn=view_spawn, view_save=view_save,
                        map_name=fetched.name if fetched else None, map_version=fetched.version if fetched else None)
    except Exception as exc:
        if view_spawn or view_save is not None:  # (rerun is imported only then)
            from litevloc.runtime.service.view import ViewError

            if isinstance(exc, ViewError):
                raise UserError(str(exc)) from exc
        raise
    if faults is not None:
        faults.apply(app.service)
    follow = follow_map(cfg, str(args.map or cfg.map), fetched, app) if fetched is not None else None
    try:
        result = app.service.run(install_signals=True)
    finally:
        if follow is not None:
            follow.close()
        app.close()
    status = result.status
    if app.view is not None:
        status["view"] = app.view.report()
        log.info("view: %s", status["view"])
    out = {"ok": result.ok, "reason": result.reason, "status": status, "recorder": app.recorder,
           "T_base_camera": app.T_base_camera}
    if faults is not None:
        status["faults"] = faults.report()
    if not result.ok:
        log.error("service stopped: %s", result.reason)
    return out


def run(args: argparse.Namespace) -> int:
    res = run_service(args, args.source, args.rate, record=False)  # runs for hours: keep no trajectory
    print(f"litevloc run: {res['reason']}")
    write_json(args.json, {"ok": res["ok"], "reason": res["reason"], "status": json.loads(json.dumps(res["status"],
                                                                                                     default=str))})
    return 0 if res["ok"] else 1
