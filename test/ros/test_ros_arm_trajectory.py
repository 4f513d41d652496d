"""The robot side through standard interfaces, each node in its own process: ``arm_sim`` as a
driver (``/robot_description``, arm and gripper ``/joint_states`` apart, ``/tf`` + ``/tf_static``,
``control_msgs/FollowJointTrajectory``), and ``nbv_planner move_mode:=trajectory`` falling back to
the next ranked view when the controller rejects a trajectory."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("control_msgs")
pytest.importorskip("tf2_msgs")
pytest.importorskip("pinocchio")

from action_msgs.msg import GoalStatus  # noqa: E402
from builtin_interfaces.msg import Duration  # noqa: E402
from control_msgs.action import FollowJointTrajectory  # noqa: E402
from control_msgs.msg import JointTolerance  # noqa: E402
from explore_goals import explore_client, explore_succeeds  # noqa: E402
from nbv_prob_cnn_msgs.action import Explore  # noqa: E402
from rclpy.action import ActionServer, GoalResponse  # noqa: E402
from rclpy.callback_groups import ReentrantCallbackGroup  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from test_ros_arm_planning import ARM_PLANNER, GraphBench, SeeingIntegrator, assert_pose_close, scene  # noqa: E402
from test_ros_explore import spun_node  # noqa: E402
from test_ros_explore import wait as wait_future  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402
from trajectory_msgs.msg import JointTrajectoryPoint  # noqa: E402

from nbv_prob_cnn.arm.description import read_description  # noqa: E402
from nbv_prob_cnn.arm.robot import DEFAULT_BASE_XYZ, DEFAULT_HAND_FROM_CAMERA_XYZ, RobotModel  # noqa: E402
from nbv_prob_cnn.ros.action_client import LockedActionClient  # noqa: E402
from nbv_prob_cnn.ros.conversions import pose_to_arrays  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, send_goal_with_resend  # noqa: E402
from nbv_prob_cnn.ros.robot_params import DESCRIPTION_QOS, description_config  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

ACTION = "/arm_controller/follow_joint_trajectory"
_counter = iter(range(1000))


@pytest.fixture
def ros(tmp_path, ros_domain):
    """Domains 150..159 (this module only); a client node spun in a background thread."""
    env = ros_domain(150 + (os.getpid() + next(_counter)) % 10)
    with spun_node("arm_trajectory_test") as node:
        graph = NodeGraph(env, log_dir=tmp_path / "logs")
        yield node, graph
        graph.stop()


def wait(future, timeout_s: float = 120.0):
    return wait_future(future, timeout_s)


def seconds(value: float) -> Duration:
    return Duration(sec=int(value), nanosec=int(round((value - int(value)) * 1e9)))


def goal_of(names: list[str], points: list[tuple[float, list[float]]], **fields) -> FollowJointTrajectory.Goal:
    goal = FollowJointTrajectory.Goal(**fields)
    goal.trajectory.joint_names = names
    goal.trajectory.points = [JointTrajectoryPoint(positions=p, time_from_start=seconds(t)) for t, p in points]
    return goal


def test_arm_sim_is_a_robot_driver_with_a_trajectory_controller(ros):
    node, graph = ros
    robot = RobotModel()  # the Panda as arm_sim's default parameters place it
    arm = robot.joint_names[:7]
    graph.start_node("arm_sim", "arm_sim", {"velocity_scale": 0.5, "rate_hz": 50.0})
    seen: dict[str, object] = {}
    states: list[JointState] = []
    node.create_subscription(String, "/robot_description", lambda m: seen.setdefault("description", m.data),
                             DESCRIPTION_QOS)  # fmt: skip
    node.create_subscription(TFMessage, "/tf_static", lambda m: seen.setdefault("static", m), DESCRIPTION_QOS)
    node.create_subscription(TFMessage, "/tf", lambda m: seen.__setitem__("tf", m), 10)
    node.create_subscription(JointState, "/joint_states", states.append, 100)
    client = LockedActionClient(node, FollowJointTrajectory, ACTION)
    assert client.wait_for_server(timeout_sec=120.0)
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and (len(seen) < 3 or len(states) < 4):
        time.sleep(0.1)
    # the description with the camera and the base in it gives the model of the parameters
    config = description_config(read_description(seen["description"]), [], "world", [0, 0, 0], [0, 0, 0],
                                "camera_optical", "", [0, 0, 0], [0, 0, 0])  # fmt: skip
    from_description = RobotModel(config)
    q = robot.reference_q + 0.05
    np.testing.assert_allclose(from_description.camera_pose(q), robot.camera_pose(q), atol=1e-12)
    # the fixed joints on /tf_static: base and camera mount as given
    static = {(t.header.frame_id, t.child_frame_id): t.transform for t in seen["static"].transforms}
    base = static[("world", "panda_link0")].translation
    np.testing.assert_allclose([base.x, base.y, base.z], DEFAULT_BASE_XYZ, atol=1e-12)
    mount = static[("panda_hand", "camera_optical")].translation
    np.testing.assert_allclose([mount.x, mount.y, mount.z], DEFAULT_HAND_FROM_CAMERA_XYZ, atol=1e-12)
    moving = {(t.header.frame_id, t.child_frame_id) for t in seen["tf"].transforms}
    assert ("panda_link0", "panda_link1") in moving and ("panda_hand", "panda_leftfinger") in moving
    # the arm and the gripper in separate joint_states messages
    groups = {tuple(m.name) for m in states}
    assert groups == {tuple(arm), ("panda_finger_joint1", "panda_finger_joint2")}

    start = robot.reference_q[:7]
    target = start + np.array([0.3, -0.2, 0.0, 0.1, 0.0, 0.0, 0.0])
    # rejected: a gripper joint is not the arm controller's, a joint missing, out of limits, too fast
    for bad in (
        goal_of([*arm, "panda_finger_joint1"], [(2.0, [*target, 0.0])]),
        goal_of(arm[:6], [(2.0, list(target[:6]))]),
        goal_of(arm, [(2.0, [*target[:3], 0.5, *target[4:]])]),  # panda_joint4 must stay below 0
        goal_of(arm, [(0.1, list(target))]),  # 0.3 rad in 0.1 s: over the 2.175 rad/s limit
    ):
        handle = send_goal_with_resend(client, bad, 60.0, resend_s=5.0)
        assert not handle.accepted
    # accepted and executed: SUCCESSFUL, the joints at the goal, feedback on the way
    feedback: list = []
    handle = send_goal_with_resend(
        client, goal_of(arm, [(1.0, list(start + (target - start) / 2)), (2.0, list(target))]), 60.0,
        feedback_callback=feedback.append, resend_s=5.0,
    )  # fmt: skip
    assert handle.accepted
    done = wait(handle.get_result_async(), 30.0)
    assert done.status == GoalStatus.STATUS_SUCCEEDED
    assert done.result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
    assert feedback and list(feedback[-1].feedback.joint_names) == arm
    # joint_states reach the goal (this process's subscription may lag behind arm_sim under load)
    deadline = time.monotonic() + 5.0
    while True:
        latest = next(m for m in reversed(states) if tuple(m.name) == tuple(arm))
        if np.allclose(latest.position, target, atol=1e-6) or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    np.testing.assert_allclose(latest.position, target, atol=1e-6)
    # a trajectory at the URDF limit, with arm_sim at half of it, lags: goal tolerance violated
    back = goal_of(arm, [(0.3 / 2.175 * 1.01, list(target - np.array([0.3, 0, 0, 0, 0, 0, 0])))],
                   goal_tolerance=[JointTolerance(name=n, position=1e-3) for n in arm],
                   goal_time_tolerance=seconds(0.01))  # fmt: skip
    handle = send_goal_with_resend(client, back, 60.0, resend_s=5.0)
    assert handle.accepted
    done = wait(handle.get_result_async(), 30.0)
    assert done.status == GoalStatus.STATUS_ABORTED
    assert done.result.error_code == FollowJointTrajectory.Result.GOAL_TOLERANCE_VIOLATED
    assert "panda_joint1" in done.result.error_string
    assert graph.alive()["arm_sim"]
    # SIGINT during a 20 s trajectory: the goal is aborted where the arm is and arm_sim exits at
    # once (as a controller deactivated mid-goal), not after running the trajectory to its end
    handle = send_goal_with_resend(client, goal_of(arm, [(20.0, list(start))]), 60.0, resend_s=5.0)
    assert handle.accepted
    time.sleep(0.5)
    result_future = handle.get_result_async()
    proc = graph.processes["arm_sim"]
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=10.0) == 0
    exit_s = time.monotonic() - sent
    assert exit_s < 5.0, f"arm_sim took {exit_s:.2f} s to exit with a trajectory running"
    done = wait(result_future, 5.0)
    assert done.status == GoalStatus.STATUS_ABORTED and done.result.error_string == "arm_sim is shutting down"


#: How deep (m) a body point of the sent path may enter blocked space in the dense check: below the
#: motion of a body point over one 0.005 rad sample of the planner's verification (up to about 1 cm).
GRAZE_M = 0.005


class FakeController:
    """A FollowJointTrajectory server in the test process that rejects its first ``reject`` goals
    and executes the others by publishing the arm at their last point (the bench publishes the
    joint states), recording every goal."""

    def __init__(self, node, bench: GraphBench, robot: RobotModel, reject: int) -> None:
        self.bench, self.robot, self.reject = bench, robot, reject
        self.goals: list[FollowJointTrajectory.Goal] = []
        self.lock = threading.Lock()
        self.q: np.ndarray | None = None  # where the last executed goal left the arm
        node.create_timer(0.1, self.publish_pose)
        ActionServer(node, FollowJointTrajectory, "/fake_controller/follow_joint_trajectory",
                     execute_callback=self.execute, goal_callback=self.decide,
                     callback_group=ReentrantCallbackGroup())  # fmt: skip

    def decide(self, goal) -> GoalResponse:
        with self.lock:
            self.goals.append(goal)
            return GoalResponse.REJECT if len(self.goals) <= self.reject else GoalResponse.ACCEPT

    def execute(self, handle):
        trajectory = handle.request.trajectory
        q = np.array(self.bench.joints[1], dtype=np.float64)
        for name, value in zip(trajectory.joint_names, trajectory.points[-1].positions, strict=True):
            q[self.robot.joint_names.index(name)] = value
        self.bench.joints = (self.robot.joint_names, q)
        self.q = q
        handle.succeed()
        return FollowJointTrajectory.Result(error_code=0)

    def publish_pose(self) -> None:
        """The camera pose at the arm's configuration, stamped now (what the SeeingIntegrator sees from)."""
        if self.q is not None:
            self.bench.latest["pose"] = pose_msg(self.robot.camera_pose(self.q), self.bench.node)


