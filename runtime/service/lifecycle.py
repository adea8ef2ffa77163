"""A managed node's life, as Nav2's lifecycle nodes have it: configure / activate / deactivate /
cleanup, with every resource held in one `contextlib.ExitStack`.

```
UNCONFIGURED --configure()--> INACTIVE --activate()--> ACTIVE
      ^                          |  ^                    |
      +--------cleanup()---------+  +----deactivate()----+
```

A transition acquires resources through `hold()`; each is released in the reverse order of its
acquisition, on every path: by `cleanup()`, on leaving a `with` block, and when `configure()` or
`activate()` fails half-way (then everything acquired so far is released and the error raised).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from enum import Enum
from types import TracebackType
from typing import Any, TypeVar

from litevloc.base.errors import LiteVLocError

log = logging.getLogger(__name__)

T = TypeVar("T")


class LifecycleState(str, Enum):
    UNCONFIGURED = "unconfigured"  # nothing held
    INACTIVE = "inactive"  # configured: resources held, nothing received or sent yet
    ACTIVE = "active"  # inputs live, the node may run


class LifecycleError(LiteVLocError, RuntimeError):
    """A transition asked for in a state that does not allow it (e.g. activate before configure)."""


class Lifecycle:
    """The transitions and the exit stack; a node implements `on_configure` and `on_activate`
    (acquiring with `hold`) and, if it has work to end, `on_deactivate`."""

    def __init__(self) -> None:
        self.state = LifecycleState.UNCONFIGURED
        self._stack = contextlib.ExitStack()

    def hold(self, resource: T, close: Callable[[], Any] | None = None) -> T:
        """Keep `resource` until cleanup, released by `close` (default `resource.close`), in reverse order."""
        closer = close if close is not None else getattr(resource, "close")  # noqa: B009 (checked when held)
        self._stack.callback(closer)
        return resource

    # ------------------------------------------------------------------ transitions
    def configure(self) -> None:
        self._expect(LifecycleState.UNCONFIGURED, "configure")
        self._transition(self.on_configure)
        self.state = LifecycleState.INACTIVE

    def activate(self) -> None:
        self._expect(LifecycleState.INACTIVE, "activate")
        self._transition(self.on_activate)
        self.state = LifecycleState.ACTIVE

    def deactivate(self) -> None:
        self._expect(LifecycleState.ACTIVE, "deactivate")
        self.on_deactivate()
        self.state = LifecycleState.INACTIVE

    def cleanup(self) -> None:
        """Release everything held, newest first (idempotent); deactivates an active node first."""
        if self.state is LifecycleState.ACTIVE:
            self.deactivate()
        self.state = LifecycleState.UNCONFIGURED
        self._stack.close()

    # ------------------------------------------------------------------ hooks
    def on_configure(self) -> None:
        """Acquire what the node needs (`hold`); nothing is received or sent yet."""

    def on_activate(self) -> None:
        """Make the inputs live (`hold` what must be released)."""

    def on_deactivate(self) -> None:
        """End the node's work (its resources stay held until `cleanup`)."""

    # ------------------------------------------------------------------ internals
    def _expect(self, state: LifecycleState, transition: str) -> None:
        if self.state is not state:
            raise LifecycleError(f"cannot {transition} a node that is {self.state.value}")

    def _transition(self, step: Callable[[], None]) -> None:
        try:
            step()
        except BaseException:
            self.state = LifecycleState.UNCONFIGURED
            try:
                self._stack.close()
            except Exception:  # the step's error is the one to raise; this one is logged
                log.exception("releasing the resources after a failed transition")
            raise

    def __enter__(self: T) -> T:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.cleanup()
