"""LightGlue (for ALIKED) on onnxruntime (export: `litevloc.models.export.lightglue`)."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.models.ort import ProviderSetup, make_session
from litevloc.models.types import Features, Matches


def normalize_keypoints(
    kpts: NDArray[np.float32], image_size: tuple[int, int]
) -> NDArray[np.float32]:
    """(N, 2) pixels of an image of (width, height) -> LightGlue's frame: centred, / max side/2."""
    w, h = image_size
    shift = np.array([w / 2.0, h / 2.0], np.float32)
    return ((kpts - shift) / np.float32(max(w, h) / 2.0)).astype(np.float32)


def confidence_threshold(layer: int, n_layers: int = 9) -> float:
    """Token-confidence threshold after `layer` (the reference's 0.8 + 0.1 exp(-4 i / L))."""
    return min(max(0.8 + 0.1 * math.exp(-4.0 * layer / n_layers), 0.0), 1.0)


def _check_descriptors(f0: Features, f1: Features, input_dim: int) -> None:
    for f in (f0, f1):
        if f.descriptors.dtype != np.float32 or f.descriptors.shape[1] != input_dim:
            raise ValueError(
                f"LightGlue needs float32 {input_dim}-D descriptors (ALIKED), "
                f"got {f.descriptors.dtype} {f.descriptors.shape[1]}-D"
            )


def _feeds(f0: Features, f1: Features) -> dict[str, NDArray[np.float32]]:
    return {
        "kpts0": normalize_keypoints(f0.keypoints, f0.image_size)[None],
        "kpts1": normalize_keypoints(f1.keypoints, f1.image_size)[None],
        "desc0": np.ascontiguousarray(f0.descriptors[None]),
        "desc1": np.ascontiguousarray(f1.descriptors[None]),
    }


class LightGlueOnnx:
    """Full-depth LightGlue (9 layers, no early stopping / pruning) with dynamic keypoint counts.

    Matches are the mutual best entries of the assignment with score > `threshold` (the
    reference default 0.1). Works on ALIKED features (128-D descriptors: n16; t16's 64-D
    descriptors are rejected with a clear error since LightGlue was trained on n16).
    """

    def __init__(
        self,
        path: Path,
        threshold: float = 0.1,
        providers: Sequence[str] | ProviderSetup = ("cpu",),
        intra_op_threads: int = 2,
    ) -> None:
        self.name = "lightglue"
        self.threshold = float(threshold)
        self.session = make_session(path, providers, intra_op_threads, dynamic_keypoints=True)
        self.input_dim = int(self.session.get_inputs()[2].shape[-1])

    def match(self, f0: Features, f1: Features) -> Matches:
        _check_descriptors(f0, f1, self.input_dim)
        if len(f0) == 0 or len(f1) == 0:
            return Matches.empty()
        m0, s0 = self.session.run(None, _feeds(f0, f1))
        m0, s0 = m0[0], s0[0]
        valid = (m0 >= 0) & (s0 > self.threshold)
        idx0 = np.nonzero(valid)[0].astype(np.int64)
        return Matches(idx0, m0[valid].astype(np.int64), s0[valid].astype(np.float32))


@dataclass
class AdaptiveStats:
    """What the adaptive matcher did on its last calls (bounded: for benchmarks and diagnostics)."""

    calls: int = 0
    layers_run: deque[int] = field(default_factory=lambda: deque(maxlen=1000))  # per call, 1..n_layers
    points_kept: deque[float] = field(default_factory=lambda: deque(maxlen=1000))  # of M + N, at the end


