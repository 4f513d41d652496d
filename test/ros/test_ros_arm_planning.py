"""``nbv_planner`` and ``gain_server`` with the arm (``use_arm``), and ``Explore`` driving
``arm_sim`` (``move_mode:=arm``), each node in its own process; the test process publishes the
grid (and, where no arm_sim runs, the joint states) and checks the answers against pinocchio's
forward kinematics and the collision checker."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")
pytest.importorskip("pinocchio")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from explore_goals import explore_client, explore_succeeds  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from nbv_prob_cnn_msgs.action import Explore  # noqa: E402
from nbv_prob_cnn_msgs.msg import VoxelGrid  # noqa: E402
from nbv_prob_cnn_msgs.srv import EvaluateViews, PlanNextBestView  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from test_ros_explore import spun_node  # noqa: E402
from test_ros_explore import wait as wait_future  # noqa: E402

from nbv_prob_cnn.arm.collision import CollisionChecker, GridObstacles  # noqa: E402
from nbv_prob_cnn.arm.robot import RobotConfig, RobotModel  # noqa: E402
from nbv_prob_cnn.arm.selection import ArmViewSelector  # noqa: E402
from nbv_prob_cnn.arm.swept import SweptVolume  # noqa: E402
from nbv_prob_cnn.arm.views import ArmPlanningSetup  # noqa: E402
from nbv_prob_cnn.basics.camera import matrix_from_quaternion, quaternion_from_matrix  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner  # noqa: E402
from nbv_prob_cnn.planners.requests import planning_context  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg, pose_to_arrays  # noqa: E402
from nbv_prob_cnn.ros.graph import NodeGraph, call_with_resend  # noqa: E402
from nbv_prob_cnn.ros.qos import GRID_QOS  # noqa: E402
from nbv_prob_cnn.ros.readiness import planner_readiness  # noqa: E402

pytestmark = pytest.mark.slow  # multi-process ROS graphs

#: 0.96 × 1.28 × 0.96 m in front of the Panda's default base (x = -0.1, y = 0.742).
GEOMETRY = GridGeometry((0.0, 0.102, 0.0), 0.04, (24, 32, 24))
#: Planner settings that keep a plan short on this small grid: no capability map (every ranked
#: view gets the exact check), every unknown cell blocks the arm.
ARM_PLANNER = {
    "dataset": "3dt", "method": "prob_ig", "in_process": True, "use_arm": True, "capability_stride": 0,
    "urdf_path": "panda",  # the built-in robot: the test publishes the joint states, no robot_description
    "arm_top_k": 300, "arm_max_checks": 0, "free_above_m": -1.0, "markers_top_k": 1,
}  # fmt: skip
_counter = iter(range(1000))


def scene() -> np.ndarray:
    """Floor, one unknown box on it, unknown strips along both y ends; the rest known empty."""
    state = np.zeros(GEOMETRY.shape, dtype=np.int8)
    state[:, :, 0] = 1
    state[10:16, 12:20, 1:6] = -1
    state[14:, :3, 1:10] = -1
    state[14:, -3:, 1:10] = -1
    return state


class GraphBench:
    """The test process's node: publishes the grid (stamped on request) and joint states, keeps
    the latest joint state and arm camera pose."""

    def __init__(self, node) -> None:
        self.node = node
        self.state = scene()
        self.joints: list | None = None  # (names, positions) published at 20 Hz when set
        self.latest: dict[str, object] = {}
        self.grid_pub = node.create_publisher(VoxelGrid, "/nbv/grid", GRID_QOS)
        self.joint_pub = node.create_publisher(JointState, "/joint_states", 10)
        node.create_subscription(JointState, "/joint_states", self.on_joints, 10)
        node.create_subscription(PoseStamped, "/arm/camera_pose", self.on_arm_pose, 10)
        node.create_timer(0.05, self.publish_joints)

    def publish_grid(self, stamp=None) -> None:
        msg = grid_to_msg(self.state, GEOMETRY)
        msg.header.stamp = stamp if stamp is not None else self.node.get_clock().now().to_msg()
        self.grid_pub.publish(msg)

    def publish_joints(self) -> None:
        if self.joints is not None:
            msg = JointState(name=self.joints[0], position=[float(v) for v in self.joints[1]])
            msg.header.stamp = self.node.get_clock().now().to_msg()
            self.joint_pub.publish(msg)

    def on_joints(self, msg: JointState) -> None:
        self.latest["joints"] = msg
        if len(msg.name) == 7:  # arm_sim publishes the Panda's arm and gripper joints apart
            self.latest["arm_joints"] = msg

    def on_arm_pose(self, msg: PoseStamped) -> None:
        self.latest["pose"] = msg


@pytest.fixture
def ros(tmp_path, ros_domain):
    """Domains 140..149 (this module only); a client node spun in a background thread."""
    env = ros_domain(140 + (os.getpid() + next(_counter)) % 10)
    with spun_node("arm_planning_test") as node:
        bench = GraphBench(node)
        graph = NodeGraph(env, log_dir=tmp_path / "logs")
        yield node, bench, graph
        graph.stop()


def wait(future, timeout_s: float = 120.0):
    """:func:`test_ros_explore.wait` with this module's longer default (arm planning checks IK)."""
    return wait_future(future, timeout_s)


