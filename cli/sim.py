"""`litevloc sim`: simulated worlds -> MCAP recordings, plans and contact sheets.

    litevloc sim record WORLD -o REC.mcap [--seed N] [--duration S] [--pass map|map-rooms|query|loop|...]
                         [--change AXIS=LEVEL | --change months_later ...]
                        [--json PATH] [--plot PNG]
    litevloc sim plot WORLD -o PLAN.png [--seed N] [--duration S] [--sheet SHEET.png]
    litevloc sim goals WORLD -o DIR [--seed N] [--world-seed M]

Simulator parameters (image size, rates, camera mount, realism) come from the config
section `sim` (`--config PRESET`, `--set sim.width=640 --set sim.height=480`).

WORLD is a shipped world name (`office`, `floor`, `bland`, `loop`, the `-aliased` first-simulator
worlds) or a YAML file; `--world-seed` generates another building from the same file.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from litevloc.cli.common import add_config_args, add_json_arg, config_of
from litevloc.cli.main import UserError
from litevloc.runtime.tools.outputs import write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim", help="simulated indoor worlds: record passes, plot plans, goal images"
    )
    ss = p.add_subparsers(dest="sim_command", metavar="SIMCOMMAND")
    ss.required = True
    r = ss.add_parser("record", help="record a simulated pass through a world to MCAP")
    r.add_argument("world", help="world name (see config/worlds) or YAML file")
    r.add_argument("-o", "--output", type=Path, required=True, help="output .mcap")
    r.add_argument(
        "--seed", type=int, default=0, help="seed of route (query), lighting, drift and noise"
    )
    r.add_argument("--world-seed", type=int, default=None, help="override the world's own seed")
    r.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="at most S seconds (default: whole pass)",
    )
    r.add_argument(
        "--pass",
        dest="pass_name",
        choices=("map", "map-rooms", "query", "loop", "loop-lane", "loop-back"),
        default="map",
        help="map: every room with full turns; map-rooms: also halfway to each end of every room; "
        "query: other route and lighting; "
        "loop: lap the ring corridor (layout-loop worlds); loop-lane: the same way in another lane; "
        "loop-back: the other way, another lane",
    )
    r.add_argument(
        "--plot", type=Path, default=None, help="also write a top-down PNG with the trajectory"
    )
    r.add_argument(
        "--workers", type=int, default=None, metavar="N",
        help="processes that render frames (default: one per CPU; 1: render in this process); "
        "the recording is the same for any N",
    )
    r.add_argument(
        "--change", action="append", default=[], metavar="AXIS=LEVEL",
        help="record the building changed: AXIS one of lighting, furniture, pictures, doors (level 0-1), "
        "people (a count), seed (of the change), or a named mix (months_later); repeatable, applied "
        "in order over the world file's change: block. The ground truth of what changed is written "
        "beside the recording (REC.change.json)",
    )
    add_config_args(r)
    add_json_arg(r)
    r.set_defaults(func=run_record)
    pl = ss.add_parser(
        "plot", help="top-down PNG of a world with map/query trajectories, and a contact sheet"
    )
    pl.add_argument("world")
    pl.add_argument("-o", "--output", type=Path, required=True, help="output PNG (plan)")
    pl.add_argument("--seed", type=int, default=0)
    pl.add_argument("--world-seed", type=int, default=None)
    pl.add_argument("--duration", type=float, default=None, metavar="S")
    pl.add_argument(
        "--sheet", type=Path, default=None, help="also write a contact sheet of frames here"
    )
    add_config_args(pl)
    pl.set_defaults(func=run_plot)
    g = ss.add_parser("goals", help="render the world's goal images (robot and hand-held camera, JPEG) and their "
                                    "poses (JSON)")
    g.add_argument("world")
    g.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    g.add_argument("--seed", type=int, default=0, help="lighting/noise seed")
    g.add_argument("--world-seed", type=int, default=None)
    add_config_args(g)
    g.set_defaults(func=run_goals)
    from litevloc.cli.sim_navigate import add_parser as add_navigate

    add_navigate(ss)


def _world(args: argparse.Namespace):
    from litevloc.base.params.world_change import ChangeSpecError, parse_change
    from litevloc.sim.spec import load_world_spec
    from litevloc.sim.world import load_world

    items = getattr(args, "change", None) or []
    if not items:
        return load_world(args.world, seed=args.world_seed)
    try:
        change = parse_change(items, load_world_spec(args.world).change)
    except ChangeSpecError as exc:
        raise UserError(str(exc)) from None
    return load_world(args.world, seed=args.world_seed, change=change)


def run_record(args: argparse.Namespace) -> int:
    from litevloc.runtime.tools.parallel_frames import default_workers
    from litevloc.runtime.tools.sim_recording import record_pass

    if args.output.suffix.lower() != ".mcap":
        raise UserError(f"output must be a .mcap file, got {args.output}")
    if args.duration is not None and args.duration <= 0:
        raise UserError("--duration must be > 0")
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers must be >= 1, got {args.workers}")
    workers = args.workers if args.workers is not None else default_workers()
    summary = record_pass(_world(args), args.pass_name, args.seed, args.duration, config_of(args).sim, args.output,
                          args.plot, workers)
    write_json(args.json, summary)
    return 0


def run_plot(args: argparse.Namespace) -> int:
    from litevloc.sim.plot import contact_sheet, depth_to_rgb, plot_world
    from litevloc.sim.source import SimSequenceSource

    world = _world(args)
    params = config_of(args).sim
    srcs = {
        p: SimSequenceSource(world, p, args.seed, args.duration, params) for p in ("map", "query")
    }
    out = plot_world(
        world, args.output, [(p, s.run.T_world_base[:, :2, 3]) for p, s in srcs.items()]
    )
    print(f"wrote {out}")
    if args.sheet is not None:
        tiles = []
        for p, s in srcs.items():
            n = s.frame_count()
            for i in np.linspace(0, n - 1, 6).astype(int):
                f = s.frame(int(i))
                tiles.append((f"{p} #{i}", f.color))
                if p == "map" and len(tiles) % 4 == 1:
                    assert f.depth is not None
                    tiles.append((f"{p} #{i} depth", depth_to_rgb(f.depth)))
        print(f"wrote {contact_sheet(tiles, args.sheet)}")
    return 0


def run_goals(args: argparse.Namespace) -> int:
    from litevloc.runtime.tools.sim_navigation import render_goals

    world = _world(args)
    cfg = config_of(args)
    args.output.mkdir(parents=True, exist_ok=True)
    poses = {}
    for camera in ("robot", "hand"):
        goals = render_goals(world, cfg, sorted(world.goal_places), seed=args.seed, camera=camera)
        for g in goals:
            assert g.T_world_base is not None and g.T_world_camera is not None
            (args.output / f"{g.name}.jpg").write_bytes(g.jpeg)
            poses[g.name] = {"camera": camera, "T_world_base": g.T_world_base.tolist(),
                             "T_world_camera": g.T_world_camera.tolist(), "image": f"{g.name}.jpg"}
    write_json(args.output / "goals.json", {"world": world.spec.name, "seed": world.spec.seed,
                                            "goal_rule": world.spec.goal_rule, "K": cfg.sim.intrinsics.K,
                                            "goals": poses})
    print(f"wrote {len(poses)} goal images (the robot camera's and the hand-held camera's of each room) and "
          f"goals.json to {args.output}")
    return 0
