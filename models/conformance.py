"""Every exported model's outputs on fixed images, to compare onnxruntime builds and machines.

The same ONNX files must give the same answers on every runtime LiteVLoc supports (onnxruntime
1.20 to the newest, x86_64 and aarch64). `model_outputs` runs each model of a model cache through
the runtime's own wrappers (preprocessing included) on the given images; `compare_outputs`
checks two such runs against the tolerances below; `python -m litevloc.models.conformance`
writes a run to an `.npz` file (plain arrays, read with `allow_pickle=False`) and, with
`--against`, compares it with another and exits 1 on a difference.

What is compared, and within what (fp32 throughout):
- extractors: the keypoint sets (each keypoint of one run within `keypoint_px` of one of the
  other's, for at least `min_agreeing` of them: a near-tie in top-k may reorder or swap one),
  and at the agreeing keypoints the descriptors (`descriptor_abs` per component) and scores;
- matchers (LightGlue whole and adaptive, on the default extractor's features of an image
  pair): the matched keypoint pairs (`min_agreeing` of the union in both), their scores;
- place recognition: the global descriptor (`descriptor_abs` per component).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.models import ModelsConfig
from litevloc.models.catalog import spec_for
from litevloc.models.registry import load_extractor, load_matcher, load_place_recognizer, read_manifest

F32 = NDArray[np.float32]
# the extractor whose features feed the matchers: the embedded default's
MATCHER_FEATURES = ("aliked-n16", (240, 320), 512)
MATCHERS = {"lightglue-aliked": "lightglue", "lightglue-aliked-adaptive": "lightglue-adaptive",
            "lightglue-aliked-int8": "lightglue-int8"}


@dataclass(frozen=True)
class Tolerance:
    """How far two runs of one model may differ and still agree."""

    keypoint_px: float = 1e-3  # pixels of the original image
    descriptor_abs: float = 1e-4  # per component of an L2-normalised descriptor
    score_abs: float = 1e-3  # detection and match scores
    min_agreeing: float = 0.99  # fraction of keypoints / matches that must agree


@dataclass(frozen=True)
class OutputDifference:
    """One output of one model that two runs disagree on, in words and the measured figure."""

    key: str
    what: str

    def __str__(self) -> str:
        return f"{self.key}: {self.what}"


def _config(cache: Path, arch: Any, size_hw: tuple[int, int], top_k: int) -> ModelsConfig:
    return ModelsConfig(cache_dir=str(cache), extractor=arch, extractor_size=size_hw,
                        max_keypoints=top_k, vpr_size=size_hw, intra_op_threads=1)


def model_outputs(cache: Path, images: Sequence[NDArray[np.uint8]]) -> dict[str, NDArray[np.generic]]:
    """Outputs of every model in the model cache `cache` on `images` (HxWx3 uint8 RGB, >= 2).

    Keys are `<model id>/<image index>/<output>`; matchers match image 0 with image 1 and
    give `<id>/pairs` (M, 4) float32 keypoint pairs (x0, y0, x1, y1, original pixels) and
    `<id>/scores` (M,).
    """
    if len(images) < 2:
        raise ValueError("model_outputs needs at least two images (the matchers match a pair)")
    out: dict[str, NDArray[np.generic]] = {}
    entries = read_manifest(cache)["models"]
    for model_id in sorted(entries):
        spec = spec_for(model_id)
        if spec.kind == "extractor":
            assert spec.input_hw is not None and spec.top_k is not None
            ex = load_extractor(spec.arch, _config(cache, spec.arch, spec.input_hw, spec.top_k))
            for i, img in enumerate(images):
                f = ex.extract(img)
                out[f"{model_id}/{i}/keypoints"] = f.keypoints
                out[f"{model_id}/{i}/descriptors"] = f.descriptors
                out[f"{model_id}/{i}/scores"] = f.scores
        elif spec.kind == "vpr":
            assert spec.input_hw is not None
            name = "effnet-gem" if spec.arch == "effnet-gem" else "cosplace"
            vpr = load_place_recognizer(name, _config(cache, "aliked-n16", spec.input_hw, 512))
            for i, img in enumerate(images):
                out[f"{model_id}/{i}/descriptor"] = np.asarray(vpr.describe(img), np.float32)
    arch, size_hw, top_k = MATCHER_FEATURES
    cfg = _config(cache, arch, size_hw, top_k)
    feats = None
    for model_id, name in MATCHERS.items():
        if model_id not in entries:
            continue
        if feats is None:
            ex = load_extractor(arch, cfg)
            feats = (ex.extract(images[0]), ex.extract(images[1]))
        m = load_matcher(name, cfg).match(*feats)
        out[f"{model_id}/pairs"] = np.hstack((feats[0].keypoints[m.idx0], feats[1].keypoints[m.idx1]))
        out[f"{model_id}/scores"] = m.scores
    return out


def _agreeing(a: F32, b: F32, tol_px: float) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
    """For each row of a: whether b has a row within tol_px (max-norm), and the nearest such row."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros(len(a), bool), np.zeros(len(a), np.int64)
    d = np.abs(a[:, None, :] - b[None, :, :]).max(axis=2)  # (Na, Nb), at most a few MB
    nearest = d.argmin(axis=1)
    return d[np.arange(len(a)), nearest] <= tol_px, nearest


