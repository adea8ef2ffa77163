"""A recording read in a child process: the service's source when it replays an MCAP file.

Reading a recording is Python work that holds the GIL: the MCAP reader, CDR deserialization
(rosbags) and the matrix conversions of 200 Hz odometry took about half of the samples in
which the service's process held the GIL (py-spy `--gil`, `bench/runtime.py`, office query
pass), so the fusion thread waited for the reader, not for a core. A robot's live inputs
(the camera driver, odometry over Zenoh) do not cost that; a replay should not either, or it
measures the reader instead of the service. Here the child reads and decodes the recording
(`McapSource(..., strict=False).messages(defer_color=True)`: colour still JPEG, as the service
takes it) and sends the messages in batches down a pipe; the parent only unpickles them.

* Backpressure: the child blocks on a full pipe, so it reads ahead only what the pipe holds
  plus one batch (`batch` messages, and at most one camera frame per batch).
* The source's skip counters (`StreamStats`) come back with the end of the stream and are
  added to the `McapSource` the caller opened, so nothing is lost silently.
* A child that fails raises `StreamError` with its message in the parent's iteration; one that
  dies raises `StreamError` naming its exit code. `close()` (also at the end of the stream or
  when the iteration is closed) ends it; one left running at exit is killed
  (`runtime.child_processes`).

The pipe carries pickles between two processes of this program only; the recording itself is
read by the MCAP reader in the child, as in one process.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from litevloc.hw.messages import EncodedRgbdFrame, RgbdFrame, SourceMessage, StreamError
from litevloc.hw.streams.mcap_io import McapSource
from litevloc.runtime.child_processes import end_child, start_child

if TYPE_CHECKING:
    from multiprocessing.connection import Connection


def _reader_main(path: Path, frames: slice, batch: int, conn: Connection) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when the replay ends
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        src = McapSource(path, frames, strict=False)
        out: list[SourceMessage] = []
        for m in src.messages(defer_color=True):
            out.append(m)
            if len(out) >= batch or isinstance(m, RgbdFrame | EncodedRgbdFrame):
                conn.send(("batch", out))
                out = []
        if out:
            conn.send(("batch", out))
        conn.send(("end", src.stats.messages, dict(src.stats.skipped)))
    except (BrokenPipeError, EOFError, OSError):  # the parent is gone or stopped reading
        return
    except Exception as exc:
        with contextlib.suppress(BrokenPipeError, EOFError, OSError):
            conn.send(("error", str(exc) if isinstance(exc, StreamError) else f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()


class RecordingReaderProcess:
    """Iterable of a recording's service messages (as `runtime.sources.service_messages` of a
    non-strict `McapSource`), read in a child process. Iterate once."""

    def __init__(self, src: McapSource, batch: int = 32) -> None:
        if src.strict:
            raise ValueError("a recording read in a child process is read non-strictly (as the service reads it)")
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        self.src, self.batch = src, batch
        self._proc: Any = None
        self._conn: Connection | None = None

    def __iter__(self) -> Iterator[SourceMessage]:
        if self._proc is not None:
            raise RuntimeError("a RecordingReaderProcess is iterated once")
        self._conn, child = multiprocessing.get_context("spawn").Pipe(duplex=False)
        self._proc = start_child(_reader_main, (self.src.path, self.src.frames, self.batch, child),
                                 "litevloc-recording")
        child.close()
        try:
            while True:
                try:
                    msg = self._conn.recv()
                except EOFError:
                    self._proc.join(5.0)
                    raise StreamError(f"{self.src.path}: the recording reader process ended unexpectedly "
                                      f"(exit code {self._proc.exitcode})") from None
                if msg[0] == "batch":
                    yield from msg[1]
                elif msg[0] == "end":
                    self.src.stats.messages += int(msg[1])
                    for reason, n in msg[2].items():
                        self.src.stats.skipped[reason] = self.src.stats.skipped.get(reason, 0) + int(n)
                    return
                else:
                    raise StreamError(str(msg[1]))
        finally:
            self.close()

    def close(self) -> None:
        """End the child (idempotent)."""
        if self._conn is not None:
            self._conn.close()
        if self._proc is not None:
            end_child(self._proc, 5.0)
