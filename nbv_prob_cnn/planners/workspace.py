"""The camera workspace of a plan (no ROS here): a box of camera positions in the grid frame made
of the planner's ``workspace_min`` / ``workspace_max``, the request's box and the camera heights."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Box bound standing for "no limit" on an axis.
UNBOUNDED = 1e9

#: A box: its low and high corners ``(3,)`` (grid frame, m).
Box = tuple[np.ndarray, np.ndarray]


def workspace_box(low: Sequence[float], high: Sequence[float]) -> Box | None:
    """The ``workspace_min`` / ``workspace_max`` parameters as a box (None when both are empty).

    Raises:
        ValueError: not three finite numbers each, or min > max.
    """
    if not low and not high:
        return None
    lo, hi = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError(f"workspace_min/workspace_max: expected 3 finite numbers each, got {low} and {high}")
    if np.any(lo > hi):
        raise ValueError(f"workspace_min {low} exceeds workspace_max {high} on some axis")
    return lo, hi


def height_box(min_height_m: float, max_height_m: float) -> Box | None:
    """The camera heights as a box (0 = no limit on that side; None when both are 0)."""
    if not (min_height_m or max_height_m):
        return None
    return (np.array([-UNBOUNDED, -UNBOUNDED, min_height_m or -UNBOUNDED]),
            np.array([UNBOUNDED, UNBOUNDED, max_height_m or UNBOUNDED]))  # fmt: skip


def intersect_boxes(*boxes: Box | None) -> Box | None:
    """The intersection of the boxes given (None: no limit); None when every one is None."""
    given = [b for b in boxes if b is not None]
    if not given:
        return None
    return np.max([b[0] for b in given], axis=0), np.min([b[1] for b in given], axis=0)
