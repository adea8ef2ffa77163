"""Summaries, failure analysis, tables and the plot of the cross-split benchmark (`experiments.splits`)."""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.figures import save_figure
from litevloc.pipelines.localization.results import LocalizationResult

RECALL_AT = (1, 5, 10)


def reason_key(reason: str) -> str:
    """A reason without its numbers and parenthesised details, for counting alike failures."""
    key = re.sub(r"\([^)]*\)", "", reason)
    key = re.sub(r"\d+(\.\d+)?", "N", key)
    return re.sub(r"\s+", " ", key).strip(" :;")


def failure_of(res: LocalizationResult, covering: set[int], shortlist: Sequence[int]) -> str:
    """Why a refused query of a covered frame failed.

    LL queries: `LL: <reason>`. GL queries: `retrieval: no covering keyframe in the shortlist`
    when place recognition did not retrieve one among the nodes GL ranks (`shortlist`);
    `re-ranking: no covering keyframe among the verified` when it did but the candidates GL
    would verify (`res.candidates`) hold none; `stopped before a covering candidate` when the
    search ended (time budget) before trying one; else the reason the best covering candidate
    (most inliers) was rejected, `covering candidate: <reason>`.
    """
    if res.mode != "global":
        return f"LL: {reason_key(res.reason)}"
    if not covering.intersection(int(n) for n in shortlist):
        return "retrieval: no covering keyframe in the shortlist"
    if res.candidates and not covering.intersection(res.candidates):
        return "re-ranking: no covering keyframe among the verified"
    tried = [a for a in res.attempts if a.node in covering]
    if not tried:
        return "stopped before a covering candidate"
    best = max(tried, key=lambda a: a.inliers)
    return f"covering candidate: {reason_key(best.reason)}"


def _pct(n: float, d: float) -> float:
    return 100.0 * n / d if d else float("nan")


def summarize(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per-split figures from the frame records of `experiments.splits.frame_record`."""
    n = len(records)
    acc = [r for r in records if r["accepted"]]
    cov = [r for r in records if r["covered"]]
    err = np.array([(r["error_m"], r["error_deg"]) for r in acc]).reshape(-1, 2)
    gl = [r["latency_ms"] for r in records if r["mode"] == "global"]
    ll = [r["latency_ms"] for r in records if r["mode"] == "local"]
    fails = Counter(r["failure"] for r in cov if not r["accepted"])
    ranks = np.array([r["first_covering_rank"] for r in cov])
    return {
        "queries": n, "accepted": len(acc), "accepted_pct": _pct(len(acc), n),
        "covered": len(cov), "covered_pct": _pct(len(cov), n),
        "near_pct": _pct(sum(r["near"] for r in records), n),
        "accepted_of_covered_pct": _pct(sum(r["accepted"] for r in cov), len(cov)),
        "accepted_uncovered": sum(1 for r in acc if not r["covered"]),
        "within_5cm_5deg_pct": _pct(int(np.sum((err[:, 0] <= 0.05) & (err[:, 1] <= 5.0))), n),
        "within_2cm_2deg_pct": _pct(int(np.sum((err[:, 0] <= 0.02) & (err[:, 1] <= 2.0))), n),
        "median_cm": 100 * float(np.median(err[:, 0])) if len(err) else float("nan"),
        "median_deg": float(np.median(err[:, 1])) if len(err) else float("nan"),
        "max_cm": 100 * float(err[:, 0].max()) if len(err) else float("nan"),
        "max_deg": float(err[:, 1].max()) if len(err) else float("nan"),
        "wrong_over_0.5m": int(np.sum(err[:, 0] > 0.5)),
        **{f"vpr_recall@{k}_covered_pct": _pct(int(np.sum((ranks >= 1) & (ranks <= k))), len(cov))
           for k in RECALL_AT},
        "gl_queries": len(gl), "gl_latency_median_ms": float(np.median(gl)) if gl else float("nan"),
        "ll_latency_median_ms": float(np.median(ll)) if ll else float("nan"),
        "covered_refused": sum(fails.values()), "covered_refused_by_reason": dict(fails.most_common()),
    }


MAIN_COLUMNS = ["split", "n", "cov %", "near %", "acc %", "acc|cov %", "5cm5° %", "med cm", "med °", "max cm",
                ">0.5 m", "R@1", "R@5", "R@10", "GL ms"]


def main_row(name: str, role: str, s: dict[str, Any]) -> list[Any]:
    """One row of the main table (MAIN_COLUMNS); choosing splits marked with '*'."""
    return [name + ("*" if role == "choose" else ""), s["queries"], s["covered_pct"], s["near_pct"],
            s["accepted_pct"], s["accepted_of_covered_pct"], s["within_5cm_5deg_pct"], s["median_cm"],
            s["median_deg"], s["max_cm"], s["wrong_over_0.5m"], s["vpr_recall@1_covered_pct"],
            s["vpr_recall@5_covered_pct"], s["vpr_recall@10_covered_pct"], _ms(s["gl_latency_median_ms"])]


def _ms(v: float) -> int | str:
    return round(v) if np.isfinite(v) else "-"


def failure_rows(results: Sequence[dict[str, Any]]) -> tuple[list[str], list[list[Any]]]:
    """(header, rows): covered-but-refused frames per failure reason (rows) and split (columns)."""
    names = [r["split"] for r in results]
    total: Counter[str] = Counter()
    for r in results:
        total.update(r["summary"]["covered_refused_by_reason"])
    rows = [[reason, *(r["summary"]["covered_refused_by_reason"].get(reason, 0) for r in results)]
            for reason, _ in total.most_common()]
    return ["covered but refused: why", *names], rows


def plot(results: Sequence[dict[str, Any]], path: Path, before: Sequence[dict[str, Any]] = ()) -> Path:
    """Bars per split: share of query frames covered (0.5 m / 30 deg) and accepted, with the
    accepted share of `before` (an earlier run of the same splits) where given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r["split"] + ("*" if r["role"] == "choose" else "") for r in results]
    x = np.arange(len(results))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(results)), 4.4))
    cols = [("covered_pct", "covered (0.5 m, 30°)", "#bbbbbb"), ("accepted_pct", "accepted", "#2b7bba"),
            ("within_5cm_5deg_pct", "within 5 cm, 5°", "#6cbf6c")]
    w = 0.8 / (len(cols) + bool(before))
    for i, (key, label, colour) in enumerate(cols):
        ax.bar(x + (i - 1) * w, [r["summary"][key] for r in results], w, label=label, color=colour)
    if before:
        prev = {r["split"]: r["summary"]["accepted_pct"] for r in before}
        ax.bar(x + len(cols) * w - w, [prev.get(r["split"], np.nan) for r in results], w,
               label="accepted before", color="none", edgecolor="#d62728", hatch="//")
    ax.set_xticks(x, names)
    ax.set_ylabel("% of query frames")
    ax.set_ylim(0, 105)
    ax.set_title("7-Scenes redkitchen splits (* = parameters chosen here)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), fontsize=8, ncol=4, frameon=False)
    ax.grid(axis="y", alpha=0.3)
    return save_figure(fig, path, dpi=110)
