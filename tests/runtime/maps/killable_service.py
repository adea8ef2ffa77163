"""A map service in its own process for the SIGKILL test: `python -m tests.runtime.maps.killable_service
STORE ENDPOINT`. Its push gate accepts every pushed map; publishing a version stops after every
byte is staged and fsynced (prints STAGED), so the test kills it inside the publish."""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

from litevloc.runtime.maps import store as st
from litevloc.runtime.maps.server import MapServer, PushVerdict
from tests.runtime.maps.conftest import CHUNK, open_router


def accept_all(name: str, current: Path | None, upload: Path, kind: str, out: Path) -> PushVerdict:
    shutil.copytree(upload, out)
    return PushVerdict(True, "accepted")


def main() -> None:
    real = st._fsync_tree

    def stall(root: Path) -> None:
        real(root)
        print("STAGED", flush=True)
        time.sleep(120)

    session = open_router(sys.argv[2])
    server = MapServer(session, st.MapStore(sys.argv[1], chunk_bytes=CHUNK), accept_all)
    st._fsync_tree = stall
    print("READY", flush=True)
    time.sleep(120)
    server.close()


if __name__ == "__main__":
    main()
