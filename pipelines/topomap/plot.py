"""Top-down PNGs: a map (occupancy grid, nodes with headings, both edge sets) and the diff of two
versions of a map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.base.figures import save_figure
from litevloc.pipelines.topomap.diff import MapDiff, coverage_raster
from litevloc.pipelines.topomap.types import OccupancyGrid, TopoMap


def plot_map(
    m: TopoMap, out_png: str | Path, title: str = "",
    extra_paths: dict[str, NDArray[np.float64]] | None = None,
) -> Path:
    """Write the top-down view; `extra_paths` maps a legend label to (N,3) map-frame points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = m.grid
    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    H, W = g.cells.shape
    rgb = np.ones((H, W, 3))
    rgb[g.cells == OccupancyGrid.UNKNOWN] = (0.85, 0.85, 0.85)
    rgb[g.cells == OccupancyGrid.FREE] = (1.0, 1.0, 1.0)
    rgb[g.cells == OccupancyGrid.OCCUPIED] = (0.25, 0.25, 0.25)
    extent = (g.origin[0], g.origin[0] + W * g.resolution, g.origin[1], g.origin[1] + H * g.resolution)
    ax.imshow(rgb, origin="lower", extent=extent, interpolation="nearest")
    xy = g.to_plane(m.positions)
    for i, j in m.conn_edges:
        ax.plot(xy[[i, j], 0], xy[[i, j], 1], color="tab:green", ls="--", lw=0.8, alpha=0.7)
    for (i, j), w in zip(m.covis_edges, m.covis_weight, strict=True):
        ax.plot(xy[[i, j], 0], xy[[i, j], 1], color="tab:blue", alpha=0.3 + 0.7 * float(w), lw=2.0)
    fwd = g.to_plane(m.positions + 0.25 * m.T_map_camera[:, :3, 2]) - xy
    ax.quiver(xy[:, 0], xy[:, 1], fwd[:, 0], fwd[:, 1], color="tab:red", angles="xy", scale_units="xy", scale=1,
              width=0.004)
    ax.scatter(xy[:, 0], xy[:, 1], s=18, color="tab:red", zorder=3, label=f"keyframes ({m.n_nodes})")
    for k, (label, pts) in enumerate((extra_paths or {}).items()):
        p = g.to_plane(np.asarray(pts))
        ax.plot(p[:, 0], p[:, 1], lw=1.0, color=f"C{k + 4}", label=label)
    ax.plot([], [], color="tab:blue", label=f"covisibility ({len(m.covis_edges)})")
    ax.plot([], [], color="tab:green", ls="--", label=f"connectivity ({len(m.conn_edges)})")
    ax.set_aspect("equal")
    ax.set_xlabel("plane axis a (m)")
    ax.set_ylabel("plane axis b (m)")
    ax.set_title(title or "LiteVLoc map (grey: occupied, white: free)")
    ax.legend(loc="upper right", fontsize=8)
    return save_figure(fig, out_png)


def plot_diff(old: TopoMap, new: TopoMap, d: MapDiff, out_png: Path) -> Path:
    """Top-down view: both occupancy grids (observed only in OLD / NEW / both), kept nodes,
    retired (red crosses), added (green), moved (arrows from the old to the new position)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    labels, origin, res = coverage_raster(old.grid, new.grid)
    if labels.size:
        rgb = np.ones((*labels.shape, 3))
        rgb[labels == 1] = (0.96, 0.70, 0.70)  # observed only in OLD
        rgb[labels == 2] = (0.70, 0.90, 0.70)  # observed only in NEW
        rgb[labels == 3] = (0.82, 0.82, 0.82)  # both
        H, W = labels.shape
        ax.imshow(rgb, origin="lower", interpolation="nearest",
                  extent=(origin[0], origin[0] + W * res, origin[1], origin[1] + H * res))
    for colour, name in (((0.96, 0.70, 0.70), "floor seen only in OLD"), ((0.70, 0.90, 0.70), "only in NEW"),
                         ((0.82, 0.82, 0.82), "in both")):
        ax.fill_between([], [], color=colour, label=name)
    po, pn = old.grid.to_plane(old.positions), new.grid.to_plane(new.positions)
    kept_new = d.kept[:, 1] if len(d.kept) else np.zeros(0, np.int64)
    ax.scatter(pn[kept_new, 0], pn[kept_new, 1], s=14, color="tab:blue", label=f"kept ({len(d.kept)})", zorder=3)
    if len(d.retired):
        ax.scatter(po[d.retired, 0], po[d.retired, 1], s=30, marker="x", color="tab:red",
                   label=f"retired ({len(d.retired)})", zorder=4)
    if len(d.added):
        ax.scatter(pn[d.added, 0], pn[d.added, 1], s=22, color="tab:green", label=f"added ({len(d.added)})",
                   zorder=4)
    for k in d.moved:
        i, j = d.kept[k]
        ax.annotate("", xy=tuple(pn[j]), xytext=tuple(po[i]),
                    arrowprops={"arrowstyle": "->", "color": "tab:orange", "lw": 1.2})
    ax.plot([], [], color="tab:orange", label=f"moved ({len(d.moved)})")
    ax.set_aspect("equal")
    ax.set_xlabel("plane axis a (m)")
    ax.set_ylabel("plane axis b (m)")
    ax.set_title(f"map diff: {d.n_old} -> {d.n_new} keyframes")
    ax.legend(loc="upper right", fontsize=8)
    return save_figure(fig, out_png)
