"""`litevloc models export|list|warmup`: build the ONNX models into the cache; show what is there;
build (and time) every session the configured runtime uses, so TensorRT engines are built and
cached before the first run.

`export` is the only runtime command that needs torch (the `[export]` extra); it imports the
exporter lazily so that every other command runs without torch.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from litevloc.base.params.models import ModelsConfig
from litevloc.cli.common import add_config_args, add_json_arg, config_of
from litevloc.models.catalog import DEFAULT_EXPORTS, EXTRA_EXPORTS, aliked_id, spec_for, vpr_id
from litevloc.models.registry import ModelError, cache_dir_of, configured_ids, locate, read_manifest
from litevloc.runtime.tools.outputs import write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("models", help="export ONNX models into the model cache, list them")
    msub = p.add_subparsers(dest="models_command", metavar="ACTION")
    msub.required = True

    e = msub.add_parser(
        "export",
        help="build the default models (or --model/--all) into the cache; "
        "idempotent: up-to-date models are skipped",
    )
    e.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="ID",
        help="model id to export (repeatable), e.g. aliked-n16-480x640-k1024, effnet-gem-480x640, "
        "cosplace-r18-240x320",
    )
    e.add_argument(
        "--all", action="store_true", help="also the larger variants: " + ", ".join(EXTRA_EXPORTS)
    )
    e.add_argument("--force", action="store_true", help="rebuild even when up to date")
    e.add_argument(
        "--cosplace-checkpoint",
        type=Path,
        default=None,
        metavar="PATH",
        help="official CosPlace ResNet-18 checkpoint (.pth); "
        "exports cosplace-r18 at the config's vpr_size",
    )
    _common(e)
    e.set_defaults(func=run_export)

    ls = msub.add_parser("list", help="show the catalogue and the state of the cache")
    _common(ls)
    ls.set_defaults(func=run_list)

    w = msub.add_parser(
        "warmup",
        help="build every model session the configured runtime uses (TensorRT engines are built and "
        "cached), run each once at its largest shape, and time it; a table per model",
    )
    w.add_argument("--runs", type=int, default=5, metavar="N", help="steady calls timed per model (median)")
    _common(w)
    w.set_defaults(func=run_warmup)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="model cache folder (default: models.cache_dir, $LITEVLOC_MODEL_CACHE, XDG cache)",
    )
    add_config_args(p)
    add_json_arg(p)


def _models_cfg(args: argparse.Namespace) -> ModelsConfig:
    cfg = config_of(args).models
    if args.cache is not None:
        from dataclasses import replace

        cfg = replace(cfg, cache_dir=str(args.cache))
    return cfg


def _unique(ids: list[str]) -> list[str]:
    return list(dict.fromkeys(ids))


def run_export(args: argparse.Namespace) -> int:
    cfg = _models_cfg(args)
    cache = cache_dir_of(cfg)
    ids = list(args.model) if args.model else [*DEFAULT_EXPORTS, *configured_ids(cfg)]
    if args.all:
        ids += list(EXTRA_EXPORTS)
    checkpoint = args.cosplace_checkpoint or (
        Path(cfg.cosplace_checkpoint) if cfg.cosplace_checkpoint else None
    )
    if checkpoint is not None and not args.model:
        ids.append(vpr_id("cosplace-r18", cfg.vpr_size))
    ids = _unique(ids)
    for i in ids:
        try:
            spec_for(i)
        except ValueError as exc:
            raise ModelError(str(exc)) from exc
    try:
        from litevloc.models.export.exporter import export_models
    except ImportError as exc:
        raise ModelError(
            f"exporting needs torch and onnx (the [export] extra: `make install-dev`): {exc}"
        ) from exc

    t0 = time.monotonic()
    timings: dict[str, float] = {}
    started: dict[str, float] = {}

    def on_progress(model_id: str, status: str) -> None:
        n = ids.index(model_id) + 1
        if status == "exporting":
            started[model_id] = time.monotonic()
            print(f"[{n}/{len(ids)}] {model_id}: exporting ...", file=sys.stderr, flush=True)
        else:
            dt = time.monotonic() - started.get(model_id, time.monotonic())
            timings[model_id] = dt
            extra = f" in {dt:.1f} s" if status == "built" else ""
            print(f"[{n}/{len(ids)}] {model_id}: {status}{extra}", file=sys.stderr, flush=True)

    results = export_models(
        ids, cache, force=args.force, cosplace_checkpoint=checkpoint, on_progress=on_progress
    )
    built = sum(1 for s in results.values() if s == "built")
    print(
        f"model cache {cache}: {built} built, {len(results) - built} up to date "
        f"({time.monotonic() - t0:.1f} s)"
    )
    write_json(args.json, {"cache": str(cache), "models": results, "seconds": timings})
    return 0


def run_list(args: argparse.Namespace) -> int:
    cfg = _models_cfg(args)
    cache = cache_dir_of(cfg)
    manifest = read_manifest(cache)["models"]
    ids = _unique([*DEFAULT_EXPORTS, *configured_ids(cfg), *EXTRA_EXPORTS, *sorted(manifest)])
    rows: list[dict[str, Any]] = []
    for i in ids:
        try:
            path, entry = locate(i, cfg)
            status = "ok"
            size = sum((path.parent / f).stat().st_size for f in spec_for(i).part_files) / 1e6
        except ModelError as exc:
            status = "missing" if i not in manifest else "stale: " + str(exc).split(";")[0][-60:]
            size, entry = 0.0, manifest.get(i, {})
        group = (
            "default"
            if i in DEFAULT_EXPORTS
            else ("config" if i in configured_ids(cfg) else "extra")
        )
        rows.append(
            {
                "id": i,
                "group": group,
                "status": status,
                "size_mb": round(size, 2),
                "source_sha256": entry.get("source", {}).get("sha256", "")[:12],
            }
        )
    print(f"model cache: {cache}")
    print(f"{'model':28s} {'group':8s} {'MB':>7s}  {'source sha256':13s} status")
    for r in rows:
        sha = r["source_sha256"]
        print(f"{r['id']:28s} {r['group']:8s} {r['size_mb']:7.1f}  {sha:13s} {r['status']}")
    print("(<model>.onnx + manifest.json in the cache; `litevloc models export` builds them)")
    write_json(args.json, {"cache": str(cache), "models": rows})
    return 0


def run_warmup(args: argparse.Namespace) -> int:
    """`litevloc models warmup`: `models.warmup.warm_up` on the configured models, with the runtime's
    threads per session; a table on stdout (and --json). A missing model is a ModelError (exit 2)."""
    from dataclasses import replace

    from litevloc.models.ort import TENSORRT, provider_report, provider_setup, tensorrt_options
    from litevloc.models.types import ProviderState
    from litevloc.models.warmup import warm_up

    if args.runs < 1:
        raise ModelError(f"--runs must be >= 1, got {args.runs}")
    full = config_of(args)
    cfg = replace(_models_cfg(args), intra_op_threads=full.runtime.ort_intra_op_threads)
    cache = cache_dir_of(cfg)
    if not (cache / "manifest.json").is_file():
        raise ModelError(f"the model cache {cache} has no models; run `litevloc models export` first")
    second_look = full.localization.second_look.candidates > 0
    skipped = set() if second_look else {aliked_id(cfg.extractor, cfg.second_look_size, cfg.second_look_keypoints)}
    for i in configured_ids(cfg):  # every model checked before any is built (a TensorRT build takes minutes)
        if i not in skipped or i == aliked_id(cfg.extractor, cfg.extractor_size, cfg.max_keypoints):
            locate(i, cfg)
    t0 = time.monotonic()
    rows = warm_up(cfg, second_look=second_look, runs=args.runs)
    report = provider_report()
    b = report.build
    print(f"onnxruntime {b.version} ({b.distribution or 'distribution unknown'}, device {b.device}); "
          f"available: {', '.join(b.available)}; asked for: {', '.join(cfg.providers)}")
    print(f"{'role':11s} {'model':28s} {'provider':26s} {'sessions':>8s} {'build s':>8s} {'first run s':>11s} "
          f"{'steady ms':>9s}  steady shape")
    for r in rows:
        print(f"{r.role:11s} {r.model:28s} {', '.join(r.providers):26s} {r.sessions:8d} {r.build_s:8.2f} "
              f"{r.first_run_s:11.2f} {r.steady_ms:9.1f}  {r.shape}")
    engines = ""
    if any(TENSORRT in r.providers for r in rows):
        opts = tensorrt_options(provider_setup(cfg, cache))
        engines = opts.get("trt_engine_cache_path", "")
        print(f"TensorRT engines: {engines or '(engine cache off: built at every start)'}")
    if report.state in (ProviderState.FALLBACK, ProviderState.DISTRIBUTION_CLASH):
        print(f"WARNING: {report.message}")
    print(f"{len(rows)} model(s) warmed up in {time.monotonic() - t0:.1f} s")
    write_json(args.json, {"cache": str(cache), "providers_asked": list(cfg.providers),
                           "onnxruntime": report.as_dict()["onnxruntime"], "state": report.state.value,
                           "message": report.message, "engine_cache": engines,
                           "models": [r.as_dict() for r in rows]})
    return 0
