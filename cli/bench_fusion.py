"""`litevloc bench fusion [SRC] [--frames A:B] [--json PATH]`: the paper's Tables II/III shape.

On a posed sequence (default: the 7-Scenes query pass, frames 500-999, 30 Hz) with
seeded drift odometry at 100 Hz and simulated 1 Hz VLoc (10 % gross outliers, late by
0.1-1 s), prints ATE and output rate of odometry alone, VLoc alone, online fusion and
batch refinement, with and without robust kernels/gating; `--synthetic-minutes M` adds
the synthetic endurance run (update-time percentiles, graph size, RSS). See
`litevloc.experiments.fusion` for the exact inputs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.cli.common import add_config_args, add_json_arg, config_of
from litevloc.runtime.tools.outputs import progress, write_json

DEFAULT_SRC = Path("..") / "shared" / "data" / "7scenes-redkitchen"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fusion", help="fusion accuracy (ATE) and rates on a posed sequence")
    p.add_argument(
        "src",
        nargs="?",
        type=Path,
        default=None,
        help=f"posed dataset folder (7-Scenes or TUM RGB-D; default {DEFAULT_SRC})",
    )
    p.add_argument(
        "--frames",
        default="500:1000",
        metavar="A:B",
        help="frames of SRC to use, a Python slice (default 500:1000, the query pass)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=5,
        help="odometry/VLoc seeds 0..N-1; medians reported (default 5)",
    )
    p.add_argument(
        "--synthetic-minutes",
        type=float,
        default=0.0,
        metavar="M",
        help="also run the synthetic endurance test for M minutes (0 = skip)",
    )
    p.add_argument(
        "--tum-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="write seed 0's trajectories here as TUM files (for evo and plots)",
    )
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from litevloc.cli.common import frames_of
    from litevloc.cli.main import UserError
    from litevloc.experiments.fusion import VARIANTS, report, run_benchmark

    cfg = config_of(args)
    if args.seeds < 1:
        raise UserError("--seeds must be >= 1")
    n_msgs = int(args.synthetic_minutes * 60 * 100)  # 100 Hz odometry
    with progress(args.seeds * len(VARIANTS) + n_msgs, "bench fusion", unit="step") as bar:
        try:
            res = run_benchmark(args.src if args.src is not None else DEFAULT_SRC, frames_of(args), cfg, args.seeds,
                                args.synthetic_minutes, args.tum_dir, lambda: bar.update(1), bar.update)
        except ValueError as exc:
            raise UserError(str(exc)) from exc
    res["frames"] = args.frames
    print(report(res, args.seeds))
    write_json(args.json, res)
    return 0
