"""`LiteVLocError`: the one base class of LiteVLoc's domain errors.

Every error that LiteVLoc raises on purpose (bad configuration, corrupt map or recording,
missing model, unusable goal, a stage that failed, ...) derives from `LiteVLocError`, so a
caller catches them all with one `except`. Subclasses keep a built-in base where callers
rely on it (`ConfigError` is also a `ValueError`, `StreamError` a `RuntimeError`).
The command line prints a `LiteVLocError` as one line and exits with code 2.
"""

from __future__ import annotations


class LiteVLocError(Exception):
    """Base class of every LiteVLoc domain error; its message is meant for the user."""
