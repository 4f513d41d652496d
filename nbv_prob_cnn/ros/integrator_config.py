"""The parameters of the ``integrator`` node (:mod:`nbv_prob_cnn.ros.integrator`): its config
dataclass, which ``docs/nodes.md`` and ``nbv node integrator --help`` are generated from."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nbv_prob_cnn.arm.robot_scene import BODIES
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.perception.frame_fusion import FrameFusion
from nbv_prob_cnn.perception.still_frames import StillFrameFilter
from nbv_prob_cnn.perception.tsdf import (
    DEFAULT_EMPTY_MARGIN_VOXELS,
    DEFAULT_ORIGIN_M,
    DEFAULT_SHAPE,
    DEFAULT_TRUNC_VOXELS,
    DEFAULT_VOXEL_M,
    TsdfIntegrator,
)
from nbv_prob_cnn.ros.parameters import param
from nbv_prob_cnn.ros.qos import RELIABILITY
from nbv_prob_cnn.ros.robot_params import RobotParams
from nbv_prob_cnn.ros.tf_listener import POSE_SOURCES

if TYPE_CHECKING:
    from nbv_prob_cnn.arm.self_filter import RobotSelfFilter


def _check_origin(value) -> None:
    """``origin``: 3 finite numbers."""
    if len(value) != 3 or not all(isinstance(v, int | float) and np.isfinite(v) for v in value):
        raise ValueError(f"origin: expected 3 finite numbers [m], got {value!r}")


def _check_shape(value) -> None:
    """``shape``: 3 positive sizes."""
    if len(value) != 3 or min(value) < 1:
        raise ValueError(f"shape: expected 3 positive sizes, got {list(value)}")


@dataclass
class IntegratorConfig(RobotParams):
    """Parameters of ``integrator`` (all fixed after start-up): the robot description (used with
    ``self_filter``), then these."""

    fixed_frame: str = param("world", "frame of the grid: images are posed in it (by TF, or /camera/pose given in it)")
    pose_source: str = param(
        "tf", "where each image's pose comes from: tf (its header.frame_id in fixed_frame at its stamp, from /tf "
        "+ /tf_static) or topic (/camera/pose)", choices=POSE_SOURCES,
    )  # fmt: skip
    origin: list = param([float(v) for v in DEFAULT_ORIGIN_M], "world coordinates [m] of the corner of cell (0, 0, 0)",
                         check=_check_origin)  # fmt: skip
    shape: list = param([int(v) for v in DEFAULT_SHAPE], "grid size [cells] nx, ny, nz", check=_check_shape)
    voxel_size: float = param(DEFAULT_VOXEL_M, "cell edge [m]", min_value=1e-4, max_value=10.0)
    trunc_voxels: float = param(DEFAULT_TRUNC_VOXELS, "TSDF truncation [voxels]", min_value=0.5, max_value=100.0)
    empty_margin_voxels: float = param(
        DEFAULT_EMPTY_MARGIN_VOXELS, "cells farther than this in front of a surface are empty [voxels]",
        min_value=0.0, max_value=100.0,
    )  # fmt: skip
    depth_max_m: float = param(
        3.0, "returns beyond this depth are ignored [m]", min_value=0.01, max_value=100.0, attribute="depth_max"
    )
    refine_pose_icp: bool = param(False, "refine each pose by frame-to-model odometry (slow)")
    device: str = param("CPU:0", "open3d device, e.g. CPU:0 or CUDA:0")
    sync_tolerance_s: float = param(
        0.01, "largest stamp difference of an image and its pose / camera_info [s]", min_value=0.0, max_value=10.0
    )
    pose_timeout_s: float = param(
        1.0, "an image whose pose (TF) / camera_info is missing this long is dropped [s]", min_value=0.0,
        max_value=60.0,
        attribute="pose_timeout",
    )  # fmt: skip
    publish_rate_hz: float = param(
        2.0, "most grids per second; 0 = a grid after every integrated frame", min_value=0.0, max_value=100.0,
        attribute="publish_rate",
    )  # fmt: skip
    cloud_rate_hz: float = param(
        1.0, "most PointCloud2s of the occupied cell centres per second on integrator/occupied_cells (for RViz; "
        "made only while it has a subscriber); 0 = none", min_value=0.0, max_value=100.0,
    )  # fmt: skip
    republish_period_s: float = param(
        1.0, "publish the latest grid again when unchanged this long while a volatile subscriber listens (it "
        "gets the current grid within this period; same header stamp); 0 = never", min_value=0.0,
        max_value=3600.0,
    )  # fmt: skip
    drop_when_behind: bool = param(
        True, "when integration falls behind, only the newest waiting frame is kept (false: all, in order)"
    )
    diagnostics_period_s: float = param(
        1.0, "period of the drop counts on /diagnostics [s]", min_value=0.05, max_value=3600.0,
        attribute="diagnostics_period",
    )  # fmt: skip
    queue_size: int = param(5, "depth of the camera subscriptions", min_value=1, max_value=10000)
    qos_reliability: str = param(
        "best_effort", "camera subscriptions: best_effort (SENSOR_DATA, as drivers publish) or reliable "
        "(lossless bag replays)", choices=RELIABILITY,
    )  # fmt: skip
    self_filter: bool = param(
        False, "remove the pixels that see the arm (self_filter_bodies at the joint_states nearest to each frame, "
        "robot description parameters) before integration; frames without joint states are dropped",
    )  # fmt: skip
    self_filter_bodies: str = param(
        "both", "self-filter: URDF geometry rendered (both = collision and visual, which the collision meshes "
        "do not enclose everywhere)", choices=BODIES,
    )  # fmt: skip
    self_filter_tolerance_m: float = param(
        0.02, "self-filter: a return this much in front of the rendered arm still counts as the arm [m]",
        min_value=0.0, max_value=1.0,
    )  # fmt: skip
    still_frames_fused: int = param(
        0, "frames fused per still camera pose (static scene): later frames from the same pose (and joint "
        "positions with the self-filter) are skipped, counted as skipped_still, and advance the grid's stamp; "
        "0 = fuse every frame", min_value=0, max_value=1000000,
    )  # fmt: skip
    still_translation_m: float = param(
        5e-4, "still camera: largest camera displacement from the pose's first frame [m]", min_value=0.0,
        max_value=1.0,
    )  # fmt: skip
    still_rotation_deg: float = param(
        0.1, "still camera: largest camera rotation from the pose's first frame [deg]", min_value=0.0,
        max_value=180.0,
    )  # fmt: skip
    still_joint_rad: float = param(
        1e-3, "still camera with the self-filter: largest joint difference from the pose's first frame [rad]",
        min_value=0.0, max_value=10.0,
    )  # fmt: skip

    def grid_geometry(self) -> GridGeometry:
        """The grid's box: ``origin``, ``voxel_size`` and ``shape``."""
        x0, y0, z0 = (float(v) for v in self.origin)  # 3 of each: checked by the parameters
        nx, ny, nz = (int(v) for v in self.shape)
        return GridGeometry((x0, y0, z0), float(self.voxel_size), (nx, ny, nz))

    def frame_fusion(self, counts: dict[str, int], self_filter: RobotSelfFilter | None = None) -> FrameFusion:
        """An empty TSDF of :meth:`grid_geometry` and the fusion of frames into it (grids at most
        ``publish_rate_hz``, still frames skipped by the ``still_*`` parameters; ``counts`` and
        ``self_filter`` as :class:`FrameFusion` takes them)."""
        geometry = self.grid_geometry()
        nx, ny, nz = geometry.shape
        tsdf = TsdfIntegrator(
            origin_m=np.array(geometry.origin),
            shape_cells=(nx, ny, nz),
            voxel_size_m=self.voxel_size,
            trunc_voxels=self.trunc_voxels,
            empty_margin_voxels=self.empty_margin_voxels,
            device=self.device,
            refine_pose_icp=self.refine_pose_icp,
        )
        still = StillFrameFilter(
            self.still_frames_fused, self.still_translation_m, math.radians(self.still_rotation_deg),
            self.still_joint_rad,
        )  # fmt: skip
        rate = self.publish_rate_hz
        return FrameFusion(tsdf, still, counts, self.depth_max_m, 1.0 / rate if rate > 0 else 0.0, self_filter)
