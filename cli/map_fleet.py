"""`litevloc map serve|fetch|versions|rollback|push`: the map service on Zenoh and its clients
(`litevloc.runtime.maps`; docs/fleet.md)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import yaml

from litevloc.cli.common import add_config_args, add_json_arg, config_of
from litevloc.cli.main import UserError
from litevloc.runtime.tools.outputs import write_json


def _add_endpoints(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="e.g. tcp/192.168.1.10:7447")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="the map service or a router")
    add_config_args(p)  # zenoh.* (TLS, user/password, access control) and fleet.*


def add_fleet_parsers(msub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    s = msub.add_parser("serve", help="serve the versioned maps in DIR on Zenoh (router by default)")
    s.add_argument("dir", type=Path, help="the map store (created if missing)")
    s.add_argument("--mode", choices=("router", "peer", "client"), default="router",
                   help="router (default: robots connect to it), or a peer/client of an existing router")
    s.add_argument("--add", action="append", default=[], metavar="NAME=MAP",
                   help="publish this map folder as the latest version of NAME first (repeatable)")
    s.add_argument("--acl", type=Path, default=None, metavar="FILE.yaml",
                   help="who may read, push, roll back: {readers: [...], writers: [...], admins: [...], "
                        "by: username|cert_common_name, allow_other: [key exprs]}")
    s.add_argument("--held-out", type=Path, default=None, metavar="REC",
                   help="posed recording of the held-out check that decides pushes (without it pushes are refused)")
    _add_endpoints(s)
    s.set_defaults(func=serve)
    f = msub.add_parser("fetch", help="fetch a map version from the map service into a folder")
    f.add_argument("ref", help="NAME or NAME@VERSION (a hash or a unique prefix of >= 8 hex digits)")
    f.add_argument("-o", "--output", type=Path, required=True, help="folder to write the map to")
    f.add_argument("--force", action="store_true", help="replace an existing output folder")
    _add_endpoints(f)
    add_json_arg(f)
    f.set_defaults(func=fetch)
    v = msub.add_parser("versions", help="list a served map's versions and which one is latest")
    v.add_argument("name")
    _add_endpoints(v)
    add_json_arg(v)
    v.set_defaults(func=versions)
    r = msub.add_parser("rollback", help="make an older version the latest again (nothing is deleted)")
    r.add_argument("name")
    r.add_argument("version", help="a hash or a unique prefix of >= 8 hex digits")
    r.add_argument("--store", type=Path, default=None, help="roll back in this store folder directly (service stopped)")
    _add_endpoints(r)
    r.set_defaults(func=rollback)
    p = msub.add_parser("push", help="send a recording or a session map to the map service, which merges or updates "
                                     "it into a candidate and publishes it if its held-out check is not worse")
    p.add_argument("src", type=Path, help="a recording file (map update) or a map folder (map merge)")
    p.add_argument("--to", required=True, metavar="NAME", help="the served map to contribute to")
    _add_endpoints(p)
    add_json_arg(p)
    p.set_defaults(func=push)


def _zenoh(args: argparse.Namespace) -> Any:
    import dataclasses

    cfg = config_of(args)
    z = cfg.zenoh
    if args.listen:
        z = dataclasses.replace(z, listen=tuple(args.listen))
    if args.connect:
        z = dataclasses.replace(z, connect=tuple(args.connect))
    return cfg, z


def _acl(path: Path | None) -> Any:
    if path is None:
        return None
    from litevloc.runtime.maps.access import map_acl

    d = yaml.safe_load(path.read_text())
    if not isinstance(d, dict) or set(d) - {"readers", "writers", "admins", "by", "allow_other"}:
        raise UserError(f"{path}: expected a mapping with readers, writers, admins, by, allow_other")
    try:
        return map_acl(list(d.get("readers") or []), list(d.get("writers") or []), d.get("admins"),
                       d.get("by", "username"), d.get("allow_other"))
    except ValueError as exc:
        raise UserError(f"{path}: {exc}") from exc


def serve(args: argparse.Namespace) -> int:
    import dataclasses

    from litevloc.runtime.maps.app import serve_maps

    cfg, z = _zenoh(args)
    acl = _acl(args.acl)
    if acl is not None:
        z = dataclasses.replace(z, access_control=acl)
    add = {}
    for item in args.add:
        name, sep, folder = item.partition("=")
        if not sep or not Path(folder).is_dir():
            raise UserError(f"--add {item!r}: give NAME=MAP_FOLDER")
        add[name] = Path(folder)
    gate = None
    if args.held_out is not None:
        from litevloc.runtime.tools.map_candidates import HeldOutGate

        gate = HeldOutGate(cfg, args.held_out, median_tolerance_m=cfg.fleet.push_median_tolerance_m)
    counts = serve_maps(args.dir, z, cfg.fleet, args.mode, gate, add,
                        on_ready=lambda _s: print(f"litevloc map serve: serving {args.dir} ({args.mode}, listen "
                                                  f"{list(z.listen)}, connect {list(z.connect)})", flush=True))
    print(f"litevloc map serve: stopped; {counts}")
    return 0


def _parse_ref(ref: str) -> tuple[str, str | None]:
    from litevloc.runtime.maps.app import parse_map_uri

    parsed = parse_map_uri("zenoh:" + ref)
    assert parsed is not None
    return parsed


def fetch(args: argparse.Namespace) -> int:
    from litevloc.runtime.maps.app import fetch_to_folder

    name, version = _parse_ref(args.ref)
    if args.output.exists() and not args.force:
        raise UserError(f"{args.output} exists; pass --force to replace it")
    cfg, z = _zenoh(args)
    t0 = time.perf_counter()
    got = fetch_to_folder(z, cfg.fleet, name, version, args.output)
    seconds = time.perf_counter() - t0
    how = "cached, service unreachable" if got.offline else "from the cache" if got.from_cache else (
        f"{got.bytes_fetched} bytes in {got.chunks_fetched} chunks, {got.chunks_resumed} resumed")
    print(f"{name}@{got.version[:12]} -> {args.output} ({how}; {seconds:.2f} s)")
    write_json(args.json, {"name": name, "version": got.version, "path": str(args.output), "offline": got.offline,
                           "from_cache": got.from_cache, "bytes_fetched": got.bytes_fetched,
                           "chunks_fetched": got.chunks_fetched, "chunks_resumed": got.chunks_resumed,
                           "chunks_refetched": got.chunks_refetched, "seconds": seconds})
    return 0


def versions(args: argparse.Namespace) -> int:
    from litevloc.runtime.maps.app import robot_session
    from litevloc.runtime.maps.client import list_versions

    cfg, z = _zenoh(args)
    with robot_session(z) as session:
        d = list_versions(session, args.name, cfg.fleet.query_timeout_s)
    for v in d["versions"]:
        mark = "*" if v.version == d["latest"] else " "
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(v.created_ns / 1e9))
        print(f"{mark} {v.version[:16]}  {when} UTC  {v.size_bytes:>12} bytes  parent "
              f"{v.parent[:16] if v.parent else '-'}")
    write_json(args.json, {"latest": d["latest"], "versions": [v.to_json() for v in d["versions"]],
                           "history": d["history"]})
    return 0


def rollback(args: argparse.Namespace) -> int:
    if args.store is not None:
        from litevloc.runtime.maps.store import MapStore

        if not args.store.is_dir():
            raise UserError(f"{args.store}: no such store folder")
        info = MapStore(args.store).rollback(args.name, args.version)
    else:
        from litevloc.runtime.maps.app import robot_session
        from litevloc.runtime.maps.client import request_rollback

        cfg, z = _zenoh(args)
        with robot_session(z) as session:
            info = request_rollback(session, args.name, args.version, cfg.fleet.query_timeout_s)
    print(f"{args.name}: latest is now {info.version[:16]}")
    return 0


def push(args: argparse.Namespace) -> int:
    from litevloc.runtime.maps.app import robot_session
    from litevloc.runtime.maps.client import push_map

    if not args.src.exists():
        raise UserError(f"{args.src}: no such recording or map folder")
    cfg, z = _zenoh(args)
    with robot_session(z) as session:
        res = push_map(session, args.to, args.src, chunk_bytes=cfg.fleet.chunk_bytes,
                       timeout_s=cfg.fleet.query_timeout_s, retries=cfg.fleet.chunk_retries,
                       commit_timeout_s=cfg.fleet.commit_timeout_s)
    if res.published and res.info is not None:
        print(f"{args.to}: published {res.info.version[:16]} ({res.reason})")
    else:
        print(f"{args.to}: refused: {res.reason}")
    write_json(args.json, {"published": res.published, "reason": res.reason,
                           "info": res.info.to_json() if res.info else None, "details": res.details})
    return 0 if res.published else 1
