"""The ``integrator``'s fusion of paired depth frames into its TSDF, without ROS: each frame decoded,
skipped when its camera stood still, the pixels that see the arm removed (with a self-filter),
fused, and the ternary grid and its stamp (the newest frame's) handed out when a grid is due.

With ``still_frames_fused:=N`` (N > 0; default 0, every frame) a camera that stands still (an
arm waiting for its next view) costs little: of the frames taken from one pose (within
``still_translation_m`` and ``still_rotation_deg`` of the first, and with the self-filter the same
joint positions within ``still_joint_rad``) the first N are fused and the rest skipped
(:class:`~nbv_prob_cnn.perception.still_frames.StillFrameFilter`), counted as ``skipped_still``
(not a drop), in a static scene they would not change the grid. A skipped frame still advances
the grid's stamp (the grid is published again, unchanged, with the newer stamp), so a client
waiting for a grid that includes frame ``T`` is not kept waiting. Leave it at 0 for scenes that
move and for replays that must give ``nbv integrate``'s grid.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN
from nbv_prob_cnn.perception.depth_camera import Intrinsics
from nbv_prob_cnn.perception.messages import DropReason, FrameRejectedError, PairedFrame, decode_frame
from nbv_prob_cnn.perception.still_frames import StillFrameFilter
from nbv_prob_cnn.perception.surfaces import write_ply
from nbv_prob_cnn.perception.tsdf import TsdfIntegrator

if TYPE_CHECKING:
    from nbv_prob_cnn.arm.self_filter import RobotSelfFilter


class FrameFusion:
    """A TSDF, the frames fused into it and the grid state that follows it.

    :attr:`lock` guards the TSDF and the grid state (:attr:`generation`, :attr:`dirty`,
    :attr:`next_grid`, the stamp and the grid); the methods take it, but for :meth:`reset`.
    """

    def __init__(
        self,
        tsdf: TsdfIntegrator,
        still: StillFrameFilter,
        counts: dict[str, int],
        depth_max_m: float,
        grid_period_s: float,
        self_filter: RobotSelfFilter | None = None,
    ) -> None:
        """``counts``: the caller's counters, where the frames ``integrated`` and ``skipped_still``
        (and with ``self_filter`` the ``self_filtered_pixels``) are added; ``grid_period_s``: the
        least time from one grid to the next (0: a grid after every fused frame)."""
        self.tsdf = tsdf
        self.lock = threading.Lock()
        self.generation = 0  # frames paired in an older generation (before a reset) are not fused
        self.dirty = False  # a frame was fused (or skipped) since the last grid
        self.next_grid = 0.0  # when (time.monotonic) the next grid is due, once dirty
        self._still = still
        self._counts = counts
        self._depth_max_m = depth_max_m
        self._grid_period_s = grid_period_s
        self._self_filter = self_filter
        self._newest_stamp_ns = 0
        self._ternary: np.ndarray | None = None  # the grid as last handed out, while nothing was fused since

    def fuse(self, frame: PairedFrame) -> bool:
        """Fuse ``frame`` (its depth without the arm with a self-filter), or only advance the grid's
        stamp when its camera stood still; False when it was paired before a reset (neither).

        Raises:
            FrameRejectedError: a frame that cannot be used (under its reason).
            ValueError: the TSDF refused it.
        """
        depth, intrinsics, pose = decode_frame(frame)
        joints = None if frame.joints is None else list(frame.joints.position)
        with self.lock:
            fuse = frame.generation != self.generation or self._still.should_fuse(pose, joints)
            if not fuse:  # the camera stood still: the grid is as current as this frame
                self._newest_stamp_ns = max(self._newest_stamp_ns, frame.stamp_ns)
                self.dirty = True
                self._counts["skipped_still"] += 1
                return True
        if self._self_filter is not None:
            depth = self._filter_arm(frame, depth, intrinsics, pose)
        with self.lock:
            if frame.generation != self.generation:
                return False
            self.tsdf.integrate(depth, intrinsics, pose, depth_max=self._depth_max_m)
            self._ternary = None
            self._newest_stamp_ns = max(self._newest_stamp_ns, frame.stamp_ns)
            self.dirty = True
        self._counts["integrated"] += 1
        return True

    def _filter_arm(
        self, frame: PairedFrame, depth: np.ndarray, intrinsics: Intrinsics, pose: np.ndarray
    ) -> np.ndarray:
        """``depth`` without the pixels that see the arm at the frame's joint states.

        Raises:
            FrameRejectedError: joint states with unknown or missing joints, or bad positions.
        """
        assert self._self_filter is not None
        try:
            q = self._self_filter.robot.joint_state_configuration(list(frame.joints.name), list(frame.joints.position))
        except ValueError as exc:
            raise FrameRejectedError(DropReason.BAD_JOINT_STATES, str(exc)) from exc
        filtered = self._self_filter.filter(depth, q, intrinsics, pose)
        self._counts["self_filtered_pixels"] += int(np.count_nonzero(depth > 0) - np.count_nonzero(filtered > 0))
        return filtered

    def grid(self) -> tuple[np.ndarray, int]:
        """The ternary grid and the stamp of the newest frame in it, now handed out: not
        :attr:`dirty`, and the next grid due in ``grid_period_s``."""
        with self.lock:
            if self._ternary is None:  # else only the stamp is new (frames of a still camera skipped)
                self._ternary = self.tsdf.ternary()
            self.dirty = False
            self.next_grid = time.monotonic() + self._grid_period_s
            return self._ternary, self._newest_stamp_ns

    def reset(self) -> None:
        """Every cell unknown again, and an all-unknown grid stamped 0 due at once (caller holds
        :attr:`lock`, and bumps :attr:`generation` under the lock of the frames waiting)."""
        self.tsdf.reset()
        self._still.reset()
        self._ternary = None
        self._newest_stamp_ns = 0
        self.dirty = True
        self.next_grid = 0.0

    def save(self, path: Path) -> str:
        """Write the grid to ``path`` (``.npz``: :meth:`TsdfIntegrator.save`); what was saved.

        Raises:
            OSError: it cannot be written.
        """
        with self.lock:
            grid = self.tsdf.save(path)
            frames = self.tsdf.stats.frames
        labels = (("unknown", UNKNOWN), ("empty", EMPTY), ("occupied", OCCUPIED))
        counts = {name: int(np.count_nonzero(grid == value)) for name, value in labels}
        return f"saved {path.resolve()} ({frames} frame(s); {counts})"

    def save_mesh(self, path: Path) -> str:
        """Write the TSDF's surface (marching cubes, world metres) to ``path`` as a binary PLY
        mesh; what was saved.

        Raises:
            OSError: it cannot be written.
        """
        with self.lock:
            vertices, triangles = self.tsdf.mesh()
            frames = self.tsdf.stats.frames
        write_ply(path, vertices, triangles)
        return f"saved {path.resolve()} ({frames} frame(s); {len(vertices)} vertices, {len(triangles)} triangles)"
