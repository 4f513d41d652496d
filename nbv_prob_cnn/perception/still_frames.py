"""Which depth frames of a still camera to fuse (no ROS here).

A camera on an arm that stands still while the planner thinks streams the same view again and
again: in a static scene those frames add nothing a few of them have not added already, and
fusing them takes CPU from the planner on the same machine. :class:`StillFrameFilter` says, per
frame, whether it should be fused: every frame whose camera pose (and joint positions, where
given) differs from the first frame of the current still spell, and the first ``fuse_per_pose``
frames of each spell; the rest are skipped (the caller counts them).

A spell ends at the first frame whose pose differs by more than ``translation_m`` or
``rotation_rad`` from the spell's first frame, or whose joints differ by more than ``joint_rad``
(the arm may move while the camera does not: the arm's own pixels change), or with :meth:`reset`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


class StillFrameFilter:
    """Keeps the first ``fuse_per_pose`` frames of every still camera pose (0: every frame).

    Args:
        fuse_per_pose: frames fused per still pose; 0 fuses every frame.
        translation_m, rotation_rad, joint_rad: largest differences of a frame from the spell's
            first frame that still count as the same pose.

    Raises:
        ValueError: a negative count or tolerance, or a non-finite one.
    """

    def __init__(
        self, fuse_per_pose: int, translation_m: float = 5e-4, rotation_rad: float = math.radians(0.1),
        joint_rad: float = 1e-3,
    ) -> None:  # fmt: skip
        values = (fuse_per_pose, translation_m, rotation_rad, joint_rad)
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise ValueError(f"still-frame filter: counts and tolerances must be finite and >= 0, got {values}")
        self.fuse_per_pose = int(fuse_per_pose)
        self.translation_m = float(translation_m)
        self.rotation_rad = float(rotation_rad)
        self.joint_rad = float(joint_rad)
        self._pose: np.ndarray | None = None
        self._joints: np.ndarray | None = None
        self._fused = 0

    def reset(self) -> None:
        """Forget the current spell (after a grid reset the next frame is fused whatever its pose)."""
        self._pose, self._joints, self._fused = None, None, 0

    def same_pose(self, pose: np.ndarray, joints: Sequence[float] | None = None) -> bool:
        """Whether ``pose`` (4×4, camera in the grid's frame) and ``joints`` are those of the current spell."""
        if self._pose is None:
            return False
        if float(np.linalg.norm(pose[:3, 3] - self._pose[:3, 3])) > self.translation_m:
            return False
        relative = self._pose[:3, :3].T @ pose[:3, :3]
        angle = math.acos(max(-1.0, min(1.0, (float(np.trace(relative)) - 1.0) / 2.0)))
        if angle > self.rotation_rad:
            return False
        if (joints is None) != (self._joints is None):
            return False
        if joints is not None and self._joints is not None:
            q = np.asarray(joints, dtype=np.float64)
            if q.shape != self._joints.shape or float(np.max(np.abs(q - self._joints), initial=0.0)) > self.joint_rad:
                return False
        return True

    def should_fuse(self, pose: np.ndarray, joints: Sequence[float] | None = None) -> bool:
        """Whether to fuse a frame taken at ``pose`` with ``joints``; a fused frame is counted
        towards its spell (call it once per frame, in stamp order)."""
        if self.fuse_per_pose == 0:
            return True
        if not self.same_pose(pose, joints):
            self._pose = np.array(pose, dtype=np.float64)
            self._joints = None if joints is None else np.asarray(joints, dtype=np.float64).copy()
            self._fused = 0
        if self._fused >= self.fuse_per_pose:
            return False
        self._fused += 1
        return True
