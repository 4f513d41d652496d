"""A recorded run (rosbag2 from ``bag_record planning:=true``) as numpy arrays and as a PNG.

Reads with ``rosbags`` (no ROS): camera positions (``/camera/pose``), next best views
(``/nbv/next_best_view``), the occupied cells of the last grid (``/nbv/grid_occupied``) and the
candidate views of every plan (``/nbv/markers``: arrow start = view position, red channel =
gain relative to that plan's best).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbv_prob_cnn.perception.bags import read_raw_messages, typestore
from nbv_prob_cnn.perception.messages import cloud_msg_to_points

TOPIC_POSE = "/camera/pose"
TOPIC_NBV = "/nbv/next_best_view"
TOPIC_OCCUPIED = "/nbv/grid_occupied"
TOPIC_MARKERS = "/nbv/markers"
#: What a planning run records beyond a camera bag's topics.
PLANNING_TOPICS = frozenset({TOPIC_NBV, TOPIC_OCCUPIED, TOPIC_MARKERS})


@dataclass
class RecordedRun:
    """What :func:`render_run` draws; positions in metres, ``candidates`` rows ``x, y, z, gain``."""

    camera_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    next_best_views: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    occupied: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    candidates: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))


def load_run(path: str | Path) -> RecordedRun:
    """Read a recorded run.

    Raises:
        FileNotFoundError: no such bag.
        BagError: unreadable, corrupt or truncated bag.
        ValueError: the bag has none of the topics above.
    """
    store = typestore()
    cameras, views, candidates = [], [], []
    occupied = np.zeros((0, 3))
    seen = set()
    for msg in read_raw_messages(path, [TOPIC_POSE, TOPIC_NBV, TOPIC_OCCUPIED, TOPIC_MARKERS]):
        seen.add(msg.topic)
        decoded = store.deserialize_cdr(msg.data, msg.msgtype)
        if msg.topic == TOPIC_POSE:
            t = decoded.transform.translation
            cameras.append((t.x, t.y, t.z))
        elif msg.topic == TOPIC_NBV:
            p = decoded.pose.position
            views.append((p.x, p.y, p.z))
        elif msg.topic == TOPIC_OCCUPIED:
            occupied = cloud_msg_to_points(decoded).astype(np.float64)
        else:
            for marker in decoded.markers:
                if marker.ns == "nbv_candidates" and len(marker.points) >= 1:
                    p = marker.points[0]
                    candidates.append((p.x, p.y, p.z, float(marker.color.r)))
    if not seen:
        raise ValueError(f"{path}: none of {TOPIC_POSE}, {TOPIC_NBV}, {TOPIC_OCCUPIED}, {TOPIC_MARKERS} is recorded")
    return RecordedRun(
        np.array(cameras, dtype=float).reshape(-1, 3),
        np.array(views, dtype=float).reshape(-1, 3),
        occupied,
        np.array(candidates, dtype=float).reshape(-1, 4),
    )


def gain_heat_map(candidates: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best relative gain per ``cell_m`` square (x, y) over all candidates.

    Returns:
        ``(cells (K, 2) integer indices, lower corner (2,) in m, best gains (K,))``.
    """
    if not cell_m > 0:
        raise ValueError(f"cell: expected a positive size, got {cell_m}")
    if len(candidates) == 0:
        return np.zeros((0, 2), dtype=int), np.zeros(2), np.zeros(0)
    corner = candidates[:, :2].min(axis=0)
    cells = np.floor((candidates[:, :2] - corner) / cell_m).astype(int)
    unique, inverse = np.unique(cells, axis=0, return_inverse=True)
    best = np.full(len(unique), -np.inf)
    np.maximum.at(best, inverse.reshape(-1), candidates[:, 3])
    return unique, corner, best


def render_run(run: RecordedRun, out: str | Path, cell_m: float = 0.02) -> tuple[Path, Path]:
    """Write ``out`` (PNG: top and side projections with camera poses and next best views, and
    the gain heat map) and ``out`` with ``.csv`` (heat-map cells: x, y centre in m, best gain)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cells, corner, best = gain_heat_map(run.candidates, cell_m)
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.2))
    for ax, (i, j, label) in zip(axes[:2], ((0, 1, "top (x, y)"), (0, 2, "side (x, z)")), strict=True):
        if len(run.occupied):
            ax.scatter(run.occupied[:, i], run.occupied[:, j], s=1, c="0.5", label="occupied cells")
        if len(run.camera_positions):
            ax.plot(run.camera_positions[:, i], run.camera_positions[:, j], ".-", c="tab:blue", ms=3,
                    lw=0.6, label="camera poses")  # fmt: skip
        if len(run.next_best_views):
            ax.scatter(run.next_best_views[:, i], run.next_best_views[:, j], marker="*", s=80, c="tab:red",
                       label="next best views")  # fmt: skip
        ax.set_title(label)
        ax.set_xlabel(f"{'xyz'[i]} (m)")
        ax.set_ylabel(f"{'xyz'[j]} (m)")
        ax.set_aspect("equal")
        ax.legend(loc="upper right", fontsize=7)
    heat = axes[2]
    if len(cells):
        grid = np.full(tuple(cells.max(axis=0) + 1), np.nan)
        grid[cells[:, 0], cells[:, 1]] = best
        extent = (corner[0], corner[0] + grid.shape[0] * cell_m, corner[1], corner[1] + grid.shape[1] * cell_m)
        image = heat.imshow(grid.T, origin="lower", extent=extent, cmap="inferno", vmin=0.0, vmax=1.0)
        fig.colorbar(image, ax=heat, label="best gain / that plan's best")
    heat.set_title(f"best gain per {cell_m * 100:g} cm cell ({len(run.candidates)} candidates)")
    heat.set_xlabel("x (m)")
    heat.set_ylabel("y (m)")
    heat.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    csv_path = out.with_suffix(".csv")
    with open(csv_path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["x_m", "y_m", "best_relative_gain"])
        for (ci, cj), gain in zip(cells, best, strict=True):
            writer.writerow([f"{corner[0] + (ci + 0.5) * cell_m:.4f}", f"{corner[1] + (cj + 0.5) * cell_m:.4f}",
                             f"{gain:.4f}"])  # fmt: skip
    return out, csv_path
