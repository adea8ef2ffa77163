"""How every map cost grows with the node count (issue #15 item 7).

`python bench/scale.py --json PATH [--sizes 100 1000 10000] [--base MAP]`

Maps of 100, 1,000 and 10,000 nodes are made from REAL keyframes: the 7-Scenes map
(frames 0-499, `--config 7scenes`, 40 keyframes; built and cached in out/maps/7s when
absent) replicated as follows (`replicate`):

* copies are laid out on a square grid in the map's ground plane (the occupancy grid's
  plane axes), one copy per tile; a tile is the base occupancy grid plus 1 m of unknown
  cells on each side, so copy k's nodes are the base nodes translated by the tile offset
  (poses otherwise unchanged); the last copy is cut to reach exactly N nodes;
* VPR descriptors: copy 0 keeps the base descriptors; copy k >= 1 adds i.i.d. Gaussian
  noise of standard deviation 0.1 / sqrt(D) per component (a noise vector of norm ~0.1,
  seeded by k) to each unit descriptor and renormalises to unit length (cosine to the
  original ~0.995: the copies look alike, as repetitive buildings do);
* local features, intrinsics, image sizes and keyframe JPEGs are the base node's
  (identical bytes per copy; they are validated and checksummed like any other);
* covisibility edges: the base edges inside every copy (none between copies);
  connectivity edges: the base edges inside every copy, plus one edge between each pair
  of grid-adjacent copies joining their closest pair of nodes (weight = that distance), so
  the graph is connected and a path from the first to the last copy crosses the grid;
* the occupancy grid is the base grid tiled the same way.

Each map is written with `save_map` (cached under out/scale/) and measured in a fresh
subprocess: `load_s` (the real `load_map`, every check included; median of 3), `rss_mb`
(VmRSS after the load, map alive), `disk_bytes`, `gl_retrieval_ms` (VPR top-k over all
descriptors, as `VisualLocalizer.localize_global` does it), `gl_verify_ms` (one
candidate: LightGlue match + depth lift + PnP of a real 7-Scenes query frame against a
map node, as `relative_pose` does it), `ll_lookup_ms` (`NodeIndex.local_candidates` from
a prior 0.3 m off a node), `planner_ms` (`shortest_path` between node 0 and the node
farthest from it). Baselines in the same run: the brute-force LL candidate scan and the
former pure-Python heap Dijkstra (with its per-query adjacency build). Prints a table,
writes PATH, PATH's `.details.json` (extras: timings' spread, CPU seconds, peak RSS, the
validation's hashing share, index build, baselines) and a log-log PNG next to PATH.
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import heapq
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, print_table, require_7scenes

from litevloc.base.process_usage import memory_mb
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.types import FeatureStore, OccupancyGrid, TopoMap

SCALE_VERSION = "2"  # bump when `replicate` or the map format changes (cached maps are rebuilt); 2: format 3
NOISE = 0.1  # norm of the VPR descriptor perturbation (per component sd = NOISE / sqrt(D))
GAP_M = 1.0  # unknown margin around each tile


def base_map(path: Path) -> Path:
    if (path / "manifest.json").is_file():
        return path
    d = require_7scenes()
    print(f"building the base map {path} (7-Scenes frames 0-499) ...", flush=True)
    subprocess.run([str(Path(sys.executable).parent / "litevloc"), "map", "build", str(d), "--frames", "0:500",
                    "-o", str(path), "--config", "7scenes"], check=True)
    return path


def replicate(base: TopoMap, n: int) -> TopoMap:
    """The base map replicated to exactly n nodes (see the module docstring)."""
    b = base.n_nodes
    copies = math.ceil(n / b)
    cols = math.ceil(math.sqrt(copies))
    g = base.grid
    gap = round(GAP_M / g.resolution)
    H, W = g.cells.shape
    th, tw = H + 2 * gap, W + 2 * gap
    rows = math.ceil(copies / cols)
    cells = np.zeros((rows * th, cols * tw), np.uint8)
    origin = g.origin - gap * g.resolution
    T, K, size, t_ns, fidx, vpr, imgs, ce, ci, cw, ne, nm = ([] for _ in range(12))
    D = base.vpr.shape[1]
    offsets_m = []
    span_ns = int(base.t_ns.max() - base.t_ns.min()) + 1
    span_f = int(base.frame_index.max()) + 1
    bf = base.features
    if not isinstance(bf, FeatureStore):
        raise ValueError("the base map must be loaded with load_map (features in a FeatureStore)")
    base_imgs = list(base.images_jpeg)  # read (and verified) once, shared by every copy
    kp_rows = []
    for k in range(copies):
        r, c = divmod(k, cols)
        cells[r * th + gap:r * th + gap + H, c * tw + gap:c * tw + gap + W] = g.cells
        off = (c * tw * g.resolution) * g.plane_axes[0] + (r * th * g.resolution) * g.plane_axes[1]
        offsets_m.append(off)
        m = min(b, n - k * b)
        Tk = base.T_map_camera[:m].copy()
        Tk[:, :3, 3] += off
        T.append(Tk)
        K.append(base.K[:m])
        size.append(base.image_size[:m])
        t_ns.append(base.t_ns[:m] + k * span_ns)
        fidx.append(base.frame_index[:m] + k * span_f)
        v = base.vpr[:m].astype(np.float64)
        if k > 0:
            v = v + np.random.default_rng(k).normal(0.0, NOISE / math.sqrt(D), v.shape)
            v /= np.linalg.norm(v, axis=1, keepdims=True)
        vpr.append(v.astype(np.float32))
        kp_rows.append(np.arange(int(bf.offsets[0]), int(bf.offsets[m])))
        imgs.extend(base_imgs[:m])
        inside = (base.covis_edges.max(axis=1) < m) if len(base.covis_edges) else np.zeros(0, bool)
        ce.append(base.covis_edges[inside] + k * b)
        ci.append(base.covis_inliers[inside])
        cw.append(base.covis_weight[inside])
        inside = (base.conn_edges.max(axis=1) < m) if len(base.conn_edges) else np.zeros(0, bool)
        ne.append(base.conn_edges[inside] + k * b)
        nm.append(base.conn_metres[inside])
    Tn = np.concatenate(T)
    pos = Tn[:, :3, 3]
    # links between grid-adjacent copies: their closest pair of nodes
    for k in range(copies):
        r, c = divmod(k, cols)
        for k2 in ([k + 1] if c + 1 < cols else []) + [k + cols]:
            if k2 >= copies:
                continue
            a = np.arange(k * b, min((k + 1) * b, n))
            z = np.arange(k2 * b, min((k2 + 1) * b, n))
            d = np.linalg.norm(pos[a][:, None] - pos[z][None], axis=2)
            i, j = np.unravel_index(int(np.argmin(d)), d.shape)
            ne.append(np.array([[a[i], z[j]]], np.int64))
            nm.append(np.array([d[i, j]], np.float32))
    grid = OccupancyGrid(cells, origin, g.resolution, g.up, g.plane_axes)
    rows_all = np.concatenate(kp_rows)
    counts = np.concatenate([np.diff(bf.offsets)[: min(b, n - k * b)] for k in range(copies)])
    size_all = np.concatenate(size)
    feats = FeatureStore(np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), bf.keypoints[rows_all],
                         np.asarray(bf.descriptors)[rows_all], bf.scores[rows_all], size_all,
                         descriptor_scale=None if bf.descriptor_scale is None else bf.descriptor_scale[rows_all],
                         depth=None if bf.depth is None else np.asarray(bf.depth)[rows_all], codebook=bf.codebook)
    return TopoMap(
        T_map_camera=Tn, K=np.concatenate(K), image_size=size_all, t_ns=np.concatenate(t_ns),
        frame_index=np.concatenate(fidx), vpr=np.concatenate(vpr), features=feats, images_jpeg=imgs,
        covis_edges=np.concatenate(ce), covis_inliers=np.concatenate(ci), covis_weight=np.concatenate(cw),
        conn_edges=np.concatenate(ne), conn_metres=np.concatenate(nm), grid=grid, extractor=base.extractor,
        vpr_model=base.vpr_model,
        meta={**base.meta, "scale_replicated": f"v{SCALE_VERSION}: {copies} copies of {b} nodes, {n} nodes, "
              f"VPR noise {NOISE}"},
    )


def scaled_map(base_path: Path, n: int, out: Path) -> Path:
    path = out / f"map_{n}"
    man = path / "manifest.json"
    if man.is_file() and json.loads(man.read_text()).get("meta", {}).get("scale_replicated", "") \
            .startswith(f"v{SCALE_VERSION}:"):
        return path
    t0 = time.perf_counter()
    m = replicate(load_map(base_path), n)
    save_map(m, path, overwrite=True)
    print(f"  wrote {path} ({n} nodes) in {time.perf_counter() - t0:.1f} s", flush=True)
    return path


# ---------------------------------------------------------------- baselines (the former code)
def brute_local_candidates(m: TopoMap, neighbours: list[list[int]], prior: np.ndarray, desc: np.ndarray,
                           radius: float, trigger: float, angle_deg: float, k: int) -> list[tuple[int, float]]:
    """`VisualLocalizer.local_candidates` as it is on main (a linear scan over all nodes)."""
    d = np.linalg.norm(m.positions - prior[:3, 3], axis=1)
    nearest = int(np.argmin(d))
    if d[nearest] > trigger:
        return []
    cos_max = np.cos(np.radians(angle_deg))
    cand = {nearest} | set(neighbours[nearest])
    cand |= {int(i) for i in np.nonzero(d <= radius)[0]}
    keep = [i for i in cand if d[i] <= max(radius, d[nearest]) and float(m.T_map_camera[i][:3, 2] @ prior[:3, 2])
            >= cos_max]
    sims = m.vpr[keep] @ desc if keep else np.zeros(0)
    return sorted(zip(keep, sims.tolist(), strict=True), key=lambda x: (-x[1], x[0]))[:k]


def heap_shortest_path(m: TopoMap, start: int, goal: int) -> float:
    """The former `shortest_path` (adjacency lists built per query + heapq Dijkstra)."""
    n = m.n_nodes
    adj: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for (i, j), w in zip(m.conn_edges, m.conn_metres, strict=True):
        adj[int(i)].append((int(j), float(w)))
        adj[int(j)].append((int(i), float(w)))
    dist = np.full(n, np.inf)
    dist[start] = 0.0
    heap = [(0.0, start)]
    while heap:
        d, u = heapq.heappop(heap)
        if d > dist[u]:
            continue
        if u == goal:
            break
        for v, w in adj[u]:
            if d + w < dist[v]:
                dist[v] = d + w
                heapq.heappush(heap, (d + w, v))
    return float(dist[goal])


def old_covisible_neighbours(m: TopoMap, node: int) -> list[tuple[int, float]]:
    """The former `TopoMap.covisible_neighbours` (a scan over every edge per node)."""
    out = []
    for (i, j), w in zip(m.covis_edges, m.covis_weight, strict=True):
        if i == node:
            out.append((int(j), float(w)))
        elif j == node:
            out.append((int(i), float(w)))
    return out


def timed(fn: Any, reps: int) -> list[float]:
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1e3)
    return out


# ---------------------------------------------------------------- one size, in a fresh process
def measure(path: Path, verify: bool) -> dict[str, Any]:
    from litevloc.config import load_config
    from litevloc.pipelines.navigation.graph import shortest_path

    rss0 = memory_mb()["rss"]
    loads, cpus = [], []
    m = None
    for _ in range(3):
        m = None
        gc.collect()
        t0, c0 = time.perf_counter(), time.process_time()
        m = load_map(path)
        loads.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    assert m is not None
    gc.collect()
    mem = memory_mb()
    rss, hwm = mem["rss"], mem["peak"]
    man = json.loads((path / "manifest.json").read_text())
    disk = sum(int(e["bytes"]) for e in man["files"].values()) + (path / "manifest.json").stat().st_size
    t0, c0 = time.perf_counter(), time.process_time()
    for rel in man["files"]:
        with (path / rel).open("rb") as f:
            hashlib.sha256(f.read())
    hash_s, hash_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    n = m.n_nodes
    rng = np.random.default_rng(0)
    cfg = load_config("7scenes")
    lp = cfg.localization

    # GL retrieval: as localize_global does it (all descriptors, stable argsort, top-k)
    q = m.vpr[n // 2] + rng.normal(0, 0.05 / math.sqrt(m.vpr.shape[1]), m.vpr.shape[1]).astype(np.float32)
    q = (q / np.linalg.norm(q)).astype(np.float32)

    def retrieval() -> None:
        sims = m.vpr @ q
        np.argsort(-sims, kind="stable")[: lp.global_search.top_k]

    c0 = time.process_time()
    gl = timed(retrieval, 50)
    gl_cpu_ms = (time.process_time() - c0) / 50 * 1e3

    # LL lookup from priors 0.3 m off random nodes
    t0 = time.perf_counter()
    index = m.node_index
    index_ms = (time.perf_counter() - t0) * 1e3
    t0 = time.perf_counter()
    neighbours = m.covisibility_lists
    neighbours_ms = (time.perf_counter() - t0) * 1e3
    priors = []
    for node in rng.integers(0, n, 200):
        P = m.T_map_camera[node].copy()
        P[:3, 3] += rng.normal(0, 0.3 / math.sqrt(3), 3)
        priors.append(P)
    ls = lp.local_search
    args = (ls.candidate_radius_m, ls.trigger_distance_m, ls.max_view_angle_deg, ls.max_candidates)
    ll, ll_brute = [], []
    for P in priors:
        t0 = time.perf_counter()
        got = index.local_candidates(P, q, m.vpr, m.T_map_camera, neighbours, *args)
        ll.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        ref = brute_local_candidates(m, neighbours, P, q, *args)
        ll_brute.append((time.perf_counter() - t0) * 1e3)
        if [c for c, _ in got] != [c for c, _ in ref]:
            raise AssertionError(f"index and brute-force LL candidates differ: {got} vs {ref}")

    # planner: node 0 -> the node farthest from it
    far = int(np.argmax(np.linalg.norm(m.positions - m.positions[0], axis=1)))
    t0 = time.perf_counter()
    _, length = shortest_path(m, 0, far)  # first call builds the CSR matrix (once per map)
    plan_first_ms = (time.perf_counter() - t0) * 1e3
    plan = timed(lambda: shortest_path(m, 0, far), 10)
    heap = timed(lambda: heap_shortest_path(m, 0, far), 3 if n > 2000 else 10)
    if abs(heap_shortest_path(m, 0, far) - length) > 1e-3:
        raise AssertionError("csgraph and heap Dijkstra disagree on the path length")

    # the former per-node neighbour scan (O(N * E)): only where it finishes in seconds
    old_neigh_ms = None
    if n <= 1000:
        t0 = time.perf_counter()
        for i in range(n):
            old_covisible_neighbours(m, i)
        old_neigh_ms = (time.perf_counter() - t0) * 1e3

    verify_ms: list[float] = []
    if verify:
        from litevloc.pipelines.localization.query import relative_pose
        from litevloc.runtime.sources import open_source
        from litevloc.runtime.tools.posed import posed_frames
        from litevloc.runtime.vloc_models import as_features, load_bundle

        bundle = load_bundle(cfg.models)
        src = open_source(require_7scenes(), slice(500, 501), strict=True, rgbd_calibration=cfg.rgbd_calibration)
        frame, _ = next(iter(posed_frames(src)))
        live = bundle.extract(frame.color)
        node = int(np.argmax(m.vpr @ bundle.describe(frame.color)))
        base_n = int(re.search(r"copies of (\d+) nodes", m.meta["scale_replicated"]).group(1))  # type: ignore[union-attr]
        copies = [node % base_n + base_n * j for j in range(n // base_n)]
        for k in range(6):  # a different copy of the node each time: its features come from disk
            cand = copies[(k * len(copies)) // 6]
            t0 = time.perf_counter()
            relative_pose(live, frame.depth, frame.K, as_features(m.features[cand]), m.K[cand], bundle.match, lp)
            verify_ms.append((time.perf_counter() - t0) * 1e3)
        verify_ms = verify_ms[1:]  # the first call warms the ONNX sessions
    mem = memory_mb()
    rss_end, hwm_end = mem["rss"], mem["peak"]
    return {
        "nodes": n, "load_s": float(np.median(loads)), "load_s_all": loads, "load_cpu_s": float(np.median(cpus)),
        "rss_mb": rss, "rss_interpreter_mb": rss0, "rss_peak_mb": hwm,
        "rss_after_all_mb": rss_end, "rss_peak_after_all_mb": hwm_end, "disk_bytes": disk, "hash_all_files_s": hash_s,
        "hash_all_files_cpu_s": hash_cpu_s, "gl_retrieval_cpu_ms": gl_cpu_ms,
        "gl_retrieval_ms": float(np.median(gl)), "gl_retrieval_p90_ms": float(np.percentile(gl, 90)),
        "gl_verify_ms": float(np.median(verify_ms)) if verify_ms else None,
        "ll_lookup_ms": float(np.median(ll)), "ll_lookup_p90_ms": float(np.percentile(ll, 90)),
        "ll_brute_ms": float(np.median(ll_brute)), "node_index_build_ms": index_ms,
        "covis_lists_build_ms": neighbours_ms, "old_covis_neighbours_all_ms": old_neigh_ms,
        "planner_ms": float(np.median(plan)), "planner_first_call_ms": plan_first_ms,
        "planner_heap_ms": float(np.median(heap)), "path_m": length,
        "edges": {"covisibility": len(m.covis_edges), "connectivity": len(m.conn_edges)},
    }


KEYS = ["load_s", "rss_mb", "disk_bytes", "gl_retrieval_ms", "gl_verify_ms", "ll_lookup_ms", "planner_ms"]


def plot(rows: list[dict[str, Any]], png: Path, load: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array([r["nodes"] for r in rows], float)
    series = [
        ("load_s", "map load, wall (s)"), ("load_cpu_s", "map load, CPU (s)"), ("rss_mb", "RSS after load (MB)"),
        ("disk_bytes", "disk (MB)"), ("gl_retrieval_ms", "GL retrieval, wall (ms)"),
        ("gl_retrieval_cpu_ms", "GL retrieval, CPU (ms)"), ("gl_verify_ms", "GL verify 1 cand. (ms)"),
        ("ll_lookup_ms", "LL lookup, KD-tree (ms)"), ("ll_brute_ms", "LL lookup, linear scan (ms)"),
        ("planner_ms", "planner, csgraph (ms)"), ("planner_heap_ms", "planner, former heapq (ms)"),
    ]
    fig, ax = plt.subplots(figsize=(8, 6))
    markers = "os^vD<>px*h"
    for i, (key, label) in enumerate(series):
        y = np.array([np.nan if r.get(key) is None else r[key] for r in rows], float)
        if key == "disk_bytes":
            y = y / 1e6
        if np.all(np.isnan(y)):
            continue
        ax.loglog(n, y, marker=markers[i % len(markers)], color=plt.get_cmap("tab20")(i / len(series)), label=label)
    ax.loglog(n, n / n[0] * 1e-2, "k:", lw=1, label="slope 1 (linear), reference")
    ax.set_xlabel("map nodes")
    ax.set_ylabel("cost (unit in the legend)")
    ax.set_title(f"LiteVLoc map costs vs node count (bench/scale.py; load average {load:.0f} on 2 CPUs)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", type=Path, default=ROOT / "out" / "bench" / "scale.json")
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    ap.add_argument("--base", type=Path, default=ROOT / "out" / "maps" / "7s", help="base map (built when absent)")
    ap.add_argument("--cache", type=Path, default=ROOT / "out" / "scale", help="where the scaled maps are kept")
    ap.add_argument("--no-verify", action="store_true", help="skip the GL verification (needs the ONNX models)")
    ap.add_argument("--measure", type=Path, help=argparse.SUPPRESS)  # internal: one size in this process
    ap.add_argument("--replot", action="store_true", help="only redraw the PNG from PATH's .details.json")
    args = ap.parse_args()
    if args.replot:
        det = json.loads(args.json.with_suffix(".details.json").read_text())
        plot(det["rows"], args.json.with_suffix(".png"), det["load_average"][0])
        return 0
    if args.measure is not None:
        print(json.dumps(measure(args.measure, not args.no_verify)))
        return 0
    base = base_map(args.base)
    args.cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in sorted(args.sizes):
        path = scaled_map(base, n, args.cache)
        cmd = [sys.executable, __file__, "--measure", str(path)] + (["--no-verify"] if args.no_verify else [])
        # one BLAS thread, as the service configures it (runtime.service.stages.configure_threads):
        # on 2 loaded CPUs a second OpenBLAS thread made the 10k-node top-k 2x slower
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(f"  measured {n} nodes", flush=True)
    load = os.getloadavg()
    print_table(f"map costs vs node count (load average {load[0]:.1f} on {os.cpu_count()} CPUs)",
                ["nodes", "load s", "load CPU s", "hash CPU s", "RSS MB", "disk MB", "GL top-k ms", "top-k CPU ms",
                 "GL verify ms", "LL ms", "LL scan ms", "plan ms", "heapq ms"],
                [[r["nodes"], r["load_s"], r["load_cpu_s"], r["hash_all_files_cpu_s"], r["rss_mb"],
                  r["disk_bytes"] / 1e6, r["gl_retrieval_ms"], r["gl_retrieval_cpu_ms"],
                  r["gl_verify_ms"] if r["gl_verify_ms"] is not None else "-",
                  r["ll_lookup_ms"], r["ll_brute_ms"], r["planner_ms"], r["planner_heap_ms"]] for r in rows])
    result = {"nodes": [r["nodes"] for r in rows], **{k: [r[k] for r in rows] for k in KEYS}}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    details = args.json.with_suffix(".details.json")
    details.write_text(json.dumps({"rows": rows, "load_average": load, "base_map": str(base),
                                   "replication": __doc__.split("Each map")[0]}, indent=2) + "\n")
    png = args.json.with_suffix(".png")
    plot(rows, png, load[0])
    print(f"wrote {args.json}, {details}, {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