def pose_msg(pose: np.ndarray, node):
    from geometry_msgs.msg import PoseStamped

    from nbv_prob_cnn.basics.camera import quaternion_from_matrix

    msg = PoseStamped()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in pose[:3, 3])
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in quaternion_from_matrix(pose[:3, :3]))
    return msg


def start_trajectory_graph(node, graph, bench: GraphBench, robot: RobotModel, reject: int, **planner_params):
    """The test's FakeController, ``nbv_planner`` (``move_mode:=trajectory``, ``planner_params``
    over :data:`ARM_PLANNER`) sending to it, a SeeingIntegrator and the bench's grid; returns the
    controller and an Explore client whose server is up."""
    controller = FakeController(node, bench, robot, reject=reject)
    planner = {**ARM_PLANNER, "move_mode": "trajectory",
               "trajectory_action": "/fake_controller/follow_joint_trajectory", **planner_params}  # fmt: skip
    graph.start_node("nbv_planner", "nbv_planner", planner)
    SeeingIntegrator(node, bench)
    bench.publish_grid()
    return controller, explore_client(node)


def workspace_goal(max_views: int, low, high, **fields) -> Explore.Goal:
    """An Explore goal whose camera positions stay in the box ``low``..``high`` (m, grid frame)."""
    goal = Explore.Goal(max_views=max_views, use_workspace=True, **fields)
    goal.workspace_min.x, goal.workspace_min.y, goal.workspace_min.z = (float(v) for v in low)
    goal.workspace_max.x, goal.workspace_max.y, goal.workspace_max.z = (float(v) for v in high)
    return goal


