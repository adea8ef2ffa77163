"""A simulated pass's colour frames rendered in worker processes, handed back in index order.

Rendering is most of a recording's CPU time (ray casting, shading, noise) and each frame is a
pure function of its index
(`SimSequenceSource.frame`), so N processes render N frames at once and the recording is
byte-identical to one rendered in-process. Workers are forked after the renderer is built, so
they share it instead of rebuilding it; each also JPEG-encodes its frame (the bytes the
recorder would write).
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor

from litevloc.hw.messages import RgbdFrame
from litevloc.hw.streams.mcap_io import JPEG_QUALITY, encode_jpeg
from litevloc.sim.source import SimSequenceSource

_source: SimSequenceSource | None = None  # the forked worker's copy of the pass
_jpeg_quality = JPEG_QUALITY


def default_workers() -> int:
    """Render processes by default: the CPUs this process may run on."""
    return max(1, len(os.sched_getaffinity(0)))


def _start_worker(src: SimSequenceSource, jpeg_quality: int) -> None:
    global _source, _jpeg_quality
    _source, _jpeg_quality = src, jpeg_quality


def _render(index: int) -> RgbdFrame:
    assert _source is not None, "worker not initialised"
    f = _source.frame(index)
    return dataclasses.replace(f, color_jpeg=encode_jpeg(f.color, _jpeg_quality, index))


def rendered_frames(src: SimSequenceSource, workers: int, jpeg_quality: int = JPEG_QUALITY) -> Iterator[RgbdFrame]:
    """Frames 0 .. src.frame_count() - 1 of `src` in order, rendered by `workers` processes
    (at most 2 x workers frames in flight); workers <= 1 renders in this process."""
    n = src.frame_count()
    if workers <= 1:
        yield from (src.frame(i) for i in range(n))
        return
    src.prepare_renderer()
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                               initializer=_start_worker, initargs=(src, jpeg_quality))
    pending: deque[Future[RgbdFrame]] = deque()
    try:
        submitted = 0
        while pending or submitted < n:
            while submitted < n and len(pending) < 2 * workers:
                pending.append(pool.submit(_render, submitted))
                submitted += 1
            yield pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
