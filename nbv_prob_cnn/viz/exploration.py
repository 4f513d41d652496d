"""Pictures of exploration results (matplotlib, Agg backend, no pyplot state kept)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from nbv_prob_cnn.basics.camera import matrix_from_quaternion

_AXES = ("x", "y", "z")


def _state_image_2d(state: np.ndarray, truth: np.ndarray | None) -> np.ndarray:
    """RGB: unknown dark grey, observed empty white, observed occupied red, unseen occupied
    (when the ground truth is known) dull red."""
    rgb = np.full(state.shape + (3,), 0.25)
    rgb[state == 0] = 1.0
    if truth is not None:
        rgb[(truth == 1) & (state == -1)] = (0.55, 0.35, 0.35)
    rgb[state == 1] = (0.85, 0.1, 0.1)
    return rgb


def _projection_image(state: np.ndarray, hidden_axis: int) -> np.ndarray:
    """RGB projection along one axis: brightness = share of known cells along the line of
    sight, red where an observed occupied cell lies on it. Seen from above (along z), occupied
    columns are coloured by the height of their highest observed occupied cell instead."""
    from matplotlib import colormaps

    known = 1.0 - np.mean(state == -1, axis=hidden_axis)
    occupied = np.any(state == 1, axis=hidden_axis)
    grey = 0.15 + 0.85 * known
    rgb = np.stack([grey, grey, grey], axis=-1)
    if hidden_axis == 2:
        top = state.shape[2] - 1 - np.argmax((state == 1)[:, :, ::-1], axis=2)
        heights = top[occupied].astype(float)
        span = max(1.0, heights.max() - heights.min()) if heights.size else 1.0
        rgb[occupied] = colormaps["plasma"]((heights - (heights.min() if heights.size else 0)) / span)[:, :3]
    else:
        rgb[occupied] = np.stack([0.5 + 0.5 * grey[occupied], 0.15 * grey[occupied], 0.15 * grey[occupied]], axis=-1)
    return rgb


def plot_views(
    state: np.ndarray,
    cells: np.ndarray,
    quats: np.ndarray,
    path: str | Path,
    title: str = "",
    truth: np.ndarray | None = None,
    curve: tuple[list[int], list[float]] | None = None,
    arms: list[np.ndarray] | None = None,
) -> None:
    """Save a PNG of a grid with camera views (cell indices + quaternions) and, optionally, the
    unknown-fraction curve ``(view indices, fractions)`` and, in 3D, the arm at each view
    (``arms``: one polyline ``(n, 3)`` per view in continuous index coordinates, e.g.
    ``geometry.to_index(arm_polyline(robot, q))``; the last view drawn strongest)."""
    cells = np.asarray(cells, dtype=float).reshape(-1, state.ndim)
    quats = np.asarray(quats, dtype=float).reshape(-1, 4)
    panels = (1 if state.ndim == 2 else 3) + (curve is not None)
    fig = Figure(figsize=(5.5 * panels, 5.2))
    axes = [fig.add_subplot(1, panels, i + 1) for i in range(panels)]
    if state.ndim == 2:
        ax = axes[0]
        ax.imshow(np.transpose(_state_image_2d(state, truth), (1, 0, 2)), origin="lower")
        yaw = 2.0 * np.arctan2(quats[:, 2], quats[:, 3])
        ax.quiver(cells[:, 0], cells[:, 1], np.cos(yaw), np.sin(yaw), color="tab:blue", scale=25, width=0.004)
        ax.plot(cells[:, 0], cells[:, 1], "o", color="tab:blue", ms=3)
        ax.set_xlabel("x (cells)")
        ax.set_ylabel("y (cells)")
        ax.set_title("white: seen empty, red: seen occupied, grey: unknown")
    else:
        forward = np.array([matrix_from_quaternion(q)[:, 2] for q in quats]).reshape(-1, 3)
        for ax, (a, b) in zip(axes[:3], ((0, 1), (0, 2), (1, 2)), strict=True):
            hidden = 3 - a - b
            ax.imshow(np.transpose(_projection_image(state, hidden), (1, 0, 2)), origin="lower")
            for index, line in enumerate(arms or []):
                strong = index == len(arms or []) - 1
                ax.plot(line[:, a], line[:, b], "-o", color="tab:cyan" if strong else "lightskyblue",
                        lw=2.0 if strong else 0.8, ms=2.5 if strong else 1.2, alpha=1.0 if strong else 0.6)  # fmt: skip
            ax.quiver(cells[:, a], cells[:, b], forward[:, a], forward[:, b], color="gold", scale=20, width=0.006)
            ax.plot(cells[:, a], cells[:, b], "o", color="gold", ms=3)
            ax.set_xlabel(f"{_AXES[a]} (cells)")
            ax.set_ylabel(f"{_AXES[b]} (cells)")
            seen = "colour = height of seen occupied" if hidden == 2 else "red = seen occupied"
            ax.set_title(f"along {_AXES[hidden]}: bright = known, {seen}", fontsize=9)
    if curve is not None:
        ax = axes[-1]
        ax.plot(curve[0], [100 * f for f in curve[1]], "-o", ms=3)
        ax.set_xlabel("view")
        ax.set_ylabel("unknown cells (%)")
        ax.grid(alpha=0.3)
        ax.set_title("unknown fraction")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


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
    )
