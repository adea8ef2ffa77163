"""`litevloc/diagnostics`: the service's health as ROS 2 `diagnostic_msgs/DiagnosticArray`.

The array is built by a pure function (`diagnostic_statuses`) from the service's status
snapshot (`Service.status()`, the same dict published as JSON on `litevloc/status`) and
the previous snapshot (for rates over the last period), with levels from
`config.schema.DiagnosticsConfig`. One `DiagnosticStatus` per:

* stage `litevloc/stage/{extract,vpr,match,pnp,fusion,publish}`: last / median / p99
  execution time in ms and the sample count; level from the p99 vs the stage's thresholds.
  extract / vpr / match / pnp come from each VLoc result's `timings_ms` (per query; match and
  pnp summed over the candidates tried), collected by `VlocStageTimes` in the fusion thread;
  fusion is the fusion thread's handling of one odometry message (fusion update + emit);
  publish is the publisher thread's handling of one outbox item (serialisation + Zenoh put),
  or the Zenoh put of `litevloc/pose` when `runtime.publish_inline` is on.
* queue `litevloc/queue/<name>`: depth, capacity, high water, drops, overflows; FIFOs get
  a level from depth / capacity and ERROR on any overflow; the latest-frame mailbox drops
  stale frames by design (counted, always OK).
* `litevloc/vloc`: VLoc rate (Hz) and acceptance (accepted / calls) over the last period
  plus totals; "lower is worse" thresholds, judged once `min_vloc_calls` calls were made.
* `litevloc/tracking`: INIT (WARN), TRACKING (OK), LOST or FAILED (ERROR), with the reasons.
* `litevloc/map`: the map in use (id: folder name and manifest hash; name and version as the map
  service names them), its node count and its switches (`runtime.service.map_switch`): requests,
  switches, refusals, the last switch's time and the last refusal's kind; WARN while the last
  version offered was refused (the service keeps the map it has).
* `litevloc/models` (when the status has a `models` entry, `models.ort.ProviderReport.as_dict`): the
  onnxruntime build and the provider each model runs on; WARN when a provider asked for is not in
  use (`ProviderState.FALLBACK`: "models: tensorrt asked for, running on CPUExecutionProvider ...").

`DiagnosticsPublisher` (used by `runtime.transport.bus.LiteVLocPublisher.publish_status`) keeps the
previous snapshot and rate-limits to `period_s`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from litevloc.config.schema import DiagnosticsConfig, LevelThresholds
from litevloc.hw import ros_msgs
from litevloc.models.types import ProviderState
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.runtime.metrics import LatencyWindow

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
VLOC_STAGES = ("extract", "vpr", "match", "pnp")
STAGES = (*VLOC_STAGES, "fusion", "publish")

Status = tuple[int, str, str, str, list[tuple[str, str]]]  # level, name, message, hardware_id, values
#: level of `litevloc/models` per provider state (an unknown state: WARN)
PROVIDER_LEVELS = {ProviderState.NO_SESSIONS: OK, ProviderState.AS_ASKED: OK, ProviderState.FALLBACK: WARN,
                   ProviderState.DISTRIBUTION_CLASH: WARN}


class VlocStageTimes:
    """Sliding windows of the per-query VLoc stage times (ms) from `LocalizationResult.timings_ms`.

    Written by one thread (the service's fusion thread, per result), read by the status tick."""

    def __init__(self, window: int = 1024) -> None:
        self.windows = {k: LatencyWindow(window) for k in VLOC_STAGES}
        self.last: dict[str, float] = {}

    def add(self, timings_ms: Mapping[str, float] | None) -> None:
        if not timings_ms:
            return
        for k in VLOC_STAGES:
            v = timings_ms.get(k)
            if v is not None and math.isfinite(float(v)):
                self.windows[k].add(float(v))
                self.last[k] = float(v)

    def summary(self) -> dict[str, dict[str, Any]]:
        out = {}
        for k, w in self.windows.items():
            s = w.summary()
            s["last_ms"] = self.last.get(k, float("nan"))
            out[k] = s
        return out


def _f(v: Any) -> float:
    try:
        return float("nan") if v is None else float(v)
    except (TypeError, ValueError):
        return float("nan")


def _fmt(v: float, digits: int = 2) -> str:
    return "nan" if not math.isfinite(v) else f"{v:.{digits}f}"


def level_high(value: float, t: LevelThresholds) -> int:
    """Higher is worse: ERROR at or above `t.error`, WARN at or above `t.warn`, else OK (NaN: OK)."""
    if not math.isfinite(value):
        return OK
    return ERROR if value >= t.error else WARN if value >= t.warn else OK


def level_low(value: float, t: LevelThresholds) -> int:
    """Lower is worse: ERROR at or below `t.error`, WARN at or below `t.warn`, else OK (NaN: OK)."""
    if not math.isfinite(value):
        return OK
    return ERROR if value <= t.error else WARN if value <= t.warn else OK


def stage_times(status: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """{stage: latency summary (last_ms, median_ms, p99_ms, count)} from a status snapshot."""
    out: dict[str, dict[str, Any]] = dict(status.get("vloc_stages") or {})
    stages = status.get("stages") or {}
    fusion = (stages.get("fusion") or {}).get("latency", {}).get("odometry")
    if fusion is not None:
        out["fusion"] = fusion
    publish = (stages.get("publisher") or {}).get("latency", {}).get("outbox")
    if not publish or not publish.get("count"):  # publish_inline: the fusion thread puts; time the put
        publish = (((status.get("bus") or {}).get("topics") or {}).get("pose") or {}).get("put_ms") or publish
    if publish is not None:
        out["publish"] = publish
    return out


def diagnostic_statuses(
    status: Mapping[str, Any], previous: Mapping[str, Any] | None, cfg: DiagnosticsConfig, map_id: str = "",
    n_nodes: int | None = None,
) -> list[Status]:
    """The DiagnosticStatus entries for one snapshot (see the module docstring).

    `status`: a `Service.status()` dict; `previous`: the snapshot of the last message (or
    None) for the VLoc rate and acceptance over the period."""
    hw = cfg.hardware_id
    out: list[Status] = []
    times = stage_times(status)
    for name in STAGES:
        s = times.get(name) or {}
        last, med, p99, n = _f(s.get("last_ms")), _f(s.get("median_ms")), _f(s.get("p99_ms")), int(s.get("count") or 0)
        thr: LevelThresholds = getattr(cfg, f"{name}_ms")
        lvl = level_high(p99, thr)
        msg = "no samples yet" if n == 0 else (
            f"p99 {_fmt(p99, 1)} ms" + ("" if lvl == OK else f" >= {thr.error if lvl == ERROR else thr.warn:g} ms"))
        out.append((lvl, f"litevloc/stage/{name}", msg, hw, [
            ("last_ms", _fmt(last, 3)), ("median_ms", _fmt(med, 3)), ("p99_ms", _fmt(p99, 3)), ("samples", str(n)),
            ("warn_p99_ms", f"{thr.warn:g}"), ("error_p99_ms", f"{thr.error:g}")]))
    for qname, q in (status.get("queues") or {}).items():
        depth, cap = int(q.get("depth") or 0), int(q.get("capacity") or 1)
        drops, overflows = int(q.get("drops") or 0), int(q.get("overflows") or 0)
        fill = depth / max(cap, 1)
        if q.get("kind") == "latest":
            lvl, msg = OK, f"latest-value mailbox: {drops} stale value(s) replaced (by design)"
        else:
            lvl = level_high(fill, cfg.queue_fill)
            msg = f"depth {depth}/{cap}"
            if overflows or q.get("error"):
                lvl, msg = ERROR, str(q.get("error") or f"{overflows} overflow(s)")
        out.append((lvl, f"litevloc/queue/{qname}", msg, hw, [
            ("depth", str(depth)), ("capacity", str(cap)), ("high_water", str(q.get("high_water", ""))),
            ("drops", str(drops)), ("overflows", str(overflows)), ("kind", str(q.get("kind", "")))]))
    c = status.get("counters") or {}
    calls, acc = int(c.get("vloc_calls") or 0), int(c.get("vloc_accepted") or 0)
    pc = (previous or {}).get("counters") or {}
    d_calls = calls - int(pc.get("vloc_calls") or 0)
    d_acc = acc - int(pc.get("vloc_accepted") or 0)
    dt = _f(status.get("uptime_s")) - _f((previous or {}).get("uptime_s", 0.0))
    rate = d_calls / dt if dt > 0 else float("nan")
    acceptance = d_acc / d_calls if d_calls > 0 else float("nan")
    if calls < cfg.min_vloc_calls:
        lvl, msg = OK, f"{calls} VLoc call(s) so far (judged from {cfg.min_vloc_calls})"
    else:
        l_rate, l_acc = level_low(rate, cfg.vloc_rate_hz), level_low(acceptance, cfg.vloc_acceptance)
        if d_calls == 0:  # no call in the period: the rate is 0
            l_rate, rate = level_low(0.0, cfg.vloc_rate_hz), 0.0
        lvl = max(l_rate, l_acc)
        msg = f"{_fmt(rate)} Hz, acceptance {_fmt(100 * acceptance, 0)} %"
    out.append((lvl, "litevloc/vloc", msg, hw, [
        ("rate_hz", _fmt(rate, 3)), ("acceptance", _fmt(acceptance, 3)), ("calls", str(calls)),
        ("accepted", str(acc)), ("fusion_accepted", str(c.get("fusion_accepted", 0))),
        ("frames_dropped", str(status.get("frames_dropped", 0))),
        ("last_reason", str(status.get("last_vloc_reason") or "")), ("period_s", _fmt(dt, 3))]))
    state = str(status.get("state", TrackingState.INIT))
    reasons = [str(r) for r in status.get("reasons") or []]
    levels: dict[str, int] = {TrackingState.TRACKING: OK, TrackingState.INIT: WARN}
    lvl = levels.get(state, ERROR)
    out.append((lvl, "litevloc/tracking", state + (f": {reasons[0]}" if reasons else ""), hw, [
        ("state", state), ("reason", "; ".join(reasons)), ("vloc_state", str(status.get("vloc_state") or "")),
        ("last_fusion_reason", str(status.get("last_fusion_reason") or ""))]))
    out.append(map_status(status.get("map"), map_id, n_nodes, hw))
    models = status.get("models")
    if models:
        out.append(models_status(models, hw))
    return out


def map_status(m: Mapping[str, Any] | None, map_id: str, n_nodes: int | None, hw: str) -> Status:
    """`litevloc/map` from the status's `map` entry (`MapSwitcher.report`; without one, the id and node
    count of the map the service started with): WARN while the last version offered was refused."""
    if not m:
        return OK, "litevloc/map", map_id or "(no map id)", hw, [
            ("map_id", map_id), ("nodes", "" if n_nodes is None else str(n_nodes))]
    name = f"{m.get('name')}@{m.get('version')}" if m.get("version") is not None else str(m.get("map_id") or "")
    lvl, msg = OK, name or "(no map id)"
    if m.get("refused_since_switch"):
        lvl = WARN
        msg += f"; version {m.get('last_refused_version')} refused ({m.get('last_refusal')})"
    keys = ("map_id", "name", "version", "nodes", "requests", "switches", "refusals",
            "last_switch_wall", "last_switch_s", "last_refusal", "last_refused_version", "last_refusal_detail",
            "loading", "pending")
    return lvl, "litevloc/map", msg, hw, [(k, "" if m.get(k) is None else str(m.get(k))) for k in keys]


def models_status(models: Mapping[str, Any], hw: str) -> Status:
    """`litevloc/models` from the status's `models` entry (`models.ort.ProviderReport.as_dict`): level
    from its `state` (`PROVIDER_LEVELS`), the build and each model's provider as values."""
    try:
        state: ProviderState | None = ProviderState(models.get("state"))
    except ValueError:
        state = None
    lvl = WARN if state is None else PROVIDER_LEVELS[state]
    b = models.get("onnxruntime") or {}
    values = [("state", str(models.get("state", ""))), ("onnxruntime", str(b.get("version", ""))),
              ("distribution", str(b.get("distribution", ""))), ("device", str(b.get("device", ""))),
              ("available_providers", ", ".join(b.get("available") or []))]
    for name, m in (models.get("sessions") or {}).items():
        values.append((f"provider/{name}", ", ".join(m.get("used") or [])))
    return lvl, "litevloc/models", str(models.get("message", "")), hw, values


@dataclass
class DiagnosticsPublisher:
    """Rate-limited DiagnosticArray builder for the status tick (one thread calls `maybe_message`)."""

    cfg: DiagnosticsConfig
    map_id: str = ""
    n_nodes: int | None = None

    def __post_init__(self) -> None:
        self._previous: dict[str, Any] | None = None
        self._last_uptime: float | None = None

    def maybe_message(self, status: Mapping[str, Any], t_ns: int) -> Any | None:
        """A DiagnosticArray (rosbags message) if `period_s` has passed since the last one
        (service uptime clock), else None. `t_ns` stamps the header (wall clock, ns)."""
        if not self.cfg.enabled:
            return None
        up = _f(status.get("uptime_s"))
        if self._last_uptime is not None and math.isfinite(up) and up - self._last_uptime < 0.95 * self.cfg.period_s:
            return None
        self._last_uptime = up
        entries = diagnostic_statuses(status, self._previous, self.cfg, self.map_id, self.n_nodes)
        self._previous = {"counters": dict(status.get("counters") or {}), "uptime_s": status.get("uptime_s")}
        return ros_msgs.diagnostic_array_msg(t_ns, entries)
