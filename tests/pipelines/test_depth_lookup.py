from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.params.localization import DepthLookupParams
from litevloc.pipelines.depth_lookup import depth_at


def test_bilinear_on_smooth_surface() -> None:
    u = np.arange(20, dtype=np.float32)
    depth = np.tile(1.0 + 0.01 * u, (10, 1)).astype(np.float32)  # slanted plane along u
    z = depth_at(depth, np.array([[3.5, 4.0], [10.25, 2.7]]))
    assert np.allclose(z, [1.035, 1.1025], atol=1e-6)


def test_rejects_holes_edges_and_outside() -> None:
    depth = np.full((10, 10), 2.0, np.float32)
    depth[:, 5:] = 4.0  # a depth discontinuity between columns 4 and 5
    depth[2, 2] = np.nan
    uv = np.array([[4.5, 5.0], [2.2, 2.2], [-1.0, 3.0], [9.5, 3.0], [7.0, 7.0], [1.0, 7.0]])
    z = depth_at(depth, uv)
    assert np.isnan(z[:4]).all()  # edge, hole, outside x2
    assert np.allclose(z[4:], [4.0, 2.0])
    far = depth_at(np.full((4, 4), 20.0, np.float32), np.array([[1.0, 1.0]]), DepthLookupParams(max_depth=10))
    assert np.isnan(far[0])


def test_params() -> None:
    with pytest.raises(ValueError):
        DepthLookupParams(min_depth=5, max_depth=1)
