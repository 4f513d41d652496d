"""``integrator``: TSDF fusion of posed depth frames into the ternary grid ``/nbv/grid`` (docs/method.md:
grids, node graph).

Subscribes ``/camera/depth/image`` (``32FC1`` metres or ``16UC1`` millimetres; 0/NaN = no return)
and ``/camera/depth/camera_info`` and pairs them by header stamp (± ``sync_tolerance_s``). Each
image is posed, by ``pose_source``:

* ``tf`` (default): by TF (``/tf`` + ``/tf_static``, :class:`~nbv_prob_cnn.ros.tf_listener.TfListener`:
  tf2_ros where it imports), the pose of the image's ``header.frame_id`` (the camera's optical
  frame, as a driver stamps it) in ``fixed_frame`` at the image's stamp, interpolated between the
  TF samples around it. An image whose transform is not there yet (TF arrives after the image)
  is held and retried (every 20 ms) for up to ``pose_timeout_s``, then dropped and counted
  under the TF failure of its last try: ``tf_unknown_frame``, ``tf_not_connected`` or
  ``tf_extrapolation`` (the log names the frame or the time gap).
* ``topic``: ``/camera/pose`` (``TransformStamped``, ``fixed_frame`` -> camera optical frame),
  paired with the image by stamp like camera_info (recorded bags, ``bag_replay``).
A paired frame is fused by :class:`~nbv_prob_cnn.perception.TsdfIntegrator` in a worker thread,
so the subscription callbacks only decode headers and never wait for an integration.

Publishes ``/nbv/grid`` (``nbv_prob_cnn_msgs/VoxelGrid``, reliable + transient local, depth 1:
late joiners with transient local durability get the latest grid at once; and while the grid has
not changed for ``republish_period_s`` and a volatile subscriber listens, the latest grid is
published again (same header: a new grid is one with a new stamp), so a subscriber with the
default QoS (volatile) also gets the current grid within that period),
at most ``publish_rate_hz`` times a second, whenever a frame
was integrated since the last grid. ``header.stamp`` is the stamp of the newest integrated frame,
so a client that moved the camera and got frame stamp ``T`` waits for a grid stamped ``>= T``
(an all-unknown grid stamped 0 follows a reset).

With ``self_filter:=true`` the node also subscribes ``joint_states`` (``sensor_msgs/JointState``,
e.g. from ``arm_sim``), pairs each image with the joint state nearest to its stamp (± the same
tolerance) and zeroes the pixels that see the arm before integration
(:class:`~nbv_prob_cnn.arm.self_filter.RobotSelfFilter`: the ``self_filter_bodies`` of the robot
description parameters ``urdf_path``, ``base_xyz``, ... rendered at that joint state); a frame
is never integrated unfiltered: without a joint state in time it is dropped as
``no_joint_states``, with joint states naming unknown or missing joints (or non-finite
positions) as ``bad_joint_states`` (the log names the joints).

No frame is dropped silently: every frame that cannot be used is counted under its reason
(:class:`~nbv_prob_cnn.perception.messages.DropReason`: ``bad_message``, ``bad_encoding`` (not
REP-118), ``size_mismatch`` (image data vs. its sizes, or image vs. camera_info),
``non_finite_pose`` (NaN/inf or zero quaternion), ``pose_frame`` (pose not in ``fixed_frame``),
``no_pose`` / ``no_camera_info`` / ``no_joint_states`` (nothing within the tolerance before
``pose_timeout_s``), ``tf_unknown_frame`` / ``tf_not_connected`` / ``tf_extrapolation``
(``pose_source:=tf``), ``bad_joint_states``,
``too_many_pending``, ``behind``, ``reset``, ``integration_error``), logged (at most every 5 s
per reason) and reported on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray`` every
``diagnostics_period_s``, status ``<node>: depth frames``: ERROR when frames were dropped in the
last period for bad input or a failure (the reasons logged as errors: ``bad_message``,
``bad_encoding``, ``size_mismatch``, ``non_finite_pose``, ``bad_joint_states``,
``integration_error``), WARN for the other reasons, OK otherwise; one key per reason)
and by ``/integrator/diagnostics`` (``std_srvs/Trigger``: ``success`` says that the call worked,
``message`` is a JSON object with the counts and the last drop's text per reason).
The node keeps running. When integration falls behind, ``drop_when_behind`` (default)
keeps only the newest waiting frame; with ``drop_when_behind:=false``
every paired frame is integrated in stamp order (deterministic: a bag replayed this way gives the
same grid as ``nbv integrate`` on the bag, provided the subscriptions lose nothing either: use
``qos_reliability:=reliable`` (the default is SENSOR_DATA: best effort, ``queue_size`` 5), and
reliable QoS keeps only the newest ``queue_size`` messages per topic that the node has not taken
yet, so a replay much faster than real time needs ``queue_size`` at least the burst).

With ``still_frames_fused:=N`` (N > 0; default 0, every frame) a camera that stands still (an
arm waiting for its next view) costs little: of the frames taken from one pose (within
``still_translation_m`` and ``still_rotation_deg`` of the first, and with the self-filter the same
joint positions within ``still_joint_rad``) the first N are fused and the rest skipped
(:class:`~nbv_prob_cnn.perception.still_frames.StillFrameFilter`), counted as ``skipped_still``
(not a drop), in a static scene they would not change the grid. A skipped frame still advances
the grid's stamp (the grid is published again, unchanged, with the newer stamp), so a client
waiting for a grid that includes frame ``T`` is not kept waiting. Leave it at 0 for scenes that
move and for replays that must give ``nbv integrate``'s grid.

Messages are taken as serialized CDR (raw subscriptions) and decoded and paired by
:mod:`nbv_prob_cnn.perception.messages` (no rclpy), the same code that reads bags offline
(and ~50x faster than rclpy's conversion of a 640x480 image).

Whether the camera's messages reach the node is on ``/diagnostics`` as well: status
``<node>: inputs`` (:class:`~nbv_prob_cnn.ros.readiness.InputReadiness`) turns OK once every
publisher of the image, camera_info (and, by topic, pose) topics is matched and has delivered a
message; from then on every frame the camera publishes is integrated or counted.

Services: ``/integrator/reset`` (``std_srvs/Trigger``, every cell unknown again, waiting frames
discarded) and ``/integrator/save`` (``nbv_prob_cnn_msgs/SaveGrid``: ``.npz`` with keys ``grid``,
``origin``, ``resolution``, ``frames`` written on the node's machine, relative paths from its
working directory) and ``/integrator/save_mesh`` (``SaveGrid``: the TSDF's surface by marching
cubes, world metres, as a binary ``.ply`` mesh). ``/integrator/occupied_cells``
(``sensor_msgs/PointCloud2``, the occupied cell centres, for RViz) follows the grids at most
``cloud_rate_hz`` times a second, and only while someone subscribes.

Run: ``nbv node integrator --ros-args -p publish_rate_hz:=2.0``
"""

