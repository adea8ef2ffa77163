"""Every ONNX model the runtime uses, run by two runtimes on the same inputs and compared.

The same ONNX files must compute the same on every runtime LiteVLoc supports: onnxruntime 1.20 to
the newest (`tests/models/test_onnx_portability.py`), and the aarch64 wheels of a Jetson
(`tools/aarch64_check.py`, under qemu). This module is what both run:

* `prepare_model_inputs`: the inputs of every model of the default and config groups (7scenes
  preset) as `.npz` files with an `index.json`: the extractors and the VPR model on a 7-Scenes
  frame (preprocessed as the runtime does), LightGlue on the strongest ALIKED points of a frame
  pair, each part of the adaptive LightGlue on the reference's outputs of the part before;
* `run_models` (`python -m litevloc.experiments.model_conformance run-models INPUTS OUT`): each
  model on its saved inputs through the runtime's session options, outputs to `.npz` (no pickle);
  the same code under each runtime;
* `compare_models` / `compare_outputs`: keypoints paired by position (a different top-k choice
  among equal scores is told apart from a wrong value), floats within `Tolerance`, match indices
  by agreement.

Only numpy is imported at module level: the worker imports onnxruntime when it runs.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError

# LightGlue's inputs: the strongest points of each image (256: minutes less under emulation)
LIGHTGLUE_POINTS = 256


class ModelInputsError(LiteVLocError):
    """The models' inputs cannot be made: a frame or an exported model is missing (the message says which)."""


@dataclass(frozen=True)
class Tolerance:
    """What counts as the same output. Floats: |a - b| <= atol + rtol * max|reference| of that
    output (float32 kernels of another instruction set sum in another order: ~1e-6 relative per
    operation; a wrong kernel is off by O(1)). Integer outputs (match indices): at least
    `min_agree` of the entries equal. Keypoints: paired when within `kpt_px` pixels."""

    rtol: float = 1e-3
    atol: float = 1e-5
    min_agree: float = 0.99
    kpt_px: float = 0.01


@dataclass(frozen=True)
class OutputDiff:
    """One output of one model, the reference run (x86, the newest onnxruntime) against the other."""

    model: str
    output: str
    shape: tuple[int, ...]
    max_abs: float  # floats: largest |a - b| (over the paired keypoints for an extractor)
    scale: float  # max |reference| of the output (the rtol's scale)
    agree: float  # share of entries (int outputs) or keypoints (extractor) that agree, 0..1
    note: str
    passed: bool


def _float_diff(model: str, name: str, a: NDArray[Any], b: NDArray[Any], tol: Tolerance, note: str = "",
                agree: float = 1.0) -> OutputDiff:
    a64, b64 = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a64.shape != b64.shape:
        return OutputDiff(model, name, tuple(a64.shape), float("inf"), 0.0, 0.0,
                          f"shape {a64.shape} vs {b64.shape}", False)
    if a64.size == 0:
        return OutputDiff(model, name, tuple(a64.shape), 0.0, 0.0, agree, note or "empty", agree >= tol.min_agree)
    finite = np.isfinite(a64) == np.isfinite(b64)
    d = np.abs(a64 - b64)
    d[~np.isfinite(a64) & ~np.isfinite(b64) & (a64 == b64)] = 0.0  # the same inf
    max_abs = float(np.max(np.where(finite, np.nan_to_num(d, nan=np.inf), np.inf)))
    scale = float(np.max(np.abs(a64[np.isfinite(a64)]), initial=0.0))
    ok = max_abs <= tol.atol + tol.rtol * scale and agree >= tol.min_agree
    return OutputDiff(model, name, tuple(a64.shape), max_abs, scale, agree, note, ok)


def _int_diff(model: str, name: str, a: NDArray[Any], b: NDArray[Any], tol: Tolerance) -> OutputDiff:
    if a.shape != b.shape:
        return OutputDiff(model, name, tuple(a.shape), float("inf"), 0.0, 0.0, f"shape {a.shape} vs {b.shape}", False)
    agree = float(np.mean(a == b)) if a.size else 1.0
    n_diff = int(np.sum(a != b))
    return OutputDiff(model, name, tuple(a.shape), float(n_diff), 0.0, agree,
                      f"{n_diff} of {a.size} entries differ", agree >= tol.min_agree)


