"""The live view as a person sees it: a saved .rrd opened in Rerun's web viewer (served by the
rerun-sdk wheel's own CLI) in headless Chromium; the screenshot must show the view, not a blank
or loading page. Skips (saying why) only where no Chromium can be had: `make test` installs
Debian's `chromium` when it is missing and runs as root."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import make_T
from litevloc.hw.messages import RgbdFrame
from tests.runtime.browser import find_chromium, image_stats, screenshot_rrd
from tests.runtime.test_view import Fused, K, Res, synthetic_map
from tests.runtime.zenoh_helpers import free_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(400)]


@pytest.mark.skipif(find_chromium() is None,
                    reason="no chromium on PATH (`make test` installs Debian's chromium when run as root)")
def test_saved_view_opens_in_the_web_viewer(tmp_path: Path) -> None:
    from litevloc.runtime.service.view import LiveView

    m = synthetic_map()
    rrd = tmp_path / "view.rrd"
    view = LiveView(save=rrd, topomap=m, pose_hz=10.0)
    rng = np.random.default_rng(1)
    for i in range(20):
        t = i * 50_000_000
        view.put_fused(Fused(t, make_T(np.eye(3), [0.1 * i, 0, 0])))
        if i % 4 == 0:
            color = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
            view.put_vloc(RgbdFrame(t, color, None, K, index=i),
                          Res(t, True, "ok", m.T_map_camera[1], np.eye(6) * 1e-3, ref_node=1, n_matches=90,
                              n_inliers=60, timings_ms={"extract": 90.0 + i, "match": 150.0 - i}))
        if i % 10 == 0:
            view.put_status({"sensor_time_ns": t, "state": "TRACKING", "reasons": []})
    assert view.close()["errors"] == 0
    png = tmp_path / "viewer.png"
    stats = screenshot_rrd(rrd, png, tmp_path / "chromium-profile", free_port(), free_port(), timeout_s=300)
    shot = png.read_bytes()
    # the web viewer's loading page has ~40 colours and < 0.1 % of pixels off its background
    assert stats["distinct"] >= 150 and stats["content"] >= 0.03, stats
    left = image_stats(shot, (0.0, 0.05, 0.6, 0.6))  # the 3D view: frusta, edges, pose, ellipsoid
    assert left["distinct"] >= 50 and left["content"] >= 0.01, left
