"""The mapping pass's SLAM, measured (`bench/slam.py` runs the commands, this holds the logic).

* `case_figures`: the benchmark's keys of one `map build --poses slam --json` report.
* `inject_wrong_loops`: a saved pose graph (`map build --slam-graph`) with `fraction` x its
  loop count of wrong loop factors added between keyframes more than `min_apart_m` apart in
  the reference (each claims the two views are at the same place, 10 cm apart, with a real
  loop's noise), re-optimised as the build did (GNC over the loops, then the build's wall
  factors); how far the keyframes move and how many wrong loops were kept.
* `graph_errors`: a saved graph against reference poses by frame index (the 7-Scenes ground
  truth read from the dataset after the build, or the SfM pseudo ground truth with a
  similarity alignment: that reference has its own scale).
* `sim_reference`: the simulator's ground-truth camera poses of a pass, by frame index;
  `mapping_pass_uri`: a world's mapping pass as a source URI.
* `regraph`: a saved graph re-optimised with other graph parameters (the loop gate's, chosen
  on tuning passes; the loop stage alone, without the build's walls), against reference
  poses: keyframe ATE, loops kept, wrong loops kept, how many loops each gate rejected and how
  many of those were true ones.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import make_T
from litevloc.base.params.slam import SlamGraphParams, SlamParams
from litevloc.pipelines.evaluation.trajectory import ate
from litevloc.pipelines.slam.evaluate import WRONG_LOOP_DEG, WRONG_LOOP_M, loop_errors, trajectory_errors
from litevloc.pipelines.slam.graph import optimise
from litevloc.pipelines.slam.types import Edge
from litevloc.runtime.tools.slam_build import SavedGraph, load_graph, solve_saved

F64 = NDArray[np.float64]

# the simulator worlds' mapping passes (what `sim navigate` and `bench/loop.py` map with)
MAPPING_PASSES = {"office": "map", "floor": "map", "bland": "map", "loop": "loop"}


def mapping_pass_uri(world: str, seed: int = 0) -> str:
    """The simulator source URI of a world's mapping pass (`MAPPING_PASSES`) with its seed."""
    return f"sim:{world}?pass={MAPPING_PASSES[world]}&seed={seed}"


def without_ground_truth(src: Path, dst: Path) -> None:
    """Copy the recording `src` to `dst` without its /ground_truth/camera_pose channel: what a
    robot records (`litevloc record`), for building a map from the robot's own sensors."""
    from litevloc.hw.messages import GroundTruthPose
    from litevloc.hw.streams.mcap_io import McapSource, record_messages

    record_messages((m for m in McapSource(src) if not isinstance(m, GroundTruthPose)), dst,
                    {"source": str(src), "note": "ground truth removed"})


def case_figures(build: dict[str, Any], world: str | None = None) -> dict[str, Any]:
    """The benchmark's keys from a `map build --poses slam` JSON summary."""
    s = build["slam"]
    ev = s.get("evaluation", {})
    return {"keyframe_ate_m": ev.get("keyframe_ate_m"), "odometry_ate_m": ev.get("odometry_ate_m"),
            "no_loop_ate_m": ev.get("no_loop_ate_m"), "rpe_per_m": ev.get("rpe_per_m"),
            "loops_kept": s["loops"]["kept"], "loops_verified": s["loops"]["verified"],
            "loops_tried": s["loops"]["tried"], "loops_pregated": s["loops"].get("skipped_by_chain_pregate"),
            "loops_rejected_by_optimiser": s["loops"]["rejected_by_optimiser"],
            "loops_rejected_by_gate": s["loops"].get("rejected_by_gate"),
            "wrong_loops_kept": ev.get("wrong_loops_kept"), "wrong_loops_verified": ev.get("wrong_loops"),
            "s_per_keyframe": build["seconds_per_keyframe"], "cpu_s_per_keyframe": build["cpu_seconds_per_keyframe"],
            "peak_rss_mb": build["peak_rss_mb"], "map_keyframes": build["nodes"], "slam_keyframes": s["keyframes"],
            "seconds": {**s["seconds"], "total": build["seconds"]}, "faults": s["faults"],
            "warnings": s["warnings"], "world": world}


def sim_reference(uri: str, sim_params: Any) -> dict[int, F64]:
    """Ground-truth camera poses of a simulated pass by frame index (no rendering)."""
    from litevloc.sim.source import open_sim_source

    src = open_sim_source(uri, sim_params)
    return dict(enumerate(src.camera_poses()))


def _ref_by_id(g: SavedGraph, ref_by_frame: dict[int, F64]) -> dict[int, F64]:
    return {k.id: ref_by_frame[k.index] for k in g.keyframes if k.index in ref_by_frame}


