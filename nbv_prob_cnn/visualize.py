"""Pictures of exploration results (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nbv_prob_cnn.camera import matrix_from_quaternion  # noqa: E402


def _state_image_2d(state: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """RGB: unknown dark grey, observed empty white, observed occupied red, unseen occupied pink."""
    rgb = np.full(state.shape + (3,), 0.25)
    rgb[state == 0] = 1.0
    rgb[(truth == 1) & (state == -1)] = (0.55, 0.35, 0.35)
    rgb[state == 1] = (0.85, 0.1, 0.1)
    return rgb


def save_exploration_png(result, world, path: str | Path, title: str = "") -> None:
    """Plot the explored grid with the chosen views and the unknown-fraction curve."""
    state, records = result.state, result.records
    cells = np.array([r.cell for r in records], dtype=float)
    quats = np.array([r.quaternion for r in records])
    axes_dirs = np.array([matrix_from_quaternion(q)[:, 2] for q in quats]) if world.dims == 3 else None
    if world.dims == 2:
        fig, (ax_map, ax_curve) = plt.subplots(1, 2, figsize=(12, 6), gridspec_kw={"width_ratios": [1.3, 1]})
        ax_map.imshow(np.transpose(_state_image_2d(state, world.ground_truth), (1, 0, 2)), origin="lower")
        yaw = 2.0 * np.arctan2(quats[:, 2], quats[:, 3])
        ax_map.quiver(cells[:, 0], cells[:, 1], np.cos(yaw), np.sin(yaw), color="tab:blue", scale=25, width=0.004)
        ax_map.plot(cells[:, 0], cells[:, 1], "o", color="tab:blue", ms=3)
        ax_map.set_xlabel("x (cells)")
        ax_map.set_ylabel("y (cells)")
        ax_map.set_title("explored map (white empty, red occupied, pink unseen occupied)")
    else:
        fig, axes = plt.subplots(1, 4, figsize=(20, 5))
        ax_curve = axes[3]
        names = ("x", "y", "z")
        for ax, (a, b) in zip(axes[:3], ((0, 1), (0, 2), (1, 2)), strict=True):
            hidden = 3 - a - b
            known_occ = np.any(state == 1, axis=hidden).astype(float)
            unknown_share = np.mean(state == -1, axis=hidden)
            img = np.stack(
                [
                    0.25 + 0.6 * known_occ,
                    0.25 * (1 - known_occ) + 0.75 * (1 - unknown_share),
                    0.3 * (1 - known_occ) + 0.7 * (1 - unknown_share),
                ],
                axis=-1,
            )
            ax.imshow(np.clip(np.transpose(img, (1, 0, 2)), 0, 1), origin="lower")
            ax.quiver(cells[:, a], cells[:, b], axes_dirs[:, a], axes_dirs[:, b], color="gold", scale=20, width=0.006)
            ax.plot(cells[:, a], cells[:, b], "o", color="gold", ms=3)
            ax.set_xlabel(f"{names[a]} (cells)")
            ax.set_ylabel(f"{names[b]} (cells)")
            ax.set_title(f"projection along {names[hidden]} (red: seen occupied; bright: known)")
    ax_curve.plot([r.iteration for r in records], [100 * r.unknown_fraction for r in records], "-o", ms=3)
    ax_curve.set_xlabel("view")
    ax_curve.set_ylabel("unknown empty cells (%)")
    ax_curve.grid(alpha=0.3)
    ax_curve.set_title("unknown fraction")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
