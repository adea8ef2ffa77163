"""Fault injection for the onboard service: the same faults in tests, `litevloc replay/run
--fault ...` and `bench/faults.py`.

A fault is `KIND@START:DURATION[,key=value...]`, times in seconds of sensor time from the
first message of the source, e.g. `camera_dropout@10:5`, `vloc_outliers@0:60,fraction=0.1`.

Kinds (what is changed, where):

* `camera_dropout`: RGB-D frames in the window are dropped (source).
* `depth_invalid`: frames in the window keep their colour but every depth pixel is NaN (source).
* `odometry_gap`: odometry messages in the window are dropped (source).
* `odometry_backwards`: odometry stamps in the window are moved back by `jump_s` (default:
  the window's duration): the odometry clock jumps back at the start and forward at the end.
* `vloc_outliers`: a `fraction` (0.1) of accepted VLoc results in the window get their
  position moved `offset_m` (2 m) in a random horizontal direction (seeded: `seed`).
* `slow_consumer`: publishing a fused pose takes `delay_ms` (20 ms) longer in the window,
  as with a blocking transport to a slow subscriber (publisher).
* `slow_vloc`: localizing a frame of the window takes `delay_ms` longer, as on an onboard
  computer loaded by other work (VLoc); in real time the frames meanwhile are dropped.

`FaultInjector(specs).apply(service)` wraps a `runtime.service.shell.Service`'s source, VLoc
callable and publisher before `run()`; `counts` says how many messages each fault changed.
A Zenoh peer that disappears and comes back is a test/bench scenario of its own (the peer
is another process), see tests/runtime/test_faults.py.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from litevloc.base.errors import LiteVLocError
from litevloc.hw.messages import EncodedRgbdFrame, Odometry, RgbdFrame, SourceMessage

FaultKind = Literal["camera_dropout", "depth_invalid", "odometry_gap", "odometry_backwards", "vloc_outliers",
                    "slow_consumer", "slow_vloc"]
FAULT_KINDS: tuple[str, ...] = ("camera_dropout", "depth_invalid", "odometry_gap", "odometry_backwards",
                                "vloc_outliers", "slow_consumer", "slow_vloc")


class FaultSpecError(LiteVLocError, ValueError):
    """A fault specification that cannot be parsed; the message names it."""


@dataclass(frozen=True)
class FaultSpec:
    """One fault in a window of sensor time [start_s, start_s + duration_s) (see module docstring)."""

    kind: FaultKind
    start_s: float
    duration_s: float
    fraction: float = 0.1  # vloc_outliers
    offset_m: float = 2.0  # vloc_outliers
    jump_s: float = 0.0  # odometry_backwards; 0 = duration_s
    delay_ms: float = 20.0  # slow_consumer, slow_vloc
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise FaultSpecError(f"unknown fault kind {self.kind!r}; known: {', '.join(FAULT_KINDS)}")
        if not (self.start_s >= 0 and self.duration_s > 0 and np.isfinite(self.start_s + self.duration_s)):
            raise FaultSpecError(f"fault {self.kind}: start must be >= 0 and duration > 0 s, got "
                                 f"{self.start_s}:{self.duration_s}")
        if not 0.0 <= self.fraction <= 1.0:
            raise FaultSpecError(f"fault {self.kind}: fraction must be in [0, 1], got {self.fraction}")
        if not (self.offset_m >= 0 and self.jump_s >= 0 and self.delay_ms >= 0):
            raise FaultSpecError(f"fault {self.kind}: offset_m, jump_s and delay_ms must be >= 0")

    def active(self, rel_s: float) -> bool:
        return self.start_s <= rel_s < self.start_s + self.duration_s

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """`KIND@START:DURATION[,key=value...]` -> FaultSpec (FaultSpecError naming the problem)."""
        head, *opts = text.strip().split(",")
        kind, at, window = head.partition("@")
        start, colon, dur = window.partition(":")
        if not at or not colon:
            raise FaultSpecError(f"fault {text!r} must look like KIND@START:DURATION, e.g. camera_dropout@10:5")
        kw: dict[str, Any] = {}
        fields = {f.name: f.type for f in dataclasses.fields(cls)}
        try:
            for o in opts:
                k, eq, v = o.partition("=")
                k = k.strip()
                if not eq or k not in fields or k in ("kind", "start_s", "duration_s"):
                    raise FaultSpecError(f"fault {text!r}: bad option {o!r}; options: fraction, offset_m, jump_s, "
                                         "delay_ms, seed")
                kw[k] = int(v) if k == "seed" else float(v)
            return cls(kind.strip(), float(start), float(dur), **kw)  # type: ignore[arg-type]
        except ValueError as exc:
            if isinstance(exc, FaultSpecError):
                raise
            raise FaultSpecError(f"fault {text!r}: {exc}") from exc


class FaultInjector:
    """Applies `specs` to a service's inputs and outputs; thread-safe counters in `counts`."""

    def __init__(self, specs: Iterable[FaultSpec | str]) -> None:
        self.specs = [s if isinstance(s, FaultSpec) else FaultSpec.parse(s) for s in specs]
        self.t0_ns: int | None = None
        self.counts: dict[str, int] = {s.kind: 0 for s in self.specs}
        self._lock = threading.Lock()
        self._rngs = {id(s): np.random.default_rng([s.seed, FAULT_KINDS.index(s.kind)]) for s in self.specs}

    def rel_s(self, t_ns: int) -> float:
        return float("nan") if self.t0_ns is None else (t_ns - self.t0_ns) * 1e-9

    def _active(self, kind: str, t_ns: int) -> list[FaultSpec]:
        r = self.rel_s(t_ns)
        return [s for s in self.specs if s.kind == kind and s.active(r)]

    def _count(self, kind: str) -> None:
        with self._lock:
            self.counts[kind] += 1

    # ------------------------------------------------------------------ source
    def source(self, messages: Iterable[SourceMessage]) -> Iterator[SourceMessage]:
        """The source with camera/depth/odometry faults applied (sets the sensor time origin).
        Frames may be decoded (`RgbdFrame`) or not (`EncodedRgbdFrame`: invalid depth takes the
        size of its depth, which the decoder checks against the colour's)."""
        for m in messages:
            if self.t0_ns is None:
                self.t0_ns = m.t_ns
            if isinstance(m, RgbdFrame | EncodedRgbdFrame):
                if self._active("camera_dropout", m.t_ns):
                    self._count("camera_dropout")
                    continue
                if self._active("depth_invalid", m.t_ns):
                    self._count("depth_invalid")
                    hw = m.color.shape[:2] if isinstance(m, RgbdFrame) else None if m.depth is None else m.depth.shape
                    if hw is not None:
                        m = dataclasses.replace(m, depth=np.full(hw, np.nan, dtype=np.float32))
            elif isinstance(m, Odometry):
                if self._active("odometry_gap", m.t_ns):
                    self._count("odometry_gap")
                    continue
                back = self._active("odometry_backwards", m.t_ns)
                if back:
                    self._count("odometry_backwards")
                    s = back[0]
                    m = dataclasses.replace(m, t_ns=m.t_ns - int((s.jump_s or s.duration_s) * 1e9))
            yield m

    # ------------------------------------------------------------------ VLoc
    def vloc(self, fn: Any) -> Any:
        """Wrap `vloc(frame, prior) -> result`: slow calls take longer; outliers replace some
        accepted results."""

        def faulty(frame: RgbdFrame, prior: Any) -> Any:
            res = fn(frame, prior)
            for s in self._active("slow_vloc", frame.t_ns):
                self._count("slow_vloc")
                time.sleep(s.delay_ms * 1e-3)
            for s in self._active("vloc_outliers", frame.t_ns):
                rng = self._rngs[id(s)]
                hit = rng.random() < s.fraction
                ang = rng.uniform(0, 2 * np.pi)
                if hit and getattr(res, "accepted", False) and getattr(res, "T_map_camera", None) is not None:
                    T = np.array(res.T_map_camera, dtype=np.float64)
                    T[:3, 3] += s.offset_m * np.array([np.cos(ang), np.sin(ang), 0.0])
                    res = dataclasses.replace(res, T_map_camera=T)
                    self._count("vloc_outliers")
            return res

        return faulty

    # ------------------------------------------------------------------ publisher
    def publisher(self, pub: Any) -> Any:
        return _SlowPublisher(pub, self) if any(s.kind == "slow_consumer" for s in self.specs) else pub

    def apply(self, service: Any) -> FaultInjector:
        """Wrap a not yet running `Service`'s source, VLoc callable and publisher."""
        service.source = self.source(service.source)
        service.vloc_fn = self.vloc(service.vloc_fn)
        if service.publisher is not None:
            service.publisher = self.publisher(service.publisher)
        return self

    def report(self) -> dict[str, Any]:
        return {"faults": [dataclasses.asdict(s) for s in self.specs], "changed": dict(self.counts)}


class _SlowPublisher:
    """A publisher whose pose puts take `delay_ms` longer inside slow_consumer windows."""

    def __init__(self, inner: Any, inj: FaultInjector) -> None:
        self._inner, self._inj = inner, inj

    def publish_pose(self, t_ns: int, T: Any, cov: Any) -> None:
        for s in self._inj._active("slow_consumer", t_ns):
            self._inj._count("slow_consumer")
            time.sleep(s.delay_ms * 1e-3)
        self._inner.publish_pose(t_ns, T, cov)

    def __getattr__(self, name: str) -> Any:  # publish_map_to_odom, publish_vloc, publish_status, status, close
        return getattr(self._inner, name)
