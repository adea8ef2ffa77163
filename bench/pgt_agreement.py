"""7-Scenes accuracy against a second reference: how far the published pseudo ground truths
themselves disagree, and how our poses score against each.

The 7-Scenes ground truth (`*.pose.txt`) comes from KinectFusion on depth (D-SLAM). Brachmann
et al., "On the Limits of Pseudo Ground Truth in Visual Camera Re-localisation" (ICCV 2021),
published an SfM (COLMAP) pseudo ground truth of the same images; their pose files
(github.com/tsattler/visloc_pseudo_gt_limitations, `pgt/sfm/7scenes/redkitchen_train.txt`;
under the 7-Scenes licence, so not shipped here: download it and pass `--pgt`) hold one line
per image, `seq-XX/frame-NNNNNN.color.png qw qx qy qz tx ty tz f`, world-to-camera (COLMAP).

The second reference lives in its own frame and scale. It is brought into ours with a
similarity (evo's Umeyama, on camera centres) and a constant camera-frame rotation (the mean
of the per-frame offsets), both fitted on the **mapping pass only** (frames 0-499); then for
the query pass (500-999) this prints

* the disagreement between the two references per 50-frame stretch (position / rotation),
* for each configuration of a `bench/accuracy.py` JSON (estimates rebuilt from its error
  fields, `T_est = T_gt inv(E)`): the shares within [2 cm, 2 deg], [5 cm, 5 deg] and
  [25 cm, 5 deg] and the median error against either reference (all 500 frames; frames
  without an accepted pose count as failures),

writes out/bench/pgt_agreement.json and a PNG of the errors along the query pass.

    python bench/pgt_agreement.py --pgt redkitchen_train.txt [--sequence seq-01]
        [--accuracy out/bench/accuracy.json]

The shared data is the first 1000 frames of redkitchen `seq-01`: that repository's D-SLAM pose
file, passed as `--pgt`, matches our colour-camera ground truth to a median under 1 mm after the alignment.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import ROOT, print_table, require_7scenes, write_json
from evo.core.geometry import umeyama_alignment
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from litevloc.base.geometry import relative_pose_error
from litevloc.config import load_config
from litevloc.runtime.sources import open_source

F64 = NDArray[np.float64]
MAPPING = range(0, 500)
QUERY = range(500, 1000)


def read_pgt(path: Path, sequence: str) -> dict[int, F64]:
    """Camera-to-world 4x4 poses of one sequence from a pose file (COLMAP world-to-camera)."""
    out: dict[int, F64] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split()
        if not parts or not parts[0].startswith(sequence + "/"):
            continue
        if len(parts) < 8 or "frame-" not in parts[0]:
            raise SystemExit(f"{path}:{n}: expected 'seq-XX/frame-NNNNNN.color.png qw qx qy qz tx ty tz [f]'")
        qw, qx, qy, qz, tx, ty, tz = (float(v) for v in parts[1:8])
        R_cw = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R_cw.T
        T[:3, 3] = -R_cw.T @ np.array([tx, ty, tz])
        out[int(parts[0].split("frame-")[1][:6])] = T
    if not out:
        raise SystemExit(f"{path}: no poses of {sequence}")
    return out


def within(errors: F64, n: int, metres: float, degrees: float) -> float:
    """Share (%) of `n` frames whose (metres, degrees) row in `errors` is within both bounds."""
    return 100.0 * float(np.sum((errors[:, 0] <= metres) & (errors[:, 1] <= degrees))) / n


def fit_alignment(ours: dict[int, F64], other: dict[int, F64], frames: list[int]) -> tuple[float, F64, F64, F64]:
    """Similarity (scale, R, t) taking our frame to the other reference's, and the constant
    camera rotation Rc, so that other_i ~ (s R, t) ours_i Rc, fitted on `frames`."""
    X = np.array([ours[i][:3, 3] for i in frames]).T
    Y = np.array([other[i][:3, 3] for i in frames]).T
    R, t, s = umeyama_alignment(X, Y, with_scale=True)
    Rc = Rotation.from_matrix([(R @ ours[i][:3, :3]).T @ other[i][:3, :3] for i in frames]).mean().as_matrix()
    return float(s), np.asarray(R), np.asarray(t), np.asarray(Rc)


def apply_alignment(s: float, R: F64, t: F64, Rc: F64, T: F64) -> F64:
    """Our camera-to-world pose T (4x4) in the other reference's frame: (s R, t) T Rc."""
    out = np.eye(4)
    out[:3, :3] = R @ T[:3, :3] @ Rc
    out[:3, 3] = s * R @ T[:3, 3] + t
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pgt", type=Path, required=True, help="pose file of the second reference")
    ap.add_argument("--sequence", default="seq-01")
    ap.add_argument("--accuracy", type=Path, default=ROOT / "out" / "bench" / "accuracy.json")
    ap.add_argument("--name", default="pgt_agreement")
    args = ap.parse_args()
    data = require_7scenes()
    if not args.pgt.is_file():
        raise SystemExit(f"no pose file at {args.pgt} (see this script's docstring for where to get one)")
    if not args.accuracy.is_file():
        raise SystemExit(f"no {args.accuracy}: run python bench/accuracy.py first")
    cfg = load_config("7scenes")
    src = open_source(data, slice(0, 1000), rgbd_calibration=cfg.rgbd_calibration)
    ours = {rec.index: np.asarray(rec.T_world_camera) for rec in src.records if rec.T_world_camera is not None}
    other = read_pgt(args.pgt, args.sequence)
    fit = [i for i in MAPPING if i in ours and i in other]
    query = [i for i in QUERY if i in ours and i in other]
    s, R, t, Rc = fit_alignment(ours, other, fit)

    def to_other(T: F64) -> F64:
        return apply_alignment(s, R, t, Rc, T)

    def disagreement(frames: list[int]) -> F64:
        return np.array([relative_pose_error(to_other(ours[i]), other[i]) for i in frames])

    d_map, d_query = disagreement(fit), disagreement(query)
    print(f"alignment on the mapping pass ({len(fit)} frames): scale {s:.4f}, camera rotation "
          f"{np.degrees(Rotation.from_matrix(Rc).magnitude()):.2f} deg")
    stretches = []
    for a in range(MAPPING.start, QUERY.stop, 50):
        for name, frames, d in (("mapping", fit, d_map), ("query", query, d_query)):
            m = [k for k, i in enumerate(frames) if a <= i < a + 50]
            if m:
                stretches.append({"pass": name, "frames": f"{a}-{a + 49}", "median_cm": 100 * float(np.median(d[m, 0])),
                                  "median_deg": float(np.median(d[m, 1]))})
    print_table("the two references after the alignment (median per 50 frames)", ["pass", "frames", "cm", "deg"],
                [[r["pass"], r["frames"], round(r["median_cm"], 1), round(r["median_deg"], 2)] for r in stretches])

    acc = json.loads(args.accuracy.read_text())
    rows, per_frame = [], {}
    for res in acc["results"]:
        e_gt, e_other, frames = [], [], []
        for f in res["frames"]:
            i = f["frame"]
            if not f["accepted"] or i not in other:
                continue
            E = np.eye(4)
            E[:3, :3] = Rotation.from_rotvec(f["err_cam_rotvec"]).as_matrix()
            E[:3, 3] = f["err_cam_m"]
            T_est = ours[i] @ np.linalg.inv(E)  # bench/accuracy.py: T_gt = T_est @ E
            e_gt.append(relative_pose_error(T_est, ours[i]))
            e_other.append(relative_pose_error(to_other(T_est), other[i]))
            frames.append(i)
        n = len(res["frames"])
        for ref, e in (("7-Scenes (D-SLAM)", np.array(e_gt)), ("second reference", np.array(e_other))):
            rows.append({"config": res["config"], "reference": ref, "accepted": len(e), "frames": n,
                         "within_2cm_2deg_pct": within(e, n, 0.02, 2), "within_5cm_5deg_pct": within(e, n, 0.05, 5),
                         "within_25cm_5deg_pct": within(e, n, 0.25, 5), "median_cm": 100 * float(np.median(e[:, 0])),
                         "median_deg": float(np.median(e[:, 1]))})
        per_frame[res["config"]] = {"frames": frames, "err_gt": e_gt, "err_other": e_other}
    print_table("our poses against either reference (percentages of ALL query frames)",
                ["config", "reference", "acc", "2cm2d%", "5cm5d%", "25cm5d%", "med cm", "med deg"],
                [[r["config"], r["reference"], r["accepted"], round(r["within_2cm_2deg_pct"], 1),
                  round(r["within_5cm_5deg_pct"], 1), round(r["within_25cm_5deg_pct"], 1), round(r["median_cm"], 2),
                  round(r["median_deg"], 2)] for r in rows])
    png = ROOT / "out" / "bench" / f"{args.name}.png"
    plot(query, d_query, per_frame, png)
    write_json(args.name, {
        "pgt": str(args.pgt), "sequence": args.sequence, "fit_frames": [fit[0], fit[-1]],
        "alignment": {"scale": s, "R": R.tolist(), "t": t.tolist(), "camera_rotation": Rc.tolist()},
        "references_mapping_pass": {"median_cm": 100 * float(np.median(d_map[:, 0])),
                                    "median_deg": float(np.median(d_map[:, 1]))},
        "references_query_pass": {"median_cm": 100 * float(np.median(d_query[:, 0])),
                                  "median_deg": float(np.median(d_query[:, 1])),
                                  "p90_cm": 100 * float(np.percentile(d_query[:, 0], 90))},
        "stretches": stretches, "results": rows, "plot": str(png)})


def plot(query: list[int], d_query: F64, per_frame: dict[str, dict[str, list]], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    for ax, col, unit, scale in ((axes[0], 0, "position error (cm)", 100.0), (axes[1], 1, "rotation error (deg)", 1.0)):
        ax.plot(query, d_query[:, col] * scale, "k-", lw=1.5, label="the two references (D-SLAM vs SfM)")
        for cfg, style in (("joint", "."),):
            if cfg in per_frame and per_frame[cfg]["frames"]:
                f = per_frame[cfg]
                ax.plot(f["frames"], np.array(f["err_gt"])[:, col] * scale, style, ms=3,
                        label=f"{cfg} vs 7-Scenes (D-SLAM)")
                ax.plot(f["frames"], np.array(f["err_other"])[:, col] * scale, style, ms=3, alpha=0.5,
                        label=f"{cfg} vs SfM pseudo ground truth")
        ax.axhline(5.0, color="grey", ls=":", lw=1)
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(0, 25)
    axes[1].set_ylim(0, 8)
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].set_xlabel("query frame (aligned on frames 0-499 only)")
    fig.suptitle("7-Scenes redkitchen query pass: our error against two pseudo ground truths")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    main()
