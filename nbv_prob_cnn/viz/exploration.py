"""Pictures of exploration results (matplotlib, Agg backend, no pyplot state kept)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from nbv_prob_cnn.basics.camera import matrix_from_quaternion
from nbv_prob_cnn.basics.geometry import GridGeometry

_AXES = ("x", "y", "z")


#: Colours of the 2D map and the legend that names them.
COLOUR_UNKNOWN = (0.25, 0.25, 0.25)
COLOUR_SEEN_EMPTY = (1.0, 1.0, 1.0)
COLOUR_SEEN_OCCUPIED = (0.85, 0.1, 0.1)
COLOUR_UNSEEN_OCCUPIED = (0.55, 0.55, 0.8)


def state_image_2d(state: np.ndarray, truth: np.ndarray | None) -> np.ndarray:
    """RGB of a 2D map: unknown dark grey, seen empty white, seen occupied red and, when the
    ground truth is given, occupied cells not seen yet in a pale blue (so the picture tells what
    the camera saw from what only the ground truth knows)."""
    rgb = np.empty(state.shape + (3,))
    rgb[...] = COLOUR_UNKNOWN
    rgb[state == 0] = COLOUR_SEEN_EMPTY
    if truth is not None:
        rgb[(truth == 1) & (state == -1)] = COLOUR_UNSEEN_OCCUPIED
    rgb[state == 1] = COLOUR_SEEN_OCCUPIED
    return rgb


def height_colorbar(fig: Figure, ax, heights: tuple[int, int], geometry: GridGeometry | None) -> None:
    """The colour bar of :func:`projection_image`'s heights (cell indices ``(lowest, highest)``), in metres
    of the grid frame with ``geometry``, else in cells."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    low, high = float(heights[0]), float(heights[1])
    if geometry is not None:  # cell index -> height of the cell centre in metres
        low, high = (geometry.origin[2] + (h + 0.5) * geometry.resolution for h in (low, high))
    bar = ScalarMappable(norm=Normalize(low, max(high, low + 1e-9)), cmap=colormaps["plasma"])
    unit = "m" if geometry is not None else "cells"
    fig.colorbar(bar, ax=ax, fraction=0.046, pad=0.02, label=f"height of the highest seen occupied cell ({unit})")


def projection_image(state: np.ndarray, hidden_axis: int) -> tuple[np.ndarray, tuple[int, int] | None]:
    """RGB projection along one axis: brightness = share of known cells along the line of
    sight, red where a seen occupied cell lies on it. Seen from above (along z), occupied
    columns are coloured by the height of their highest seen occupied cell instead; then the
    second value is that height range (lowest, highest cell index), else None."""
    from matplotlib import colormaps

    known = 1.0 - np.mean(state == -1, axis=hidden_axis)
    occupied = np.any(state == 1, axis=hidden_axis)
    grey = 0.15 + 0.85 * known
    rgb = np.stack([grey, grey, grey], axis=-1)
    if hidden_axis == 2:
        top = state.shape[2] - 1 - np.argmax((state == 1)[:, :, ::-1], axis=2)
        heights = top[occupied].astype(float)
        if not heights.size:
            return rgb, None
        low, high = int(heights.min()), int(heights.max())
        span = max(1.0, float(high - low))
        rgb[occupied] = colormaps["plasma"]((heights - low) / span)[:, :3]
        return rgb, (low, high)
    rgb[occupied] = np.stack([0.5 + 0.5 * grey[occupied], 0.15 * grey[occupied], 0.15 * grey[occupied]], axis=-1)
    return rgb, None


def axis_extent(
    geometry: GridGeometry | None, shape: tuple[int, ...], a: int, b: int
) -> tuple[float, float, float, float]:
    """imshow extent of axes ``a``, ``b``: metres with a geometry, else cell indices (centre at i)."""
    if geometry is None:
        return (-0.5, shape[a] - 0.5, -0.5, shape[b] - 0.5)
    o, r = geometry.origin, geometry.resolution
    return (o[a], o[a] + shape[a] * r, o[b], o[b] + shape[b] * r)


def _to_plot(points: np.ndarray, geometry: GridGeometry | None) -> np.ndarray:
    """Continuous index coordinates ``(n, dims)`` (centre of cell i at i) -> plot coordinates:
    metres with a geometry (``origin + (i + 0.5) * resolution``), else unchanged."""
    points = np.asarray(points, dtype=float)
    if geometry is None:
        return points
    dims = points.shape[-1]
    return np.asarray(geometry.origin[:dims]) + (points + 0.5) * geometry.resolution