def call_when_ready(node, srv_type, name: str, request, not_ready: str | tuple[str, ...], timeout_s: float = 120.0):
    """Call until the answer no longer says ``not_ready`` (one message or several: e.g. the node
    has not got the grid or the joint states yet)."""
    client = node.create_client(srv_type, name)
    deadline = time.monotonic() + timeout_s
    waits = (not_ready,) if isinstance(not_ready, str) else not_ready
    while True:  # planning checks IK: resend only after 30 s without an answer
        reply = call_with_resend(client, request, timeout_s, resend_s=30.0)
        if not any(text in reply.message for text in waits) or time.monotonic() > deadline:
            return client, reply
        time.sleep(0.2)


def matrix(position, quaternion) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = matrix_from_quaternion(quaternion), position
    return pose


def assert_pose_close(actual: np.ndarray, position, quaternion, atol_m: float = 2e-3) -> None:
    np.testing.assert_allclose(actual[:3, 3], position, atol=atol_m)
    q = quaternion_from_matrix(actual[:3, :3])
    assert abs(float(np.dot(q, np.asarray(quaternion) / np.linalg.norm(quaternion)))) > np.cos(0.01)


def test_plan_with_arm_answers_a_reachable_view_with_its_joint_goal(ros):
    node, bench, graph = ros
    robot = RobotModel()
    readiness: list[tuple[bytes, str]] = []  # the planner's states on /diagnostics, in order of arrival
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda msg: readiness.append(planner_readiness(msg) or (b"", "")), 10)  # fmt: skip
    graph.start_node("nbv_planner", "nbv_planner", ARM_PLANNER)
    deadline = time.monotonic() + 60.0
    while not readiness and time.monotonic() < deadline:
        time.sleep(0.1)
    # before any grid the arm set-up has not started: not ready, and saying why
    assert readiness and readiness[0] == (DiagnosticStatus.WARN, "waiting for the first grid")
    bench.publish_grid()
    request = PlanNextBestView.Request(top_k=5)
    client, reply = call_when_ready(node, PlanNextBestView, "/nbv/plan", request, "no grid received yet")
    # no joint state yet: a clear error, not a plan from a guessed configuration
    assert not reply.success and "no joint state received yet on joint_states" in reply.message

    def plan_with(names, positions):
        bench.joints = (names, positions)
        time.sleep(0.5)
        return wait(client.call_async(request))

    # the arm's joints alone (the gripper publishes apart): the gripper's are missing until they arrive
    partial = plan_with(robot.joint_names[:7], robot.reference_q[:7])
    assert not partial.success and not partial.reachable
    assert "no position received yet for joints ['panda_finger_joint1', 'panda_finger_joint2']" in partial.message
    malformed = plan_with(["panda_joint1", "panda_joint1"], [0.0, 0.0])
    assert not malformed.success and "duplicate joint names ['panda_joint1']" in malformed.message

    start = robot.reference_q
    ok = plan_with([*robot.joint_names, "drive_joint"], [*start, 0.2])  # an extra name is ignored; still serving
    assert ok.success, ok.message
    assert ok.reachable and list(ok.joint_goal.name) == robot.joint_names
    goal = np.array(ok.joint_goal.position)
    position, quaternion = pose_to_arrays(ok.best_pose.pose)
    assert_pose_close(robot.camera_pose(goal), position, quaternion)  # FK of the joint goal = the pose
    assert robot.within_limits(goal, tol=1e-9)
    checker = CollisionChecker(robot, spacing=0.75 * GEOMETRY.resolution)
    obstacles = GridObstacles.from_state(bench.state, GEOMETRY).cleared(checker.body_points(start))
    assert checker.is_free(goal, obstacles) and checker.path_is_free(start, goal, obstacles, 0.1)
    chain = np.arange(7)  # the Panda's arm joints move the camera, the fingers do not
    assert ok.joint_path_length == pytest.approx(np.linalg.norm(goal[chain] - start[chain]), abs=1e-9)
    assert 0 < ok.best_gain <= ok.ranked[0].gain + 1e-6  # the best reachable view, not above the best view
    cell = GEOMETRY.containing_cell(np.asarray(position)[None])[0][0]
    assert bench.state[tuple(cell)] == 0  # a known-empty cell
    # the core's selector (node defaults: swept space from the joint state seen, 4 IK alternatives,
    # strict capability lookup, near-camera fallback) chooses the same view and joint goal
    setup = ArmPlanningSetup(RobotConfig(), 0.0, None, 0, 0, ik_alternatives=4, strict_capability=True)
    arm = setup.feasibility(GEOMETRY)
    selector = ArmViewSelector(arm, GEOMETRY, SweptVolume(arm.checker, GEOMETRY), fallback_radius_m=0.25)
    selector.swept.add_configuration(start)
    context = planning_context("3dt", GEOMETRY, "auto", 0, np.random.default_rng(0))
    core = selector.select(GainPlanner(GAIN_METHODS["prob_ig"]), bench.state, context, start, 300).view
    assert core is not None
    assert_pose_close(robot.camera_pose(core.q), position, quaternion)
    np.testing.assert_allclose(core.q, goal, atol=1e-6)  # the same IK solution (the base pose via parameters)
    assert graph.alive()["nbv_planner"]
    # the grid started the arm set-up (WARN while it ran: at least the status sent at its start)
    # and it ended ready
    assert (DiagnosticStatus.WARN, "arm set-up for the grid running") in readiness
    assert readiness[-1] == (DiagnosticStatus.OK, "ready")


