"""The map service's one error type and the kinds callers branch on (never on the message)."""

from __future__ import annotations

from enum import Enum

from litevloc.base.errors import LiteVLocError


class MapErrorKind(str, Enum):
    """Why a map-service operation failed; travels in replies as `{"error": kind.value}`."""

    NOT_FOUND = "not_found"          # no such map / version
    BAD_REQUEST = "bad_request"      # malformed name, version, payload
    BAD_REPLY = "bad_reply"          # the peer answered something malformed
    CHECKSUM = "checksum"            # bytes that do not hash to what the manifest says, after retries
    UNREACHABLE = "unreachable"      # no map service answered (no route, no credentials, timed out)
    REFUSED = "refused"              # a push the service declined (the reason says why)
    CONFLICT = "conflict"            # a write that would overwrite an existing version


class MapServiceError(LiteVLocError, RuntimeError):
    """A map-service operation failed; `kind` says why, the message names map and version."""

    def __init__(self, kind: MapErrorKind, message: str) -> None:
        super().__init__(message)
        self.kind = kind
