"""Relocalization results in the map-free benchmark's file layout, and scoring them from the files.

Each reference keyframe is a map-free *scene* named `kf<NODE>` (4+ digits): its reference
image is `seq0/frame_00000.jpg`, its queries are `seq1/frame_<SOURCE INDEX, 5 digits>.jpg`.
Poses are world-to-camera with the reference keyframe's camera frame as the world
(`T_query_ref`, quaternion w x y z then translation), as the scorer reads them.

Written under DIR:

- `submission_<METHOD>.zip`: one `pose_kf<NODE>.txt` per scene, lines
  `seq1/frame_00500.jpg qw qx qy qz tx ty tz confidence` (confidence = PnP inliers);
- `dataset/val/kf<NODE>/intrinsics.txt` (`NAME fx fy cx cy W H` per query) and `poses.txt`
  (ground truth, `NAME qw qx qy qz tx ty tz`): what the official scorer reads with
  `--dataset_path DIR/dataset --split val`;
- `references.csv`: `scene,frame,source_index,reference_keyframe` for every query, estimated
  or not.

`score_submission` reads those files back and scores them with
`pipelines.evaluation.mapfree` (the official scorer's protocol keeps only every 5th
ground-truth frame of a scene: `subsample=5`; 1 scores every query).
"""

from __future__ import annotations

import csv
import io
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import invert, make_T, matrix_to_quat_xyzw, quat_xyzw_to_matrix
from litevloc.pipelines.evaluation.mapfree import QueryScore, mapfree_metrics, score_query


class SubmissionError(LiteVLocError, ValueError):
    """A map-free submission or dataset file is missing or malformed (names the file and line)."""


@dataclass(frozen=True)
class MapFreeQuery:
    """One query of the layout: its source frame index, reference keyframe, intrinsics (3x3,
    image W x H) and ground-truth `T_ref_query` (4x4, query camera in the reference camera)."""

    source_index: int
    reference: int
    K: NDArray[np.float64]
    size_wh: tuple[int, int]
    T_ref_query_gt: NDArray[np.float64]


def scene_name(node: int) -> str:
    return f"kf{node:04d}"


def frame_name(source_index: int) -> str:
    if not 0 <= source_index <= 99999:
        raise SubmissionError(f"frame index {source_index} does not fit the map-free name seq1/frame_%05d.jpg")
    return f"seq1/frame_{source_index:05d}.jpg"


def _pose_line(name: str, T_cam_world: NDArray[np.float64], confidence: float | None) -> str:
    x, y, z, w = matrix_to_quat_xyzw(T_cam_world[:3, :3])
    tx, ty, tz = T_cam_world[:3, 3]
    tail = "" if confidence is None else f" {confidence:.6g}"
    return f"{name} {w:.12f} {x:.12f} {y:.12f} {z:.12f} {tx:.12f} {ty:.12f} {tz:.12f}{tail}"


def write_dataset(out_dir: Path, queries: list[MapFreeQuery]) -> None:
    """Ground truth of the queries in the scorer's dataset layout, plus `references.csv`.

    The reference frame (`seq0/frame_00000.jpg`, the identity) is not listed: the scorer keys
    frames by their number only, so it would collide with a query numbered 0 and count as a
    query without an estimate."""
    by_scene: dict[int, list[MapFreeQuery]] = {}
    for q in queries:
        by_scene.setdefault(q.reference, []).append(q)
    for node, qs in sorted(by_scene.items()):
        d = out_dir / "dataset" / "val" / scene_name(node)
        d.mkdir(parents=True, exist_ok=True)
        intr: list[str] = []
        poses: list[str] = []
        for q in sorted(qs, key=lambda q: q.source_index):
            name = frame_name(q.source_index)
            w, h = q.size_wh
            intr.append(f"{name} {q.K[0, 0]:.6f} {q.K[1, 1]:.6f} {q.K[0, 2]:.6f} {q.K[1, 2]:.6f} {w} {h}")
            poses.append(_pose_line(name, invert(q.T_ref_query_gt), None))
        (d / "intrinsics.txt").write_text("\n".join(intr) + "\n")
        (d / "poses.txt").write_text("\n".join(poses) + "\n")
    with (out_dir / "references.csv").open("w", newline="") as f:
        wr_ = csv.writer(f)
        wr_.writerow(["scene", "frame", "source_index", "reference_keyframe"])
        for q in queries:
            wr_.writerow([scene_name(q.reference), frame_name(q.source_index), q.source_index, q.reference])


