"""The one stream interface: an iterable of time-ordered `Message`s.

Every source (dataset folder, MCAP file, simulator, live driver) implements
`StreamSource`. `parse_frames` turns the CLI's `--frames A:B` into a slice over frame
indices; sources apply it to RGB-D frames and keep the odometry and ground truth that
fall inside the selected frames' time span.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, runtime_checkable

from litevloc.hw.messages import Message, StreamError, StreamStats


@runtime_checkable
class StreamSource(Protocol):
    """A source of timestamped messages in non-decreasing `t_ns` order."""

    name: str
    stats: StreamStats

    def __iter__(self) -> Iterator[Message]: ...

    def frame_count(self) -> int:
        """Number of RGB-D frames this source will yield (after `--frames`)."""
        ...


def select_indices(n: int, frames: slice) -> list[int]:
    """Indices 0..n-1 selected by `frames`, sorted ascending (negative steps are rejected)."""
    if frames.step is not None and frames.step < 0:
        raise ValueError("--frames with a negative step would reverse time; not allowed")
    return list(range(n))[frames]


def check_monotonic(prev_ns: int | None, t_ns: int, where: str) -> None:
    """Raise StreamError if time goes backwards."""
    if prev_ns is not None and t_ns < prev_ns:
        raise StreamError(f"{where}: timestamps go backwards ({t_ns} ns after {prev_ns} ns)")