def test_evaluate_views_reports_reachability_and_ik_solutions(ros):
    node, bench, graph = ros
    robot = RobotModel()
    graph.start_node("gain_server", "gain_server", {"dataset": "3dt", "use_arm": True, "free_above_m": -1.0,
                                                  "urdf_path": "panda"})  # fmt: skip
    bench.publish_grid()
    at_reference = robot.camera_pose(robot.reference_q)
    poses = []
    for position, quaternion in (
        (at_reference[:3, 3], quaternion_from_matrix(at_reference[:3, :3])),  # where the camera is
        ((3.0, 3.0, 0.5), (0.0, 0.0, 0.0, 1.0)),  # 3 m away: out of reach (and outside the grid)
        ((np.nan, 0.5, 0.5), (0.0, 0.0, 0.0, 1.0)),
    ):
        pose = PoseStamped()
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in position)
        o = pose.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
        poses.append(pose)
    request = EvaluateViews.Request(poses=poses, method="prob_ig")
    client, reply = call_when_ready(node, EvaluateViews, "/nbv/evaluate_views", request, "no grid received yet")
    assert reply.success, reply.message
    assert list(reply.reachable) == [True, False, False]
    assert "1 reachable by the arm" in reply.message
    solution = reply.ik_solutions[0]
    assert list(solution.name) == robot.joint_names
    assert_pose_close(robot.camera_pose(np.array(solution.position)), *pose_to_arrays(poses[0].pose))
    assert [list(s.name) for s in reply.ik_solutions[1:]] == [[], []]
    assert list(reply.validity)[1:] == [EvaluateViews.Request.OUTSIDE_GRID, EvaluateViews.Request.INVALID_POSE]

    bench.joints = ([*robot.joint_names, "drive_joint"], [*robot.reference_q, 0.3])  # an extra name is ignored
    time.sleep(0.5)
    extra = wait(client.call_async(request))
    assert extra.success and list(extra.reachable) == [True, False, False], extra.message
    bench.joints = (["panda_joint1", "panda_joint1"], [0.0, 0.0])  # malformed (a name twice): a clear error ...
    time.sleep(0.5)
    wrong = wait(client.call_async(request))
    assert not wrong.success and "duplicate joint names ['panda_joint1']" in wrong.message
    assert list(wrong.validity) == [EvaluateViews.Request.INVALID_POSE] * 3  # an error reply marks no pose valid
    assert list(wrong.reachable) == []
    bench.joints = (robot.joint_names, robot.reference_q)  # ... and the server keeps serving
    time.sleep(0.5)
    again = wait(client.call_async(request))
    assert again.success and list(again.reachable) == [True, False, False]