def pair_keypoints(ka: NDArray[Any], kb: NDArray[Any], max_px: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(ia, ib): mutual nearest keypoints of two (N, 2) / (M, 2) sets within `max_px` pixels."""
    a, b = np.asarray(ka, np.float64).reshape(-1, 2), np.asarray(kb, np.float64).reshape(-1, 2)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    nb, na = np.argmin(d, axis=1), np.argmin(d, axis=0)
    ia = np.nonzero((na[nb] == np.arange(len(a))) & (d[np.arange(len(a)), nb] <= max_px))[0]
    return ia.astype(np.int64), nb[ia].astype(np.int64)


def compare_extractor(model: str, ref: Sequence[NDArray[Any]], other: Sequence[NDArray[Any]],
                      tol: Tolerance) -> list[OutputDiff]:
    """ALIKED's (keypoints (K, 2) px, descriptors (K, D), scores (K,)): keypoints paired by position
    (`pair_keypoints`); descriptors and scores compared over the pairs. A keypoint without a
    partner is a top-k tie when its score is within tolerance of the other set's lowest kept
    score (the cut); `agree` is the paired share, and the unpaired ones that are not ties fail."""
    (ka, da, sa), (kb, db, sb) = (tuple(np.asarray(x) for x in ref[:3]), tuple(np.asarray(x) for x in other[:3]))
    ka, kb, sa, sb = ka.reshape(-1, 2), kb.reshape(-1, 2), sa.reshape(-1), sb.reshape(-1)
    da, db = da.reshape(len(ka), -1), db.reshape(len(kb), -1)
    ia, ib = pair_keypoints(ka, kb, tol.kpt_px)
    n = max(len(ka), len(kb), 1)
    agree = len(ia) / n
    s_tol = tol.atol + tol.rtol * float(np.max(np.abs(sa), initial=0.0))
    cut_a, cut_b = float(np.min(sa, initial=np.inf)), float(np.min(sb, initial=np.inf))
    lone_a = np.setdiff1d(np.arange(len(ka)), ia)
    lone_b = np.setdiff1d(np.arange(len(kb)), ib)
    not_ties = int(np.sum(sa[lone_a] > cut_b + s_tol) + np.sum(sb[lone_b] > cut_a + s_tol))
    note = f"{len(ia)}/{len(ka)} keypoints paired within {tol.kpt_px} px"
    if len(lone_a) or len(lone_b):
        note += f"; {len(lone_a)} + {len(lone_b)} unpaired, {not_ties} of them not at the top-k cut"
    # the paired share gates nothing: an unpaired keypoint fails only when it is not a tie
    paired = Tolerance(tol.rtol, tol.atol, 0.0, tol.kpt_px)
    pos = _float_diff(model, "keypoints", ka[ia], kb[ib], Tolerance(0.0, tol.kpt_px, 0.0, tol.kpt_px), note, agree)
    pos = OutputDiff(**{**asdict(pos), "passed": pos.passed and not_ties == 0})
    return [pos, _float_diff(model, "descriptors", da[ia], db[ib], paired, "over the paired keypoints", agree),
            _float_diff(model, "scores", sa[ia], sb[ib], paired, "over the paired keypoints", agree)]


def compare_outputs(model: str, kind: str, names: Sequence[str], ref: Sequence[NDArray[Any]],
                    other: Sequence[NDArray[Any]], tol: Tolerance = Tolerance()) -> list[OutputDiff]:
    """Every output of one model run: `kind` "extractor" pairs keypoints (`compare_extractor`);
    otherwise integer outputs (match indices) by agreement and float ones by max abs difference."""
    if len(ref) != len(other):
        return [OutputDiff(model, "*", (), float("inf"), 0.0, 0.0, f"{len(ref)} vs {len(other)} outputs", False)]
    if kind == "extractor":
        return compare_extractor(model, ref, other, tol)
    out = []
    for name, a, b in zip(names, ref, other, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if np.issubdtype(a.dtype, np.integer) or a.dtype == np.bool_:
            out.append(_int_diff(model, name, a, b, tol))
        else:
            out.append(_float_diff(model, name, a, b, tol))
    return out


# --- the worker: ONNX models on saved inputs ---------------------------------------------------

INDEX = "index.json"  # in the inputs folder: [{"name", "kind", "onnx", "feeds"}] (feeds: an .npz beside it)


def save_npz(path: Path, arrays: Mapping[str, NDArray[Any]]) -> None:
    """Arrays by name into an uncompressed `.npz` (read back with allow_pickle=False)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    named: dict[str, Any] = {k: np.ascontiguousarray(v) for k, v in arrays.items()}
    np.savez(str(path), allow_pickle=False, **named)


def load_npz(path: Path) -> dict[str, NDArray[Any]]:
    with np.load(str(path), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def run_models(inputs_dir: Path, out_dir: Path, threads: int = 2, only: Sequence[str] = ()) -> dict[str, float]:
    """Run every model of `inputs_dir/index.json` on its saved feeds with the runtime's session
    options and write its outputs (by output name, in the model's order) to `out_dir/NAME.npz`;
    `out_dir/timings.json`: {name: seconds of session creation + one run}; `out_dir/runtime.json`:
    the onnxruntime version and machine that computed them. Progress on stderr."""
    import platform

    import onnxruntime

    from litevloc.models.ort import make_session

    index = json.loads((inputs_dir / INDEX).read_text())
    if only:
        index = [e for e in index if e["name"] in only]
    timings: dict[str, float] = {}
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "runtime.json").write_text(json.dumps({"onnxruntime": onnxruntime.__version__,
                                                      "machine": platform.machine()}))
    t_all = time.perf_counter()
    for k, entry in enumerate(index, 1):
        t0 = time.perf_counter()
        sess = make_session(Path(entry["onnx"]), ("cpu",), threads)
        feeds = load_npz(inputs_dir / entry["feeds"])
        outs = sess.run(None, feeds)
        names = [o.name for o in sess.get_outputs()]
        save_npz(out_dir / f"{entry['name']}.npz", dict(zip(names, outs, strict=True)))
        (out_dir / f"{entry['name']}.names.json").write_text(json.dumps(names))
        timings[entry["name"]] = time.perf_counter() - t0
        print(f"[models {k}/{len(index)}] {entry['name']}: {timings[entry['name']]:.1f} s "
              f"({time.perf_counter() - t_all:.0f} s so far)", file=sys.stderr, flush=True)
    (out_dir / "timings.json").write_text(json.dumps(timings, indent=1))
    return timings


def read_outputs(out_dir: Path, name: str) -> tuple[list[str], list[NDArray[Any]]]:
    """(output names, arrays in the model's order) that `run_models` wrote for model `name`."""
    names: list[str] = json.loads((out_dir / f"{name}.names.json").read_text())
    arrays = load_npz(out_dir / f"{name}.npz")
    return names, [arrays[n] for n in names]


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m litevloc.experiments.model_conformance run-models INPUTS OUT [--threads N] [--only NAME...]`
    (what each runtime under comparison runs: another onnxruntime, the emulated aarch64 Python)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m litevloc.experiments.model_conformance")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("run-models", help="run the models of INPUTS/index.json, outputs to OUT")
    p.add_argument("inputs", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--only", nargs="*", default=[])
    args = ap.parse_args(argv)
    run_models(args.inputs, args.out, args.threads, args.only)
    return 0


# --- inputs of every model ----------------------------------------------------------------------


def model_ids() -> list[str]:
    """The models `litevloc models list` puts in the default and config groups (7scenes preset)."""
    from litevloc.config import load_config
    from litevloc.models.catalog import DEFAULT_EXPORTS
    from litevloc.models.registry import configured_ids

    return list(dict.fromkeys([*DEFAULT_EXPORTS, *configured_ids(load_config("7scenes").models)]))


def prepare_model_inputs(data: Path, out: Path, frames: tuple[int, int] = (500, 510),
                         lightglue_points: int = LIGHTGLUE_POINTS) -> list[dict[str, str]]:
    """Inputs of every model (`model_ids`) as `.npz` files and `out/index.json` for `run_models`:
    the extractors and the VPR model on frame frames[0] (each at its own input size, preprocessed
    as the runtime does), LightGlue on the `lightglue_points` strongest configured ALIKED-n16
    features of both frames, each
    adaptive part on the x86 outputs of the part before it (no pruning: every layer's input is the
    whole set)."""
    import cv2

    from litevloc.config import load_config
    from litevloc.models.catalog import VPR_NORMALIZATION, spec_for
    from litevloc.models.lightglue import normalize_keypoints
    from litevloc.models.ort import make_session
    from litevloc.models.preprocess import prepare_image
    from litevloc.models.registry import ModelError, load_extractor, locate, locate_parts

    cfg = load_config("7scenes").models
    rgb: list[NDArray[np.uint8]] = []
    for i in frames:
        img = cv2.imread(str(data / f"frame-{i:06d}.color.jpg"))
        if img is None:
            raise ModelInputsError(f"{data}: frame {i} is missing")
        rgb.append(np.asarray(cv2.cvtColor(img, cv2.COLOR_BGR2RGB), np.uint8))
    ext = load_extractor("aliked-n16", cfg)
    feats = []
    for f in (ext.extract(rgb[0]), ext.extract(rgb[1])):
        keep = np.sort(np.argsort(-f.scores, kind="stable")[:lightglue_points])
        feats.append((normalize_keypoints(f.keypoints[keep], f.image_size)[None],
                      np.ascontiguousarray(f.descriptors[keep][None])))
    pair = {"kpts0": feats[0][0], "kpts1": feats[1][0], "desc0": feats[0][1], "desc1": feats[1][1]}
    shutil.rmtree(out, ignore_errors=True)
    index: list[dict[str, str]] = []

    def add(name: str, kind: str, onnx: Path, feeds: dict[str, Any]) -> None:
        save_npz(out / f"{name}.npz", feeds)
        index.append({"name": name, "kind": kind, "onnx": str(onnx), "feeds": f"{name}.npz"})

    for mid in model_ids():
        spec = spec_for(mid)
        try:
            path, _ = locate(mid, cfg)
        except ModelError as exc:
            raise ModelInputsError(str(exc)) from exc
        if spec.kind == "extractor":
            assert spec.input_hw is not None
            add(mid, "extractor", path, {"image": prepare_image(rgb[0], spec.input_hw)})
        elif spec.kind == "vpr":
            assert spec.input_hw is not None
            mean, std = VPR_NORMALIZATION[spec.arch]
            add(mid, "vpr", path, {"image": prepare_image(rgb[0], spec.input_hw, mean, std)})
        elif not spec.adaptive:
            add(mid, "matcher", path, pair)
        else:
            parts = locate_parts(mid, cfg)
            enc = make_session(parts["encoder"], ("cpu",), cfg.intra_op_threads)
            add(f"{mid}.encoder", "matcher-part", parts["encoder"], pair)
            d0, d1, e0, e1 = enc.run(None, pair)
            n_layers = sum(1 for k in parts if k.startswith("layer"))
            for i in range(n_layers):
                layer = make_session(parts[f"layer{i}"], ("cpu",), cfg.intra_op_threads)
                names = [x.name for x in layer.get_inputs()]
                feeds = dict(zip(names, (d0, d1, e0, e1), strict=True))
                add(f"{mid}.layer{i}", "matcher-part", parts[f"layer{i}"], feeds)
                res = layer.run(None, feeds)
                head = make_session(parts[f"head{i}"], ("cpu",), cfg.intra_op_threads)
                hnames = [x.name for x in head.get_inputs()]
                add(f"{mid}.head{i}", "matcher-part", parts[f"head{i}"], dict(zip(hnames, res[:2], strict=True)))
                d0, d1 = res[0], res[1]
    (out / INDEX).write_text(json.dumps(index, indent=1))
    return index


def compare_models(index: list[dict[str, str]], ref_dir: Path, other_dir: Path) -> list[OutputDiff]:
    """Every output of every model of `index` (`prepare_model_inputs`), `run_models`' outputs in
    `ref_dir` (the reference) against those in `other_dir`."""
    diffs: list[OutputDiff] = []
    for e in index:
        names, ref = read_outputs(ref_dir, e["name"])
        _, other = read_outputs(other_dir, e["name"])
        diffs += compare_outputs(e["name"], e["kind"], names, ref, other)
    return diffs


if __name__ == "__main__":
    raise SystemExit(main())
