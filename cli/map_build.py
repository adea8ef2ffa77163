"""`litevloc map build SRC -o MAP --poses auto|ground-truth|odometry|slam|FILE`: the arguments
as a `MapBuildRequest` for `litevloc.runtime.tools.map_building.build_map` (whose docstring says where
each `--poses` choice takes the keyframe poses from)."""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.cli.common import config_of
from litevloc.runtime.tools.map_building import MapBuildRequest, build_map
from litevloc.runtime.tools.outputs import write_json


def add_pose_args(b: argparse.ArgumentParser) -> None:
    b.add_argument("--poses", default="auto", metavar="auto|ground-truth|odometry|slam|FILE",
                   help="keyframe poses: the source's ground truth, its /odom alone, the mapping pass's own SLAM, "
                        "or a TUM trajectory file from another SLAM (auto: ground truth where there is one, else slam)")
    b.add_argument("--slam-graph", type=Path, default=None, metavar="NPZ",
                   help="--poses slam: also write the pose graph (keyframes, edges, loop weights) for analysis")
    b.add_argument("--poses-frame", choices=("camera", "base_link"), default="camera",
                   help="--poses FILE: the poses are of the camera optical frame, or of base_link (moved to the "
                        "camera with fusion.base_camera_*)")


def build(args: argparse.Namespace) -> int:
    """`litevloc map build`: the arguments as a request, the build, its JSON summary."""
    req = MapBuildRequest(src=args.src, output=args.output, force=args.force, frames=args.frames,
                          poses=str(args.poses), poses_frame=args.poses_frame, slam_graph=args.slam_graph,
                          config=args.config)
    write_json(args.json, build_map(req, config_of(args)))
    return 0