from __future__ import annotations

import bisect
import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import TransformStamped
from nbv_prob_cnn_msgs.msg import VoxelGrid
from nbv_prob_cnn_msgs.srv import SaveGrid
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState, PointCloud2
from std_srvs.srv import Trigger

from nbv_prob_cnn.arm.joint_states import JointStateMerger
from nbv_prob_cnn.arm.robot_scene import BODIES
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN
from nbv_prob_cnn.perception.messages import (
    ENCODINGS,
    MAX_PENDING,
    MSG_CAMERA_INFO,
    MSG_IMAGE,
    MSG_JOINT_STATE,
    MSG_TRANSFORM,
    DropCounts,
    DropReason,
    FrameRejectedError,
    PairedFrame,
    StampSync,
    decode_frame,
    pose_to_transform_msg,
    stamp_of,
    typestore,
)
from nbv_prob_cnn.perception.still_frames import StillFrameFilter
from nbv_prob_cnn.perception.surfaces import write_ply
from nbv_prob_cnn.perception.tf_buffer import TransformError
from nbv_prob_cnn.perception.tsdf import (
    DEFAULT_EMPTY_MARGIN_VOXELS,
    DEFAULT_ORIGIN_M,
    DEFAULT_SHAPE,
    DEFAULT_TRUNC_VOXELS,
    DEFAULT_VOXEL_M,
    TsdfIntegrator,
)
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import grid_to_msg, time_msg
from nbv_prob_cnn.ros.occupied_cloud import occupied_cloud_msg
from nbv_prob_cnn.ros.parameters import declare_config, param
from nbv_prob_cnn.ros.qos import GRID_QOS, RELIABILITY, lost_message_counter, subscription_qos
from nbv_prob_cnn.ros.readiness import InputReadiness
from nbv_prob_cnn.ros.robot_params import RobotParams, merged_joint_state
from nbv_prob_cnn.ros.runtime import run_node
from nbv_prob_cnn.ros.stream_node import StreamNode
from nbv_prob_cnn.ros.tf_listener import POSE_SOURCES, TfListener

