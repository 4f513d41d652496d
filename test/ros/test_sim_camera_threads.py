"""``sim_camera``'s threads (issue 37, the self-filter hunt): joint states arrive on the stream
thread while a frame renders, so a slow render (a loaded machine) does not age the arm's joint
state; the frame carries the stamp of the joint state it draws."""

from __future__ import annotations

import threading

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("pinocchio")

from sensor_msgs.msg import JointState  # noqa: E402

from nbv_prob_cnn.arm.robot import RobotModel  # noqa: E402
from nbv_prob_cnn.ros import sim_camera as sim_camera_module  # noqa: E402
from nbv_prob_cnn.ros.sim_camera import SimCamera  # noqa: E402


def _joint_state(robot: RobotModel, q: np.ndarray, stamp_ns: int) -> JointState:
    msg = JointState(name=list(robot.joint_names), position=[float(v) for v in q])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


@pytest.fixture
def sim_camera(ros_domain):
    ros_domain(160)
    params = {
        "render_arm": "true",
        "rate_hz": "0.0",
        "width": "32",
        "height": "24",
        "dataset": "3dt",
        "urdf_path": "panda",
    }
    args = ["--ros-args"] + [arg for k, v in params.items() for arg in ("-p", f"{k}:={v}")]
    rclpy.init(args=args)
    node = SimCamera()
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown()


def test_joint_states_arrive_while_a_frame_renders(sim_camera, monkeypatch) -> None:
    # a joint state stamps the frame while at most ARM_STATE_MAX_AGE_NS (0.5 s) old: a loaded
    # machine takes longer than that between the test's steps, so the test allows a minute
    monkeypatch.setattr(sim_camera_module, "ARM_STATE_MAX_AGE_NS", 60 * 10**9)
    robot = sim_camera._arm.robot
    q0 = np.asarray(robot.reference_q, float)
    now = sim_camera.get_clock().now().nanoseconds
    sim_camera._on_joint_states(_joint_state(robot, q0, now))
    rendering, release = threading.Event(), threading.Event()
    real_render = sim_camera._camera.render

    def held_render(pose, occluders):  # a render that lasts until the test releases it
        rendering.set()
        release.wait(30.0)
        return real_render(pose, occluders)

    sim_camera._camera.render = held_render
    stamps: list[int] = []
    frame = threading.Thread(target=lambda: stamps.append(sim_camera.publish_frame()))
    frame.start()
    try:
        assert rendering.wait(30.0), "the frame never started rendering"
        q1 = q0 + 0.1
        later = now + 100_000_000
        callback = threading.Thread(target=sim_camera._on_joint_states, args=(_joint_state(robot, q1, later),))
        callback.start()
        callback.join(10.0)
        # the joint state went in while the frame was still rendering (the render held the lock
        # the callback needs: the callback waited for the whole render)
        assert not callback.is_alive(), "the joint-state callback waited for the render"
        assert not release.is_set()
    finally:
        release.set()
        frame.join(30.0)
    assert stamps == [now]  # the first frame: the joint state it drew
    assert sim_camera.publish_frame() == later  # the next frame: the newer joint state's stamp