def test_a_rejected_trajectory_makes_the_exploration_take_the_next_ranked_view(ros):
    node, graph = ros
    robot = RobotModel()
    bench = GraphBench(node)
    bench.joints = (robot.joint_names, robot.reference_q)
    controller, client = start_trajectory_graph(node, graph, bench, robot, reject=1, max_joint_acceleration=2.0,
                                                max_joint_jerk=20.0)  # fmt: skip
    done, feedback = explore_succeeds(client, Explore.Goal(max_views=2), 300.0)
    assert done.result.views == 2 and done.result.failed_executions == 1, done.result.reason_stopped
    fbs = [m.feedback for m in feedback]
    assert [fb.executed for fb in fbs] == [False, True, True]
    assert "rejected" in fbs[0].execution_error and fbs[1].execution_error == ""
    assert fbs[0].view_index == fbs[1].view_index == 0
    rejected, taken = (tuple(np.round(np.concatenate(pose_to_arrays(fb.pose.pose)), 4)) for fb in fbs[:2])
    assert rejected != taken  # the next ranked view, not the rejected one again
    assert fbs[1].gain <= fbs[0].gain + 1e-6  # ranked after it
    # every goal the controller got is the straight joint path, within the limits, from rest to rest
    assert len(controller.goals) == 3
    vmax = np.asarray(robot.model.velocityLimit)[:7] * 0.5
    for goal in controller.goals:
        trajectory = goal.trajectory
        assert list(trajectory.joint_names) == robot.joint_names[:7]
        t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in trajectory.points])
        v = np.array([p.velocities for p in trajectory.points])
        a = np.array([p.accelerations for p in trajectory.points])
        assert np.all(np.diff(t) > 0)
        assert np.all(np.abs(v) <= vmax * (1 + 1e-6)) and np.all(np.abs(a) <= 2.0 * (1 + 1e-6))
        np.testing.assert_allclose(v[-1], 0.0, atol=1e-9)
    goal_q = np.array(controller.goals[1].trajectory.points[-1].positions)
    assert_pose_close(robot.camera_pose(np.r_[goal_q, robot.reference_q[7:]]), *pose_to_arrays(fbs[1].pose.pose))
    assert (bench.state == -1).sum() < (scene() == -1).sum()