NODE_NAME = "integrator"
TOPIC_GRID = names.GRID
SERVICE_RESET = names.INTEGRATOR_RESET
SERVICE_SAVE = names.INTEGRATOR_SAVE
SERVICE_SAVE_MESH = names.INTEGRATOR_SAVE_MESH
TOPIC_OCCUPIED_CELLS = names.INTEGRATOR_OCCUPIED_CELLS
SERVICE_DIAGNOSTICS = names.INTEGRATOR_DIAGNOSTICS
#: The standard diagnostics topic (absolute, as diagnostic_aggregator expects it).
TOPIC_DIAGNOSTICS = names.DIAGNOSTICS
#: Most frames waiting for integration with ``drop_when_behind:=false`` (older ones are dropped beyond it).
MAX_BACKLOG = 1000
#: ``pose_source:=tf``: period of the retries of images whose transform had not arrived [s].
TF_RETRY_PERIOD_S = 0.02
#: The drop reason of an image whose TF lookup failed, by :attr:`TransformError.reason`.
TF_DROP_REASONS = {
    "unknown_frame": DropReason.TF_UNKNOWN_FRAME,
    "not_connected": DropReason.TF_NOT_CONNECTED,
    "extrapolation": DropReason.TF_EXTRAPOLATION,
}
#: Depth of the ``joint_states`` subscription with ``self_filter`` (2 s of a 50 Hz stream).
JOINT_STATES_QUEUE = 100
#: The image rate reported in the diagnostics is measured over the images of this last span [s].
IMAGE_RATE_WINDOW_S = 5.0
#: Re-exported for callers that took them from here.
__all__ = ["ENCODINGS", "Integrator", "PairedFrame", "StampSync", "main"]


def _check_origin(value) -> None:
    if len(value) != 3 or not all(isinstance(v, int | float) and np.isfinite(v) for v in value):
        raise ValueError(f"origin: expected 3 finite numbers [m], got {value!r}")


def _check_shape(value) -> None:
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


