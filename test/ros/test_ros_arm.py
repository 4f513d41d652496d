"""The ``arm_sim`` node in its own process, driven by a client node in the test process."""

from __future__ import annotations

import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("pinocchio")

from builtin_interfaces.msg import Duration  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from nbv_prob_cnn_msgs.srv import MoveToJoints  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint  # noqa: E402

from nbv_prob_cnn.arm.robot import RobotModel  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, call_with_resend  # noqa: E402

_counter = iter(range(1000))


@pytest.fixture
def ros(tmp_path, ros_domain):
    """A fresh domain (101..119, shared with test_ros_explore's 101..109 and test_ros_namespaces'
    111..119: test modules run one after another), an rclpy context and a client node for one test."""
    domain = 101 + (os.getpid() + next(_counter)) % 19
    env = ros_domain(domain)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("test_arm_client", context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    graph = NodeGraph(env, log_dir=tmp_path / "logs")
    yield node, executor, graph
    graph.stop()
    executor.remove_node(node)
    node.destroy_node()
    rclpy.shutdown(context=context)


def spin_until(executor, predicate, timeout_s: float) -> bool:
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not predicate():
        executor.spin_once(timeout_sec=0.05)
    return bool(predicate())


def test_arm_sim_moves_at_limited_speed_and_refuses_bad_goals(ros):
    node, executor, graph = ros
    graph.start_node("arm_sim", "arm_sim", {"velocity_scale": 0.5, "rate_hz": 50.0})
    robot = RobotModel()
    latest: dict[str, object] = {}
    arm, gripper = robot.joint_names[:7], robot.joint_names[7:]  # published apart, as two drivers would

    def on_joints(msg: JointState) -> None:
        latest["joints" if list(msg.name) == arm else "gripper"] = msg

    node.create_subscription(JointState, "/joint_states", on_joints, 10)
    node.create_subscription(PoseStamped, "/arm/camera_pose", lambda m: latest.__setitem__("pose", m), 10)
    assert spin_until(executor, lambda: {"joints", "gripper", "pose"} <= set(latest), 40.0), "arm_sim did not publish"
    assert list(latest["gripper"].name) == gripper
    np.testing.assert_allclose(latest["joints"].position, robot.reference_q[:7], atol=1e-9)
    np.testing.assert_allclose(latest["gripper"].position, robot.reference_q[7:], atol=1e-9)

    client = node.create_client(MoveToJoints, "/arm_sim/move_to_joints")

    def move(names, positions):  # the same goal again after 15 s without an answer (a lost request)
        request = MoveToJoints.Request(name=names, position=positions)
        return call_with_resend(client, request, 40.0, executor=executor, resend_s=15.0)

    bad = move(["elbow"], [0.1])
    assert not bad.success and "unknown joint names ['elbow']" in bad.message
    outside = move(["panda_joint4"], [1.0])  # limit is [-3.07, -0.07]
    assert not outside.success and "outside the URDF limits" in outside.message
    mismatch = move(["panda_joint1", "panda_joint2"], [0.1])
    assert not mismatch.success and "2 joint names but 1 positions" in mismatch.message

    reply = move(["panda_joint1"], [0.6])  # the node still serves
    assert reply.success
    expected = 0.6 / (0.5 * float(robot.model.velocityLimit[0]))
    assert reply.duration_s == pytest.approx(expected, rel=1e-6)
    goal = robot.configuration({"panda_joint1": 0.6})
    assert spin_until(executor, lambda: abs(latest["joints"].position[0] - 0.6) < 1e-9, expected + 10.0)
    np.testing.assert_allclose(latest["joints"].position, goal[:7], atol=1e-9)
    assert spin_until(executor, lambda: latest["pose"].header.stamp.sec > 0, 5.0)
    # the camera pose is forward kinematics of the published joints
    latest.pop("pose")
    assert spin_until(executor, lambda: "pose" in latest, 5.0)
    p = latest["pose"].pose.position
    np.testing.assert_allclose([p.x, p.y, p.z], robot.camera_pose(goal)[:3, 3], atol=1e-6)

    publisher = node.create_publisher(JointTrajectory, "/arm/joint_trajectory", 10)
    trajectory = JointTrajectory(joint_names=["panda_joint1", "panda_joint7"])
    trajectory.points = [
        JointTrajectoryPoint(positions=[0.5, 0.7], time_from_start=Duration(sec=0, nanosec=200_000_000)),
        JointTrajectoryPoint(positions=[0.4, 0.6], time_from_start=Duration(sec=0, nanosec=400_000_000)),
    ]
    publisher.publish(trajectory)
    assert spin_until(
        executor, lambda: np.allclose(np.asarray(latest["joints"].position)[[0, 6]], [0.4, 0.6], atol=1e-9), 15.0
    ), "the trajectory was not followed"
    speeds = np.abs(np.asarray(latest["joints"].velocity))
    assert np.all(speeds <= 0.5 * np.asarray(robot.model.velocityLimit)[:7] + 1e-9)
    assert graph.alive()["arm_sim"]
