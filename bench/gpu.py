"""Per-model latency per onnxruntime execution provider, and the end-to-end VLoc rate on each.

For every provider asked for (`--providers`, default cpu cuda tensorrt) that this onnxruntime
has: the configured models built on it (`models.warmup.warm_up`, what `litevloc models warmup`
runs: build time, first run at the largest TensorRT profile shape, median of `--runs` steady
calls), then the VLoc rate: the localizer (`pipelines.localization.vloc.VisualLocalizer`, as
`litevloc localize` runs it, second look included) on the first `--frames` frames of the query
recording, as fast as it goes: queries/s, median and p90 latency, accepted share.
A provider asked for that is not available, or that the sessions did not take, is reported
(skipped / fell back, with the reason, in the table and the JSON), not a crash.

    tensorrt: providers [tensorrt, cuda, cpu] (CUDA takes what TensorRT does not), FP16 as
              `models.tensorrt.fp16`, engines cached under the model cache (the first run on a
              Jetson builds them: minutes; `build s` says so, later runs load them)
    cuda:     providers [cuda, cpu]
    cpu:      providers [cpu]

Input: the simulated office's map and query pass (`bench/_common.office_inputs`, made when absent,
cached under out/bench/inputs/office), or `--map` / `--rec`.

    python bench/gpu.py [--providers cpu cuda tensorrt] [--frames 40] [--runs 10] [--set KEY=VALUE]

Writes out/bench/gpu.json (meta, machine, load_average, config, onnxruntime, results) and prints tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import office_inputs, print_table, write_json

PROVIDER_CHAINS: dict[str, tuple[str, ...]] = {
    "cpu": ("cpu",),
    "cuda": ("cuda", "cpu"),
    "tensorrt": ("tensorrt", "cuda", "cpu"),
}


def vloc_rate(cfg: Any, map_dir: Path, rec: Path, frames: int) -> dict[str, Any]:
    """The localizer on the first `frames` frames of `rec`, back to back: queries/s and latency (ms)."""
    from litevloc.hw.streams.mcap_io import McapSource
    from litevloc.pipelines.localization.vloc import VisualLocalizer
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.runtime.tools.posed import posed_frames
    from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(map_dir), bundle)
    loc = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, bundle))
    lat: list[float] = []
    accepted = 0
    t0 = time.perf_counter()
    for frame, _ in posed_frames(McapSource(rec, strict=False)):
        if len(lat) >= frames:
            break
        q0 = time.perf_counter()
        res = loc.process(frame.t_ns, frame.color, frame.depth, frame.K)
        lat.append(1e3 * (time.perf_counter() - q0))
        accepted += int(res.accepted)
    wall = time.perf_counter() - t0
    if not lat:
        return {"queries": 0}
    q = sorted(lat)
    return {"queries": len(lat), "rate_hz": len(lat) / wall, "median_ms": statistics.median(lat),
            "p90_ms": q[min(len(q) - 1, int(0.9 * len(q)))], "accepted_pct": 100.0 * accepted / len(lat)}


def one_provider(name: str, base: Any, map_dir: Path | None, rec: Path | None, frames: int,
                 runs: int) -> dict[str, Any]:
    """Warm-up times per model and the VLoc rate on provider `name`; skipped (with the reason) where
    onnxruntime lacks it; `fell_back` where a session did not take it."""
    from litevloc.models import ort as mort
    from litevloc.models.warmup import warm_up

    full = mort.PROVIDER_NAMES[name]
    build = mort.ort_build()
    if full not in build.available:
        return {"status": "skipped", "reason": f"{full} is not in this onnxruntime ({build.distribution or '?'} "
                f"{build.version}: {', '.join(build.available)}); a Jetson needs onnxruntime-gpu (JetPack's wheel)"}
    cfg = dataclasses.replace(base, models=dataclasses.replace(base.models, providers=PROVIDER_CHAINS[name]))
    before = len(mort.session_reports())
    rows = warm_up(cfg.models, second_look=cfg.localization.second_look.candidates > 0, runs=runs)
    report = mort.provider_report(mort.session_reports()[before:])
    out: dict[str, Any] = {"status": "ok", "providers": list(PROVIDER_CHAINS[name]),
                           "models": [r.as_dict() for r in rows]}
    if report.state is mort.ProviderState.FALLBACK:
        out["status"], out["reason"] = "fell_back", report.message
    if map_dir is not None and rec is not None and frames > 0:
        out["vloc"] = vloc_rate(cfg, map_dir, rec, frames)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--providers", nargs="+", default=["cpu", "cuda", "tensorrt"], choices=sorted(PROVIDER_CHAINS),
                    help="execution providers to measure (unavailable ones are skipped, with the reason)")
    ap.add_argument("--config", default="default", help="preset or config file (models, localization)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="config override, e.g. "
                    "models.tensorrt.fp16=false")
    ap.add_argument("--runs", type=int, default=10, help="steady calls timed per model (median)")
    ap.add_argument("--frames", type=int, default=40, help="query frames of the VLoc rate (0: no VLoc rate)")
    ap.add_argument("--map", type=Path, default=None, help="map folder (default: the office map)")
    ap.add_argument("--rec", type=Path, default=None, help="query recording (default: the office query pass)")
    ap.add_argument("--name", default="gpu", help="JSON name under out/bench (or a path ending in .json)")
    args = ap.parse_args()

    from litevloc.config import load_config
    from litevloc.models import ort as mort

    base = load_config(args.config, args.overrides)
    base = dataclasses.replace(base, models=dataclasses.replace(
        base.models, intra_op_threads=base.runtime.ort_intra_op_threads))
    map_dir, rec = args.map, args.rec
    if args.frames > 0 and (map_dir is None or rec is None):
        office_map, office_rec = office_inputs()
        map_dir, rec = map_dir or office_map, rec or office_rec
    build = mort.ort_build()
    print(f"onnxruntime {build.version} ({build.distribution or '?'}, device {build.device}); "
          f"available: {', '.join(build.available)}")
    results: dict[str, dict[str, Any]] = {}
    for p in dict.fromkeys(args.providers):
        t0 = time.perf_counter()
        results[p] = one_provider(p, base, map_dir, rec, args.frames, args.runs)
        results[p]["seconds"] = time.perf_counter() - t0
        if results[p]["status"] != "ok":
            print(f"{p}: {results[p]['status']}: {results[p]['reason']}")

    rows = []
    for p, r in results.items():
        for m in r.get("models", []):
            rows.append([p, m["role"], m["model"], ", ".join(m["providers"]), f"{m['build_s']:.2f}",
                         f"{m['first_run_s']:.2f}", f"{m['steady_ms']:.1f}", m["shape"]])
    print_table("per-model latency per provider (build s: session + engine; first run at the largest profile shape)",
                ["provider", "role", "model", "runs on", "build s", "first run s", "steady ms", "steady shape"], rows)
    vrows = [[p, r["status"], r.get("vloc", {}).get("queries", "-"),
              *(f"{r['vloc'][k]:.2f}" if "vloc" in r and k in r["vloc"] else "-"
                for k in ("rate_hz", "median_ms", "p90_ms", "accepted_pct"))] for p, r in results.items()]
    print_table(f"end-to-end VLoc (localizer back to back, first {args.frames} query frames)",
                ["provider", "status", "queries", "Hz", "median ms", "p90 ms", "accepted %"], vrows)
    write_json(args.name, {
        "machine": {"platform": platform.platform(), "machine": platform.machine(), "cpus": os.cpu_count()},
        "load_average": list(os.getloadavg()),
        "config": {"preset": args.config, "overrides": args.overrides, "providers": args.providers,
                   "runs": args.runs, "frames": args.frames, "map": str(map_dir), "rec": str(rec),
                   "models": dataclasses.asdict(base.models)},
        "onnxruntime": dataclasses.asdict(build),
        "results": results,
    })
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
