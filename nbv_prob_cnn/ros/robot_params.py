"""The robot description every node that models the arm reads, and the conversions between
``sensor_msgs/JointState`` and configuration vectors.

``arm_sim`` moves the arm; ``sim_camera`` renders it, ``integrator`` filters it out of the depth
images and ``nbv_planner`` / ``gain_server`` plan views it can reach. They all read the robot as a
ROS graph carries it (:meth:`RobotParams.robot_config`):

1. the description: the ``robot_description`` parameter (URDF or xacro text), else ``urdf_path``
   (a ``.urdf`` or ``.xacro`` file; ``panda`` = the Panda of ``pybullet_data``), else the
   ``robot_description`` topic (``std_msgs/String``, transient local, as ``robot_state_publisher``
   serves it), waited for ``description_timeout_s``; ``package://`` resolved through
   ``package_dirs``, ``AMENT_PREFIX_PATH`` and ``ROS_PACKAGE_PATH``;
2. where it stands: a link ``world_frame`` in the description places it (its root), else TF
   (``world_frame`` → the root link, waited for ``tf_timeout_s``), else ``base_xyz`` / ``base_rpy``;
3. the camera: a link ``camera_frame`` (the images' optical frame) in the description is the
   camera, else TF (``camera_parent`` → ``camera_frame``), else ``camera_xyz`` / ``camera_rpy`` on
   ``camera_parent``.

So a graph with ``arm_sim`` (or a real driver) publishing the description with the camera in it
needs none of the pose parameters.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from nbv_prob_cnn.arm.description import read_description, urdf_links, urdf_root_link
from nbv_prob_cnn.arm.joint_states import JointStateMerger
from nbv_prob_cnn.arm.robot import (
    DEFAULT_BASE_XYZ,
    DEFAULT_HAND_FROM_CAMERA_XYZ,
    RobotConfig,
    RobotModel,
    pose_from_xyz_rpy,
    robot_config,
)
from nbv_prob_cnn.basics.interrupt import Interrupt, wait_on
from nbv_prob_cnn.perception.messages import stamp_ns
from nbv_prob_cnn.ros.parameters import param

if TYPE_CHECKING:
    from nbv_prob_cnn.ros.tf_listener import TfListener

#: ``urdf_path`` value of the built-in robot: the Franka Panda of ``pybullet_data``.
BUILTIN_PANDA = "panda"
#: Topic of the description (relative: ``/robot_description`` without a namespace).
ROBOT_DESCRIPTION = "robot_description"
#: QoS of ``robot_description``: the last message kept for late joiners (as robot_state_publisher).
DESCRIPTION_QOS = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


@dataclass
class RobotParams:
    """Robot description parameters (read-only after start-up); default: the ``robot_description`` topic."""

    robot_description: str = param("", "URDF or xacro text of the robot (empty: urdf_path, else the topic)")
    urdf_path: str = param(
        "", "URDF or .xacro file of the robot, 'panda' = the Panda of pybullet_data (empty: robot_description topic)"
    )
    xacro_args: list = param([""], "xacro arguments name:=value (['']: none)")
    package_dirs: list = param([""], "folders searched first for package://<pkg>/ (the package's folder or its parent)")
    description_timeout_s: float = param(60.0, "wait for the robot_description topic", min_value=0.1, max_value=3600.0)
    tf_timeout_s: float = param(
        5.0, "wait for TF of the base / camera mount the description lacks (then the parameters)", min_value=0.0,
        max_value=600.0,
    )  # fmt: skip
    world_frame: str = param(
        "world", "fixed frame the robot stands in: a link of this name in the description places it"
    )
    base_xyz: list = param(
        list(DEFAULT_BASE_XYZ), "root link position in world_frame (m), when the description has no world_frame link"
    )
    base_rpy: list = param(
        [0.0, 0.0, 0.0], "root link roll, pitch, yaw (rad), when the description has no world_frame link"
    )
    camera_frame: str = param(
        "camera_optical", "optical frame of the depth images: a link of this name in the description is the camera"
    )
    camera_parent: str = param(
        "", "link carrying the camera, when the description has no camera_frame link (empty = panda_hand)"
    )
    camera_xyz: list = param(list(DEFAULT_HAND_FROM_CAMERA_XYZ), "optical frame on camera_parent (m), as camera_parent")
    camera_rpy: list = param([0.0, 0.0, 0.0], "optical frame roll, pitch, yaw on camera_parent (rad), as camera_parent")

    def robot_config(self, node: Node | None = None) -> RobotConfig:
        """The core :class:`~nbv_prob_cnn.arm.robot.RobotConfig` these parameters describe; reads
        the ``robot_description`` topic through ``node`` when neither text nor file is given.

        Raises:
            ValueError: no description in time, a missing package, a xacro error, a custom URDF
                without the camera (no ``camera_frame`` link, no ``camera_parent``), bad poses.
        """
        dirs = [d for d in self.package_dirs if d]
        if not self.robot_description and self.urdf_path == BUILTIN_PANDA:
            return robot_config("", self.base_xyz, self.base_rpy, self.camera_parent, self.camera_xyz,
                                self.camera_rpy, dirs)  # fmt: skip
        if node is None:
            text = self.robot_description
            if not text and not self.urdf_path:
                raise ValueError("robot description: no robot_description or urdf_path, and no node to read the topic")
            urdf = read_description(text, self.urdf_path, dirs, xacro_arguments(self.xacro_args))
            return description_config(urdf, dirs, self.world_frame, self.base_xyz, self.base_rpy, self.camera_frame,
                                      self.camera_parent, self.camera_xyz, self.camera_rpy)  # fmt: skip
        with GraphReader(node) as reader:
            text = self.robot_description
            if not text and not self.urdf_path:
                text = reader.robot_description(self.description_timeout_s)
            urdf = read_description(text, self.urdf_path, dirs, xacro_arguments(self.xacro_args))
            return description_config(
                urdf, dirs, self.world_frame, self.base_xyz, self.base_rpy, self.camera_frame, self.camera_parent,
                self.camera_xyz, self.camera_rpy, lambda target, source: reader.transform(target, source,
                                                                                         self.tf_timeout_s),
                node.get_logger().info,
            )  # fmt: skip


def xacro_arguments(values: list) -> dict[str, str]:
    """``name:=value`` strings as a mapping.

    Raises:
        ValueError: an entry without ``:=``.
    """
    mappings = {}
    for item in values:
        if not item:
            continue
        name, sep, value = str(item).partition(":=")
        if not sep or not name:
            raise ValueError(f"xacro_args: expected name:=value, got {item!r}")
        mappings[name] = value
    return mappings


def description_config(
    urdf: str,
    package_dirs: list[str],
    world_frame: str,
    base_xyz,
    base_rpy,
    camera_frame: str,
    camera_parent: str,
    camera_xyz,
    camera_rpy,
    lookup: Callable[[str, str], np.ndarray | None] | None = None,
    log: Callable[[str], object] | None = None,
) -> RobotConfig:
    """The :class:`RobotConfig` of a resolved URDF text: placed by its ``world_frame`` root link
    when it has one, else by ``lookup(world_frame, root)`` (TF), else by the base parameters; the
    camera at its ``camera_frame`` link when it has one, else at ``lookup(camera_parent,
    camera_frame)``, else at the mount parameters on ``camera_parent``.

    Raises:
        ValueError: ``world_frame`` is a link but not the root; no camera (see above).
    """
    links = urdf_links(urdf)
    say = log or (lambda _: None)
    root = urdf_root_link(urdf)
    if world_frame and world_frame in links:
        if root != world_frame:
            raise ValueError(f"robot description: link {world_frame!r} (world_frame) is not the root")
        world_from_base = np.eye(4)
        say(f"robot description: stands in {world_frame} (its root link)")
    else:
        found = lookup(world_frame, root) if lookup is not None else None
        world_from_base = found if found is not None else pose_from_xyz_rpy(base_xyz, base_rpy)
        say(f"robot description: root {root!r} placed in {world_frame} by " + ("TF" if found is not None else
            f"base_xyz {list(base_xyz)} / base_rpy {list(base_rpy)}"))  # fmt: skip
    if camera_frame and camera_frame in links:
        parent, mount = camera_frame, np.eye(4)
        say(f"robot description: camera at its link {camera_frame!r}")
    elif camera_parent:
        found = lookup(camera_parent, camera_frame) if lookup is not None else None
        parent = camera_parent
        mount = found if found is not None else pose_from_xyz_rpy(camera_xyz, camera_rpy)
        say(f"robot description: camera {camera_frame!r} on {camera_parent!r} by " + ("TF" if found is not None else
            f"camera_xyz {list(camera_xyz)} / camera_rpy {list(camera_rpy)}"))  # fmt: skip
    else:
        raise ValueError(
            f"robot description: no link {camera_frame!r} (camera_frame) and no camera_parent; "
            f"set camera_frame to the optical frame's link, or camera_parent + camera_xyz/camera_rpy"
        )
    return RobotConfig(
        description=urdf, package_dirs=tuple(package_dirs), world_from_base=world_from_base,
        camera_parent=parent, parent_from_camera=mount,
    )  # fmt: skip


class GraphReader:
    """A helper node beside ``node`` (same namespace and remappings; ``node`` is not spun yet
    while it builds itself) that reads the latest ``robot_description`` (``std_msgs/String``,
    transient local) and TF lookups; a context manager that destroys it afterwards."""

    def __init__(self, node: Node) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node = node
        self.helper = rclpy.create_node(f"{node.get_name()}_robot_reader", namespace=node.get_namespace(),
                                        context=node.context)  # fmt: skip
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(self.helper)
        self._descriptions: list[str] = []
        self._tf: TfListener | None = None

    def __enter__(self) -> GraphReader:
        return self

    def __exit__(self, *exc) -> None:
        self.executor.shutdown()
        self.helper.destroy_node()

    def _spin_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
        return done()

    def robot_description(self, timeout_s: float) -> str:
        """The latest description on the ``robot_description`` topic.

        Raises:
            ValueError: nothing within ``timeout_s``.
        """
        topic = self.helper.resolve_topic_name(ROBOT_DESCRIPTION)

        def on_description(msg: String) -> None:
            self._descriptions.append(msg.data)

        self.helper.create_subscription(String, ROBOT_DESCRIPTION, on_description, DESCRIPTION_QOS)
        if not self._spin_until(lambda: bool(self._descriptions), timeout_s):
            raise ValueError(
                f"robot description: nothing on {topic} within {timeout_s:g} s (start the robot's "
                "robot_state_publisher, or set robot_description / urdf_path)"
            )
        self.node.get_logger().info(f"robot description: {len(self._descriptions[-1])} characters from {topic}")
        return self._descriptions[-1]

    def transform(self, target: str, source: str, timeout_s: float) -> np.ndarray | None:
        """``target_from_source`` (4×4) by TF, latest; None when TF has none within ``timeout_s``."""
        from nbv_prob_cnn.perception.tf_buffer import TransformError
        from nbv_prob_cnn.ros.tf_listener import TfListener

        if self._tf is None:
            self._tf = TfListener(self.helper)
        tf = self._tf
        found: list[np.ndarray] = []

        def ready() -> bool:
            if not found:
                try:
                    found.append(tf.lookup(target, source)[0])
                except TransformError:
                    return False
            return True

        return found[0] if self._spin_until(ready, timeout_s) else None


def wait_for_robot_description(node: Node, timeout_s: float) -> str:
    """The latest ``robot_description`` seen beside ``node`` (see :class:`GraphReader`).

    Raises:
        ValueError: nothing within ``timeout_s``.
    """
    with GraphReader(node) as reader:
        return reader.robot_description(timeout_s)


@dataclass
class ArmViewParams(RobotParams):
    """The robot description plus the switch and the scene prior of nodes that check views with the arm."""

    use_arm: bool = param(False, "only views the arm reaches collision-free (IK + collision checks)")
    free_above_m: float = param(
        0.25, "tabletop prior: unknown cells at or above this height (m) do not block the arm; < 0 = all block",
        min_value=-1.0, max_value=100.0,
    )  # fmt: skip

    def free_above(self) -> float | None:
        """The prior as the core takes it (None: every unknown cell blocks)."""
        return None if self.free_above_m < 0 else float(self.free_above_m)


def joint_state_msg(robot: RobotModel, q: np.ndarray | None) -> JointState:
    """``sensor_msgs/JointState`` of a configuration (every joint, URDF order); empty for None."""
    msg = JointState()
    if q is not None:
        msg.name = list(robot.joint_names)
        msg.position = [float(v) for v in robot.check_q(q)]
    return msg


def merged_joint_state(merger: JointStateMerger, msg):
    """A joint state message (rclpy or rosbags) merged into every joint of the robot: a copy
    naming all of them, ``None`` while some never arrived; a malformed one is returned as it is,
    so that its conversion reports the error.

    The copy keeps the header and carries no velocities or efforts.
    """
    try:
        merger.update(list(msg.name), list(msg.position))
    except ValueError:
        return msg
    if not merger.complete():
        return None
    q = merger.configuration()
    if dataclasses.is_dataclass(msg) and not isinstance(msg, type):  # rosbags message
        return dataclasses.replace(msg, name=list(merger.joint_names), position=q, velocity=np.zeros(0),
                                   effort=np.zeros(0))  # fmt: skip
    return JointState(header=msg.header, name=list(merger.joint_names), position=[float(v) for v in q])


class JointStateTracker:
    """The robot's configuration from ``joint_states`` (subscription callback
    :meth:`on_joint_state`), merged over partial messages (:class:`JointStateMerger`: names the
    robot lacks are ignored, a joint is missing until its first position arrives). A malformed
    message is kept as the error, so the next request reports it instead of planning from a stale
    configuration; the next good message clears it."""

    def __init__(self, robot: RobotModel) -> None:
        self.robot = robot
        self._condition = threading.Condition()
        self._merger = JointStateMerger(robot.joint_names)
        self._q: np.ndarray | None = None  # the merged configuration once complete
        self._stamp_ns = -1
        self._error = ""
        self._arrived = False

    def on_joint_state(self, msg: JointState) -> str:
        """Merge one message; returns its error ("" when it was valid)."""
        with self._condition:
            try:
                self._merger.update(msg.name, msg.position)
                self._error = ""
                if self._merger.complete():
                    self._q = self._merger.configuration()
            except ValueError as exc:
                self._error = str(exc)
            self._arrived = True
            self._stamp_ns = stamp_ns(msg.header.stamp)
            self._condition.notify_all()
            return self._error

    def ignored_names(self) -> list[str]:
        """Names seen on joint_states that the robot lacks."""
        with self._condition:
            return sorted(self._merger.ignored)

    def current(self) -> tuple[np.ndarray, int]:
        """The merged configuration and the stamp (ns) of the latest message.

        Raises:
            ValueError: no joint state yet, joints never received (named), or the latest message
                was malformed.
        """
        with self._condition:
            return self._checked()

    def current_or(self, default: np.ndarray) -> np.ndarray:
        """The merged configuration, or ``default`` before any joint state arrived.

        Raises:
            ValueError: the latest message was malformed, or joints are still missing.
        """
        with self._condition:
            return default if not self._arrived else self._checked()[0]

    def _checked(self) -> tuple[np.ndarray, int]:
        if self._error:
            raise ValueError(self._error)
        if not self._arrived:
            raise ValueError("no joint state received yet on joint_states")
        # before every joint arrived, the merger's configuration raises, naming the joints never received
        q = self._q if self._q is not None else self._merger.configuration()
        return q.copy(), self._stamp_ns

    def wait_for_first(self, timeout_s: float, interrupt: Interrupt | None = None) -> None:
        """Wait until every joint of the robot has a position (or a malformed message arrived).

        Raises:
            TimeoutError: not within ``timeout_s`` (the message names the missing joints).
            WaitInterruptedError: ``interrupt`` was triggered first.
        """
        with self._condition:
            if not wait_on(self._condition, lambda: self._q is not None or bool(self._error), timeout_s, interrupt):
                missing = self._merger.missing()
                raise TimeoutError(
                    f"no complete joint state on joint_states within {timeout_s:g} s (never received: {missing})"
                )

    def wait_until(
        self,
        goal: np.ndarray,
        tolerance: float,
        min_stamp_ns: int,
        timeout_s: float,
        interrupt: Interrupt | None = None,
    ) -> int:
        """Wait until a joint state stamped at or after ``min_stamp_ns`` is within ``tolerance``
        (max abs difference, rad or m) of ``goal``; returns its stamp (ns).

        Raises:
            ValueError: a malformed joint state arrives meanwhile.
            TimeoutError: not reached in time.
            WaitInterruptedError: ``interrupt`` was triggered first.
        """

        def done() -> bool:
            if self._error:
                return True
            if self._q is None or self._stamp_ns < min_stamp_ns:
                return False
            return float(np.max(np.abs(self._q - goal))) <= tolerance

        with self._condition:
            if not wait_on(self._condition, done, timeout_s, interrupt):
                q = "none" if self._q is None else f"{float(np.max(np.abs(self._q - goal))):.4f} away"
                raise TimeoutError(f"joint_states did not reach the joint goal within {timeout_s:.0f} s (last: {q})")
            return self._checked()[1]
