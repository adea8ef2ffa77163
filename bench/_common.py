"""Helpers for benchmarks: results table on stdout, JSON in out/bench/."""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "bench"
SEVEN_SCENES = ROOT.parent / "shared" / "data" / "7scenes-redkitchen"


def require_7scenes() -> Path:
    if not (SEVEN_SCENES / "frame-000000.color.jpg").is_file():
        raise SystemExit(f"benchmark needs the 7-Scenes data at {SEVEN_SCENES}")
    return SEVEN_SCENES


def stats_ms(samples_s: list[float]) -> dict[str, float]:
    a = np.asarray(samples_s) * 1e3
    return {"median_ms": float(np.median(a)), "p90_ms": float(np.percentile(a, 90)), "n": len(a)}


def print_table(title: str, header: list[str], rows: list[list[Any]]) -> None:
    cells = [[str(c) if not isinstance(c, float) else f"{c:.3g}" for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(header)]
    print(f"\n{title}")
    print("  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)))
    print("  ".join("-" * w for w in widths))
    for r in cells:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)))


def write_json(name: str, data: dict[str, Any]) -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"{name}.json"
    meta = {"machine": platform.machine(), "python": platform.python_version(), "time": time.strftime("%FT%T%z")}
    path.write_text(json.dumps({"meta": meta, **data}, indent=2, default=float) + "\n")
    print(f"\nwrote {path}")
    return path