def compare_outputs(a: dict[str, NDArray[np.generic]], b: dict[str, NDArray[np.generic]],
                    tol: Tolerance = Tolerance()) -> list[OutputDifference]:
    """The outputs on which runs `a` and `b` of `model_outputs` disagree (empty: they agree)."""
    diffs: list[OutputDifference] = []
    for key in sorted(set(a) ^ set(b)):
        diffs.append(OutputDifference(key, "present in only one run"))
    for key in sorted(set(a) & set(b)):
        va, vb = np.asarray(a[key], np.float32), np.asarray(b[key], np.float32)
        model_id, *_, output = key.split("/")
        if output == "keypoints":
            ok, near = _agreeing(va, vb, tol.keypoint_px)
            if ok.mean() < tol.min_agreeing:
                diffs.append(OutputDifference(key, f"only {ok.mean():.3f} of keypoints within {tol.keypoint_px} px"))
                continue
            prefix = key[: -len("keypoints")]
            for sub, lim in (("descriptors", tol.descriptor_abs), ("scores", tol.score_abs)):
                da = np.asarray(a[prefix + sub], np.float32)[ok]
                db = np.asarray(b[prefix + sub], np.float32)[near[ok]]
                err = float(np.abs(da - db).max()) if len(da) else 0.0
                if err > lim:
                    diffs.append(OutputDifference(prefix + sub, f"max |diff| {err:.2e} > {lim:g}"))
        elif output == "pairs":
            ok_ab, near = _agreeing(va, vb, tol.keypoint_px)
            ok_ba, _ = _agreeing(vb, va, tol.keypoint_px)
            union = len(va) + len(vb) - int(ok_ab.sum())
            share = float(ok_ab.sum()) / union if union else 1.0
            if min(share, float(ok_ba.mean()) if len(vb) else 1.0) < tol.min_agreeing:
                diffs.append(OutputDifference(key, f"only {share:.3f} of matches in both ({len(va)} vs {len(vb)})"))
                continue
            sa = np.asarray(a[f"{model_id}/scores"], np.float32)[ok_ab]
            sb = np.asarray(b[f"{model_id}/scores"], np.float32)[near[ok_ab]]
            err = float(np.abs(sa - sb).max()) if len(sa) else 0.0
            if err > tol.score_abs:
                diffs.append(OutputDifference(f"{model_id}/scores", f"max |diff| {err:.2e} > {tol.score_abs:g}"))
        elif output == "descriptor":
            err = float(np.abs(va - vb).max()) if va.shape == vb.shape else float("inf")
            if err > tol.descriptor_abs:
                diffs.append(OutputDifference(key, f"max |diff| {err:.2e} > {tol.descriptor_abs:g}"))
    return diffs


def _read_images(paths: Sequence[Path]) -> list[NDArray[np.uint8]]:
    import cv2

    images: list[NDArray[np.uint8]] = []
    for p in paths:
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            raise SystemExit(f"conformance: cannot read image {p}")
        images.append(np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), np.uint8))
    return images


def main(argv: Sequence[str] | None = None) -> int:
    """Write this runtime's outputs (`-o`), compare them with another run (`--against`), or both."""
    import onnxruntime

    ap = argparse.ArgumentParser(prog="python -m litevloc.models.conformance", description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True, help="model cache folder (manifest.json + ONNX files)")
    ap.add_argument("--images", type=Path, nargs="+", required=True, help="two or more RGB images")
    ap.add_argument("-o", "--out", type=Path, help="write the outputs here (.npz)")
    ap.add_argument("--against", type=Path, help="compare with the outputs in this .npz")
    args = ap.parse_args(argv)
    outputs = model_outputs(args.cache, _read_images(args.images))
    print(f"onnxruntime {onnxruntime.__version__}: {len(outputs)} outputs of "
          f"{len({k.split('/')[0] for k in outputs})} models", file=sys.stderr)
    if args.out:
        np.savez(args.out, **outputs)  # type: ignore[arg-type]
    if args.against:
        with np.load(args.against, allow_pickle=False) as ref:
            diffs = compare_outputs(outputs, {k: ref[k] for k in ref.files})
        for d in diffs:
            print(f"differs: {d}")
        return 1 if diffs else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
