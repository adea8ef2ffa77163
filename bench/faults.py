"""Fault table: each injected fault on the service + GTSAM fusion (simulated office pass,
oracle VLoc at 5 Hz, deterministic mode; see tests/runtime/fault_scenarios.py), with the
fused camera position error before / during / right after / later, and what the status said.

    python bench/faults.py [--seconds 30] [--recover-s 3]

Its inputs are simulated here (nothing to prepare). For the full pipeline (real map, models,
VLoc) on a recording use the same fault syntax, e.g. on the office inputs that bench/soak.py
makes (out/bench/inputs/office, `_common.office_inputs`):
    litevloc replay out/bench/inputs/office/query.mcap --config default --map out/bench/inputs/office/map \
        --fault camera_dropout@10:5 --json r.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import print_table, write_json

FAULTS = [  # (name, spec, window start, window end)
    ("none", [], 10.0, 15.0),
    ("camera dropout 5 s", ["camera_dropout@10:5"], 10.0, 15.0),
    ("depth all invalid 5 s", ["depth_invalid@10:5"], 10.0, 15.0),
    ("odometry gap 1 s", ["odometry_gap@10:1"], 10.0, 11.0),
    ("odometry time back 1 s", ["odometry_backwards@10:1"], 10.0, 11.0),
    ("10 % VLoc 2 m off", ["vloc_outliers@5:20,fraction=0.1,offset_m=2,seed=3"], 5.0, 25.0),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--recover-s", type=float, default=3.0)
    args = ap.parse_args()
    from tests.runtime.fault_scenarios import run_scenario, summary_row

    rows, out = [], []
    for name, spec, a, b in FAULTS:
        t0 = time.perf_counter()
        r = run_scenario(spec, seconds=args.seconds)
        s = summary_row(name, r, a, b, args.recover_s)
        s["wall_s"] = time.perf_counter() - t0
        out.append(s)
        cm = [100 * s[k] for k in ("max_err_before_m", "max_err_during_m", "max_err_recovery_m", "max_err_after_m")]
        rows.append([name, "yes" if s["ok"] else "NO", *cm, ",".join(s["states_during"]), ",".join(s["states_after"]),
                     (s["reasons_during"] or [""])[0][:60]])
    print_table(f"Injected faults ({args.seconds:g} s office pass, 5 Hz oracle VLoc + GTSAM fusion); "
                f"max fused camera error in cm", ["fault", "kept running", "before", "during",
                                                  f"next {args.recover_s:g} s", "later", "states during",
                                                  "states later", "status reason during"], rows)
    write_json("faults", {"seconds": args.seconds, "recover_s": args.recover_s, "faults": out})


if __name__ == "__main__":
    main()
