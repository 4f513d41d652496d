"""``sim_camera``: a simulated depth camera looking at a generated world or a mesh (docs/method.md: sensor, node graph).

Publishes, all with the same header stamp per frame:

* ``/camera/depth/image`` (``sensor_msgs/Image``, ``32FC1`` metres or ``16UC1`` millimetres, 0 = no return)
* ``/camera/depth/camera_info`` (``sensor_msgs/CameraInfo``, pinhole, no distortion)
* the camera pose ``frame_id`` -> ``camera_frame`` (the optical frame the images are stamped in):
  on ``/tf`` (``tf2_msgs/TFMessage``) with ``pose_source:=tf`` (the default) and on ``/camera/pose``
  (``geometry_msgs/TransformStamped``), for the free-flying camera, which stands in for the robot
  that would publish it

Moves with the service ``/sim_camera/move_to`` (``nbv_prob_cnn_msgs/MoveCamera``: the frame at the
target is rendered and published inside the service call, the reply carries its stamp) or the
topic ``/camera/goal_pose`` (``geometry_msgs/PoseStamped``; a frame is published immediately).
Target poses are ``camera_optical`` poses (REP-103: z forward, x right, y down) in ``frame_id``.
With ``follow_arm:=true`` the camera rides on the simulated arm instead (the move requests are
refused) and publishes what a real camera driver does, the image and camera_info in
``camera_frame`` and no pose: with ``pose_source:=tf`` it renders at the newest TF pose of
``camera_frame`` in ``frame_id`` (``arm_sim`` publishes the links on ``/tf``, the camera mount on
``/tf_static``) and stamps the frame with that transform's stamp; with ``pose_source:=topic`` it
takes ``arm/camera_pose`` (``arm_sim``'s forward kinematics) and publishes ``/camera/pose`` as well.

With ``render_arm:=true`` the arm (the robot of the robot description parameters ``urdf_path``,
``base_xyz``, ..., its visual meshes) is rendered into every frame at the latest ``joint_states``
(``sensor_msgs/JointState``, e.g. from ``arm_sim``; every joint must be named), and the frame is
stamped with that joint state's stamp when it is at most 0.5 s old (else with the time now): the
moment the arm was where the frame shows it, so a self-filter pairing by stamp sees the same
joint state even when rendering lags. Until the first joint state arrives no frame is
published (``move_to`` answers with an error), and joint states naming unknown or missing joints
are refused with a warning (the previous one stays in use).

Frames are rendered by :class:`~nbv_prob_cnn.perception.DepthCamera` and converted by the
rosbag2 helpers of :mod:`nbv_prob_cnn.perception.bags` (CDR bytes published as they are), so a
live stream and a recorded bag carry byte-for-byte the same message layout.

Run: ``nbv node sim_camera --ros-args -p dataset:=3dt -p seed:=1000 -p rate_hz:=5.0``
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped, TransformStamped
from nbv_prob_cnn_msgs.srv import MoveCamera
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState

from nbv_prob_cnn.arm.joint_states import JointStateMerger
from nbv_prob_cnn.basics.camera import look_rotation, matrix_from_quaternion, quaternion_from_matrix
from nbv_prob_cnn.perception.depth_camera import DepthCamera, DepthNoise, Intrinsics, room_mesh
from nbv_prob_cnn.perception.messages import (
    ENCODINGS,
    MSG_CAMERA_INFO,
    MSG_IMAGE,
    MSG_TRANSFORM,
    depth_to_image_msg,
    intrinsics_to_camera_info,
    pose_to_transform_msg,
    typestore,
)
from nbv_prob_cnn.perception.messages import stamp_ns as message_stamp_ns
from nbv_prob_cnn.perception.tf_buffer import TransformError
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.conversions import pose_to_arrays, time_msg, transform_stamped_msg
from nbv_prob_cnn.ros.parameters import declare_config, param
from nbv_prob_cnn.ros.robot_params import RobotParams
from nbv_prob_cnn.ros.runtime import run_node
from nbv_prob_cnn.ros.stream_node import StreamNode
from nbv_prob_cnn.ros.tf_listener import POSE_SOURCES, TF_QOS, TOPIC_TF, TfListener
from nbv_prob_cnn.sensing.sensor_noise import PRESETS, SensorNoise, sensor_noise

NODE_NAME = "sim_camera"
TOPIC_GOAL_POSE = names.GOAL_POSE
SERVICE_MOVE_TO = names.MOVE_TO
#: ``render_arm``: a frame carries the stamp of the joint state it shows when that is at most this old.
ARM_STATE_MAX_AGE_NS = 500_000_000
ARM_STATES_KEPT = 100  # joint states kept by stamp for follow_arm + render_arm (2 s at arm_sim's 50 Hz)


def look_at_pose(position, target) -> list[float]:
    """``[x, y, z, qx, qy, qz, qw]`` of a camera_optical pose at ``position`` looking at ``target``."""
    rot = look_rotation(np.asarray(target, dtype=np.float64) - np.asarray(position, dtype=np.float64))
    return [float(v) for v in position] + [float(q) for q in quaternion_from_matrix(rot)]


def overview_pose(meshes) -> list[float]:
    """Default camera pose: looking at the centre of the scene's bounding box (a third of the way up)
    from the front (-y) side, 45 degrees above it, far enough to see most of the scene
    (for a 3DT world: from about 0.95 m away, above the front edge of the table)."""
    vertices = np.concatenate([np.asarray(m.vertices, dtype=np.float64).reshape(-1, 3) for m in meshes])
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    target = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2] + (hi[2] - lo[2]) / 3])
    distance = 0.65 * float(np.max(hi - lo))
    position = target + distance * np.array([0.0, -math.sqrt(0.5), math.sqrt(0.5)])
    return look_at_pose(position, target)


def pose_matrix(values) -> np.ndarray:
    """4×4 ``world_from_optical`` matrix of ``[x, y, z, qx, qy, qz, qw]``.

    Raises:
        ValueError: not 7 numbers, NaN/inf, or a zero quaternion.
    """
    values = np.asarray(list(values), dtype=np.float64)
    if values.shape != (7,):
        raise ValueError(f"pose: expected 7 numbers [x, y, z, qx, qy, qz, qw], got {values.size}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"pose: NaN or infinite components {values.tolist()}")
    pose = np.eye(4)
    pose[:3, :3] = matrix_from_quaternion(values[3:])  # raises on a zero quaternion
    pose[:3, 3] = values[:3]
    return pose


def camera_noise(preset: str, sigma_per_m: float, dropout: float, seed: int) -> DepthNoise | SensorNoise | None:
    """The noise model of the parameters: the sensor preset ``preset`` when given (the
    :mod:`~nbv_prob_cnn.sensing.sensor_noise` model that ``nbv explore --noise`` uses), else the
    depth-proportional :class:`DepthNoise` when ``sigma_per_m`` or ``dropout`` is positive, else
    None (exact depth).

    Raises:
        ValueError: a preset together with ``sigma_per_m`` or ``dropout`` (two noise models), or an
            unknown preset.
    """
    if preset:
        if sigma_per_m > 0 or dropout > 0:
            raise ValueError(
                f"noise_preset {preset!r} and noise_sigma_per_m / noise_dropout ({sigma_per_m}, {dropout}) "
                "both set: choose one noise model"
            )
        return sensor_noise(preset)
    return DepthNoise(sigma_per_m, dropout, seed) if (sigma_per_m > 0 or dropout > 0) else None


def load_meshes(dataset: str, seed: int, mesh_file: str, room_margin_m: float = 0.0) -> tuple[list, str]:
    """The scene meshes (world metres) and a description of where they came from; generated
    worlds get walls ``room_margin_m`` outside their grid when that is positive."""
    if mesh_file:
        import trimesh

        path = Path(mesh_file).expanduser()
        if not path.is_file():
            raise ValueError(f"mesh_file: no such file {str(path)!r}")
        try:
            mesh = trimesh.load(path, force="mesh")
        except Exception as exc:  # trimesh raises many types on unreadable files
            raise ValueError(f"mesh_file: cannot read {str(path)!r} ({exc})") from exc
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise ValueError(f"mesh_file: {str(path)!r} has no triangles")
        return [mesh], f"mesh {path}"
    if dataset not in ("3dt", "3du"):
        raise ValueError(f"dataset: expected '3dt' or '3du' (3D worlds with meshes), got {dataset!r}")
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate(dataset, seed)
    meshes = world.triangle_meshes()
    if not meshes:
        raise ValueError(f"dataset {dataset} seed {seed}: the world has no meshes")
    if room_margin_m > 0:
        lower = np.asarray(world.origin, dtype=np.float64) - room_margin_m
        upper = lower + np.asarray(world.shape) * world.resolution + 2 * room_margin_m
        meshes.append(room_mesh(lower, upper))
    return meshes, f"{dataset} world seed {seed}" + (
        f" in a room ({room_margin_m} m margin)" if room_margin_m > 0 else ""
    )


@dataclass(frozen=True)
class FrameCdr:
    """One depth frame as the CDR bytes :class:`SimCamera` publishes, all with one header stamp."""

    image: bytes  #: ``sensor_msgs/Image``
    info: bytes  #: ``sensor_msgs/CameraInfo``
    pose: bytes  #: ``geometry_msgs/TransformStamped`` ``frame_id`` -> ``camera_frame``


def frame_cdr(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    pose: np.ndarray,
    stamp_ns: int,
    encoding: str,
    frame_id: str,
    camera_frame: str,
) -> FrameCdr:
    """The frame of ``depth`` (metres) seen with ``intrinsics`` from ``pose`` (4×4 ``frame_id`` <-
    ``camera_frame``), stamped ``stamp_ns``: the image (``encoding``) and camera_info in
    ``camera_frame``, and the pose."""
    store = typestore()
    info = intrinsics_to_camera_info(intrinsics, stamp_ns, camera_frame)
    image = depth_to_image_msg(depth, stamp_ns, encoding, camera_frame)
    transform = pose_to_transform_msg(pose, stamp_ns, frame_id, camera_frame)
    return FrameCdr(
        image=bytes(store.serialize_cdr(image, MSG_IMAGE)),
        info=bytes(store.serialize_cdr(info, MSG_CAMERA_INFO)),
        pose=bytes(store.serialize_cdr(transform, MSG_TRANSFORM)),
    )


@dataclass
class SimCameraConfig(RobotParams):
    """Parameters of ``sim_camera`` (all fixed after start-up): the robot description (used with
    ``render_arm``), then these."""

    dataset: str = param("3dt", "generated world to look at (ignored with mesh_file)", choices=("3dt", "3du"))
    seed: int = param(1000, "world seed", min_value=0, max_value=2**31 - 1)
    mesh_file: str = param("", "mesh file (world metres, any format trimesh reads); overrides dataset/seed")
    width: int = param(640, "image width [px]", min_value=1, max_value=8192)
    height: int = param(480, "image height [px]", min_value=1, max_value=8192)
    hfov_deg: float = param(60.0, "horizontal field of view [deg]", min_value=1.0, max_value=179.0)
    frame_id: str = param("world", "fixed frame of the scene and of the published pose")
    camera_frame: str = param("camera_optical", "optical frame of the images (REP-103)")
    rate_hz: float = param(5.0, "frame rate [Hz]; 0 = publish only when moved", min_value=0.0, max_value=100.0)
    encoding: str = param("32FC1", "image encoding (REP-118): float metres or uint16 millimetres", choices=ENCODINGS)
    initial_pose: list = param(
        [], "initial camera_optical pose [x, y, z, qx, qy, qz, qw] in frame_id; empty = looking at the "
        "scene centre from above its front (-y) side",
    )  # fmt: skip
    depth_min_m: float = param(0.0, "returns nearer than this are 'no return' [m]", min_value=0.0, max_value=100.0)
    depth_max_m: float = param(10.0, "returns farther than this are 'no return' [m]", min_value=0.0, max_value=655.0)
    noise_sigma_per_m: float = param(
        0.0, "depth noise standard deviation per metre of depth (0 = exact)", min_value=0.0, max_value=1.0
    )
    noise_dropout: float = param(0.0, "probability of a pixel dropout (no return)", min_value=0.0, max_value=1.0)
    room_margin_m: float = param(
        0.3, "walls this far outside a generated world's grid, so every pixel has a return (0 = none)",
        min_value=0.0, max_value=100.0,
    )  # fmt: skip
    noise_seed: int = param(0, "seed of the noise generator", min_value=0, max_value=2**31 - 1)
    noise_preset: str = param(
        "", "depth-sensor model of nbv_prob_cnn.sensing.sensor_noise (ranges, axial and lateral noise, grazing "
        "angles, edges, dropouts); '' = the noise_sigma_per_m / noise_dropout model",
        choices=("", *PRESETS),
    )  # fmt: skip
    render_arm: bool = param(
        False, "render the arm's visual meshes into every frame at the latest joint_states (robot description "
        "parameters); no frame before the first joint state",
    )  # fmt: skip
    follow_arm: bool = param(False, "ride on the arm (pose from TF or arm/camera_pose) instead of move_to/goal_pose")
    pose_source: str = param(
        "tf", "tf: the free camera broadcasts its pose on /tf, on the arm it reads it from /tf; topic: "
        "arm/camera_pose in and /camera/pose out only", choices=POSE_SOURCES,
    )  # fmt: skip


class SimCamera(Node):
    """Renders depth frames of a static scene from a movable camera pose."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.config = cfg = declare_config(self, SimCameraConfig)
        dataset, seed, mesh_file, width, height = cfg.dataset, cfg.seed, cfg.mesh_file, cfg.width, cfg.height
        hfov, rate, initial, depth_min, depth_max = (
            cfg.hfov_deg,
            cfg.rate_hz,
            cfg.initial_pose,
            cfg.depth_min_m,
            cfg.depth_max_m,
        )
        sigma, dropout, room_margin, noise_seed = (
            cfg.noise_sigma_per_m,
            cfg.noise_dropout,
            cfg.room_margin_m,
            cfg.noise_seed,
        )

        if not cfg.frame_id or not cfg.camera_frame:
            raise ValueError("frame_id and camera_frame must not be empty")
        if cfg.follow_arm and not rate > 0:
            raise ValueError("follow_arm: needs rate_hz > 0 (the timer renders frames at the arm's latest pose)")
        if not depth_max > depth_min:
            raise ValueError(f"depth_max_m ({depth_max}) must be greater than depth_min_m ({depth_min})")
        if not isinstance(initial, list | tuple) or not all(isinstance(v, int | float) for v in initial):
            raise ValueError(f"initial_pose: expected 7 numbers [x, y, z, qx, qy, qz, qw], got {initial!r}")
        if initial:
            self._pose = pose_matrix(initial)  # checked before the (slow) scene loading

        noise = camera_noise(cfg.noise_preset, sigma, dropout, noise_seed)  # checked before the scene loading
        meshes, source = load_meshes(dataset, seed, mesh_file, room_margin)
        if not initial:
            self._pose = pose_matrix(overview_pose(meshes))
        self.intrinsics = Intrinsics.from_hfov(width, height, hfov)
        self._camera = DepthCamera(
            meshes, self.intrinsics, noise=noise, depth_min=depth_min, depth_max=depth_max, noise_seed=noise_seed
        )
        # one frame at a time (pose, stamp, render, publish in order); the render runs outside
        # _lock, so joint states and arm poses keep arriving on the stream thread meanwhile (a
        # render that held _lock kept them out: the next frame then found its newest joint state
        # older than ARM_STATE_MAX_AGE_NS and was stamped now, while the arm moved on)
        self._frame_lock = threading.RLock()
        self._lock = threading.Lock()  # the pose, the arm's joint states and poses: held briefly
        self._last_stamp_ns = 0
        self._arm_pose: tuple[np.ndarray, int] | None = None  # follow_arm: latest pose and its stamp (ns)
        self.frames = 0
        self.bad_joint_states = 0
        self._arm_q: np.ndarray | None = None
        self._arm_stamp_ns = 0
        self._arm_qs: dict[int, np.ndarray] = {}  # recent joint states by stamp (follow_arm pairs them with poses)
        self._arm = None
        # joint_states and /tf come at the robot's rate: a side node with its own thread, where they are used
        uses_streams = cfg.render_arm or (cfg.follow_arm and cfg.pose_source == "tf")
        self._streams = StreamNode(self) if uses_streams else None
        if cfg.render_arm:
            assert self._streams is not None  # uses_streams
            from nbv_prob_cnn.arm.robot import RobotModel
            from nbv_prob_cnn.arm.robot_scene import RobotScene

            self._arm = RobotScene(RobotModel(cfg.robot_config(self)), "visual")
            self._arm_merger = JointStateMerger(self._arm.robot.joint_names)  # arm and gripper may come apart
            # without follow_arm only the newest joint state matters (a backlog would render the arm
            # where it was); with it every one is kept by stamp, to pair with the arm pose of that stamp
            depth = ARM_STATES_KEPT if cfg.follow_arm else 10  # room for the arm's and the gripper's messages
            self._streams.node.create_subscription(JointState, names.JOINT_STATES, self._on_joint_states, depth)

        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=5,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.VOLATILE,
        )
        self._image_pub = self.create_publisher(Image, names.DEPTH_IMAGE, qos)
        self._info_pub = self.create_publisher(CameraInfo, names.CAMERA_INFO, qos)
        # a real camera driver publishes no pose: on the arm (TF) only the image and camera_info
        self._pose_pub = None
        if not (cfg.follow_arm and cfg.pose_source == "tf"):
            self._pose_pub = self.create_publisher(TransformStamped, names.CAMERA_POSE, qos)
        self._tf_pub = None
        if not cfg.follow_arm and cfg.pose_source == "tf":
            from tf2_msgs.msg import TFMessage

            self._tf_message = TFMessage
            self._tf_pub = self.create_publisher(TFMessage, TOPIC_TF, TF_QOS)
        self._tf: TfListener | None = None
        self.create_service(MoveCamera, SERVICE_MOVE_TO, self._on_move_to)
        self.create_subscription(PoseStamped, TOPIC_GOAL_POSE, self._on_goal_pose, 10)
        if cfg.follow_arm and cfg.pose_source == "tf":
            assert self._streams is not None  # uses_streams
            self._tf = TfListener(self._streams.node)
        elif cfg.follow_arm:
            self.create_subscription(PoseStamped, names.ARM_CAMERA_POSE, self._on_arm_pose, 10)
        self._timer = self.create_timer(1.0 / rate, self._on_timer) if rate > 0 else None
        self.get_logger().info(
            f"{source}: {self._camera.n_meshes} mesh(es), {width}x{height} px, hfov {hfov:g} deg, "
            f"{cfg.encoding}, {rate:g} Hz, pose {np.round(self._pose[:3, 3], 3).tolist()}"
            + (f"; pose of {cfg.camera_frame!r} in {cfg.frame_id!r} from TF ({self._tf.backend})" if self._tf else "")
            + (f"; broadcasting {cfg.frame_id!r} -> {cfg.camera_frame!r} on {TOPIC_TF}" if self._tf_pub else "")
            + (f"; rendering the arm ({len(self._arm.meshes)} visual meshes) at joint_states" if self._arm else "")
        )

    # ------------------------------------------------------------------ frames
    def publish_frame(self, at_ns: int | None = None) -> int:
        """Render and publish one frame from the current pose; returns its stamp (ns).

        The stamp is ``at_ns`` (``follow_arm``: the stamp of the arm pose), else the time now. With
        ``render_arm`` the arm is drawn at the joint state of stamp ``at_ns`` when given (``arm_sim``
        stamps its joint state and camera pose alike), else at the latest joint state, whose stamp
        the frame then carries when it is at most 0.5 s old: the moment the arm was where the frame
        shows it, so a self-filter pairing by stamp sees the same joint state.

        Raises:
            ValueError: ``render_arm`` and no joint state received yet (or none of stamp ``at_ns``).
        """
        with self._frame_lock:
            with self._lock:
                stamp_ns = self.get_clock().now().nanoseconds if at_ns is None else at_ns
                q = None
                if self._arm is not None:
                    q = self._arm_q if at_ns is None else self._arm_qs.get(at_ns)
                    if q is None:
                        which = "" if at_ns is None else f" stamped {at_ns} ns (the arm pose's)"
                        raise ValueError(f"render_arm: no {names.JOINT_STATES}{which} received yet, no frame")
                    # the frame shows the arm as it was at that joint state: it carries its stamp (unless
                    # the joint states stopped: then the frame is stamped now and shows the last known arm)
                    if at_ns is None and 0 <= stamp_ns - self._arm_stamp_ns <= ARM_STATE_MAX_AGE_NS:
                        stamp_ns = self._arm_stamp_ns
                if at_ns is None:
                    stamp_ns = max(stamp_ns, self._last_stamp_ns + 1)
                self._last_stamp_ns = stamp_ns
                pose = self._pose
            occluders = [] if q is None or self._arm is None else [self._arm.scene(q)]  # rebuilt when the joints moved
            depth = self._camera.render(pose, occluders)
            cfg = self.config
            cdr = frame_cdr(depth, self.intrinsics, pose, stamp_ns, cfg.encoding, cfg.frame_id, cfg.camera_frame)
            if self._tf_pub is not None:  # before the image, so a TF listener has the pose when the image comes
                pose_tf = transform_stamped_msg(pose, stamp_ns, cfg.frame_id, cfg.camera_frame)
                self._tf_pub.publish(self._tf_message(transforms=[pose_tf]))
            if self._pose_pub is not None:
                self._pose_pub.publish(cdr.pose)
            self._info_pub.publish(cdr.info)
            self._image_pub.publish(cdr.image)
            self.frames += 1
            return stamp_ns

    @property
    def camera_renders(self) -> int:
        """Ray casts of the scene so far (a still camera re-uses its last: fewer than frames)."""
        return self._camera.renders

    def _target_pose(self, msg: PoseStamped) -> np.ndarray:
        frame = msg.header.frame_id
        if frame not in ("", self.config.frame_id):
            raise ValueError(f"target frame {frame!r} is not the camera's fixed frame {self.config.frame_id!r}")
        position, quat = pose_to_arrays(msg.pose)  # raises on NaN / zero quaternion
        pose = np.eye(4)
        pose[:3, :3] = matrix_from_quaternion(quat)
        pose[:3, 3] = position
        return pose

    def _move(self, msg: PoseStamped) -> int:
        if self.config.follow_arm:
            raise ValueError("follow_arm is set: the camera moves with the arm (arm_sim/move_to_joints)")
        pose = self._target_pose(msg)
        with self._frame_lock:  # the frame shows this pose, not a pose another request set meanwhile
            with self._lock:
                self._pose = pose
            return self.publish_frame()

    # --------------------------------------------------------------- callbacks
    def _on_timer(self) -> None:
        try:
            self._publish_timer_frame()
        except ValueError as exc:
            self.get_logger().warning(str(exc), throttle_duration_sec=5.0)

    def _publish_timer_frame(self) -> None:
        if not self.config.follow_arm:
            self.publish_frame()
            return
        if self._tf is not None:
            self._arm_pose_from_tf()
        with self._frame_lock:
            with self._lock:
                latest = self._arm_pose
                if latest is None or latest[1] <= self._last_stamp_ns:
                    return  # no arm pose yet, or none newer than the last frame
                if self._arm is not None and latest[1] not in self._arm_qs:
                    return  # the joint state of that instant has not arrived yet: next tick
                self._pose = latest[0]
            self.publish_frame(latest[1])

    def _on_joint_states(self, msg: JointState) -> None:
        if self._arm is None:
            return
        try:
            self._arm_merger.update(list(msg.name), list(msg.position))  # names the robot lacks are ignored
            if not self._arm_merger.complete():
                return  # a joint has never arrived yet (e.g. the gripper's message comes next)
            q = self._arm_merger.configuration()
        except ValueError as exc:
            self.bad_joint_states += 1
            self.get_logger().warning(
                f"{exc}; ignored ({self.bad_joint_states} so far), the arm stays where it was",
                throttle_duration_sec=5.0,
            )
            return
        with self._lock:
            self._arm_q = q
            self._arm_stamp_ns = message_stamp_ns(msg.header.stamp)
            self._arm_qs[self._arm_stamp_ns] = q
            while len(self._arm_qs) > ARM_STATES_KEPT:
                self._arm_qs.pop(next(iter(self._arm_qs)))

    def _arm_pose_from_tf(self) -> None:
        """``follow_arm`` + TF: the newest pose of ``camera_frame`` in ``frame_id`` becomes the arm pose."""
        assert self._tf is not None
        try:
            pose, stamp = self._tf.lookup(self.config.frame_id, self.config.camera_frame)
        except TransformError as exc:
            self.get_logger().warning(f"no frame: no camera pose in TF yet ({exc})", throttle_duration_sec=5.0)
            return
        if stamp == 0:  # a chain of static transforms holds at any time: a frame per tick
            stamp = self.get_clock().now().nanoseconds
        with self._lock:
            self._arm_pose = (pose, stamp)

    def _on_arm_pose(self, msg: PoseStamped) -> None:
        try:
            pose = self._target_pose(msg)
        except ValueError as exc:
            self.get_logger().warning(f"arm/camera_pose ignored: {exc}", throttle_duration_sec=2.0)
            return
        with self._lock:
            self._arm_pose = (pose, message_stamp_ns(msg.header.stamp))

    def _on_move_to(self, request: MoveCamera.Request, response: MoveCamera.Response) -> MoveCamera.Response:
        try:
            stamp_ns = self._move(request.target)
        except ValueError as exc:
            response.success = False
            response.message = f"rejected: {exc}"
            self.get_logger().warning(f"move_to {response.message}")
            return response
        response.success = True
        p = request.target.pose.position
        response.message = f"moved to ({p.x:.3f}, {p.y:.3f}, {p.z:.3f}); frame published"
        response.frame_stamp = time_msg(stamp_ns)
        return response

    def _on_goal_pose(self, msg: PoseStamped) -> None:
        try:
            self._move(msg)
        except ValueError as exc:
            self.get_logger().warning(f"goal_pose rejected: {exc}", throttle_duration_sec=2.0)

    def destroy_node(self) -> None:
        if self._streams is not None:
            self._streams.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the node until interrupted; 1 on a configuration error."""
    return run_node(SimCamera, args, threads=1, summary=frame_summary)


def frame_summary(node: Node) -> str:
    """The node's last log line: frames published and ray casts they took."""
    assert isinstance(node, SimCamera)
    return f"published {node.frames} frame(s), {node.camera_renders} ray cast(s)"


if __name__ == "__main__":
    raise SystemExit(main())
