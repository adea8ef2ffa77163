"""Pictures of a world: top-down plan with trajectories (matplotlib, Agg) and contact sheets."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.figures import save_figure
from litevloc.sim.elements import s_increasing
from litevloc.sim.world import World


def plot_world(
    world: World,
    path: str | Path,
    trajectories: Sequence[tuple[str, NDArray[np.float64]]] = (),
    title: str | None = None,
) -> Path:
    """Top-down PNG: walls, doors, boxes, posters, goal places and (N, 2) xy trajectories."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    x0, y0, x1, y1 = world.bounds
    fig, ax = plt.subplots(figsize=(max(6.0, (x1 - x0) / 3), max(4.0, (y1 - y0) / 3)), dpi=100)
    for r in world.regions.values():
        bx0, by0, bx1, by1 = r.bbox
        ax.text(
            (bx0 + bx1) / 2,
            (by0 + by1) / 2,
            f"{r.name}\n{r.material}",
            ha="center",
            va="center",
            fontsize=6,
            color="0.5",
        )
    for f in world.faces:
        if f.kind != "wall":
            continue
        xs, ys = ((f.c, f.c), (f.lo, f.hi)) if f.axis == 0 else ((f.lo, f.hi), (f.c, f.c))
        ax.plot(xs, ys, color="k", lw=1.5)
    for bx0, by0, bx1, by1, h in world.boxes:
        ax.add_patch(
            Rectangle(
                (bx0, by0), bx1 - bx0, by1 - by0, color="tab:brown", alpha=0.3 + 0.2 * min(h / 2, 1)
            )
        )
    for p in world.posters:
        f = world.faces[p.face]
        a = f.lo + p.s0 if s_increasing(f) else f.hi - p.s0 - p.width
        xs, ys = ((f.c, f.c), (a, a + p.width)) if f.axis == 0 else ((a, a + p.width), (f.c, f.c))
        ax.plot(xs, ys, color="tab:red", lw=3)
    for name, T in world.goal_places.items():
        ax.plot(T[0, 3], T[1, 3], "g*", ms=8)
        ax.arrow(T[0, 3], T[1, 3], 0.5 * T[0, 0], 0.5 * T[1, 0], color="g", width=0.03)
        ax.text(T[0, 3], T[1, 3] - 0.4, name, fontsize=6, color="g", ha="center")
    colours = ["tab:blue", "tab:orange", "tab:purple", "tab:cyan"]
    for k, (label, xy) in enumerate(trajectories):
        ax.plot(xy[:, 0], xy[:, 1], color=colours[k % len(colours)], lw=1, label=label)
    if trajectories:
        ax.legend(loc="upper right", fontsize=7)
    ax.set_aspect("equal")
    ax.set_xlim(x0 - 0.5, x1 + 0.5)
    ax.set_ylim(y0 - 0.5, y1 + 0.5)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"world {world.spec.name} (seed {world.spec.seed})")
    return save_figure(fig, path)


def depth_to_rgb(depth: NDArray[np.float32], max_m: float = 8.0) -> NDArray[np.uint8]:
    """Colour-mapped depth (NaN black)."""
    d = np.nan_to_num(depth, nan=0.0)
    u8 = (np.clip(d / max_m, 0, 1) * 255).astype(np.uint8)
    rgb = cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)[:, :, ::-1].copy()
    rgb[~np.isfinite(depth)] = 0
    return rgb


def contact_sheet(
    tiles: Sequence[tuple[str, NDArray[np.uint8]]], path: str | Path, cols: int = 4
) -> Path:
    """Grid of labelled RGB tiles (all the same size) written as a PNG."""
    if not tiles:
        raise ValueError("no images for the contact sheet")
    h, w = tiles[0][1].shape[:2]
    rows = (len(tiles) + cols - 1) // cols
    sheet = np.full((rows * (h + 16), cols * w, 3), 255, np.uint8)
    for k, (label, img) in enumerate(tiles):
        r, c = divmod(k, cols)
        y, x = r * (h + 16), c * w
        sheet[y + 16 : y + 16 + h, x : x + w] = img
        cv2.putText(
            sheet,
            label[:48],
            (x + 2, y + 12),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.38,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), sheet[:, :, ::-1])
    return out