def test_base_and_camera_mount_come_from_tf_when_the_description_lacks_them(ros, tmp_path):
    """A plain URDF file (no world link, no camera link) and TF with world → panda_link0 and
    panda_hand → camera_optical (as a robot's static transform publishers): the planner's joint
    goal puts the camera mounted as TF says at the planned view."""
    from geometry_msgs.msg import TransformStamped

    from nbv_prob_cnn.arm.robot import RobotConfig, panda_urdf, translation
    from nbv_prob_cnn.ros.tf_listener import TF_STATIC_QOS

    node, graph = ros
    bench = GraphBench(node)
    mount = translation([0.07, 0.0, 0.08])  # 3 cm further along the approach axis than the default
    robot = RobotModel(RobotConfig(parent_from_camera=mount))
    static = node.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)

    def transform(parent: str, child: str, xyz) -> TransformStamped:
        msg = TransformStamped()
        msg.header.frame_id, msg.child_frame_id = parent, child
        msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = xyz
        msg.transform.rotation.w = 1.0
        return msg

    static.publish(TFMessage(transforms=[transform("world", "panda_link0", DEFAULT_BASE_XYZ),
                                         transform("panda_hand", "camera_optical", [0.07, 0.0, 0.08])]))  # fmt: skip
    bench.joints = (robot.joint_names, robot.reference_q)
    planner = {
        **ARM_PLANNER,
        "urdf_path": str(panda_urdf()[0]),
        "camera_parent": "panda_hand",
        "base_xyz": [5.0, 5.0, 5.0],
        "camera_xyz": [0.0, 0.0, 0.0],
    }  # fmt: skip  (both wrong: TF must win)
    graph.start_node("nbv_planner", "nbv_planner", planner)
    bench.publish_grid()
    from nbv_prob_cnn_msgs.srv import PlanNextBestView
    from test_ros_arm_planning import call_when_ready

    # the joint states are published from the start, but under load the planner's reader may
    # match them after the grid's: wait for both
    _, reply = call_when_ready(node, PlanNextBestView, "/nbv/plan", PlanNextBestView.Request(top_k=5),
                               ("no grid received yet", "no joint state received yet"), 240.0)  # fmt: skip
    assert reply.success and reply.reachable, reply.message
    assert_pose_close(robot.camera_pose(np.array(reply.joint_goal.position)), *pose_to_arrays(reply.best_pose.pose))
    log = (tmp_path / "logs" / "nbv_planner.log").read_text()
    assert "placed in world by TF" in log and "on 'panda_hand' by TF" in log


