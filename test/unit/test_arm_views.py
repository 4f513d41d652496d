"""The arm's side of the ROS planning requests without ROS graphs: reachability of arbitrary
camera poses (EvaluateViews), the arm drawn as a polyline, and the joint-state conversions and
tracking of the planner and the gain server."""

from __future__ import annotations

import threading

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from nbv_prob_cnn.arm.robot import RobotConfig  # noqa: E402
from nbv_prob_cnn.arm.views import ArmPlanningSetup, arm_polyline, reachable_poses  # noqa: E402
from nbv_prob_cnn.basics.camera import quaternion_from_matrix  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402

#: 0.96 × 1.28 × 0.96 m in front of the Panda's default base (x = -0.1, y = 0.742): a floor and an
#: unknown box on it, the rest known empty.
GEOMETRY = GridGeometry((0.0, 0.102, 0.0), 0.04, (24, 32, 24))


def scene() -> np.ndarray:
    state = np.zeros(GEOMETRY.shape, dtype=np.int8)
    state[:, :, 0] = 1
    state[10:16, 12:20, 1:6] = -1
    return state


@pytest.fixture(scope="module")
def setup():
    return ArmPlanningSetup(RobotConfig(), capability_stride=0, seed=3)


def random_free_configurations(setup, count: int, rng) -> list[np.ndarray]:
    """Random configurations within the limits whose camera lies in the grid's empty space and
    that are free of self- and grid collision (checked with the collision checker)."""
    from nbv_prob_cnn.arm.collision import GridObstacles

    robot, arm = setup.robot, setup.feasibility(GEOMETRY)
    obstacles = GridObstacles.from_state(scene(), GEOMETRY)
    found = []
    while len(found) < count:
        q = robot.reference_q.copy()
        q[arm.chain.q_index] = rng.uniform(arm.chain.lower, arm.chain.upper)
        cell, inside = GEOMETRY.containing_cell(robot.camera_pose(q)[:3, 3][None])
        if inside[0] and scene()[tuple(cell[0])] == 0 and arm.checker.is_free(q, obstacles):
            found.append(q)
    return found


def pose_arrays(robot, q):
    pose = robot.camera_pose(q)
    return pose[:3, 3], quaternion_from_matrix(pose[:3, :3])


def test_reachable_poses_solve_reachable_poses_and_flag_the_rest(setup, rng):
    from nbv_prob_cnn.arm.collision import GridObstacles

    robot = setup.robot
    arm = setup.feasibility(GEOMETRY)
    obstacles = GridObstacles.from_state(scene(), GEOMETRY)
    targets = random_free_configurations(setup, 4, rng)
    solutions = []
    for q in targets:  # seeded near the target configuration: IK must find it (or one as good)
        seed = q.copy()
        seed[arm.chain.q_index] += rng.uniform(-0.05, 0.05, arm.chain.n)
        position, quat = pose_arrays(robot, q)
        (solution,) = reachable_poses(arm, position[None], quat[None], scene(), GEOMETRY, seed)
        assert solution is not None
        solutions.append((solution, position, quat))
    for solution, position, quat in solutions:
        assert robot.within_limits(solution, tol=1e-9)
        assert arm.checker.is_free(solution, obstacles)
        pose = robot.camera_pose(solution)  # pinocchio forward kinematics, not the IK's own chain
        np.testing.assert_allclose(pose[:3, 3], position, atol=2e-3)
        q = quaternion_from_matrix(pose[:3, :3])
        assert abs(float(np.dot(q, quat))) > np.cos(0.01)  # within ~0.02 rad
    far = np.array([3.0, 3.0, 3.0])  # 3 m from the base: beyond the Panda's reach
    positions = np.array([far, [np.nan, 0.5, 0.5], solutions[0][1]])
    quats = np.array([[0, 0, 0, 1.0], [0, 0, 0, 1.0], [0, 0, 0, 0.0]])  # the last: a zero quaternion
    assert reachable_poses(arm, positions, quats, scene(), GEOMETRY, robot.reference_q) == [None, None, None]


