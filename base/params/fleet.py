"""Parameters of the map service and of the robots' map fetch (config `fleet`; the code is
`litevloc.runtime.maps`: `litevloc map serve|fetch|push|versions|rollback`, `run --map zenoh:NAME`)."""

from __future__ import annotations

from dataclasses import dataclass

from litevloc.base.settings import Settings, setting


@dataclass(frozen=True)
class FleetParams(Settings):
    """Chunked map transfer, time-outs and the robot's local map cache."""

    cache_dir: str = setting(
        "", 'the robot\'s cache of fetched map versions; "" = $LITEVLOC_MAP_CACHE, else ~/.cache/litevloc/maps')
    chunk_bytes: int = setting(
        1 << 20, "size of one transfer chunk of a stored version (each checked by its own sha256)", unit="bytes",
        low=1024, high=64 << 20)
    query_timeout_s: float = setting(
        5.0, "wait for one answer of the map service (a chunk, the latest version); then it counts as unreachable",
        unit="s", low=0, low_open=True, high=600)
    follow_latest: bool = setting(
        True, "run --map zenoh:NAME (no @VERSION) follows the map: each announced new version is fetched and "
        "switched to while running; NAME@VERSION always stays on that version")
    fetch_window: int = setting(
        4, "chunk queries a fetch keeps in flight (hides the round trip of a Wi-Fi link)", low=1, high=256)
    chunk_retries: int = setting(3, "fetches again of a chunk that fails its sha256 before the fetch is refused",
                                 low=0, high=100)
    commit_timeout_s: float = setting(
        900.0, "wait for the service's verdict on a push (it builds and checks the candidate)", unit="s", low=1,
        high=86400)
    max_push_bytes: int = setting(
        4 << 30, "largest push (recording or session map) the service accepts", unit="bytes", low=1)
    push_median_tolerance_m: float = setting(
        0.01, "a pushed candidate is refused when its held-out median position error exceeds the current version's "
        "by more than this (and when it localizes fewer held-out frames)", unit="m", low=0, high=1)