def test_a_second_robot_from_parameters_alone_the_xarm6(ros):
    """The xArm6 of pybullet_data (package://xarm_description meshes) in arm_sim, and our planner
    reading it from /robot_description with only package_dirs set: Explore drives it through
    FollowJointTrajectory, each view's joint goal puts the xArm's camera at that view."""
    pybullet_data = pytest.importorskip("pybullet_data")
    from pathlib import Path

    from nbv_prob_cnn.arm.description import mount_camera
    from nbv_prob_cnn.arm.robot import RobotConfig, pose_from_xyz_rpy, translation

    node, graph = ros
    folder = Path(pybullet_data.getDataPath()) / "xarm"
    urdf = folder / "xarm6_robot.urdf"
    base, mount = [-0.1, 0.742, 0.0], [0.0, 0.0, 0.06]
    graph.start_node("arm_sim", "arm_sim", {
        "urdf_path": str(urdf), "package_dirs": [str(folder)], "camera_parent": "link6", "camera_xyz": mount,
        "base_xyz": base, "velocity_scale": 1.0,  # gripper_joints: the Panda's default names, absent here
    })  # fmt: skip
    bench = GraphBench(node)
    SeeingIntegrator(node, bench)
    planner = {k: v for k, v in ARM_PLANNER.items() if k != "urdf_path"}  # the description from the topic
    planner.update(move_mode="trajectory", package_dirs=[str(folder)], trajectory_velocity_scale=1.0,
                   max_joint_acceleration=3.0, max_joint_jerk=30.0)  # fmt: skip
    graph.start_node("nbv_planner", "nbv_planner", planner)
    bench.publish_grid()
    done, feedback = explore_succeeds(explore_client(node), Explore.Goal(max_views=2), 400.0)
    assert done.result.views == 2, done.result.reason_stopped
    # our own model of the xArm as the parameters place it (independent of the description arm_sim built)
    text = mount_camera(read_description(path=str(urdf), package_dirs=[str(folder)]), "link6", translation(mount),
                        "camera_optical", "world", pose_from_xyz_rpy(base, [0, 0, 0]))  # fmt: skip
    xarm = RobotModel(RobotConfig(description=text, world_from_base=np.eye(4), camera_parent="camera_optical",
                                  parent_from_camera=np.eye(4)))  # fmt: skip
    assert xarm.joint_names == [f"joint{i}" for i in range(1, 7)]
    for message in feedback:
        fb = message.feedback
        assert fb.executed and list(fb.joint_goal.name) == xarm.joint_names
        assert_pose_close(xarm.camera_pose(np.array(fb.joint_goal.position)), *pose_to_arrays(fb.pose.pose))
    assert (bench.state == -1).sum() < (scene() == -1).sum()
    log = (graph.log_dir / "nbv_planner.log").read_text()
    assert "characters from /robot_description" in log


def test_the_camera_workspace_holds_in_explore_goals_and_parameters(ros):
    """The Explore goal's box and the planner's height parameter keep every view inside both
    (arm, move_mode trajectory), and the box parameters hold for /nbv/plan without the arm."""
    from nbv_prob_cnn_msgs.srv import PlanNextBestView
    from test_ros_arm_planning import call_when_ready

    from nbv_prob_cnn.ros.graph import NodeGraph

    node, graph = ros
    robot = RobotModel()
    bench = GraphBench(node)
    bench.joints = (robot.joint_names, robot.reference_q)
    _, client = start_trajectory_graph(node, graph, bench, robot, reject=0, min_camera_height_m=0.3)
    goal = workspace_goal(3, (0.3, 0.2, 0.0), (0.8, 1.3, 1.0), max_camera_height=0.6)
    done, feedback = explore_succeeds(client, goal, 300.0)
    assert done.result.views >= 1, done.result.reason_stopped
    half = GEOMETRY_HALF_CELL
    for message in feedback:
        x, y, z = pose_to_arrays(message.feedback.pose.pose)[0]
        # poses are cell centres: inside the box and between the heights (the parameter's 0.3, the goal's 0.6)
        assert 0.3 - half <= x <= 0.8 + half and 0.2 - half <= y <= 1.3 + half and 0.3 - half <= z <= 0.6 + half
    graph.stop()

    free = NodeGraph(graph.env, log_dir=graph.log_dir / "free")
    box = {"workspace_min": [0.2, 0.3, 0.4], "workspace_max": [0.7, 0.9, 0.8]}
    free.start_node("nbv_planner", "nbv_planner", {"dataset": "3dt", "method": "prob_ig", "in_process": True, **box})
    try:
        request = PlanNextBestView.Request(top_k=50)
        _, reply = call_when_ready(node, PlanNextBestView, "/nbv/plan", request, "no grid received yet", 240.0)
        assert reply.success, reply.message
        for view in reply.ranked:
            x, y, z = pose_to_arrays(view.pose.pose)[0]
            assert 0.2 - half <= x <= 0.7 + half and 0.3 - half <= y <= 0.9 + half and 0.4 - half <= z <= 0.8 + half
        assert len(reply.ranked) > 5
    finally:
        free.stop()