def inject_wrong_loops(graph_npz: Path, ref_by_frame: dict[int, F64], slam: SlamParams,
                       fraction: float = 0.1, min_apart_m: float = 3.0, seed: int = 0) -> dict[str, Any]:
    """See the module docstring."""
    params = slam.graph
    g = load_graph(graph_npz)
    ref = _ref_by_id(g, ref_by_frame)
    loops = [e for e in g.edges if e.kind == "loop"]
    kept = [e for e, w in zip(loops, g.loop_weights, strict=True) if w > params.kept_weight]
    base = solve_saved(g, slam)
    cov = np.median(np.stack([e.covariance for e in kept]), axis=0) if kept else np.diag([1e-4] * 6)
    rng = np.random.default_rng(seed)
    ids = sorted(ref)
    n_wrong = max(1, round(fraction * len(loops)))
    wrong: list[Edge] = []
    while len(wrong) < n_wrong:
        a, b = sorted(int(x) for x in rng.choice(ids, 2, replace=False))
        if np.linalg.norm(ref[a][:3, 3] - ref[b][:3, 3]) > min_apart_m:
            wrong.append(Edge(a, b, make_T(np.eye(3), np.array([0.1, 0.0, 0.0])), cov, "loop"))
    res = solve_saved(g, slam, wrong)
    common = sorted(set(base.poses) & set(res.poses))
    moved = np.array([np.linalg.norm(res.poses[k][:3, 3] - base.poses[k][:3, 3]) for k in common])
    w_wrong = res.loop_weights[len(loops):]
    return {"loops": len(loops), "wrong_loops_added": n_wrong, "fraction": fraction, "min_apart_m": min_apart_m,
            "wrong_loops_kept": int(sum(w > params.kept_weight for w in w_wrong)),
            "true_loops_kept_before": int(sum(w > params.kept_weight for w in base.loop_weights)),
            "true_loops_kept_after": int(sum(w > params.kept_weight for w in res.loop_weights[:len(loops)])),
            "moved_max_m": float(moved.max()) if len(moved) else None,
            "moved_median_m": float(np.median(moved)) if len(moved) else None,
            "keyframes_left_out_after": len(res.dropped) - len(base.dropped)}


def graph_errors(graph_npz: Path, ref_by_frame: dict[int, F64], params: SlamGraphParams,
                 similarity: bool = False) -> dict[str, Any]:
    """Keyframe ATE / RPE of a saved graph against reference poses by frame index, and its
    wrong loops; `similarity`: align with scale (a reference in its own scale)."""
    g = load_graph(graph_npz)
    ref = _ref_by_id(g, ref_by_frame)
    ids = [k for k in sorted(ref) if np.isfinite(g.poses[k]).all()]
    est = np.stack([g.poses[k] for k in ids])
    R = np.stack([ref[k] for k in ids])
    out: dict[str, Any] = {"keyframes_compared": len(ids)}
    if similarity:
        out["keyframe_ate_m"], out["scale"] = _ate_sim3(est, R)
    else:
        e = trajectory_errors(est, R)
        out.update(keyframe_ate_m=e["ate_m"], keyframe_ate_median_m=e["ate_median_m"], rpe_per_m=e["rpe_per_m"])
        out["T_reference_map"] = ate(est, R).T_ref_est.tolist()
    loops = [e for e in g.edges if e.kind == "loop"]
    errs = loop_errors(loops, ref)
    wrong = [x is not None and (x[0] > WRONG_LOOP_M or x[1] > WRONG_LOOP_DEG) for x in errs]
    out["wrong_loops"] = int(sum(wrong))
    out["wrong_loops_kept"] = int(sum(w and lw > params.kept_weight for w, lw in zip(wrong, g.loop_weights,
                                                                                     strict=True)))
    return out


def _ate_sim3(est: F64, ref: F64) -> tuple[float, float]:
    """RMSE (in the estimate's metres) after a similarity alignment of positions, and its scale."""
    X, Y = est[:, :3, 3], ref[:, :3, 3]
    mx, my = X.mean(0), Y.mean(0)
    U, S, Vt = np.linalg.svd((Y - my).T @ (X - mx) / len(X))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    s = float(np.trace(np.diag(S) @ D) / (((X - mx) ** 2).sum() / len(X)))
    p = s * (X - mx) @ (U @ D @ Vt).T + my
    return float(np.sqrt(np.mean(np.sum((p - Y) ** 2, axis=1))) / s), s


def regraph(graph_npz: Path, ref_by_frame: dict[int, F64], params: SlamGraphParams) -> dict[str, Any]:
    """See the module docstring (the graph's keyframes and edges as the build made them)."""
    import time

    g = load_graph(graph_npz)
    ref = _ref_by_id(g, ref_by_frame)
    t0 = time.perf_counter()
    res = optimise(g.keyframes, g.edges, g.T_map_first, params, g.level)
    seconds = time.perf_counter() - t0
    loops = [e for e in g.edges if e.kind == "loop"]
    errs = loop_errors(loops, ref)
    wrong = [x is not None and (x[0] > WRONG_LOOP_M or x[1] > WRONG_LOOP_DEG) for x in errs]
    kept = [w > params.kept_weight for w in res.loop_weights]
    ids = [k for k in sorted(res.poses) if k in ref]
    gates: dict[str, dict[str, int]] = {}
    for gate, w in zip(res.loop_gate, wrong, strict=True):
        if gate:
            d = gates.setdefault(gate, {"wrong": 0, "true": 0})
            d["wrong" if w else "true"] += 1
    return {"keyframe_ate_m": trajectory_errors(np.stack([res.poses[k] for k in ids]),
                                                np.stack([ref[k] for k in ids]))["ate_m"],
            "loops": len(loops), "wrong_loops": int(sum(wrong)), "loops_kept": int(sum(kept)),
            "wrong_loops_kept": int(sum(w and k for w, k in zip(wrong, kept, strict=True))),
            "true_loops_kept": int(sum(not w and k for w, k in zip(wrong, kept, strict=True))),
            "rejected_by_gate": gates, "keyframes_left_out": len(res.dropped), "optimise_s": round(seconds, 2)}