class AdaptiveLightGlueOnnx:
    """LightGlue with the reference's adaptive depth (early stopping) and width (point pruning).

    The exported parts (`encoder`, `layer{i}`, `head{i}`; see
    `litevloc.models.export.lightglue`) are chained here; after layer i (< n_layers - 1):
    - stop when more than `depth_confidence` of the original M + N points have a token
      confidence >= `confidence_threshold(i)` (pruned points count as confident), and match
      with layer i's assignment head;
    - otherwise drop the points that are confident and unmatchable (matchability <=
      1 - `width_confidence`): later layers attend over fewer points.
    Defaults are the reference's (0.95, 0.99). Easy pairs (tracking a nearby keyframe) stop
    after 3-5 of 9 layers; hard pairs run all 9 and give the full-depth result.
    Matches: mutual best entries with score > `threshold`, indices into the full sets.
    """

    def __init__(
        self,
        parts: dict[str, Path],
        threshold: float = 0.1,
        depth_confidence: float = 0.95,
        width_confidence: float = 0.99,
        providers: Sequence[str] | ProviderSetup = ("cpu",),
        intra_op_threads: int = 2,
    ) -> None:
        self.name = "lightglue-adaptive"
        self.threshold = float(threshold)
        if not (depth_confidence <= 0 or 0 < depth_confidence < 1):
            raise ValueError(f"depth_confidence must be in (0, 1) or <= 0 (off), got {depth_confidence}")
        if not (width_confidence <= 0 or 0 < width_confidence < 1):
            raise ValueError(f"width_confidence must be in (0, 1) or <= 0 (off), got {width_confidence}")
        self.depth_confidence = float(depth_confidence)
        self.width_confidence = float(width_confidence)
        layers = sorted((k for k in parts if k.startswith("layer")), key=lambda k: int(k[5:]))
        self.n_layers = len(layers)
        if self.n_layers < 1 or "encoder" not in parts:
            raise ValueError(f"adaptive LightGlue needs encoder, layer0.. and head0.. parts, got {sorted(parts)}")

        def session(name: str) -> object:
            return make_session(parts[name], providers, intra_op_threads, dynamic_keypoints=True)

        self.encoder = session("encoder")
        self.layers = [session(f"layer{i}") for i in range(self.n_layers)]
        self.heads = [session(f"head{i}") for i in range(self.n_layers)]
        self.input_dim = int(self.encoder.get_inputs()[2].shape[-1])  # type: ignore[attr-defined]
        self.stats = AdaptiveStats()

    def match(self, f0: Features, f1: Features) -> Matches:
        _check_descriptors(f0, f1, self.input_dim)
        m, n = len(f0), len(f1)
        if m == 0 or n == 0:
            return Matches.empty()
        d0, d1, e0, e1 = self.encoder.run(None, _feeds(f0, f1))  # type: ignore[attr-defined]
        ind0, ind1 = np.arange(m), np.arange(n)
        i = 0
        for i in range(self.n_layers):
            if d0.shape[1] == 0 or d1.shape[1] == 0:
                break
            out = self.layers[i].run(None, {"d0": d0, "d1": d1, "e0": e0, "e1": e1})  # type: ignore[attr-defined]
            d0, d1 = out[0], out[1]
            if i == self.n_layers - 1:
                break
            c0, c1, z0, z1 = out[2][0], out[3][0], out[4][0], out[5][0]
            th = confidence_threshold(i, self.n_layers)
            if self.depth_confidence > 0:
                unsure = int((c0 < th).sum() + (c1 < th).sum())
                if 1.0 - unsure / (m + n) > self.depth_confidence:
                    break
            if self.width_confidence > 0:
                keep0 = (z0 > 1 - self.width_confidence) | (c0 <= th)
                keep1 = (z1 > 1 - self.width_confidence) | (c1 <= th)
                if not keep0.all():
                    ind0, d0, e0 = ind0[keep0], d0[:, keep0], np.ascontiguousarray(e0[:, :, :, keep0])
                if not keep1.all():
                    ind1, d1, e1 = ind1[keep1], d1[:, keep1], np.ascontiguousarray(e1[:, :, :, keep1])
        self.stats.calls += 1
        self.stats.layers_run.append(i + 1)
        self.stats.points_kept.append((len(ind0) + len(ind1)) / (m + n))
        if d0.shape[1] == 0 or d1.shape[1] == 0:
            return Matches.empty()
        mm, ss = self.heads[i].run(None, {"d0": d0, "d1": d1})  # type: ignore[attr-defined]
        mm, ss = mm[0], ss[0]
        valid = (mm >= 0) & (ss > self.threshold)
        return Matches(
            ind0[valid].astype(np.int64), ind1[mm[valid]].astype(np.int64), ss[valid].astype(np.float32)
        )
