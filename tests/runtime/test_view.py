"""The live view: bounded drop queue, geometry helpers, a saved .rrd with every part of the view,
and nothing imported when the view is off."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.hw.messages import RgbdFrame
from litevloc.pipelines.localization.results import MatchedPixels
from litevloc.pipelines.topomap.types import NodeFeatures, OccupancyGrid, TopoMap
from litevloc.runtime.service.queues import DropQueue
from litevloc.runtime.service.view_scene import covariance_ellipsoid, occupied_points
from tests.conftest import HeldOut
from tests.runtime.zenoh_helpers import free_port

K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])


def synthetic_map(n: int = 5) -> TopoMap:
    T = np.stack([make_T(so3_exp(np.array([0.0, 0.3 * i, 0.0])), [0.5 * i, 0.0, 0.0]) for i in range(n)])
    rng = np.random.default_rng(0)
    jpegs = [bytes(cv2.imencode(".jpg", rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))[1]) for _ in range(n)]
    feats = [NodeFeatures(rng.uniform(0, 120, (30, 2)).astype(np.float32), np.zeros((30, 8), np.float32),
                          np.ones(30, np.float32), (160, 120)) for _ in range(n)]
    cells = np.zeros((10, 12), np.uint8)
    cells[0, :] = OccupancyGrid.OCCUPIED
    cells[5, 3] = OccupancyGrid.FREE
    grid = OccupancyGrid(cells, np.array([-1.0, -2.0]), 0.25, np.array([0.0, -1.0, 0.0]), np.eye(3)[[0, 2]])
    edges = np.array([(i, i + 1) for i in range(n - 1)], np.int64)
    return TopoMap(T, np.stack([K] * n), np.array([[160, 120]] * n, np.int32), np.arange(n, dtype=np.int64),
                   np.arange(n, dtype=np.int64), np.eye(n, dtype=np.float32), feats, jpegs, edges,
                   np.full(n - 1, 50, np.int32), np.ones(n - 1, np.float32), edges[:2], np.ones(2, np.float32), grid)


@dataclass
class Res:
    t_ns: int
    accepted: bool
    reason: str
    T_map_camera: Any = None
    covariance: Any = None
    ref_node: int = -1
    mode: str = "local"
    n_matches: int = 0
    n_inliers: int = 0
    inlier_ratio: float = 0.0
    median_reprojection_px: float = float("nan")
    timings_ms: dict[str, float] = field(default_factory=dict)
    matches: Any = None


@dataclass
class Fused:
    t_ns: int
    T_map_base: Any
    initialised: bool = True


def test_drop_queue_never_blocks_and_counts_drops() -> None:
    q = DropQueue(3)
    for i in range(10):
        q.put(i)
    assert q.drops == 7 and q.puts == 10 and q.get_all(0.0) == [7, 8, 9] and len(q) == 0
    t0 = time.perf_counter()
    assert q.get_all(0.05) == [] and time.perf_counter() - t0 >= 0.04
    threads = [threading.Thread(target=lambda: [q.put(j) for j in range(1000)]) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert q.puts == 4010 and q.drops + len(q) == 4007 - 0 and len(q) == 3
    with pytest.raises(ValueError):
        DropQueue(0)


def test_covariance_ellipsoid_and_occupancy_points() -> None:
    R = so3_exp(np.array([0.0, 0.0, np.pi / 2]))
    cov = np.diag([0.04, 0.01, 0.0001, 1, 1, 1])  # camera frame: 20 cm along x, 10 cm along y
    half, Rm = covariance_ellipsoid(make_T(R, [1, 2, 3]), cov)
    assert np.allclose(sorted(half), [0.03, 0.3, 0.6]) and np.isclose(np.linalg.det(Rm), 1.0)
    big = Rm[:, int(np.argmax(half))]
    assert np.allclose(np.abs(big), [0, 1, 0], atol=1e-9)  # camera x rotated by 90 deg about z -> map y
    assert covariance_ellipsoid(np.eye(4), None) is None
    assert covariance_ellipsoid(np.eye(4), np.full((6, 6), np.nan)) is None
    pts = occupied_points(synthetic_map().grid)
    assert pts.shape == (12, 3)
    assert np.allclose(pts[0], [-1 + 0.125, 0.0, -2 + 0.125])  # row 0 col 0 -> plane (x, z) of the axes


def test_saved_stream_holds_every_part_of_the_view(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    from litevloc.runtime.service.view import LiveView

    m = synthetic_map()
    out = tmp_path / "view.rrd"
    view = LiveView(save=out, topomap=m, T_base_camera=np.eye(4), pose_hz=10.0)
    color = np.zeros((120, 160, 3), np.uint8)
    rng = np.random.default_rng(1)
    for i in range(20):  # 200 Hz odometry for 1 s, VLoc at 5 Hz, status at 2 Hz
        t = i * 50_000_000
        for k in range(10):
            view.put_fused(Fused(t + k * 5_000_000, make_T(np.eye(3), [0.01 * (i * 10 + k), 0, 0])))
        if i % 4 == 0:
            ok = i != 8
            res = Res(t, ok, "ok" if ok else "too few inliers (3)", m.T_map_camera[1] if ok else None,
                      np.diag([1e-4, 1e-4, 4e-4, 1e-5, 1e-5, 1e-5]), ref_node=1, n_matches=120, n_inliers=80,
                      inlier_ratio=0.66, median_reprojection_px=1.2,
                      timings_ms={"extract": 90.0, "vpr": 20.0, "match": 150.0, "pnp": 1.0, "total": 270.0},
                      matches=MatchedPixels(1, rng.uniform(0, 120, (40, 2)).astype(np.float32),
                                            rng.uniform(0, 120, (40, 2)).astype(np.float32),
                                            np.arange(40) % 3 != 0) if ok else None)
            view.put_vloc(RgbdFrame(t, color, None, K, index=i), res)
        if i % 10 == 0:
            view.put_status({"sensor_time_ns": t, "state": "TRACKING" if i else "INIT", "reasons": [],
                             "queues": {"odometry": {"depth": 2}}, "latency": {"odometry_to_publish": {"p99_ms": 2.0}},
                             "stages": {"fusion": {"latency": {"odometry": {"p99_ms": 0.5}}}},
                             "map": {"name": "office", "version": f"v{1 + i // 10}", "map_id": "m@1",
                                     "switches": i // 10, "refusals": 0}})
    rep = view.close()
    assert rep["errors"] == 0, rep["last_error"]
    assert rep["logged"] == {"fused": 10, "vloc": 5, "status": 2, "matches": 4 * 40}  # 200 Hz thinned to 10 Hz
    assert out.is_file() and out.stat().st_size > 10_000
    rows: dict[str, int] = {}
    for chunk in RrdReader(out).store().stream():
        rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    for path in ("/world/map/keyframes/0", "/world/map/keyframes/4", "/world/map/covisibility",
                 "/world/map/connectivity", "/world/map/occupancy", "/world/fused", "/world/fused_trail",
                 "/world/vloc/camera", "/world/vloc/covariance", "/world/vloc/reference",
                 "/images/matches", "/images/matches/lines", "/images/match_info", "/status/tracking",
                 "/status/vloc", "/plots/vloc_ms/extract", "/plots/vloc_ms/pnp", "/plots/runtime_ms/fusion_p99",
                 "/plots/state", "/plots/queues/odometry", "/plots/view_drops"):
        assert rows.get(path, 0) > 0, (path, sorted(rows))
    assert rows["/images/matches"] == 5  # every result
    assert rows["/images/matches/lines"] == 5  # 4 accepted results, and the rejected one clears them
    assert rows["/world/vloc/covariance"] == 4  # the rejected result moves nothing
    assert rows["/status/map"] == 2  # the map version, logged when it changes


def test_view_needs_a_sink() -> None:
    from litevloc.runtime.service.view import LiveView, ViewError

    with pytest.raises(ViewError, match="--view-save"):
        LiveView()


def test_nothing_is_imported_with_the_view_off() -> None:
    code = ("import sys; from litevloc.cli.main import build_parser; "
            "import litevloc.runtime.service.app, litevloc.cli.replay, litevloc.cli.run, "
            "litevloc.cli.localize; "
            "a = build_parser().parse_args(['replay', 'x.mcap', '--map', 'm']); "
            "assert a.view is False and a.view_save is None, a; "
            "bad = [m for m in sys.modules if m.split('.')[0] in ('rerun', 'rerun_bindings', 'pyarrow') "
            "or m == 'litevloc.runtime.service.view']; print(bad); assert not bad")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


def _entity_rows(rrd: Path) -> dict[str, int]:
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(rrd).store().stream():
        rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    return rows


@pytest.mark.timeout(300)
def test_replay_and_localize_save_the_view(seven_scenes_held_out: HeldOut, tmp_path: Path) -> None:
    """`litevloc replay REC --map MAP --view-save` and `litevloc localize ... --view-save` on 16
    held-out 7-Scenes frames: the files hold the map, fused poses, VLoc results and status."""
    from litevloc.cli.main import main

    rec, mp = seven_scenes_held_out.queries, seven_scenes_held_out.map_dir
    fast = ["--set", "models.matcher=mnn"]
    replay_rrd, loc_rrd = tmp_path / "replay.rrd", tmp_path / "localize.rrd"
    assert main(["replay", str(rec), "--frames", "0:16", "--config", "7scenes", "--map", str(mp), "--listen",
                 f"tcp/127.0.0.1:{free_port()}", "--set", "runtime.mode=deterministic", *fast,
                 "--view-save", str(replay_rrd)]) == 0
    rows = _entity_rows(replay_rrd)
    for path in ("/world/map/keyframes/0", "/world/map/connectivity", "/world/fused", "/world/vloc/camera",
                 "/images/matches", "/images/matches/lines", "/status/tracking", "/plots/vloc_ms/extract",
                 "/plots/runtime_ms/fusion_p99"):
        assert rows.get(path, 0) > 0, (path, sorted(rows))
    assert rows["/images/matches"] == 16  # deterministic mode: every frame reached the view
    assert main(["localize", str(mp), str(rec), "--frames", "0:16:4", "--config", "7scenes", "-o",
                 str(tmp_path / "t.txt"), *fast, "--view-save", str(loc_rrd)]) == 0
    rows = _entity_rows(loc_rrd)
    assert rows.get("/world/vloc/camera", 0) > 0 and rows.get("/status/tracking", 0) > 0