def plot_views(
    state: np.ndarray,
    cells: np.ndarray,
    quats: np.ndarray,
    path: str | Path,
    title: str = "",
    truth: np.ndarray | None = None,
    curve: tuple[list[int], list[float]] | None = None,
    arms: list[np.ndarray] | None = None,
    geometry: GridGeometry | None = None,
    curve_label: str = "unknown cells of the grid (%)",
) -> Figure:
    """Save a PNG of a grid with camera views (cell indices + quaternions) and, optionally, the
    unknown-fraction curve ``(view indices, fractions)`` and, in 3D, the arm at each view
    (``arms``: one polyline ``(n, 3)`` per view in continuous index coordinates, e.g.
    ``geometry.to_index(arm_polyline(robot, q))``; the last view drawn strongest).

    With ``geometry`` the axes are in metres of the grid frame, else in cells. Each panel has a
    legend naming what its colours show. Returns the figure (already saved)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator

    cells = np.asarray(cells, dtype=float).reshape(-1, state.ndim)
    quats = np.asarray(quats, dtype=float).reshape(-1, 4)
    where = _to_plot(cells, geometry)
    unit = "m" if geometry is not None else "cells"
    panels = (1 if state.ndim == 2 else 3) + (curve is not None)
    fig = Figure(figsize=(5.5 * panels, 5.8))
    axes = [fig.add_subplot(1, panels, i + 1) for i in range(panels)]
    if state.ndim == 2:
        ax = axes[0]
        ax.imshow(np.transpose(state_image_2d(state, truth), (1, 0, 2)), origin="lower",
                  extent=axis_extent(geometry, state.shape, 0, 1), interpolation="nearest")  # fmt: skip
        yaw = 2.0 * np.arctan2(quats[:, 2], quats[:, 3])
        ax.quiver(where[:, 0], where[:, 1], np.cos(yaw), np.sin(yaw), color="tab:blue", scale=25, width=0.004)
        ax.plot(where[:, 0], where[:, 1], "o", color="tab:blue", ms=3)
        ax.set_xlabel(f"x ({unit})")
        ax.set_ylabel(f"y ({unit})")
        handles = [
            Patch(facecolor=COLOUR_SEEN_EMPTY, edgecolor="0.5", label="seen empty"),
            Patch(facecolor=COLOUR_SEEN_OCCUPIED, label="seen occupied"),
            Patch(facecolor=COLOUR_UNKNOWN, label="unknown"),
            Line2D([], [], color="tab:blue", marker="o", ms=3, lw=0, label="camera views (arrow: direction)"),
        ]
        if truth is not None:
            handles.insert(2, Patch(facecolor=COLOUR_UNSEEN_OCCUPIED, label="occupied, not seen (ground truth)"))
        ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=7)
        ax.set_title("the map after the last view", fontsize=9)
    else:
        forward = np.array([matrix_from_quaternion(q)[:, 2] for q in quats]).reshape(-1, 3)
        for ax, (a, b) in zip(axes[:3], ((0, 1), (0, 2), (1, 2)), strict=True):
            hidden = 3 - a - b
            image, heights = projection_image(state, hidden)
            ax.imshow(np.transpose(image, (1, 0, 2)), origin="lower", extent=axis_extent(geometry, state.shape, a, b),
                      interpolation="nearest")  # fmt: skip
            for index, line in enumerate(arms or []):
                strong = index == len(arms or []) - 1
                drawn = _to_plot(line, geometry)
                ax.plot(drawn[:, a], drawn[:, b], "-o", color="tab:cyan" if strong else "lightskyblue",
                        lw=2.0 if strong else 0.8, ms=2.5 if strong else 1.2, alpha=1.0 if strong else 0.6)  # fmt: skip
            ax.quiver(where[:, a], where[:, b], forward[:, a], forward[:, b], color="gold", scale=20, width=0.006)
            ax.plot(where[:, a], where[:, b], "o", color="gold", ms=3)
            if not arms:  # the arm's base may stand outside the grid: then let the axes take it in
                ax.set_xlim(*axis_extent(geometry, state.shape, a, b)[:2])
                ax.set_ylim(*axis_extent(geometry, state.shape, a, b)[2:])
            ax.set_xlabel(f"{_AXES[a]} ({unit})")
            ax.set_ylabel(f"{_AXES[b]} ({unit})")
            handles = [
                Patch(facecolor="0.95", edgecolor="0.5", label="known along the line of sight"),
                Patch(facecolor="0.2", label="unknown along the line of sight"),
                Line2D([], [], color="gold", marker="o", ms=3, lw=0, label="camera views (arrow: optical axis)"),
            ]
            if hidden != 2:
                handles.insert(2, Patch(facecolor=(0.95, 0.15, 0.15), label="seen occupied"))
            if arms:
                handles.append(Line2D([], [], color="tab:cyan", lw=2, label="arm (last view strongest)"))
            ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.17), ncol=2, fontsize=6.5)
            ax.set_title(f"projection along {_AXES[hidden]}", fontsize=9)
            if heights is not None:
                height_colorbar(fig, ax, heights, geometry)
    if curve is not None:
        ax = axes[-1]
        ax.plot(curve[0], [100 * f for f in curve[1]], "-o", ms=3)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # views are counted, not measured
        ax.set_xlabel("view")
        ax.set_ylabel(curve_label)
        ax.grid(alpha=0.3)
        ax.set_title("unknown fraction")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90, bbox_inches="tight")  # "tight": the legends below the axes
    return fig


def save_exploration_png(result, world, path: str | Path, title: str = "") -> None:
    """Plot a simulated exploration (:class:`nbv_prob_cnn.exploration.explore.ExplorationResult`)."""
    records = result.records
    plot_views(
        result.state,
        np.array([r.cell for r in records]),
        np.array([r.quaternion for r in records]),
        path,
        title,
        truth=world.ground_truth,
        curve=([r.iteration for r in records], [r.unknown_fraction for r in records]),
        geometry=world.geometry,
        curve_label="unknown share of the ground-truth-empty cells (%)",
    )
