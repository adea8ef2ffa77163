"""`litevloc bench reloc MAP SRC`: the relocalization benchmark (see runtime/reloc_bench.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of, source_of
from litevloc.cli.main import UserError
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.tools.outputs import progress, write_json


def register(sub: argparse._SubParsersAction) -> None:
    from litevloc.experiments.reloc import DEFAULT_METHODS

    p = sub.add_parser("reloc", help="relocalization benchmark: per-method pose errors vs a map's keyframes")
    p.add_argument("map", type=Path)
    p.add_argument("src", type=Path, help="query recording or dataset folder with ground truth")
    p.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), metavar="EXTRACTOR+MATCHER@HxW")
    p.add_argument("--poses-dir", type=Path, default=None,
                   help="write the results in the map-free benchmark's layout here (a submission zip per method, "
                        "the ground truth as its dataset folder, references.csv) and score them from the files")
    add_frames_arg(p)
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from litevloc.experiments.reloc import parse_method, run_reloc

    try:
        methods = [parse_method(m) for m in args.methods]
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    cfg = config_of(args)
    topomap = load_map(args.map)
    src = source_of(args, cfg)
    with progress(src.frame_count() * len(methods), "bench reloc", unit="query") as bar:
        res = run_reloc(topomap, src, methods, cfg, args.poses_dir, on_query=lambda: bar.update(1))
    hdr = ["method", "est %", "med cm", "med deg", "max cm", "max deg", "5cm5d", "25cm5d", "1m10d", "ms/q"]
    print(f"\nrelocalization: {res['queries']} queries against {res['reference_nodes']} reference keyframes")
    print("  ".join(f"{h:>10}" if i else f"{h:<30}" for i, h in enumerate(hdr)))
    for name, m in res["methods"].items():
        vals = [m["pct_estimated"], 100 * m["median_trans_m"], m["median_rot_deg"], 100 * m["max_trans_m"],
                m["max_rot_deg"], m["precision_5cm_5deg"], m["precision_25cm_5deg"], m["precision_1m_10deg"],
                m["time_median_ms"]]
        print(f"{name:<30}" + "  ".join(f"{v:>10.2f}" for v in vals))
    if args.poses_dir is not None:
        print(f"\nmap-free metrics, scored from the files in {args.poses_dir} (all queries; a query without an "
              "estimate is a failure)")
        hdr2 = ["method", "est %", "med t cm", "med r deg", "med VCRE px", "prec pose", "AUC pose", "prec VCRE",
                "AUC VCRE"]
        print("  ".join(f"{h:>11}" if i else f"{h:<30}" for i, h in enumerate(hdr2)))
        for name, m in res["methods"].items():
            mf = m["mapfree"]["all_queries"]
            vals = [100 * mf["Estimates for % of frames"], 100 * mf["Average Median Translation Error"],
                    mf["Average Median Rotation Error"], mf["Average Median Reprojection Error"],
                    *(mf[k] for k in mf if k.startswith(("Precision", "AUC")))]
            print(f"{name:<30}" + "  ".join(f"{v:>11.3f}" for v in vals))
    write_json(args.json, res)
    return 0
