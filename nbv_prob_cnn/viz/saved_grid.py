"""A saved grid as a picture: projections of what is known and a heat map of the best view gain
per (x, y) column, plus the heat map as CSV (``nbv view --grid``, and ``nbv view --bag`` on a
camera-only bag after fusing it)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.viz.exploration import (
    COLOUR_SEEN_EMPTY,
    COLOUR_SEEN_OCCUPIED,
    COLOUR_UNKNOWN,
    axis_extent,
    height_colorbar,
    projection_image,
    state_image_2d,
)

#: Heat-map CSV columns (metres of the grid frame; the gain is the ray-count-normalised view gain).
HEAT_CSV_COLUMNS = ["x_m", "y_m", "best_view_gain", "origins_in_column"]


def column_best_gains(
    origins: np.ndarray, gains: np.ndarray, shape: tuple[int, ...], bin_cells: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """The best gain over the origins of every (x, y) column of ``bin_cells`` × ``bin_cells`` cells.

    Returns:
        ``(best (nx, ny) float, NaN where no origin; count (nx, ny) int)`` with
        ``nx = ceil(shape[0] / bin_cells)`` (likewise ny).
    """
    if bin_cells < 1:
        raise ValueError(f"bin_cells: expected a positive integer, got {bin_cells}")
    nx, ny = -(-shape[0] // bin_cells), -(-shape[1] // bin_cells)
    best = np.full((nx, ny), -np.inf)
    count = np.zeros((nx, ny), dtype=np.int64)
    if len(origins):
        ix, iy = origins[:, 0] // bin_cells, origins[:, 1] // bin_cells
        np.maximum.at(best, (ix, iy), gains.astype(np.float64))
        np.add.at(count, (ix, iy), 1)
    best[count == 0] = np.nan
    return best, count


def render_saved_grid(
    state: np.ndarray,
    geometry: GridGeometry,
    origins: np.ndarray,
    gains: np.ndarray,
    out: str | Path,
    title: str = "",
    method: str = "",
    bin_cells: int = 1,
    camera_positions_m: np.ndarray | None = None,
) -> tuple[Path, Path]:
    """Write ``out`` (PNG) and ``out`` with ``.csv`` (the heat map, :data:`HEAT_CSV_COLUMNS`).

    Panels: 3D: the projections along z and along y (bright = known along the line of sight, red
    = seen occupied, from above coloured by height) and the heat map; 2D: the map and the heat map.
    ``camera_positions_m``: ``(n, 3)`` camera positions to draw (e.g. from a bag)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    best, count = column_best_gains(origins, gains, state.shape, bin_cells)
    fig = Figure(figsize=(16 if state.ndim == 3 else 11, 5.8))
    panels = 3 if state.ndim == 3 else 2
    axes = [fig.add_subplot(1, panels, i + 1) for i in range(panels)]
    cams = np.zeros((0, 3)) if camera_positions_m is None else np.asarray(camera_positions_m).reshape(-1, 3)
    if state.ndim == 2:
        axes[0].imshow(np.transpose(state_image_2d(state, None), (1, 0, 2)), origin="lower",
                       extent=axis_extent(geometry, state.shape, 0, 1), interpolation="nearest")  # fmt: skip
        handles = [Patch(facecolor=COLOUR_SEEN_EMPTY, edgecolor="0.5", label="seen empty"),
                   Patch(facecolor=COLOUR_SEEN_OCCUPIED, label="seen occupied"),
                   Patch(facecolor=COLOUR_UNKNOWN, label="unknown")]  # fmt: skip
        axes[0].set_title("the grid", fontsize=9)
        axes[0].set(xlabel="x (m)", ylabel="y (m)")
        axes[0].legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, fontsize=7)
    else:
        for ax, (a, b) in zip(axes[:2], ((0, 1), (0, 2)), strict=True):
            picture, heights = projection_image(state, 3 - a - b)
            ax.imshow(np.transpose(picture, (1, 0, 2)), origin="lower", extent=axis_extent(geometry, state.shape, a, b),
                      interpolation="nearest")  # fmt: skip
            if len(cams):
                ax.plot(cams[:, a], cams[:, b], ".-", color="tab:blue", ms=3, lw=0.6)
            ax.set(xlabel=f"{'xyz'[a]} (m)", ylabel=f"{'xyz'[b]} (m)")
            ax.set_title(f"projection along {'xyz'[3 - a - b]}" + (": colour = height of seen occupied" if b == 1
                         else ""), fontsize=9)  # fmt: skip
            legend: list[Patch | Line2D] = [
                Patch(facecolor="0.95", edgecolor="0.5", label="known along the line of sight"),
                Patch(facecolor="0.2", label="unknown along the line of sight"),
            ]
            if b == 2:
                legend.append(Patch(facecolor=(0.95, 0.15, 0.15), label="seen occupied"))
            if len(cams):
                legend.append(Line2D([], [], color="tab:blue", marker=".", label="camera positions"))
            ax.legend(handles=legend, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=7)
            if heights is not None:  # seen from above: occupied columns coloured by height
                height_colorbar(fig, ax, heights, geometry)
    heat = axes[-1]
    side = bin_cells * geometry.resolution
    o = geometry.origin
    extent = (o[0], o[0] + best.shape[0] * side, o[1], o[1] + best.shape[1] * side)
    finite = best[np.isfinite(best)]
    image = heat.imshow(best.T, origin="lower", extent=extent, cmap="inferno", vmin=0.0,
                        vmax=float(finite.max()) if finite.size and finite.max() > 0 else 1.0)  # fmt: skip
    fig.colorbar(image, ax=heat, fraction=0.046, pad=0.02, label="best view gain in the column")
    heat.set(xlabel="x (m)", ylabel="y (m)")
    where = f"{len(origins)} candidate origins" + (f", {side * 100:.3g} cm columns" if bin_cells > 1 else "")
    heat.set_title(f"best view gain ({method}), {where}; blank: no empty cell", fontsize=9)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out, dpi=100, bbox_inches="tight")
    csv_path = out.with_suffix(".csv")
    with open(csv_path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(HEAT_CSV_COLUMNS)
        for i, j in np.argwhere(count > 0):
            writer.writerow([f"{o[0] + (i + 0.5) * side:.4f}", f"{o[1] + (j + 0.5) * side:.4f}",
                             f"{best[i, j]:.6g}", int(count[i, j])])  # fmt: skip
    return out, csv_path
