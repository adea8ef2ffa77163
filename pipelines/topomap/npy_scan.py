"""One streaming pass over a large `.npy` file: the SHA-256 of all its bytes, its header and, on
the same chunks of whole rows, the finiteness of float data and a caller's row check.

Nothing is kept, so checking a file costs no memory however large it is; `io.load_map` reads
its local features (keypoints, scores, descriptors) this way and only then memory-maps them.
The scan reports what it found and raises nothing: the caller decides the order of the errors.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

CHUNK = 1 << 22  # bytes per read when streaming a large file through the checksum

# (rows of a chunk, index of its first row) -> the first problem of those rows, or None
RowCheck = Callable[[NDArray[Any], int], str | None]
NpyHeader = tuple[tuple[int, ...], bool, np.dtype[Any]]  # (shape, fortran order, dtype)


@dataclass(frozen=True)
class NpyScan:
    """What one pass over a `.npy` file found."""

    sha256: str  # hex digest of all the file's bytes
    header: NpyHeader | None  # None: no readable header (`header_error` says why)
    header_error: Exception | None
    problem: str | None  # the first value problem of the rows; None: none, or the rows were not read as rows


def _rows_problem(a: NDArray[Any], scratch: NDArray[np.uint16], row_check: RowCheck | None, row: int) -> str | None:
    """The first value problem of a chunk of whole rows `a` (row index `row` first): NaN or
    infinity in float data, else what `row_check` returns. `scratch` (at least a.size uint16)
    holds float16 exponent bits."""
    if a.dtype == np.float16:  # non-finite iff all exponent bits are set (in place: no temporaries)
        bits = scratch[: a.size]
        np.bitwise_and(a.reshape(-1).view(np.uint16), 0x7C00, out=bits)
        bad = bool(bits.max() == 0x7C00)
    else:
        bad = a.dtype.kind == "f" and not bool(np.all(np.isfinite(a)))
    if bad:
        return "contains NaN or infinity"
    return row_check(a, row) if row_check is not None else None


def _read_header(head: bytes) -> tuple[NpyHeader | None, int, Exception | None]:
    """The header parsed from the file's first bytes, the offset of the data after it, and
    the reason when the header cannot be read."""
    try:
        hf = io.BytesIO(head)
        version = np.lib.format.read_magic(hf)
        if version == (1, 0):
            hdr = np.lib.format.read_array_header_1_0(hf)
        elif version == (2, 0):
            hdr = np.lib.format.read_array_header_2_0(hf)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
        return hdr, hf.tell(), None
    except (ValueError, OSError, EOFError, SyntaxError) as exc:
        return None, 0, exc


def _scan_rows(f: Any, h: Any, head: bytes, start: int, dt: np.dtype[Any], row_shape: tuple[int, ...],
               row_check: RowCheck | None) -> str | None:
    """Read the rest of `f` into the hash `h` in chunks of whole rows, checking each chunk;
    the first problem found (later chunks are still hashed, not checked)."""
    row_items = int(np.prod(row_shape, dtype=np.int64))
    row_bytes = dt.itemsize * row_items
    # read into one reused buffer (no per-chunk allocation or copy); the bytes of a row split
    # across two reads (< one row) move to the buffer's start
    buf = bytearray(CHUNK + row_bytes + len(head))
    scratch = np.empty(len(buf) // 2 if dt == np.float16 else 0, np.uint16)
    mv = memoryview(buf)
    carry = len(head) - start
    buf[:carry] = head[start:]
    row = 0
    problem: str | None = None
    while True:
        got = f.readinto(mv[carry:carry + CHUNK])
        h.update(mv[carry:carry + got])
        have = carry + got
        n_rows = have // row_bytes if row_bytes else 0
        if n_rows and problem is None:
            a = np.frombuffer(buf, dt, count=n_rows * row_items)
            problem = _rows_problem(a.reshape((n_rows, *row_shape)), scratch, row_check, row)
            del a
        rest = have - n_rows * row_bytes
        buf[:rest] = buf[n_rows * row_bytes:have]
        carry, row = rest, row + n_rows
        if not got:
            return problem


def scan_npy(path: Path, size: int, dtypes: tuple[Any, ...], ndim: int, row_check: RowCheck | None) -> NpyScan:
    """Scan the `size`-byte `.npy` file at `path` in one pass.

    The rows are checked only when the header is readable, C-ordered, of one of `dtypes` and
    of `ndim` >= 1 dimensions; otherwise the file is only hashed (the caller reports the
    layout)."""
    h = hashlib.sha256()
    problem: str | None = None
    with path.open("rb") as f:
        head = f.read(min(size, 4096))
        h.update(head)
        hdr, start, head_exc = _read_header(head)
        ok_layout = (hdr is not None and not hdr[1] and np.dtype(hdr[2]) in [np.dtype(d) for d in dtypes]
                     and len(hdr[0]) == ndim and len(hdr[0]) >= 1)
        if ok_layout and hdr is not None:
            problem = _scan_rows(f, h, head, start, np.dtype(hdr[2]), tuple(hdr[0][1:]), row_check)
        else:
            for chunk in iter(lambda: f.read(CHUNK), b""):
                h.update(chunk)
    return NpyScan(h.hexdigest(), hdr, head_exc, problem)