def write_submission(path: Path, estimates: dict[int, tuple[int, NDArray[np.float64], float]]) -> Path:
    """The submission zip: `estimates[source_index] = (reference node, T_ref_query, confidence)`."""
    by_scene: dict[int, list[str]] = {}
    for idx in sorted(estimates):
        node, T_ref_query, conf = estimates[idx]
        by_scene.setdefault(node, []).append(_pose_line(frame_name(idx), invert(T_ref_query), conf))
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for node, lines in sorted(by_scene.items()):
            z.writestr(f"pose_{scene_name(node)}.txt", "\n".join(lines) + "\n")
    return path


def _read_poses(text: str, where: str, with_confidence: bool) -> dict[int, tuple[NDArray[np.float64], float]]:
    """`frame number -> (T_cam_world, confidence)`; malformed lines are errors naming the line."""
    out: dict[int, tuple[NDArray[np.float64], float]] = {}
    n_fields = 9 if with_confidence else 8
    for k, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if len(parts) != n_fields:
            raise SubmissionError(f"{where} line {k}: {len(parts)} fields, expected {n_fields}")
        try:
            num = int(parts[0][-9:-4])
            vals = np.array([float(v) for v in parts[1:]])
        except ValueError as exc:
            raise SubmissionError(f"{where} line {k}: {exc}") from exc
        if not np.all(np.isfinite(vals)) or np.linalg.norm(vals[:4]) == 0:
            raise SubmissionError(f"{where} line {k}: non-finite values or a zero quaternion")
        qw, qx, qy, qz = vals[:4]
        T = make_T(quat_xyzw_to_matrix(np.array([qx, qy, qz, qw])), vals[4:7])
        out[num] = (T, float(vals[7]) if with_confidence else 0.0)
    return out


def score_submission(submission: Path, dataset: Path, subsample: int = 1) -> dict[str, float]:
    """Score a submission zip against a split folder written by `write_dataset`
    (`DIR/dataset/val`), as the official scorer does: `subsample` keeps every n-th ground-truth
    frame of a scene that has a pose file (its val/test protocol), and a scene without one
    fails with all its frames."""
    if not submission.is_file():
        raise SubmissionError(f"no submission zip at {submission}")
    scenes = sorted(d for d in dataset.iterdir() if d.is_dir()) if dataset.is_dir() else []
    if not scenes:
        raise SubmissionError(f"no scene folders under {dataset}")
    results: dict[str, list[QueryScore]] = {}
    failures = 0
    with zipfile.ZipFile(submission) as z:
        names = set(z.namelist())
        for d in scenes:
            gt = _read_poses((d / "poses.txt").read_text(), str(d / "poses.txt"), False)
            intr: dict[int, tuple[NDArray[np.float64], float, float]] = {}
            for line in (d / "intrinsics.txt").read_text().splitlines():
                p = line.split()
                if p and not p[0].startswith("#"):
                    fx, fy, cx, cy, W, H = (float(v) for v in p[1:7])
                    intr[int(p[0][-9:-4])] = (np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), W, H)
            member = f"pose_{d.name}.txt"
            if member not in names:
                # as the official scorer does: a scene without a pose file fails with ALL its frames
                # (its subsampling applies only to scenes that have one)
                failures += len(gt)
                results[d.name] = []
                continue
            gt = {k: v for i, (k, v) in enumerate(gt.items()) if i % subsample == 0}
            est = _read_poses(io.TextIOWrapper(z.open(member), encoding="utf-8").read(), f"{submission}:{member}",
                              True)
            scores: list[QueryScore] = []
            for num, (T_gt, _) in gt.items():
                if num not in est:
                    failures += 1
                    continue
                K, W, H = intr[num]
                scores.append(score_query(est[num][0], T_gt, K, W, H, est[num][1]))
            results[d.name] = scores
    return mapfree_metrics(results, failures)
