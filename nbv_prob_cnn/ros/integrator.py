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
(an all-unknown grid stamped 0 follows a reset). The same grids, compressed
(``nbv_prob_cnn_msgs/CompressedVoxelGrid``, zlib, the same QoS and republishing), go on
``/nbv/grid/compressed``, made only while that topic has a subscriber (as image_transport's
``compressed``): a room-sized grid is 52 MB raw.

With ``self_filter:=true`` the node also subscribes ``joint_states`` (``sensor_msgs/JointState``,
e.g. from ``arm_sim``), pairs each image with the joint state nearest to its stamp (± the same
tolerance) and zeroes the pixels that see the arm before integration
(:class:`~nbv_prob_cnn.arm.self_filter.RobotSelfFilter`: the ``self_filter_bodies`` of the robot
description parameters ``urdf_path``, ``base_xyz``, ... rendered at that joint state); a frame
is never integrated unfiltered: without a joint state in time it is dropped as
``no_joint_states``, with joint states naming unknown or missing joints (or non-finite
positions) as ``bad_joint_states`` (the log names the joints).

No frame is dropped silently: every frame that cannot be used is counted under its reason,
logged (at most every 5 s per reason) and reported on ``/diagnostics`` (status ``<node>: depth
frames``, every ``diagnostics_period_s``) and by ``/integrator/diagnostics`` (``std_srvs/Trigger``:
``message`` is a JSON object with the counts and the last drop's text per reason): the reasons and
the status levels are in :mod:`nbv_prob_cnn.ros.drop_report`. The node keeps running. When
integration falls behind, ``drop_when_behind`` (default) keeps only the newest waiting frame; with
``drop_when_behind:=false`` every paired frame is integrated in stamp order (for a replay that must
give ``nbv integrate``'s grid: :mod:`nbv_prob_cnn.perception.frame_queue`).

With ``still_frames_fused:=N`` (N > 0; default 0, every frame) of the frames a still camera takes
from one pose only the first N are fused, the rest counted as ``skipped_still`` (not a drop) and
still advancing the grid's stamp: :mod:`nbv_prob_cnn.perception.frame_fusion`.

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
``cloud_rate_hz`` times a second, and only while someone subscribes; the latest grid's cloud is
always sent (later, when throttled), and again when a subscriber joins (RViz opened later).

Run: ``nbv node integrator --ros-args -p publish_rate_hz:=2.0``
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TransformStamped
from nbv_prob_cnn_msgs.msg import CompressedVoxelGrid, VoxelGrid
from nbv_prob_cnn_msgs.srv import SaveGrid
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState, PointCloud2
from std_srvs.srv import Trigger

from nbv_prob_cnn.arm.joint_states import JointStateMerger
from nbv_prob_cnn.perception.frame_queue import FrameQueue
from nbv_prob_cnn.perception.messages import (
    ENCODINGS,
    MAX_PENDING,
    MSG_CAMERA_INFO,
    MSG_IMAGE,
    MSG_JOINT_STATE,
    MSG_TRANSFORM,
    DropReason,
    FrameRejectedError,
    PairedFrame,
    StampSync,
    stamp_of,
    typestore,
)
from nbv_prob_cnn.perception.tf_poses import TfPoses
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import compress_grid_msg, grid_to_msg, time_msg
from nbv_prob_cnn.ros.drop_report import DropReport
from nbv_prob_cnn.ros.integrator_config import IntegratorConfig
from nbv_prob_cnn.ros.latest_sent import LatestSent
from nbv_prob_cnn.ros.occupied_cloud import OccupiedCloudOutput
from nbv_prob_cnn.ros.parameters import declare_config
from nbv_prob_cnn.ros.qos import GRID_QOS, lost_message_counter, subscription_qos
from nbv_prob_cnn.ros.readiness import InputReadiness
from nbv_prob_cnn.ros.robot_params import merged_joint_state
from nbv_prob_cnn.ros.runtime import run_node
from nbv_prob_cnn.ros.stream_node import StreamNode
from nbv_prob_cnn.ros.tf_listener import TfListener

NODE_NAME = "integrator"
TOPIC_GRID = names.GRID
SERVICE_RESET = names.INTEGRATOR_RESET
SERVICE_SAVE = names.INTEGRATOR_SAVE
SERVICE_SAVE_MESH = names.INTEGRATOR_SAVE_MESH
TOPIC_OCCUPIED_CELLS = names.INTEGRATOR_OCCUPIED_CELLS
SERVICE_DIAGNOSTICS = names.INTEGRATOR_DIAGNOSTICS
#: The standard diagnostics topic (absolute, as diagnostic_aggregator expects it).
TOPIC_DIAGNOSTICS = names.DIAGNOSTICS
#: ``pose_source:=tf``: period of the retries of images whose transform had not arrived [s].
TF_RETRY_PERIOD_S = 0.02
#: Depth of the ``joint_states`` subscription with ``self_filter`` (2 s of a 50 Hz stream).
JOINT_STATES_QUEUE = 100
#: The image rate reported in the diagnostics is measured over the images of this last span [s].
IMAGE_RATE_WINDOW_S = 5.0
#: Re-exported for callers that took them from here.
__all__ = ["ENCODINGS", "Integrator", "IntegratorConfig", "PairedFrame", "StampSync", "main"]


def save_path(requested: str, suffix: str, any_case: bool = False) -> Path:
    """Where a save service writes ``requested`` (``~`` expanded; relative to the working
    directory): with ``suffix`` appended unless it ends so (in any letter case with ``any_case``).

    Raises:
        ValueError: the path is empty, or its directory does not exist (the message says which).
    """
    path = Path(requested).expanduser()
    if not requested:
        raise ValueError("path is empty")
    if (path.suffix.lower() if any_case else path.suffix) != suffix:
        path = path.with_name(path.name + suffix)
    if not path.parent.is_dir():
        raise ValueError(f"{path.parent}: no such directory")
    return path


class Integrator(Node):
    """Fuses posed depth frames into a ternary grid and publishes it."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = cfg = declare_config(self, IntegratorConfig)  # also sets self.<name> per parameter
        camera_qos = subscription_qos(cfg.queue_size, cfg.qos_reliability)
        self.geometry = cfg.grid_geometry()

        # state shared by the executor threads and the worker: _cv guards the pairing and the queue,
        # self._fusion.lock the TSDF and the grid state (never taken while holding _cv)
        self._cv = threading.Condition()
        # by TF every image gets the pose of its own stamp (0 tolerance: never a neighbour's)
        self._sync = StampSync(round(cfg.sync_tolerance_s * 1e9), require_joints=cfg.self_filter,
                               pose_tolerance_ns=0 if cfg.pose_source == "tf" else None)  # fmt: skip
        self_filter = None
        self._joint_merger: JointStateMerger | None = None
        if cfg.self_filter:
            from nbv_prob_cnn.arm.robot import RobotModel
            from nbv_prob_cnn.arm.self_filter import RobotSelfFilter

            robot = RobotModel(cfg.robot_config(self))
            self_filter = RobotSelfFilter(robot, cfg.self_filter_bodies, cfg.self_filter_tolerance_m)
            self._joint_merger = JointStateMerger(robot.joint_names)  # arm and gripper may come separately
        self.counts = dict.fromkeys(
            ("images", "integrated", "skipped_still", "grids", "grids_compressed", "grids_republished"), 0
        )
        if cfg.self_filter:
            self.counts["self_filtered_pixels"] = 0
        self._fusion = cfg.frame_fusion(self.counts, self_filter)
        self._queue = FrameQueue(cfg.drop_when_behind)
        self._integrating = 0  # frames the worker took from the queue and has not finished (0 or 1)
        self._image_times: deque[float] = deque()  # arrival times (monotonic) of the last images
        self.lost_in_transport: dict[str, int] = {}  # topic -> messages DDS reported lost before delivery
        self._stop = False
        self.drops = DropReport(self.get_logger())  # every frame not integrated, under its reason
        self._store = typestore()

        self._grid_pub = self.create_publisher(VoxelGrid, TOPIC_GRID, GRID_QOS)
        self._compressed_pub = self.create_publisher(CompressedVoxelGrid, names.GRID_COMPRESSED, GRID_QOS)
        self._compressed_lock = threading.Lock()  # the worker (new grids) and a timer both send compressed grids
        self._compressed_sent = LatestSent()  # the grid sent compressed, and the subscribers then
        self._compressed_of: tuple[VoxelGrid | None, CompressedVoxelGrid | None] = (None, None)  # the latest packed
        self._cloud_pub = self.create_publisher(PointCloud2, TOPIC_OCCUPIED_CELLS, 1)
        self._cloud = OccupiedCloudOutput(self._cloud_pub, cfg.cloud_rate_hz, self.geometry, cfg.fixed_frame)
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
        self._tf_poses: TfPoses | None = None
        if cfg.pose_source == "tf":
            if not cfg.fixed_frame:
                raise ValueError("fixed_frame must not be empty")
            assert self._streams is not None  # made for pose_source tf
            self._tf = TfListener(self._streams.node)
            self._tf_poses = TfPoses(self._sync, self._tf.lookup, cfg.fixed_frame)
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
        self.create_timer(0.25, self._publish_compressed, callback_group=services)  # for subscribers that came later
        if cfg.cloud_rate_hz > 0:  # the latest grid's cloud, when throttled away or for a subscriber that came later
            self.create_timer(max(1.0 / cfg.cloud_rate_hz, 0.05), self._publish_cloud, callback_group=services)
        self._worker = threading.Thread(target=self._work, name="tsdf_worker", daemon=True)
        self._worker.start()
        poses = f"by TF ({self._tf.backend})" if self._tf else f"from {names.CAMERA_POSE}"
        self.get_logger().info(
            f"grid {self.geometry.shape} voxel {cfg.voxel_size:g} m origin {list(self.geometry.origin)} "
            f"in {cfg.fixed_frame!r}; poses {poses}; sync ±{cfg.sync_tolerance_s:g} s, "
            f"publish <= {cfg.publish_rate_hz:g} Hz, drop_when_behind={cfg.drop_when_behind}"
            + (f"; self-filter: {cfg.self_filter_bodies} bodies" if self_filter else "")
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

    def _decode(self, raw: bytes, msgtype: str, topic: str) -> Any | None:
        try:
            return self._store.deserialize_cdr(raw, msgtype)
        except Exception as exc:  # malformed CDR from a foreign publisher
            self.drops.drop(DropReason.BAD_MESSAGE, f"{topic}: cannot decode a {msgtype} ({exc}); dropped", error=True)
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
            self.drops.drop(
                DropReason.BAD_ENCODING,
                f"image stamped {stamp * 1e-9:.3f}: unsupported encoding {msg.encoding!r} "
                f"(expected one of {', '.join(ENCODINGS)}, REP-118); dropped",
                error=True,
            )
            return
        with self._cv:
            if self._tf_poses is not None:
                self._enqueue(self._pose_by_tf(stamp, msg.header.frame_id))
            frames, overflow = self._sync.add_image(stamp, msg, time.monotonic())
            self._enqueue(frames)
        if overflow:
            self.drops.drop(
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
            self.drops.drop(
                DropReason.POSE_FRAME,
                f"pose in frame {msg.header.frame_id!r}, expected the grid frame {self.config.fixed_frame!r} "
                "(pose_source:=tf looks poses up in any frame); ignored",
            )
            return
        with self._cv:
            self._enqueue(self._sync.add_pose(stamp_of(msg), msg))

    def _pose_by_tf(self, stamp: int, frame: str) -> list[PairedFrame]:
        """``pose_source:=tf``: the frames that the TF pose of image frame ``frame`` at ``stamp``
        completes (caller holds ``_cv``); none while the transform is missing (retried)."""
        assert self._tf_poses is not None
        frames = self._tf_poses.pose(stamp, frame)
        if stamp in self._tf_poses.errors and self._tf_retry.is_canceled():
            self._tf_retry.reset()
        return frames

    def _on_tf_retry_timer(self) -> None:
        """Retry the TF lookup of every image still waiting for its pose."""
        assert self._tf_poses is not None
        with self._cv:
            for stamp, frame in self._tf_poses.to_retry():
                self._enqueue(self._pose_by_tf(stamp, frame))
            if not self._tf_poses.errors:
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
            if self._tf_poses is not None:
                dropped = self._tf_poses.expired(dropped)
        for stamp, reason, text in dropped:
            self.drops.drop(
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
            **self.drops.report(),
            "inputs": self.inputs.snapshot(),
        }

    def _publish_diagnostics(self) -> None:
        if not self.context.ok():
            return
        name = f"{self.get_fully_qualified_name()}: depth frames"
        status = self.drops.status(name, self.config.fixed_frame, self.diagnostics())
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
            frame.generation = self._fusion.generation
            dropped += self._queue.put(frame)
        self._cv.notify_all()
        if dropped:
            self.drops.drop(
                DropReason.BEHIND, f"integration is behind: {dropped} frame(s) dropped (newest wins)", n=dropped
            )

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self._fusion.lock:
            self._fusion.reset()
            with self._cv:
                discarded = self._queue.clear() + len(self._sync.images)  # queued, or waiting for their pose
                self._sync.images.clear()
                self._fusion.generation += 1
                self._cv.notify_all()
        if discarded:
            self.drops.drop(DropReason.RESET, f"reset: {discarded} waiting frame(s) discarded", n=discarded)
        response.success = True
        response.message = f"grid reset to unknown ({discarded} waiting frame(s) discarded)"
        self.get_logger().info(response.message)
        return response

    def _on_save(self, request: SaveGrid.Request, response: SaveGrid.Response) -> SaveGrid.Response:
        """The grid as ``.npz`` (keys ``grid``, ``origin``, ``resolution``, ``frames``) at ``request.path``."""
        return self._save(response, request.path, ".npz", self._fusion.save)

    def _on_save_mesh(self, request: SaveGrid.Request, response: SaveGrid.Response) -> SaveGrid.Response:
        """The TSDF's surface (marching cubes, world metres) as a binary PLY mesh at ``request.path``."""
        return self._save(response, request.path, ".ply", self._fusion.save_mesh, any_case=True)

    def _save(
        self, response: SaveGrid.Response, requested: str, suffix: str, write: Callable[[Path], str],
        any_case: bool = False,
    ) -> SaveGrid.Response:  # fmt: skip
        """``response`` to a save request: ``write`` called with the path (:func:`save_path`), its message logged."""
        try:
            path = save_path(requested, suffix, any_case)
        except ValueError as exc:
            response.success, response.message = False, str(exc)
            return response
        try:
            response.message = write(path)
        except OSError as exc:
            response.success, response.message = False, f"{path}: cannot write ({exc})"
            return response
        response.success = True
        self.get_logger().info(response.message)
        return response

    # ----------------------------------------------------------------- worker
    def _work(self) -> None:
        while True:
            with self._cv:
                while not self._stop and not self._queue:
                    if self._fusion.dirty:
                        remaining = self._fusion.next_grid - time.monotonic()
                        if remaining <= 0:
                            break
                        self._cv.wait(remaining)
                    else:
                        self._cv.wait(0.5)
                if self._stop:
                    return
                frame = self._queue.pop()
                self._integrating = int(frame is not None)
            try:
                if frame is not None:
                    self._integrate(frame)
            except Exception as exc:  # keep serving: report and go on with the next frame
                self.drops.drop(DropReason.INTEGRATION_ERROR, f"worker: {type(exc).__name__}: {exc}", error=True)
            finally:
                with self._cv:
                    self._integrating = 0
            try:
                if self._fusion.dirty and time.monotonic() >= self._fusion.next_grid:
                    self._publish_grid()
            except Exception as exc:  # keep serving: report and go on with the next frame
                self.get_logger().error(f"worker: {type(exc).__name__}: {exc}", throttle_duration_sec=5.0)

    def _integrate(self, frame: PairedFrame) -> None:
        try:
            if not self._fusion.fuse(frame):
                self.drops.counts.add(DropReason.RESET)  # queued before a reset
        except FrameRejectedError as exc:
            self.drops.drop(exc.reason, f"frame stamped {frame.stamp_ns * 1e-9:.3f} rejected: {exc}", error=True)
        except ValueError as exc:
            self.drops.drop(
                DropReason.INTEGRATION_ERROR, f"frame stamped {frame.stamp_ns * 1e-9:.3f} rejected: {exc}", error=True
            )

    def _publish_grid(self) -> None:
        if not self.context.ok():
            return  # shutting down (SIGINT): the publisher is no longer usable
        grid, stamp_ns = self._fusion.grid()
        msg = grid_to_msg(grid, self.geometry, self.config.fixed_frame, time_msg(stamp_ns))
        self._grid_pub.publish(msg)
        self._last_grid, self._last_grid_at = msg, time.monotonic()
        self.counts["grids"] += 1
        self._publish_compressed()
        self._cloud.update(grid, stamp_ns)

    def _publish_compressed(self) -> None:
        """The latest grid on ``nbv/grid/compressed`` while that topic has subscribers: each new
        grid, and the current one again when a subscriber joined since it was sent (a subscriber
        that comes later gets the current grid at once, as on ``nbv/grid``). The worker (new
        grids) and a timer call it."""
        with self._compressed_lock:
            msg, subscribers = self._last_grid, self._compressed_pub.get_subscription_count()
            if not self.context.ok() or not self._compressed_sent.due(msg, subscribers):
                return
            self._compressed_pub.publish(self._compressed(msg))
            self._compressed_sent.sent(msg, subscribers)
            self.counts["grids_compressed"] += 1

    def _compressed(self, msg: VoxelGrid) -> CompressedVoxelGrid:
        """``msg`` compressed, once per grid: a subscriber that joins later and the volatile
        republishing send the same message again. Called with ``_compressed_lock`` held."""
        grid, packed = self._compressed_of
        if grid is not msg or packed is None:
            packed = compress_grid_msg(msg)
            self._compressed_of = (msg, packed)
        return packed

    def _publish_cloud(self) -> None:
        """The latest grid's cloud on ``occupied_cells`` when due (:class:`OccupiedCloudOutput`)."""
        if self.context.ok():
            self._cloud.send()

    def _on_republish_timer(self) -> None:
        """The latest grid again, when unchanged for ``republish_period_s`` and a volatile
        subscriber listens (transient-local ones got it when they matched)."""
        msg = self._last_grid
        if msg is None or not self.context.ok():
            return
        if time.monotonic() - self._last_grid_at < self.config.republish_period_s:
            return
        for publisher in (self._grid_pub, self._compressed_pub):
            subscribers = self.get_subscriptions_info_by_topic(publisher.topic_name)
            if not any(s.qos_profile.durability == DurabilityPolicy.VOLATILE for s in subscribers):
                continue
            if publisher is self._grid_pub:
                publisher.publish(msg)
            else:
                with self._compressed_lock:
                    publisher.publish(self._compressed(msg))
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
        dropped = ", ".join(f"{k} {v}" for k, v in self.drops.counts.as_dict().items() if v) or "none"
        return ", ".join(f"{name} {value}" for name, value in self.counts.items()) + f"; dropped: {dropped}"


def main(args: list[str] | None = None) -> int:
    """Run the node until interrupted; 1 on a configuration error."""
    return run_node(Integrator, args, threads=2, summary=lambda node: node.summary())


if __name__ == "__main__":
    raise SystemExit(main())