def test_a_pose_inside_occupied_space_is_unreachable(setup, rng):
    robot = setup.robot
    arm = setup.feasibility(GEOMETRY)
    for q in random_free_configurations(setup, 20, rng):  # one the IK reaches from the reference
        position, quat = pose_arrays(robot, q)
        if reachable_poses(arm, position[None], quat[None], scene(), GEOMETRY, robot.reference_q)[0] is not None:
            break
    else:
        pytest.fail("no random pose reachable from the reference configuration")
    blocked = scene()
    cell = GEOMETRY.containing_cell(position[None])[0][0]
    lo, hi = np.maximum(cell - 2, 0), cell + 3
    blocked[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = 1  # the camera sits in an obstacle
    assert reachable_poses(arm, position[None], quat[None], blocked, GEOMETRY, robot.reference_q)[0] is None
    # from q itself the arm is already there: the cells it fills count as free (feasibility.py)
    assert reachable_poses(arm, position[None], quat[None], blocked, GEOMETRY, q)[0] is not None
    with pytest.raises(ValueError, match="positions"):
        reachable_poses(arm, position, quat, scene(), GEOMETRY, robot.reference_q)


def test_arm_polyline_is_rigid_and_ends_at_the_camera(setup, rng):
    robot = setup.robot
    configurations = [robot.reference_q, *random_free_configurations(setup, 2, rng)]
    lines = [arm_polyline(robot, q) for q in configurations]
    lengths = [np.linalg.norm(np.diff(line, axis=0), axis=1) for line in lines]
    # Panda: base -> joint1 0.333 m, joint3 -> joint4 0.0825 m (the DH parameters), links are rigid
    np.testing.assert_allclose(lengths[0][0], 0.333, atol=1e-6)
    assert np.any(np.isclose(lengths[0], 0.0825, atol=1e-6))
    for q, line, length in zip(configurations, lines, lengths, strict=True):
        np.testing.assert_allclose(line[-1], robot.camera_pose(q)[:3, 3], atol=1e-12)
        np.testing.assert_allclose(line[0], robot.config.world_from_base[:3, 3], atol=1e-12)
        np.testing.assert_allclose(length, lengths[0], atol=1e-9)
    assert not np.allclose(lines[1], lines[0])  # the joints moved


rclpy = pytest.importorskip("rclpy")


def joint_state(names, positions, sec=1):
    from sensor_msgs.msg import JointState

    msg = JointState(name=list(names), position=[float(v) for v in positions])
    msg.header.stamp.sec = sec
    return msg


def test_joint_state_msg_round_trip_and_bad_joint_states(setup):
    from nbv_prob_cnn.ros.robot_params import joint_state_msg

    robot = setup.robot
    q = robot.reference_q + 0.01
    names = list(reversed(robot.joint_names))  # order does not matter
    np.testing.assert_array_equal(robot.joint_state_configuration(names, list(reversed(q))), q)
    with pytest.raises(ValueError, match=r"unknown joint names \['elbow'\]"):
        robot.joint_state_configuration([*robot.joint_names, "elbow"], [*q, 0.0])
    with pytest.raises(ValueError, match=r"missing joints \['panda_finger_joint1', 'panda_finger_joint2'\]"):
        robot.joint_state_configuration(robot.joint_names[:7], q[:7])
    with pytest.raises(ValueError, match="9 joint names but 8 positions"):
        robot.joint_state_configuration(robot.joint_names, q[:8])
    with pytest.raises(ValueError, match="duplicate"):
        robot.joint_state_configuration([robot.joint_names[0]] * 9, q)
    with pytest.raises(ValueError, match="non-finite"):
        robot.joint_state_configuration(robot.joint_names, [np.nan, *q[1:]])
    msg = joint_state_msg(robot, q)
    assert list(msg.name) == robot.joint_names and np.allclose(msg.position, q)
    assert list(joint_state_msg(robot, None).name) == []


def test_joint_state_tracker_reports_bad_states_and_waits_for_the_goal(setup):
    from nbv_prob_cnn.ros.robot_params import JointStateTracker

    robot = setup.robot
    tracker = JointStateTracker(robot)
    default = robot.reference_q
    assert tracker.current_or(default) is default
    with pytest.raises(ValueError, match="no joint state received yet"):
        tracker.current()
    with pytest.raises(
        TimeoutError, match=r"no complete joint state on joint_states within 0.05 s \(never received: \["
    ):
        tracker.wait_for_first(0.05)
    first = threading.Timer(0.1, tracker.on_joint_state, [joint_state(robot.joint_names, robot.reference_q, sec=1)])
    first.start()
    tracker.wait_for_first(5.0)  # returns once the timer's state arrived
    first.join()
    np.testing.assert_array_equal(tracker.current()[0], robot.reference_q)
    # a name the model lacks (a gripper, a conveyor) is ignored and listed, not an error
    assert tracker.on_joint_state(joint_state(["elbow"], [0.0])) == ""
    assert tracker.ignored_names() == ["elbow"]
    np.testing.assert_array_equal(tracker.current()[0], robot.reference_q)
    # a malformed message is an error until a valid one arrives
    assert "2 joint names but 1 positions" in tracker.on_joint_state(joint_state(robot.joint_names[:2], [0.0]))
    with pytest.raises(ValueError, match="2 joint names but 1 positions"):
        tracker.current()
    with pytest.raises(ValueError, match="2 joint names but 1 positions"):
        tracker.current_or(default)
    goal = robot.reference_q + 0.1
    assert tracker.on_joint_state(joint_state(robot.joint_names, robot.reference_q, sec=2)) == ""
    q, stamp = tracker.current()
    np.testing.assert_array_equal(q, robot.reference_q)
    assert stamp == 2_000_000_000
    with pytest.raises(TimeoutError, match="did not reach the joint goal"):
        tracker.wait_until(goal, 1e-3, 0, 0.05)
    later = threading.Timer(0.1, tracker.on_joint_state, [joint_state(robot.joint_names, goal, sec=3)])
    later.start()
    assert tracker.wait_until(goal, 1e-3, 2_500_000_000, 5.0) == 3_000_000_000
    later.join()


def test_allowed_origins_travel_as_flat_indices_x_fastest():
    from nbv_prob_cnn.planners.requests import allowed_origins_filter, flat_cells

    shape = (4, 3, 2)
    cells = np.array([[1, 0, 0], [0, 1, 0], [3, 2, 1], [2, 1, 1]])
    np.testing.assert_array_equal(flat_cells(cells, shape), [1, 4, 3 + 4 * 2 + 12, 2 + 4 * 1 + 12])
    keep = allowed_origins_filter(np.array([4, 23], dtype=np.uint32), shape)
    np.testing.assert_array_equal(keep(cells), cells[[1, 2]])
    with pytest.raises(ValueError, match="allowed_origins"):
        allowed_origins_filter(np.array([24]), shape)