class Integrator(Node):
    """Fuses posed depth frames into a ternary grid and publishes it."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = cfg = declare_config(self, IntegratorConfig)  # also sets self.<name> per parameter
        camera_qos = subscription_qos(cfg.queue_size, cfg.qos_reliability)
        origin, shape, voxel, tolerance = cfg.origin, cfg.shape, cfg.voxel_size, cfg.sync_tolerance_s
        x0, y0, z0 = (float(v) for v in origin)  # 3 of each: checked by the parameters
        nx, ny, nz = (int(v) for v in shape)
        self.geometry = GridGeometry((x0, y0, z0), float(voxel), (nx, ny, nz))
        self._tsdf = TsdfIntegrator(
            origin_m=np.array(self.geometry.origin),
            shape_cells=(nx, ny, nz),
            voxel_size_m=voxel,
            trunc_voxels=cfg.trunc_voxels,
            empty_margin_voxels=cfg.empty_margin_voxels,
            device=cfg.device,
            refine_pose_icp=cfg.refine_pose_icp,
        )

        # state shared by the executor threads and the worker: _cv guards the pairing and the queue,
        # _tsdf_lock the integrator and the grid state (never taken while holding _cv)
        self._cv = threading.Condition()
        self._tsdf_lock = threading.Lock()
        # by TF every image gets the pose of its own stamp (0 tolerance: never a neighbour's)
        self._sync = StampSync(round(tolerance * 1e9), require_joints=cfg.self_filter,
                               pose_tolerance_ns=0 if cfg.pose_source == "tf" else None)  # fmt: skip
        self._self_filter = None
        self._joint_merger: JointStateMerger | None = None
        if cfg.self_filter:
            from nbv_prob_cnn.arm.robot import RobotModel
            from nbv_prob_cnn.arm.self_filter import RobotSelfFilter

            robot = RobotModel(cfg.robot_config(self))
            self._self_filter = RobotSelfFilter(robot, cfg.self_filter_bodies, cfg.self_filter_tolerance_m)
            self._joint_merger = JointStateMerger(robot.joint_names)  # arm and gripper may come separately
        self._still = StillFrameFilter(
            cfg.still_frames_fused, cfg.still_translation_m, math.radians(cfg.still_rotation_deg), cfg.still_joint_rad
        )
        self._ternary: np.ndarray | None = None  # the grid as last published, while nothing was fused since
        self._queue: deque[PairedFrame] = deque()
        self._integrating = 0  # frames the worker took from the queue and has not finished (0 or 1)
        self._image_times: deque[float] = deque()  # arrival times (monotonic) of the last images
        self.lost_in_transport: dict[str, int] = {}  # topic -> messages DDS reported lost before delivery
        self._generation = 0
        self._stop = False
        self._dirty = False
        self._newest_stamp_ns = 0
        self._next_publish = 0.0
        self.counts = dict.fromkeys(("images", "integrated", "skipped_still", "grids", "grids_republished"), 0)
        if cfg.self_filter:
            self.counts["self_filtered_pixels"] = 0
        self.drops = DropCounts()  # every frame not integrated is counted here under its reason
        self._drops_reported: dict[str, int] = {}  # reason -> drops published on /diagnostics so far
        self._error_reasons: set[str] = set()  # reasons of drops that were errors (bad input, a failure)
        self._last_drop_log: dict[DropReason, float] = {}
        self._last_drop_text: dict[str, str] = {}  # reason -> why its last frame was dropped
        self._store = typestore()

        self._grid_pub = self.create_publisher(VoxelGrid, TOPIC_GRID, GRID_QOS)
        self._cloud_pub = self.create_publisher(PointCloud2, TOPIC_OCCUPIED_CELLS, 1)
        self._next_cloud = 0.0
        inputs = MutuallyExclusiveCallbackGroup()
        services = MutuallyExclusiveCallbackGroup()
        image, info, pose = (
            self.resolve_topic_name(n) for n in (names.DEPTH_IMAGE, names.CAMERA_INFO, names.CAMERA_POSE)
        )
        #: ``/diagnostics`` ``<node>: inputs``: OK once every camera publisher's messages arrive
        self.inputs = InputReadiness(
            self, [image, info] if cfg.pose_source == "tf" else [image, info, pose], callback_group=services
        )
        self.create_subscription(
            Image, names.DEPTH_IMAGE, self._counted(image, self._on_image), camera_qos, callback_group=inputs,
            raw=True, event_callbacks=self._input_events(names.DEPTH_IMAGE, image),
        )  # fmt: skip
        self.create_subscription(
            CameraInfo, names.CAMERA_INFO, self._counted(info, self._on_info), camera_qos, callback_group=inputs,
            raw=True, event_callbacks=self._input_events(names.CAMERA_INFO, info),
        )  # fmt: skip
        # /tf and joint_states come at the robot's rate: a side node with its own thread, where they are used
        self._streams = StreamNode(self) if cfg.pose_source == "tf" or cfg.self_filter else None
        self._tf: TfListener | None = None
        self._tf_errors: dict[int, TransformError] = {}  # image stamp -> why its last TF lookup failed
        if cfg.pose_source == "tf":
            if not cfg.fixed_frame:
                raise ValueError("fixed_frame must not be empty")
            assert self._streams is not None  # made for pose_source tf
            self._tf = TfListener(self._streams.node)
            # runs only while an image waits for its transform (a 50 Hz timer wakes the executor for nothing)
            self._tf_retry = self.create_timer(TF_RETRY_PERIOD_S, self._on_tf_retry_timer, callback_group=inputs)
            self._tf_retry.cancel()
        else:
            self.create_subscription(
                TransformStamped, names.CAMERA_POSE, self._counted(pose, self._on_pose), camera_qos,
                callback_group=inputs, raw=True, event_callbacks=self._input_events(names.CAMERA_POSE, pose),
            )  # fmt: skip
        if cfg.self_filter:
            # the filter needs the joint state of each frame's stamp: keep a few seconds of them (they are small)
            joints_qos = subscription_qos(max(cfg.queue_size, JOINT_STATES_QUEUE), cfg.qos_reliability)
            assert self._streams is not None  # made for self_filter
            self._streams.node.create_subscription(
                JointState, names.JOINT_STATES, self._on_joints, joints_qos, raw=True
            )
        self.create_timer(0.1, self._on_expire_timer, callback_group=inputs)
        self.create_service(Trigger, SERVICE_RESET, self._on_reset, callback_group=services)
        self.create_service(SaveGrid, SERVICE_SAVE, self._on_save, callback_group=services)
        self.create_service(SaveGrid, SERVICE_SAVE_MESH, self._on_save_mesh, callback_group=services)
        self.create_service(Trigger, SERVICE_DIAGNOSTICS, self._on_diagnostics, callback_group=services)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self.create_timer(cfg.diagnostics_period_s, self._publish_diagnostics, callback_group=services)
        self._last_grid: VoxelGrid | None = None  # the latest grid published, and when (time.monotonic)
        self._last_grid_at = 0.0
        if cfg.republish_period_s > 0:
            self.create_timer(min(cfg.republish_period_s, 0.25), self._on_republish_timer, callback_group=services)
        self._worker = threading.Thread(target=self._work, name="tsdf_worker", daemon=True)
        self._worker.start()
        poses = f"by TF ({self._tf.backend})" if self._tf else f"from {names.CAMERA_POSE}"
        self.get_logger().info(
            f"grid {self.geometry.shape} voxel {voxel:g} m origin {list(self.geometry.origin)} "
            f"in {cfg.fixed_frame!r}; poses {poses}; sync ±{tolerance:g} s, publish <= {cfg.publish_rate_hz:g} Hz, "
            f"drop_when_behind={cfg.drop_when_behind}"
            + (f"; self-filter: {cfg.self_filter_bodies} bodies" if self._self_filter else "")
        )

    # -------------------------------------------------------------- callbacks
    def _input_events(self, name: str, topic: str) -> SubscriptionEventCallbacks:
        """The events of camera input ``name`` (resolved: ``topic``): DDS losses counted under
        ``name``, matches tracked by :attr:`inputs`."""
        return self.inputs.events(topic, lost_message_counter(self, self.lost_in_transport, name))

    def _counted(self, topic: str, callback: Callable[[bytes], None]) -> Callable[[bytes], None]:
        """``callback`` that first tells :attr:`inputs` that a message of ``topic`` arrived."""

        def on_message(raw: bytes) -> None:
            self.inputs.received(topic)
            callback(raw)

        return on_message

    def _drop(self, reason: DropReason, text: str, n: int = 1, error: bool = False) -> None:
        """Count ``n`` dropped frames under ``reason`` and log why (at most every 5 s per reason)."""
        self.drops.add(reason, n)
        self._last_drop_text[reason.value] = text
        if error:
            self._error_reasons.add(reason.value)
        now = time.monotonic()
        if now - self._last_drop_log.get(reason, -np.inf) < 5.0:
            return
        self._last_drop_log[reason] = now
        text = f"{text} ({self.drops.counts[reason.value]} dropped for {reason.value} so far)"
        if error:
            self.get_logger().error(text)
        else:
            self.get_logger().warning(text)

    def _decode(self, raw: bytes, msgtype: str, topic: str) -> Any | None:
        try:
            return self._store.deserialize_cdr(raw, msgtype)
        except Exception as exc:  # malformed CDR from a foreign publisher
            self._drop(DropReason.BAD_MESSAGE, f"{topic}: cannot decode a {msgtype} ({exc}); dropped", error=True)
            return None

    def _on_image(self, raw: bytes) -> None:
        msg = self._decode(raw, MSG_IMAGE, names.DEPTH_IMAGE)
        if msg is None:
            return
        stamp = stamp_of(msg)
        with self._cv:  # counted under the pairing's lock: never seen received but not yet pending
            self.counts["images"] += 1
            now = time.monotonic()
            self._image_times.append(now)
            while self._image_times and self._image_times[0] < now - IMAGE_RATE_WINDOW_S:
                self._image_times.popleft()
        if msg.encoding not in ENCODINGS:
            self._drop(
                DropReason.BAD_ENCODING,
                f"image stamped {stamp * 1e-9:.3f}: unsupported encoding {msg.encoding!r} "
                f"(expected one of {', '.join(ENCODINGS)}, REP-118); dropped",
                error=True,
            )
            return
        with self._cv:
            if self._tf is not None:
                self._enqueue(self._pose_by_tf(stamp, msg.header.frame_id))
            frames, overflow = self._sync.add_image(stamp, msg, time.monotonic())
            self._enqueue(frames)
        if overflow:
            self._drop(
                DropReason.TOO_MANY_PENDING,
                f"{len(overflow)} image(s) dropped: more than {MAX_PENDING} waiting for their pose",
                n=len(overflow),
            )

    def _on_info(self, raw: bytes) -> None:
        msg = self._decode(raw, MSG_CAMERA_INFO, names.CAMERA_INFO)
        if msg is not None:
            with self._cv:
                self._enqueue(self._sync.add_info(stamp_of(msg), msg))

    def _on_pose(self, raw: bytes) -> None:
        msg = self._decode(raw, MSG_TRANSFORM, names.CAMERA_POSE)
        if msg is None:
            return
        if msg.header.frame_id != self.config.fixed_frame:
            self._drop(
                DropReason.POSE_FRAME,
                f"pose in frame {msg.header.frame_id!r}, expected the grid frame {self.config.fixed_frame!r} "
                "(pose_source:=tf looks poses up in any frame); ignored",
            )
            return
        with self._cv:
            self._enqueue(self._sync.add_pose(stamp_of(msg), msg))

    def _pose_by_tf(self, stamp: int, frame: str) -> list[PairedFrame]:
        """``pose_source:=tf``: add the TF pose of image frame ``frame`` in ``fixed_frame`` at
        ``stamp`` to the pairing and return the frames it completes (caller holds ``_cv``); when
        the transform is not available (yet) none, and the error is kept for the drop report."""
        assert self._tf is not None
        try:
            if not frame:
                raise TransformError("the image has no header.frame_id (its optical frame) to look up in TF")
            matrix, _ = self._tf.lookup(self.config.fixed_frame, frame, stamp)
        except TransformError as exc:
            self._tf_errors[stamp] = exc
            if self._tf_retry.is_canceled():
                self._tf_retry.reset()
            return []
        self._tf_errors.pop(stamp, None)
        return self._sync.add_pose(stamp, pose_to_transform_msg(matrix, stamp, self.config.fixed_frame, frame))

    def _on_tf_retry_timer(self) -> None:
        """Retry the TF lookup of every image still waiting for its pose."""
        with self._cv:
            waiting = {stamp: msg for stamp, (msg, _) in self._sync.images.items()}
            for stamp in list(self._tf_errors):
                if stamp not in waiting:
                    del self._tf_errors[stamp]  # paired, expired or reset
            for stamp in sorted(stamp for stamp in waiting if stamp in self._tf_errors):
                self._enqueue(self._pose_by_tf(stamp, waiting[stamp].header.frame_id))
            if not self._tf_errors:
                self._tf_retry.cancel()  # nothing waits: until the next lookup that fails

    def _on_joints(self, raw: bytes) -> None:
        msg = self._decode(raw, MSG_JOINT_STATE, names.JOINT_STATES)
        if msg is not None and self._joint_merger is not None:
            msg = merged_joint_state(self._joint_merger, msg)  # None until every joint has arrived once
        if msg is not None:
            with self._cv:
                self._enqueue(self._sync.add_joints(stamp_of(msg), msg))

    def _on_expire_timer(self) -> None:
        with self._cv:
            dropped = self._sync.expire(time.monotonic(), self.config.pose_timeout_s)
            tf_errors = {stamp: self._tf_errors.pop(stamp) for stamp, _, _ in dropped if stamp in self._tf_errors}
        for stamp, reason, text in dropped:
            error = tf_errors.get(stamp)
            if error is not None and reason == DropReason.NO_POSE:
                reason = TF_DROP_REASONS.get(error.reason, DropReason.TF_UNKNOWN_FRAME)
                text = f"no transform from {self.config.fixed_frame!r} in TF: {error}"
            self._drop(
                reason, f"image stamped {stamp * 1e-9:.3f} dropped: {text} after {self.config.pose_timeout_s:g} s"
            )

    def diagnostics(self) -> dict[str, Any]:
        """Frame counts, drops per reason and the last drop's text per reason (what ``/diagnostics``
        and the service report); ``pending``: images received and neither integrated nor dropped
        yet (waiting for their pose / camera_info, queued or being integrated);
        ``image_rate_hz``: images received per second over the last few seconds (compare it with
        the camera's rate: best-effort messages lost on the way are invisible otherwise);
        ``lost_in_transport``: messages per topic that DDS reported lost; ``inputs``: per camera
        topic the publishers in the graph, those the subscription matched and the messages
        received (:meth:`InputReadiness.snapshot`: a replay waits for ``matched`` before it starts)."""
        with self._cv:
            pending = len(self._sync.images) + len(self._queue) + self._integrating
            times = list(self._image_times)
        span = times[-1] - times[0] if len(times) > 1 else 0.0
        return {
            **self.counts,
            "pending": pending,
            "image_rate_hz": round((len(times) - 1) / span, 3) if span > 0 else 0.0,
            "lost_in_transport": dict(self.lost_in_transport),
            "dropped": self.drops.as_dict(),
            "dropped_total": self.drops.total(),
            "last_drop": dict(self._last_drop_text),
            "inputs": self.inputs.snapshot(),
        }

    def _publish_diagnostics(self) -> None:
        if not self.context.ok():
            return
        report = self.diagnostics()
        new = {k: n - self._drops_reported.get(k, 0) for k, n in report["dropped"].items()}
        new = {k: n for k, n in new.items() if n}
        self._drops_reported = dict(report["dropped"])
        level = DiagnosticStatus.OK
        if new:
            level = DiagnosticStatus.ERROR if self._error_reasons & set(new) else DiagnosticStatus.WARN
        reasons = ", ".join(f"{k} {n}" for k, n in new.items())
        status = DiagnosticStatus(
            level=level,
            name=f"{self.get_fully_qualified_name()}: depth frames",
            message=f"{sum(new.values())} frame(s) dropped in the last period ({reasons})" if new else "integrating",
            hardware_id=self.config.fixed_frame,
        )
        values = {k: v for k, v in report.items() if k not in ("dropped", "last_drop", "lost_in_transport", "inputs")}
        values.update({f"lost_in_transport_{k}": v for k, v in report["lost_in_transport"].items()})
        values.update({f"dropped_{k}": v for k, v in report["dropped"].items()})
        values.update({f"last_drop_{k}": v for k, v in report["last_drop"].items()})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(array)

    def _on_diagnostics(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """``success``: the call worked (always; drops are in the report, not a failed call);
        ``message``: the JSON of :meth:`diagnostics`."""
        response.success = True
        response.message = json.dumps(self.diagnostics(), sort_keys=True)
        return response

    def _enqueue(self, frames: list[PairedFrame]) -> None:
        """Queue paired frames for the worker (caller holds ``_cv``)."""
        if not frames:
            return
        dropped = 0
        for frame in frames:
            frame.generation = self._generation
            if self.config.drop_when_behind:
                dropped += len(self._queue)
                self._queue.clear()
                self._queue.append(frame)
            else:
                index = bisect.bisect_right([f.stamp_ns for f in self._queue], frame.stamp_ns)
                self._queue.insert(index, frame)
                while len(self._queue) > MAX_BACKLOG:
                    self._queue.popleft()
                    dropped += 1
        self._cv.notify_all()
        if dropped:
            self._drop(DropReason.BEHIND, f"integration is behind: {dropped} frame(s) dropped (newest wins)", n=dropped)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self._tsdf_lock:
            self._tsdf.reset()
            self._still.reset()
            self._ternary = None
            with self._cv:
                discarded = len(self._queue) + len(self._sync.images)  # queued, or waiting for their pose
                self._queue.clear()
                self._sync.images.clear()
                self._generation += 1
                self._cv.notify_all()
            self._newest_stamp_ns = 0
            self._dirty = True
            self._next_publish = 0.0
        if discarded:
            self._drop(DropReason.RESET, f"reset: {discarded} waiting frame(s) discarded", n=discarded)
        response.success = True
        response.message = f"grid reset to unknown ({discarded} waiting frame(s) discarded)"
        self.get_logger().info(response.message)
        return response

    def _on_save(self, request: SaveGrid.Request, response: SaveGrid.Response) -> SaveGrid.Response:
        path = Path(request.path).expanduser()
        if not request.path:
            response.success, response.message = False, "path is empty"
            return response
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        if not path.parent.is_dir():
            response.success, response.message = False, f"{path.parent}: no such directory"
            return response
        try:
            with self._tsdf_lock:
                grid = self._tsdf.save(path)
                frames = self._tsdf.stats.frames
        except OSError as exc:
            response.success, response.message = False, f"{path}: cannot write ({exc})"
            return response
        counts = {name: int(np.count_nonzero(grid == value)) for name, value in self._labels()}
        response.success = True
        response.message = f"saved {path.resolve()} ({frames} frame(s); {counts})"
        self.get_logger().info(response.message)
        return response

    def _on_save_mesh(self, request: SaveGrid.Request, response: SaveGrid.Response) -> SaveGrid.Response:
        """The TSDF's surface (marching cubes, world metres) as a binary PLY mesh at ``request.path``."""
        path = Path(request.path).expanduser()
        if not request.path:
            response.success, response.message = False, "path is empty"
            return response
        if path.suffix.lower() != ".ply":
            path = path.with_name(path.name + ".ply")
        if not path.parent.is_dir():
            response.success, response.message = False, f"{path.parent}: no such directory"
            return response
        with self._tsdf_lock:
            vertices, triangles = self._tsdf.mesh()
            frames = self._tsdf.stats.frames
        try:
            write_ply(path, vertices, triangles)
        except OSError as exc:
            response.success, response.message = False, f"{path}: cannot write ({exc})"
            return response
        response.success = True
        response.message = (
            f"saved {path.resolve()} ({frames} frame(s); {len(vertices)} vertices, {len(triangles)} triangles)"
        )
        self.get_logger().info(response.message)
        return response

    @staticmethod
    def _labels():
        return (("unknown", UNKNOWN), ("empty", EMPTY), ("occupied", OCCUPIED))

    # ----------------------------------------------------------------- worker
    def _work(self) -> None:
        while True:
            with self._cv:
                while not self._stop and not self._queue:
                    if self._dirty:
                        remaining = self._next_publish - time.monotonic()
                        if remaining <= 0:
                            break
                        self._cv.wait(remaining)
                    else:
                        self._cv.wait(0.5)
                if self._stop:
                    return
                frame = self._queue.popleft() if self._queue else None
                self._integrating = int(frame is not None)
            try:
                if frame is not None:
                    self._integrate(frame)
            except Exception as exc:  # keep serving: report and go on with the next frame
                self._drop(DropReason.INTEGRATION_ERROR, f"worker: {type(exc).__name__}: {exc}", error=True)
            finally:
                with self._cv:
                    self._integrating = 0
            try:
                if self._dirty and time.monotonic() >= self._next_publish:
                    self._publish_grid()
            except Exception as exc:  # keep serving: report and go on with the next frame
                self.get_logger().error(f"worker: {type(exc).__name__}: {exc}", throttle_duration_sec=5.0)

    def _integrate(self, frame: PairedFrame) -> None:
        try:
            depth, intrinsics, pose = decode_frame(frame)
            joints = None if frame.joints is None else list(frame.joints.position)
            with self._tsdf_lock:
                fuse = frame.generation != self._generation or self._still.should_fuse(pose, joints)
                if not fuse:  # the camera stood still: the grid is as current as this frame
                    self._newest_stamp_ns = max(self._newest_stamp_ns, frame.stamp_ns)
                    self._dirty = True
                    self.counts["skipped_still"] += 1
                    return
            if self._self_filter is not None:
                depth = self._filter_arm(frame, depth, intrinsics, pose)
            with self._tsdf_lock:
                if frame.generation != self._generation:
                    self.drops.add(DropReason.RESET)  # queued before a reset
                    return
                self._tsdf.integrate(depth, intrinsics, pose, depth_max=self.config.depth_max_m)
                self._ternary = None
                self._newest_stamp_ns = max(self._newest_stamp_ns, frame.stamp_ns)
                self._dirty = True
        except FrameRejectedError as exc:
            self._drop(exc.reason, f"frame stamped {frame.stamp_ns * 1e-9:.3f} rejected: {exc}", error=True)
            return
        except ValueError as exc:
            self._drop(
                DropReason.INTEGRATION_ERROR, f"frame stamped {frame.stamp_ns * 1e-9:.3f} rejected: {exc}", error=True
            )
            return
        self.counts["integrated"] += 1

    def _filter_arm(self, frame: PairedFrame, depth: np.ndarray, intrinsics, pose: np.ndarray) -> np.ndarray:
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
        self.counts["self_filtered_pixels"] += int(np.count_nonzero(depth > 0) - np.count_nonzero(filtered > 0))
        return filtered

    def _publish_grid(self) -> None:
        if not self.context.ok():
            return  # shutting down (SIGINT): the publisher is no longer usable
        rate = self.config.publish_rate_hz
        with self._tsdf_lock:
            if self._ternary is None:  # else only the stamp is new (frames of a still camera skipped)
                self._ternary = self._tsdf.ternary()
            grid = self._ternary
            stamp_ns = self._newest_stamp_ns
            self._dirty = False
            self._next_publish = time.monotonic() + (1.0 / rate if rate > 0 else 0.0)
        msg = grid_to_msg(grid, self.geometry, self.config.fixed_frame, time_msg(stamp_ns))
        self._grid_pub.publish(msg)
        self._last_grid, self._last_grid_at = msg, time.monotonic()
        self.counts["grids"] += 1
        cloud_rate = self.config.cloud_rate_hz
        if cloud_rate > 0 and time.monotonic() >= self._next_cloud and self._cloud_pub.get_subscription_count() > 0:
            self._next_cloud = time.monotonic() + 1.0 / cloud_rate
            self._cloud_pub.publish(
                occupied_cloud_msg(grid, self.geometry.origin, self.geometry.resolution, self.config.fixed_frame,
                                   time_msg(stamp_ns))
            )  # fmt: skip

    def _on_republish_timer(self) -> None:
        """The latest grid again, when unchanged for ``republish_period_s`` and a volatile
        subscriber listens (transient-local ones got it when they matched)."""
        msg = self._last_grid
        if msg is None or not self.context.ok():
            return
        if time.monotonic() - self._last_grid_at < self.config.republish_period_s:
            return
        subscribers = self.get_subscriptions_info_by_topic(self._grid_pub.topic_name)
        if not any(s.qos_profile.durability == DurabilityPolicy.VOLATILE for s in subscribers):
            return
        self._grid_pub.publish(msg)
        self._last_grid_at = time.monotonic()
        self.counts["grids_republished"] += 1

    def destroy_node(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        self._worker.join(timeout=10.0)
        if self._streams is not None:
            self._streams.destroy()
        super().destroy_node()

    def summary(self) -> str:
        dropped = ", ".join(f"{k} {v}" for k, v in self.drops.as_dict().items() if v) or "none"
        return ", ".join(f"{name} {value}" for name, value in self.counts.items()) + f"; dropped: {dropped}"


def main(args: list[str] | None = None) -> int:
    """Run the node until interrupted; 1 on a configuration error."""
    return run_node(Integrator, args, threads=2, summary=lambda node: node.summary())


if __name__ == "__main__":
    raise SystemExit(main())