class SeeingIntegrator:
    """Stands in for sim_camera + integrator: at 5 Hz it marks the unknown cells within 12° of the
    arm camera's optical axis as seen empty and publishes the grid stamped with that pose's stamp."""

    def __init__(self, node, bench: GraphBench) -> None:
        self.bench = bench
        node.create_timer(0.2, self.tick)

    def tick(self) -> None:
        msg = self.bench.latest.get("pose")
        if msg is None:
            return
        position, quaternion = pose_to_arrays(msg.pose)
        axis = matrix_from_quaternion(quaternion)[:, 2]
        unknown = np.argwhere(self.bench.state == -1)
        if unknown.size:
            rays = GEOMETRY.cell_centre(unknown) - position
            cosine = rays @ axis / np.linalg.norm(rays, axis=1)
            seen = unknown[cosine > np.cos(np.radians(12.0))]
            self.bench.state[seen[:, 0], seen[:, 1], seen[:, 2]] = 0
        self.bench.publish_grid(msg.header.stamp)


def test_explore_drives_the_arm_through_arm_sim(ros):
    node, bench, graph = ros
    robot = RobotModel()
    graph.start_node("arm_sim", "arm_sim", {"velocity_scale": 1.0, "rate_hz": 50.0})
    graph.start_node("nbv_planner", "nbv_planner", {**ARM_PLANNER, "move_mode": "arm"})
    SeeingIntegrator(node, bench)
    done, feedback = explore_succeeds(explore_client(node), Explore.Goal(max_views=3), 300.0)
    assert done.result.views == 3 == len(feedback), done.result.reason_stopped
    previous = robot.reference_q
    for message in feedback:
        fb = message.feedback
        assert list(fb.joint_goal.name) == robot.joint_names
        goal = np.array(fb.joint_goal.position)
        assert_pose_close(robot.camera_pose(goal), *pose_to_arrays(fb.pose.pose))
        assert fb.joint_travel == pytest.approx(np.linalg.norm(goal[:7] - previous[:7]), abs=1e-9)
        previous = goal
    assert sum(m.feedback.joint_travel for m in feedback) > 0.1  # the arm really moved
    views = {tuple(np.round(np.concatenate(pose_to_arrays(m.feedback.pose.pose)), 4)) for m in feedback}
    assert len(views) == 3  # no view taken twice
    # arm_sim is at the last goal and its camera at the last view
    time.sleep(0.5)
    np.testing.assert_allclose(bench.latest["arm_joints"].position, previous[:7], atol=1e-3)  # the gripper apart
    assert_pose_close(
        matrix(*pose_to_arrays(bench.latest["pose"].pose)), *pose_to_arrays(feedback[-1].feedback.pose.pose)
    )
    assert (bench.state == -1).sum() < (scene() == -1).sum()  # the views saw something


def test_plan_with_arm_through_the_servers_ranks_only_origins_the_arm_reaches(ros):
    """Over /nbv/rank_views the capability map travels as allowed origins: every ranked view lies
    where the map says the arm may reach, and the chosen view is reachable."""
    from nbv_prob_cnn.arm.capability import load_or_build_capability_map

    node, bench, graph = ros
    robot = RobotModel()
    graph.start_node("gain_server", "gain_server", {"dataset": "3dt", "method": "prob_ig"})
    planner = {**ARM_PLANNER, "in_process": False, "capability_stride": 4, "arm_max_checks": 30}
    graph.start_node("nbv_planner", "nbv_planner", planner)
    bench.publish_grid()
    bench.joints = (robot.joint_names, robot.reference_q)
    request = PlanNextBestView.Request(top_k=1000)
    not_ready = ("no grid received yet", "no joint state received yet")  # under load either may come last
    _, reply = call_when_ready(node, PlanNextBestView, "/nbv/plan", request, not_ready, 240.0)
    assert reply.success and reply.reachable, reply.message
    position, quaternion = pose_to_arrays(reply.best_pose.pose)
    assert_pose_close(robot.camera_pose(np.array(reply.joint_goal.position)), position, quaternion)
    capability = load_or_build_capability_map(robot, GEOMETRY, 4, progress=False)  # the map the planner cached
    cells = GEOMETRY.containing_cell(np.array([pose_to_arrays(v.pose.pose)[0] for v in reply.ranked]))[0]
    assert len(reply.ranked) > 10
    assert capability.origin_filter(cells).shape[0] == cells.shape[0]  # all of them allowed
    everywhere = GEOMETRY.containing_cell(GEOMETRY.cell_centre(np.argwhere(bench.state == 0)))[0]
    assert capability.origin_filter(everywhere).shape[0] < everywhere.shape[0]  # the map does exclude cells


