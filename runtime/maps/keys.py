"""The map service's key space on Zenoh and its reply encoding (JSON metadata, raw chunk bytes).

```
litevloc/maps/_index                        query -> {"maps": [{"name", "latest": info}]}
litevloc/maps/<name>/latest                 query -> info (MapVersionInfo JSON)
litevloc/maps/<name>/versions               query -> {"latest", "versions": [info], "history": [...]}
litevloc/maps/<name>/v/<version>/manifest   query -> {"info", "transfer": TransferManifest JSON}
litevloc/maps/<name>/v/<version>/chunk/<i>  query -> raw bytes of chunk i
litevloc/maps/<name>/announce               publication: info, each time a version becomes latest
litevloc/maps/<name>/push/begin             query + JSON {"kind", "transfer"} -> {"upload": id}
litevloc/maps/<name>/push/<id>/chunk/<i>    query + raw chunk bytes -> {"ok": true}
litevloc/maps/<name>/push/<id>/commit       query -> {"published", "reason", "info", "details"}
litevloc/maps/<name>/rollback               query + JSON {"version"} -> info
```

Map names start with a letter or digit, so `_index` never collides with one. Errors are
Zenoh error replies whose payload is `{"error": MapErrorKind value, "message": ...}`.
"""

from __future__ import annotations

import json
from typing import Any

from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError

PREFIX = "litevloc/maps"
INDEX = f"{PREFIX}/_index"
# what the service answers, one queryable each (access rules name the same expressions)
READ_KEYS = (INDEX, f"{PREFIX}/*/latest", f"{PREFIX}/*/versions", f"{PREFIX}/*/v/**")
PUSH_KEYS = (f"{PREFIX}/*/push/**",)
ROLLBACK_KEYS = (f"{PREFIX}/*/rollback",)
ANNOUNCE_KEYS = f"{PREFIX}/*/announce"


def latest_key(name: str) -> str:
    return f"{PREFIX}/{name}/latest"


def versions_key(name: str) -> str:
    return f"{PREFIX}/{name}/versions"


def manifest_key(name: str, version: str) -> str:
    return f"{PREFIX}/{name}/v/{version}/manifest"


def chunk_key(name: str, version: str, i: int) -> str:
    return f"{PREFIX}/{name}/v/{version}/chunk/{i}"


def announce_key(name: str) -> str:
    return f"{PREFIX}/{name}/announce"


def push_begin_key(name: str) -> str:
    return f"{PREFIX}/{name}/push/begin"


def push_chunk_key(name: str, upload: str, i: int) -> str:
    return f"{PREFIX}/{name}/push/{upload}/chunk/{i}"


def push_commit_key(name: str, upload: str) -> str:
    return f"{PREFIX}/{name}/push/{upload}/commit"


def rollback_key(name: str) -> str:
    return f"{PREFIX}/{name}/rollback"


def dumps(obj: Any) -> bytes:
    return json.dumps(obj, sort_keys=True).encode()


def loads(data: bytes, what: str) -> Any:
    """JSON from a peer; `MapServiceError(BAD_REPLY)` naming `what` when it is not JSON."""
    try:
        return json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapServiceError(MapErrorKind.BAD_REPLY, f"{what}: not JSON ({exc})") from exc


def error_payload(exc: MapServiceError) -> bytes:
    return dumps({"error": exc.kind.value, "message": str(exc)})


def error_from_payload(data: bytes, what: str) -> MapServiceError:
    """The `MapServiceError` an error reply carries (BAD_REPLY when it is not ours)."""
    try:
        d = json.loads(data.decode("utf-8"))
        return MapServiceError(MapErrorKind(d["error"]), str(d["message"]))
    except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError):
        return MapServiceError(MapErrorKind.BAD_REPLY, f"{what}: error reply {data[:200]!r}")