GEOMETRY_HALF_CELL = 0.02 + 1e-9  # half of test_ros_arm_planning's 4 cm cells


def test_a_view_behind_a_pillar_is_reached_by_a_planned_path_over_follow_joint_trajectory(ros):
    """The arm starts on one side of a pillar and the Explore goal's box puts every view on the
    other: the straight joint path to the chosen view hits the pillar, so the trajectory sent over
    FollowJointTrajectory is the OMPL path around it. Checked by the independent dense sampler
    of test_arm_path_planning (0.005 rad, ten times finer than the planner's validation) on the
    polyline of the trajectory's points, against the grid the planner got."""
    from arm_checks import dense_free, first_blocked
    from test_ros_arm_planning import GEOMETRY

    from nbv_prob_cnn.arm.collision import CollisionChecker
    from nbv_prob_cnn.basics.grid import OCCUPIED, UNKNOWN

    node, graph = ros
    robot = RobotModel()
    q_start, halfway, q_far = (robot.reference_q.copy() for _ in range(3))
    q_start[0], halfway[0], q_far[0] = -0.9, 0.0, 0.9  # the base turns 1.8 rad: camera at y 0.45 -> 1.04 m
    bench = GraphBench(node)
    state = np.zeros(GEOMETRY.shape, dtype=np.int8)
    state[:, :, 0] = OCCUPIED  # the floor
    pillar = GEOMETRY.containing_cell(robot.camera_pose(halfway)[:3, 3][None])[0][0]
    state[pillar[0] - 3 : pillar[0] + 4, pillar[1] - 3 : pillar[1] + 4, : pillar[2] + 3] = OCCUPIED
    far = GEOMETRY.containing_cell(robot.camera_pose(q_far)[:3, 3][None])[0][0]
    state[max(far[0] - 4, 0) : far[0] + 5, far[1] - 4 : far[1] + 5, 1:8] = UNKNOWN  # what the views look at
    bench.state = state.copy()
    bench.joints = (robot.joint_names, q_start)
    controller, client = start_trajectory_graph(node, graph, bench, robot, reject=0, arm_path_timeout_s=5.0)
    far_camera = robot.camera_pose(q_far)[:3, 3]
    goal = workspace_goal(1, far_camera - 0.12, far_camera + 0.12)
    done, feedback = explore_succeeds(client, goal, 300.0)
    assert done.result.views == 1, done.result.reason_stopped
    assert len(controller.goals) == 1
    trajectory = controller.goals[0].trajectory
    assert list(trajectory.joint_names) == robot.joint_names[:7]
    points = np.array([p.positions for p in trajectory.points])
    fingers = np.tile(q_start[7:], (points.shape[0], 1))
    polyline = np.vstack([q_start, np.hstack([points, fingers])])  # from where the arm stood
    checker = CollisionChecker(robot, spacing=0.75 * GEOMETRY.resolution)
    q_goal = polyline[-1]
    straight = np.array([q_start, q_goal])
    assert not dense_free(
        robot, checker, GEOMETRY, state, straight, tolerance_m=GRAZE_M
    )  # straight: through the pillar
    # the path sent: free, up to grazes below the planner's sampling (1 in ~100 runs the sent path
    # grazed a pillar cell by 0.2 mm between the planner's 0.005 rad samples, where this sampler landed)
    blocked = first_blocked(robot, checker, GEOMETRY, state, polyline, tolerance_m=GRAZE_M)
    arm_line = [line for line in (graph.log_dir / "nbv_planner.log").read_text().splitlines() if "arm check" in line]
    assert not blocked, f"{blocked}; {len(points)} trajectory points; {arm_line[-1:]}"
    fb = feedback[0].feedback
    assert fb.executed and fb.execution_error == ""
    assert_pose_close(robot.camera_pose(q_goal), *pose_to_arrays(fb.pose.pose))
    length = float(np.linalg.norm(np.diff(polyline[:, :7], axis=0), axis=1).sum())
    straight = float(np.linalg.norm(q_goal[:7] - q_start[:7]))
    assert fb.joint_travel == pytest.approx(length, rel=1e-3)  # the motion is the path's length
    assert fb.joint_travel > straight * 1.01  # around the pillar, not through it
    t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in trajectory.points])
    v = np.array([p.velocities for p in trajectory.points])
    assert np.all(np.diff(t) > 0)
    assert np.all(np.abs(v) <= np.asarray(robot.model.velocityLimit)[:7] * (1 + 1e-6))
    np.testing.assert_allclose(v[-1], 0.0, atol=1e-9)