def test_sim_camera_follows_the_arm(ros):
    """With follow_arm the camera's frames are taken at arm_sim's camera pose, stamped with that
    pose's stamp; moving the camera by request is refused while it rides on the arm."""
    from geometry_msgs.msg import TransformStamped
    from nbv_prob_cnn_msgs.srv import MoveCamera, MoveToJoints

    node, bench, graph = ros
    robot = RobotModel()
    graph.start_node("arm_sim", "arm_sim", {"velocity_scale": 1.0, "rate_hz": 50.0})
    graph.start_node("sim_camera", "sim_camera", {"follow_arm": True, "pose_source": "topic", "rate_hz": 5.0,
                                                  "width": 64, "height": 48})  # fmt: skip
    arm_poses: dict[int, PoseStamped] = {}
    newest_pose = [0]  # stamp of the newest arm pose received
    sequence: list[int] = []  # arm_sim's publication sequence numbers of the poses received
    frames: list[TransformStamped] = []

    def on_arm_pose(msg: PoseStamped, info) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        arm_poses[stamp] = msg
        newest_pose[0] = max(newest_pose[0], stamp)
        sequence.append(info["publication_sequence_number"])

    # keep all: the test's own queue never drops an arm pose however late its executor takes them
    keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(PoseStamped, "/arm/camera_pose", on_arm_pose, keep_all)
    node.create_subscription(TransformStamped, "/camera/pose", frames.append, 10)
    deadline = time.monotonic() + 120
    while len(frames) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(frames) >= 2, "sim_camera published no frames"
    goal = robot.reference_q.copy()
    goal[0] += 0.5  # panda_joint1: the camera swings around the base
    move = node.create_client(MoveToJoints, "/arm_sim/move_to_joints")
    request = MoveToJoints.Request(name=robot.joint_names, position=list(goal))
    assert call_with_resend(move, request, 120.0, resend_s=30.0).success
    target = robot.camera_pose(goal)
    deadline = time.monotonic() + 30

    def last_position() -> np.ndarray:
        t = frames[-1].transform.translation
        return np.array([t.x, t.y, t.z])

    while np.linalg.norm(last_position() - target[:3, 3]) > 1e-6 and time.monotonic() < deadline:
        time.sleep(0.05)
    np.testing.assert_allclose(last_position(), target[:3, 3], atol=1e-6)  # the frame at the arm's new pose
    seen = len(frames)
    while len(frames) < seen + 3 and time.monotonic() < deadline + 10:
        time.sleep(0.05)
    # one camera and one arm in this domain (a graph of another test process would publish its frames here)
    assert node.count_publishers("/camera/pose") == 1 and node.count_publishers("/arm/camera_pose") == 1
    for frame in frames[seen : seen + 3]:  # frames long after both subscriptions matched
        stamp = frame.header.stamp.sec * 1_000_000_000 + frame.header.stamp.nanosec
        # arm_sim's poses arrive in the order it published them: once one stamped at or after the
        # frame has arrived, the pose of the frame's stamp has too, if arm_sim published one
        deadline = time.monotonic() + 60
        while newest_pose[0] < stamp and time.monotonic() < deadline:
            time.sleep(0.02)
        assert newest_pose[0] >= stamp, "no arm pose as new as the frame arrived"
        lost = [(a, b) for a, b in zip(sequence, sequence[1:], strict=False) if b != a + 1]
        assert not lost, f"arm poses lost on the way to the test (sequence numbers {lost})"
        assert stamp in arm_poses, "a frame's stamp is not the stamp of an arm camera pose"
        p, t = arm_poses[stamp].pose.position, frame.transform.translation
        np.testing.assert_allclose([t.x, t.y, t.z], [p.x, p.y, p.z], atol=1e-9)
    camera = node.create_client(MoveCamera, "/sim_camera/move_to")
    refused = call_with_resend(camera, MoveCamera.Request(), 60.0)
    assert not refused.success and "follow_arm" in refused.message
