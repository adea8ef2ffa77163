"""Model calls recorded once and replayed, with a clock that still counts their time.

A benchmark that localizes the same query frames against the same map under several
configurations runs each model (feature extraction, place recognition, matching with one map
keyframe) once per frame and pair: results are stored as npz (no pickle) with the wall time the
call took, and a replayed call advances `clock` by that recorded time. A localizer built with
`clock=ReplayedModels.clock` (see `VisualLocalizer`) therefore measures stage times, latency and
time budgets as a run that called the models would, on the machine and load of the first run.
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.models.types import Features
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap
from litevloc.runtime.vloc_models import ModelBundle


def map_key(map_dir: Path) -> str:
    """A short name for a map's content (its folder name + a hash of its manifest): cached
    matches are valid only for the map whose keyframes they index."""
    digest = hashlib.sha1((map_dir / "manifest.json").read_bytes()).hexdigest()[:10]
    return f"{map_dir.name}-{digest}"


def _fingerprint(features: FeatureSet) -> bytes:
    return hashlib.sha1(np.ascontiguousarray(features.keypoints).tobytes()).digest()


class ReplayedModels:
    """`extract` / `describe` / `match` of `bundle`, recorded per query frame under `root`.

    Features and place descriptors of a frame do not depend on the map: they are kept in
    `root/frames/`; matches with map node i in `root/<map key>/`. Call `start(frame)` before
    each query frame and `flush()` at the end.
    """

    def __init__(self, root: Path, bundle: ModelBundle, topomap: TopoMap, map_dir: Path) -> None:
        models = f"{bundle.extractor.name}+{bundle.vpr.name}+{bundle.matcher.name}+k{bundle.max_keypoints}"
        self.frames_dir = root / models / "frames"
        self.matches_dir = root / models / map_key(map_dir)
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        self.matches_dir.mkdir(parents=True, exist_ok=True)
        self.bundle = bundle
        # map keyframes by the content of their keypoints (a loaded map's features are read lazily:
        # each access is a new object)
        self.node_of = {_fingerprint(topomap.features[i]): i for i in range(topomap.n_nodes)}
        self.replayed_s = 0.0  # recorded time of every replayed call so far (the clock's offset)
        self.calls = {"run": 0, "replayed": 0}
        self.frame = -1
        self._frame: dict[str, NDArray] = {}
        self._matches: dict[str, NDArray] = {}
        self._dirty = {"frame": False, "matches": False}

    def clock(self) -> float:
        """Seconds: the wall clock plus the recorded time of the calls replayed so far."""
        return time.perf_counter() + self.replayed_s

    def _file(self, folder: Path) -> Path:
        return folder / f"frame_{self.frame:05d}.npz"

    def start(self, frame: int) -> None:
        self.flush()
        self.frame = frame
        self._frame = self._load(self._file(self.frames_dir))
        self._matches = self._load(self._file(self.matches_dir))

    @staticmethod
    def _load(path: Path) -> dict[str, NDArray]:
        if not path.is_file():
            return {}
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def flush(self) -> None:
        if self.frame < 0:
            return
        if self._dirty["frame"]:
            np.savez(self._file(self.frames_dir), allow_pickle=False, **self._frame)
        if self._dirty["matches"]:
            np.savez(self._file(self.matches_dir), allow_pickle=False, **self._matches)
        self._dirty = {"frame": False, "matches": False}

    def _replay(self, store: dict[str, NDArray], key: str) -> bool:
        """True (and the clock advanced by its recorded time) when `key` is recorded."""
        if f"{key}_ms" not in store:
            self.calls["run"] += 1
            return False
        self.replayed_s += float(store[f"{key}_ms"]) * 1e-3
        self.calls["replayed"] += 1
        return True

    def extract(self, color: NDArray[np.uint8]) -> Features:
        d = self._frame
        if not self._replay(d, "extract"):
            t0 = time.perf_counter()
            f = self.bundle.extract(color)
            d.update(kp=f.keypoints, desc=f.descriptors, score=f.scores, size=np.array(f.image_size),
                     extract_ms=np.array((time.perf_counter() - t0) * 1e3))
            self._dirty["frame"] = True
        return Features(d["kp"], d["desc"], d["score"], (int(d["size"][0]), int(d["size"][1])))

    def describe(self, color: NDArray[np.uint8]) -> NDArray[np.float32]:
        d = self._frame
        if not self._replay(d, "vpr"):
            t0 = time.perf_counter()
            v = np.asarray(self.bundle.describe(color), dtype=np.float32)
            d.update(vpr=v, vpr_ms=np.array((time.perf_counter() - t0) * 1e3))
            self._dirty["frame"] = True
        return np.asarray(d["vpr"], dtype=np.float32)

    def descriptor(self) -> NDArray[np.float32]:
        """The current frame's place descriptor as recorded (no call, no clock advance)."""
        return np.asarray(self._frame["vpr"], dtype=np.float32)

    def match(self, live: FeatureSet, ref: FeatureSet) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        key, d = f"m{self.node_of[_fingerprint(ref)]}", self._matches
        if not self._replay(d, key):
            t0 = time.perf_counter()
            a, b = self.bundle.match(live, ref)
            d.update({f"{key}_live": np.asarray(a, np.int64), f"{key}_ref": np.asarray(b, np.int64),
                      f"{key}_ms": np.array((time.perf_counter() - t0) * 1e3)})
            self._dirty["matches"] = True
        return d[f"{key}_live"], d[f"{key}_ref"]
