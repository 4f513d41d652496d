"""PNG previews of generated worlds (matplotlib's Agg canvas; pyplot and the global backend are
left alone)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nbv_prob_cnn.worlds.world import World


def _height_projection(grid: np.ndarray, axis: int) -> np.ndarray:
    """Max-projection of a 3D binary grid along ``axis`` valued by height: the z index of the
    highest occupied cell (top view, ``axis=2``) or of the cell row itself (side views); NaN
    where nothing is occupied."""
    nz = grid.shape[2]
    heights = np.where(grid > 0, np.arange(nz, dtype=np.float64)[None, None, :], -1.0)
    img = heights.max(axis=axis)  # side views: rows are the remaining horizontal axis, columns z
    return np.where(img >= 0, img, np.nan)


def save_preview(world: World, path: str | Path) -> Path:
    """Write a preview PNG of ``world``: the map for 2D worlds; for 3D worlds three projections
    (top: x-y; front: x-z; side: y-z), coloured by height. Returns the path written."""
    from matplotlib.figure import Figure

    path = Path(path)
    grid = world.ground_truth
    title = f"{world.dataset} seed {world.seed} (v{world.generator_version}): {'x'.join(map(str, grid.shape))}, "
    title += f"occupied {grid.mean():.1%}"
    if world.meshes:
        title += f", {len(world.meshes)} objects"
    if grid.ndim == 2:
        fig = Figure(figsize=(7, 7))
        ax = fig.subplots()
        ax.imshow(grid.T, origin="lower", cmap="gray_r", interpolation="nearest")
        ax.set_xlabel("x (cells)")
        ax.set_ylabel("y (cells)")
        ax.set_title(title, fontsize=9)
    else:
        nz = grid.shape[2]
        fig = Figure(figsize=(15, 5.2))
        axes = fig.subplots(1, 3)
        views = [
            ("top (x-y)", _height_projection(grid, 2).T, "x", "y"),
            ("front (x-z)", _height_projection(grid, 1).T, "x", "z"),
            ("side (y-z)", _height_projection(grid, 0).T, "y", "z"),
        ]
        top = views[0][1]
        # colour range: from the lowest visible top surface (the table top in 3DT) to the highest cell
        vmin = float(np.nanmin(top)) if np.isfinite(top).any() else 0.0
        vmax = max(float(np.nanmax(top)) if np.isfinite(top).any() else nz - 1.0, vmin + 1.0)
        for ax, (name, img, xl, yl) in zip(axes, views, strict=True):
            image = ax.imshow(img, origin="lower", cmap="viridis", vmin=vmin, vmax=vmax, interpolation="nearest")
            ax.set_facecolor("white")
            ax.set_title(name)
            ax.set_xlabel(f"{xl} (cells)")
            ax.set_ylabel(f"{yl} (cells)")
        fig.colorbar(image, ax=axes, shrink=0.8, label="height z (cells)")
        fig.suptitle(title, fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    return path
