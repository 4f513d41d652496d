"""``integrator``: TSDF fusion of posed depth frames into the ternary grid ``/nbv/grid`` (SPEC §1, §10).

Subscribes ``/camera/depth/image`` (``32FC1`` metres or ``16UC1`` millimetres; 0/NaN = no return),
``/camera/depth/camera_info`` and ``/camera/pose`` (``TransformStamped``, ``frame_id`` -> camera
optical frame; there is no tf here) and pairs them by header stamp (± ``sync_tolerance_s``).
A paired frame is fused by :class:`~nbv_prob_cnn.perception.TsdfIntegrator` in a worker thread,
so the subscription callbacks only decode headers and never wait for an integration.

Publishes ``/nbv/grid`` (``nbv_prob_cnn_msgs/VoxelGrid``, reliable + transient local, depth 1:
late joiners get the latest grid) at most ``publish_rate_hz`` times a second, whenever a frame
was integrated since the last grid. ``header.stamp`` is the stamp of the newest integrated frame,
so a client that moved the camera and got frame stamp ``T`` waits for a grid stamped ``>= T``
(an all-unknown grid stamped 0 follows a reset).

Frames that cannot be used are dropped with a throttled log and the node keeps running: an
unsupported encoding (error), a frame whose pose or camera_info did not arrive within
``pose_timeout_s`` (warning: missing, or no pose within the tolerance), a pose in another frame
than ``frame_id`` (warning). When integration falls behind, ``drop_when_behind`` (default)
keeps only the newest waiting frame and counts the dropped ones; with ``drop_when_behind:=false``
every paired frame is integrated in stamp order (deterministic: a bag replayed this way gives the
same grid as ``nbv integrate`` on the bag, provided the subscriptions lose nothing either: reliable
QoS keeps only the newest ``queue_size`` messages per topic that the node has not taken yet, so a
replay much faster than real time needs ``queue_size`` at least the burst, e.g. the bag's frame count).

Messages are taken as serialized CDR (raw subscriptions) and decoded with the rosbags helpers of
:mod:`nbv_prob_cnn.perception.bags`, the same code that reads bags offline (and ~50x faster than
rclpy's conversion of a 640x480 image).

Services: ``/integrator/reset`` (``std_srvs/Trigger``, every cell unknown again, waiting frames
discarded) and ``/integrator/save`` (``nbv_prob_cnn_msgs/SaveGrid``: ``.npz`` with keys ``grid``,
``origin``, ``resolution``, ``frames`` written on the node's machine, relative paths from its
working directory).

Run: ``nbv node integrator --ros-args -p publish_rate_hz:=2.0``
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from nbv_prob_cnn_msgs.msg import VoxelGrid
from nbv_prob_cnn_msgs.srv import SaveGrid
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

from nbv_prob_cnn.geometry import GridGeometry
from nbv_prob_cnn.grid import EMPTY, OCCUPIED, UNKNOWN
from nbv_prob_cnn.perception.bags import (
    MSG_CAMERA_INFO,
    MSG_IMAGE,
    MSG_TRANSFORM,
    TOPIC_CAMERA_INFO,
    TOPIC_IMAGE,
    TOPIC_POSE,
    camera_info_to_intrinsics,
    image_msg_to_depth,
    stamp_of,
    transform_msg_to_pose,
    typestore,
)
from nbv_prob_cnn.perception.tsdf import (
    DEFAULT_EMPTY_MARGIN_VOXELS,
    DEFAULT_ORIGIN_M,
    DEFAULT_SHAPE,
    DEFAULT_TRUNC_VOXELS,
    DEFAULT_VOXEL_M,
    TsdfIntegrator,
)
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.common import GRID_QOS, declare_subscription_qos, descriptor, run_node
from nbv_prob_cnn.ros.conversions import grid_to_msg

NODE_NAME = "integrator"
TOPIC_GRID = names.GRID
SERVICE_RESET = names.INTEGRATOR_RESET
SERVICE_SAVE = names.INTEGRATOR_SAVE
ENCODINGS = ("32FC1", "16UC1")
#: Most frames waiting for integration with ``drop_when_behind:=false`` (older ones are dropped beyond it).
MAX_BACKLOG = 1000
#: Images waiting for their pose/camera_info at most (older ones are dropped beyond it).
MAX_PENDING = 64
#: Poses and camera_infos kept for pairing.
HISTORY = 256


def stamp_to_time(stamp_ns: int) -> Time:
    return Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


@dataclass
class PairedFrame:
    """Image, camera_info and pose messages (rosbags objects) of one stamp."""

    stamp_ns: int
    image: Any
    info: Any
    pose: Any
    generation: int = 0


class StampSync:
    """Pairs each image with the camera_info and the pose nearest to its stamp within a tolerance.

    Not thread-safe (the node calls it under its lock). Poses and camera_infos are kept (the
    newest :data:`HISTORY`) and may serve several images; an image waits until both partners
    are there, or is dropped by :meth:`expire`.
    """

    def __init__(self, tolerance_ns: int) -> None:
        self.tolerance_ns = int(tolerance_ns)
        self.images: dict[int, tuple[Any, float]] = {}  # stamp -> (message, arrival time.monotonic())
        self.infos: list[tuple[int, Any]] = []  # sorted by stamp
        self.poses: list[tuple[int, Any]] = []

    def clear(self) -> None:
        self.images.clear()
        self.infos.clear()
        self.poses.clear()

    @staticmethod
    def _insert(history: list[tuple[int, Any]], stamp: int, msg: Any) -> None:
        i = bisect.bisect_left(history, stamp, key=lambda item: item[0])
        if i < len(history) and history[i][0] == stamp:
            history[i] = (stamp, msg)  # a repeated stamp replaces the older message
        else:
            history.insert(i, (stamp, msg))
        del history[:-HISTORY]

    def nearest(self, history: list[tuple[int, Any]], stamp: int) -> tuple[int, Any] | None:
        """The entry of ``history`` nearest to ``stamp`` within the tolerance (ties: the older)."""
        i = bisect.bisect_left(history, stamp, key=lambda item: item[0])
        best = None
        for j in (i - 1, i):
            if 0 <= j < len(history) and abs(history[j][0] - stamp) <= self.tolerance_ns:
                if best is None or abs(history[j][0] - stamp) < abs(best[0] - stamp):
                    best = history[j]
        return best

    def add_image(self, stamp: int, msg: Any, now: float) -> tuple[list[PairedFrame], list[int]]:
        """Returns the frames completed and the stamps of images dropped for lack of room."""
        self.images[stamp] = (msg, now)
        overflow = []
        while len(self.images) > MAX_PENDING:
            oldest = min(self.images)
            del self.images[oldest]
            overflow.append(oldest)
        return self._complete(), overflow

    def add_info(self, stamp: int, msg: Any) -> list[PairedFrame]:
        self._insert(self.infos, stamp, msg)
        return self._complete()

    def add_pose(self, stamp: int, msg: Any) -> list[PairedFrame]:
        self._insert(self.poses, stamp, msg)
        return self._complete()

    def _complete(self) -> list[PairedFrame]:
        done = []
        for stamp in sorted(self.images):
            info = self.nearest(self.infos, stamp)
            pose = self.nearest(self.poses, stamp)
            if info is not None and pose is not None:
                image, _ = self.images.pop(stamp)
                done.append(PairedFrame(stamp, image, info[1], pose[1]))
        return done

    def expire(self, now: float, timeout_s: float) -> list[tuple[int, str]]:
        """Drop images that waited longer than ``timeout_s``; returns ``(stamp, reason)`` pairs."""
        dropped = []
        for stamp in sorted(self.images):
            _, arrived = self.images[stamp]
            if now - arrived <= timeout_s:
                continue
            del self.images[stamp]
            reasons = []
            for name, history in (("pose", self.poses), ("camera_info", self.infos)):
                if self.nearest(history, stamp) is not None:
                    continue
                if not history:
                    reasons.append(f"no {name} received yet")
                else:
                    closest = min(history, key=lambda item: abs(item[0] - stamp))
                    offset = (closest[0] - stamp) * 1e-9
                    reasons.append(
                        f"no {name} within ±{self.tolerance_ns * 1e-9:g} s (nearest is {offset:+.3f} s away)"
                    )
            dropped.append((stamp, "; ".join(reasons) or "partners expired"))
        return dropped


class Integrator(Node):
    """Fuses posed depth frames into a ternary grid and publishes it."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.frame_id = self.declare_parameter(
            "frame_id", "world", descriptor("fixed frame of the grid; poses must be given in it")
        ).value
        origin = self.declare_parameter(
            "origin",
            [float(v) for v in DEFAULT_ORIGIN_M],
            descriptor("world coordinates [m] of the corner of cell (0, 0, 0)", dynamic_typing=True),
        ).value
        shape = self.declare_parameter(
            "shape", [int(v) for v in DEFAULT_SHAPE], descriptor("grid size [cells] nx, ny, nz")
        ).value
        voxel = self.declare_parameter(
            "voxel_size", DEFAULT_VOXEL_M, descriptor("cell edge [m]", float_range=(1e-4, 10.0))
        ).value
        trunc = self.declare_parameter(
            "trunc_voxels", DEFAULT_TRUNC_VOXELS, descriptor("TSDF truncation [voxels]", float_range=(0.5, 100.0))
        ).value
        margin = self.declare_parameter(
            "empty_margin_voxels",
            DEFAULT_EMPTY_MARGIN_VOXELS,
            descriptor("cells farther than this in front of a surface are empty [voxels]", float_range=(0.0, 100.0)),
        ).value
        self.depth_max = self.declare_parameter(
            "depth_max_m", 3.0, descriptor("returns beyond this depth are ignored [m]", float_range=(0.01, 100.0))
        ).value
        refine = self.declare_parameter(
            "refine_pose_icp", False, descriptor("refine each pose by frame-to-model odometry (slow)")
        ).value
        device = self.declare_parameter("device", "CPU:0", descriptor("open3d device, e.g. CPU:0 or CUDA:0")).value
        tolerance = self.declare_parameter(
            "sync_tolerance_s",
            0.01,
            descriptor("largest stamp difference of an image and its pose / camera_info [s]", float_range=(0.0, 10.0)),
        ).value
        self.pose_timeout = self.declare_parameter(
            "pose_timeout_s",
            1.0,
            descriptor(
                "an image whose pose / camera_info is missing this long is dropped [s]", float_range=(0.0, 60.0)
            ),
        ).value
        self.publish_rate = self.declare_parameter(
            "publish_rate_hz",
            2.0,
            descriptor("most grids per second; 0 = a grid after every integrated frame", float_range=(0.0, 100.0)),
        ).value
        self.drop_when_behind = self.declare_parameter(
            "drop_when_behind",
            True,
            descriptor("when integration falls behind, only the newest waiting frame is kept (false: all, in order)"),
        ).value
        camera_qos = declare_subscription_qos(self, 10, "camera subscriptions")

        if (
            not isinstance(origin, list | tuple)
            or len(origin) != 3
            or not all(isinstance(v, int | float) for v in origin)
        ):
            raise ValueError(f"origin: expected 3 numbers [m], got {origin!r}")
        if len(shape) != 3 or min(shape) < 1:
            raise ValueError(f"shape: expected 3 positive sizes, got {list(shape)}")
        self.geometry = GridGeometry(tuple(float(v) for v in origin), float(voxel), tuple(int(v) for v in shape))
        self._tsdf = TsdfIntegrator(
            origin_m=np.array(self.geometry.origin),
            shape_cells=self.geometry.shape,
            voxel_size_m=voxel,
            trunc_voxels=trunc,
            empty_margin_voxels=margin,
            device=device,
            refine_pose_icp=refine,
        )

        # state shared by the executor threads and the worker: _cv guards the pairing and the queue,
        # _tsdf_lock the integrator and the grid state (never taken while holding _cv)
        self._cv = threading.Condition()
        self._tsdf_lock = threading.Lock()
        self._sync = StampSync(round(tolerance * 1e9))
        self._queue: deque[PairedFrame] = deque()
        self._generation = 0
        self._stop = False
        self._dirty = False
        self._newest_stamp_ns = 0
        self._next_publish = 0.0
        self.counts = dict.fromkeys(("images", "integrated", "dropped_behind", "unpaired", "rejected", "grids"), 0)
        self._store = typestore()

        self._grid_pub = self.create_publisher(VoxelGrid, TOPIC_GRID, GRID_QOS)
        inputs = MutuallyExclusiveCallbackGroup()
        services = MutuallyExclusiveCallbackGroup()
        self.create_subscription(Image, names.DEPTH_IMAGE, self._on_image, camera_qos, callback_group=inputs, raw=True)
        self.create_subscription(
            CameraInfo, names.CAMERA_INFO, self._on_info, camera_qos, callback_group=inputs, raw=True
        )
        self.create_subscription(
            TransformStamped, names.CAMERA_POSE, self._on_pose, camera_qos, callback_group=inputs, raw=True
        )
        self.create_timer(0.1, self._on_expire_timer, callback_group=inputs)
        self.create_service(Trigger, SERVICE_RESET, self._on_reset, callback_group=services)
        self.create_service(SaveGrid, SERVICE_SAVE, self._on_save, callback_group=services)
        self._worker = threading.Thread(target=self._work, name="tsdf_worker", daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"grid {self.geometry.shape} voxel {voxel:g} m origin {list(self.geometry.origin)} in {self.frame_id!r}; "
            f"sync ±{tolerance:g} s, publish <= {self.publish_rate:g} Hz, drop_when_behind={self.drop_when_behind}"
        )

    # -------------------------------------------------------------- callbacks
    def _decode(self, raw: bytes, msgtype: str, topic: str) -> Any | None:
        try:
            return self._store.deserialize_cdr(raw, msgtype)
        except Exception as exc:  # malformed CDR from a foreign publisher
            self.get_logger().error(f"{topic}: cannot decode a {msgtype} ({exc}); dropped", throttle_duration_sec=5.0)
            return None

    def _on_image(self, raw: bytes) -> None:
        msg = self._decode(raw, MSG_IMAGE, TOPIC_IMAGE)
        if msg is None:
            return
        stamp = stamp_of(msg)
        self.counts["images"] += 1
        if msg.encoding not in ENCODINGS:
            self.counts["rejected"] += 1
            self.get_logger().error(
                f"image stamped {stamp * 1e-9:.3f}: unsupported encoding {msg.encoding!r} "
                f"(expected one of {', '.join(ENCODINGS)}); dropped",
                throttle_duration_sec=5.0,
            )
            return
        with self._cv:
            frames, overflow = self._sync.add_image(stamp, msg, time.monotonic())
            self._enqueue(frames)
        if overflow:
            self.counts["unpaired"] += len(overflow)
            self.get_logger().warning(
                f"{len(overflow)} image(s) dropped: more than {MAX_PENDING} waiting for their pose",
                throttle_duration_sec=5.0,
            )

    def _on_info(self, raw: bytes) -> None:
        msg = self._decode(raw, MSG_CAMERA_INFO, TOPIC_CAMERA_INFO)
        if msg is not None:
            with self._cv:
                self._enqueue(self._sync.add_info(stamp_of(msg), msg))

    def _on_pose(self, raw: bytes) -> None:
        msg = self._decode(raw, MSG_TRANSFORM, TOPIC_POSE)
        if msg is None:
            return
        if msg.header.frame_id != self.frame_id:
            self.counts["rejected"] += 1
            self.get_logger().warning(
                f"pose in frame {msg.header.frame_id!r}, expected the grid frame {self.frame_id!r} (no tf here); "
                "ignored",
                throttle_duration_sec=5.0,
            )
            return
        with self._cv:
            self._enqueue(self._sync.add_pose(stamp_of(msg), msg))

    def _on_expire_timer(self) -> None:
        with self._cv:
            dropped = self._sync.expire(time.monotonic(), self.pose_timeout)
        if dropped:
            self.counts["unpaired"] += len(dropped)
            stamp, reason = dropped[-1]
            self.get_logger().warning(
                f"image stamped {stamp * 1e-9:.3f} dropped: {reason} after {self.pose_timeout:g} s "
                f"({self.counts['unpaired']} unpaired image(s) dropped so far)",
                throttle_duration_sec=5.0,
            )

    def _enqueue(self, frames: list[PairedFrame]) -> None:
        """Queue paired frames for the worker (caller holds ``_cv``)."""
        if not frames:
            return
        dropped = 0
        for frame in frames:
            frame.generation = self._generation
            if self.drop_when_behind:
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
            self.counts["dropped_behind"] += dropped
            self.get_logger().warning(
                f"integration is behind: {self.counts['dropped_behind']} frame(s) dropped so far (newest wins)",
                throttle_duration_sec=5.0,
            )

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self._tsdf_lock:
            self._tsdf.reset()
            with self._cv:
                discarded = len(self._queue)
                self._queue.clear()
                self._sync.images.clear()
                self._generation += 1
                self._cv.notify_all()
            self._newest_stamp_ns = 0
            self._dirty = True
            self._next_publish = 0.0
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
            try:
                if frame is not None:
                    self._integrate(frame)
                if self._dirty and time.monotonic() >= self._next_publish:
                    self._publish_grid()
            except Exception as exc:  # keep serving: report and go on with the next frame
                self.get_logger().error(f"worker: {type(exc).__name__}: {exc}", throttle_duration_sec=5.0)

    def _integrate(self, frame: PairedFrame) -> None:
        try:
            depth = image_msg_to_depth(frame.image)
            intrinsics = camera_info_to_intrinsics(frame.info)
            pose = transform_msg_to_pose(frame.pose)
            with self._tsdf_lock:
                if frame.generation != self._generation:
                    return  # queued before a reset
                self._tsdf.integrate(depth, intrinsics, pose, depth_max=self.depth_max)
                self._newest_stamp_ns = max(self._newest_stamp_ns, frame.stamp_ns)
                self._dirty = True
        except ValueError as exc:
            self.counts["rejected"] += 1
            self.get_logger().error(
                f"frame stamped {frame.stamp_ns * 1e-9:.3f} rejected: {exc}", throttle_duration_sec=5.0
            )
            return
        self.counts["integrated"] += 1

    def _publish_grid(self) -> None:
        if not self.context.ok():
            return  # shutting down (SIGINT): the publisher is no longer usable
        with self._tsdf_lock:
            grid = self._tsdf.ternary()
            stamp_ns = self._newest_stamp_ns
            self._dirty = False
            self._next_publish = time.monotonic() + (1.0 / self.publish_rate if self.publish_rate > 0 else 0.0)
        self._grid_pub.publish(grid_to_msg(grid, self.geometry, self.frame_id, stamp_to_time(stamp_ns)))
        self.counts["grids"] += 1

    def destroy_node(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        self._worker.join(timeout=10.0)
        super().destroy_node()

    def summary(self) -> str:
        return ", ".join(f"{name} {value}" for name, value in self.counts.items())


def main(args: list[str] | None = None) -> int:
    """Run the node until interrupted; 1 on a configuration error."""
    return run_node(Integrator, args, threads=2, summary=lambda node: node.summary())


if __name__ == "__main__":
    raise SystemExit(main())
