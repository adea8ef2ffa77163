"""Remake the README's live-view picture (docs/live_view_office.png).

`litevloc replay` (real time, threaded runtime) of the simulated office's query pass (its
first 30 s, cut with `litevloc convert`) against the office map with `--view-save`, then the
saved .rrd opened in Rerun's web viewer in headless Chromium (tests/runtime/browser.py) and
screenshotted. Inputs come from bench/_common.office_inputs
(made when absent). Needs chromium (`make browser`).

    python docs/make_live_view_png.py [--out docs/live_view_office.png]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT))

from _common import office_inputs  # noqa: E402

from tests.runtime.browser import find_chromium, screenshot_rrd  # noqa: E402
from tests.runtime.zenoh_helpers import free_port  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "docs/live_view_office.png")
    ap.add_argument("--rrd", type=Path, default=ROOT / "out/docs/office_replay.rrd")
    ap.add_argument("--frames", default="0:450", help="query frames to replay (15 Hz)")
    args = ap.parse_args()
    if find_chromium() is None:
        raise SystemExit("needs chromium on PATH (make browser)")
    map_dir, query = office_inputs()
    args.rrd.parent.mkdir(parents=True, exist_ok=True)
    cut = args.rrd.with_suffix(".mcap")
    cli = [sys.executable, "-m", "litevloc.cli.main"]
    for cmd in ([*cli, "convert", str(query), str(cut), "--frames", args.frames],
                [*cli, "replay", str(cut), "--map", str(map_dir), "--listen", f"tcp/127.0.0.1:{free_port()}",
                 "--view-save", str(args.rrd)]):
        print("$", " ".join(cmd[2:]), flush=True)
        subprocess.run(cmd, check=True)
    with tempfile.TemporaryDirectory() as d:
        stats = screenshot_rrd(args.rrd, args.out, Path(d), free_port(), free_port(), timeout_s=300, settle_s=8.0)
    print(f"wrote {args.out} ({stats})")


if __name__ == "__main__":
    main()
