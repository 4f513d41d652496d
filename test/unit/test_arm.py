"""The arm in the loop (no ROS): robot model, IK, collision, capability map, feasibility, self-filter."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from arm_views import GEOMETRY_3DT  # noqa: E402

from nbv_prob_cnn.arm.capability import (  # noqa: E402
    MAP_IK,
    CapabilityMap,
    UnreachableWorkspaceError,
    build_capability_map,
    capability_key,
    capability_map_path,
    load_or_build_capability_map,
    view_rotations,
)
from nbv_prob_cnn.arm.collision import CollisionChecker, GridObstacles, body_mesh  # noqa: E402
from nbv_prob_cnn.arm.feasibility import ArmFeasibility  # noqa: E402
from nbv_prob_cnn.arm.ik import DEFAULT_IK, ROLL_HALF_TURN, rotation_error, solve_camera_pose, solve_camera_poses  # noqa: E402,E501
from nbv_prob_cnn.arm.robot import RobotConfig, RobotModel, translation  # noqa: E402
from nbv_prob_cnn.basics.camera import DATASETS, look_rotation  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.basics.grid import OCCUPIED, UNKNOWN  # noqa: E402
from nbv_prob_cnn.planners import PlanningContext, ViewChoice  # noqa: E402


def pose_errors(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Position (m) and rotation (rad) distance of two 4×4 poses (angle from the trace)."""
    rel = a[:3, :3].T @ b[:3, :3]
    angle = math.acos(min(1.0, max(-1.0, (np.trace(rel) - 1.0) / 2.0)))
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), angle


# --- robot model -------------------------------------------------------------------------------


def test_batched_kinematics_match_pinocchio(robot, chain):
    import pinocchio as pin

    rng = np.random.default_rng(0)
    qs = rng.uniform(robot.lower, robot.upper, size=(20, robot.nq))
    poses, jac = chain.camera_poses(qs[:, chain.q_index], jacobian=True)
    data = robot.model.createData()
    for q, pose, j in zip(qs, poses, jac, strict=True):
        np.testing.assert_allclose(pose, robot.camera_pose(q), atol=1e-12)
        pin.computeJointJacobians(robot.model, data, q)
        pin.updateFramePlacements(robot.model, data)
        ref = pin.getFrameJacobian(robot.model, data, robot.camera_frame, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(j, ref[:, chain.q_index], atol=1e-12)


def test_base_pose_and_camera_mount_compose(robot):
    q = robot.reference_q
    hand = robot.frame_pose(q, "panda_hand")
    np.testing.assert_allclose(robot.camera_pose(q), hand @ robot.config.parent_from_camera, atol=1e-12)
    np.testing.assert_allclose(robot.frame_pose(q, "panda_link0"), robot.config.world_from_base, atol=1e-12)
    yaw = np.eye(4)
    yaw[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
    moved_base = translation((0.3, -0.2, 0.1)) @ yaw
    moved = RobotModel(RobotConfig(world_from_base=moved_base))
    expected = moved_base @ np.linalg.inv(robot.config.world_from_base) @ robot.camera_pose(q)
    np.testing.assert_allclose(moved.camera_pose(q), expected, atol=1e-12)


def test_joint_state_names_map_onto_the_model(robot):
    q = robot.configuration({"panda_joint2": 0.25, "panda_joint7": -1.0})
    assert q[robot.joint_names.index("panda_joint2")] == 0.25
    assert q[robot.joint_names.index("panda_joint7")] == -1.0
    assert q[0] == robot.reference_q[0]
    assert robot.joint_positions(q)["panda_joint2"] == 0.25
    with pytest.raises(ValueError, match=r"unknown joint names \['elbow'\].*panda_joint1"):
        robot.configuration({"elbow": 0.1})
    with pytest.raises(ValueError, match="non-finite"):
        robot.configuration({"panda_joint1": float("nan")})
    with pytest.raises(ValueError, match="expected 9 joint positions"):
        robot.camera_pose(np.zeros(7))


def test_bad_urdf_gives_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        RobotModel(RobotConfig(urdf_path=str(tmp_path / "missing.urdf")))
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'><joint oops")
    with pytest.raises(ValueError, match="cannot load URDF"):
        RobotModel(RobotConfig(urdf_path=str(broken)))
    with pytest.raises(ValueError, match="camera_parent 'no_such_link' is not a link"):
        RobotModel(RobotConfig(camera_parent="no_such_link"))
    with pytest.raises(ValueError, match="world_from_base"):
        RobotModel(RobotConfig(world_from_base=np.full((4, 4), np.nan)))


TWO_LINK_URDF = """<?xml version="1.0"?>
<robot name="planar">
  <link name="base"/>
  <link name="upper"><collision><origin xyz="0.25 0 0"/><geometry><box size="0.5 0.04 0.04"/></geometry>
  </collision></link>
  <link name="fore"><collision><origin xyz="0.15 0 0"/><geometry><cylinder radius="0.02" length="0.3"/></geometry>
  </collision></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/>
    <origin xyz="0.5 0 0"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
</robot>
"""


def test_any_urdf_through_parameters(tmp_path):
    path = tmp_path / "planar.urdf"
    path.write_text(TWO_LINK_URDF)
    config = RobotConfig(
        urdf_path=str(path),
        world_from_base=np.eye(4),
        camera_parent="fore",
        parent_from_camera=translation((0.3, 0.0, 0.0)),
    )
    robot = RobotModel(config)
    assert robot.joint_names == ["shoulder", "elbow"]
    np.testing.assert_allclose(robot.reference_q, [0.0, 0.0])  # middle of the limits
    a, b = 0.4, -0.9
    pose = robot.camera_pose(robot.configuration({"shoulder": a, "elbow": b}))
    expected = [0.5 * math.cos(a) + 0.3 * math.cos(a + b), 0.5 * math.sin(a) + 0.3 * math.sin(a + b), 0.1]
    np.testing.assert_allclose(pose[:3, 3], expected, atol=1e-12)
    checker = CollisionChecker(robot, spacing=0.01)
    assert checker.n_pairs == 0  # two bodies on adjacent joints
    assert {len(p) > 0 for p in checker.points.values()} == {True}
    with pytest.raises(ValueError, match="reference names unknown joints"):
        RobotModel(RobotConfig(urdf_path=str(path), camera_parent="fore", reference={"panda_joint1": 0.0}))


# --- inverse kinematics ------------------------------------------------------------------------


def test_ik_recovers_random_reachable_camera_poses(robot, chain):
    rng = np.random.default_rng(1)
    solved, seconds = 0, []
    for _ in range(25):
        q_true = rng.uniform(robot.lower, robot.upper)
        target = robot.camera_pose(q_true)
        start = time.perf_counter()
        result = solve_camera_pose(chain, target, robot.reference_q, rng)
        seconds.append(time.perf_counter() - start)
        if result.q is None:
            continue
        solved += 1
        position_error, angle_error = pose_errors(robot.camera_pose(result.q), target)
        assert position_error < DEFAULT_IK.position_tol
        assert angle_error < DEFAULT_IK.rotation_tol
        assert robot.within_limits(result.q)
        np.testing.assert_array_equal(result.q[7:], robot.reference_q[7:])  # fingers untouched
    print(f"IK: {solved}/25 random reachable poses solved, median {1000 * np.median(seconds):.1f} ms")
    assert solved >= 23


def test_ik_prefers_the_current_configuration(robot, chain):
    rng = np.random.default_rng(2)
    current = robot.configuration({"panda_joint1": 0.3, "panda_joint4": -1.9})
    goal = current.copy()
    goal[:7] += rng.uniform(-0.05, 0.05, size=7)
    result = solve_camera_pose(chain, robot.camera_pose(goal), current, rng)
    assert result.q is not None
    assert result.distance < 0.3  # the nearby branch, not a random restart's
    assert result.distance == pytest.approx(np.linalg.norm(result.q[:7] - current[:7]))


def test_roll_symmetric_ik_takes_the_view_turned_about_its_axis_when_nearer(robot, chain):
    """A target whose half-turn about the optical axis is 0.05 rad from the current
    configuration: with ``roll_symmetric`` that pose is solved (flagged) near the current
    configuration; without, the target itself needs the wrist turned by about π."""
    rng = np.random.default_rng(4)
    current = robot.configuration({"panda_joint1": 0.3, "panda_joint4": -1.9, "panda_joint7": 0.2})
    near = current.copy()
    near[:7] += rng.uniform(-0.05, 0.05, size=7)
    target = robot.camera_pose(near) @ ROLL_HALF_TURN  # the half-turn of what `near` sees
    flipped = solve_camera_poses(chain, target[None], current, rng, roll_symmetric=True)[0]
    assert flipped.q is not None and flipped.roll_flipped and flipped.distance < 0.3
    position_error, angle_error = pose_errors(robot.camera_pose(flipped.q), target @ ROLL_HALF_TURN)
    assert position_error < DEFAULT_IK.position_tol and angle_error < DEFAULT_IK.rotation_tol
    plain = solve_camera_poses(chain, target[None], current, rng)[0]
    assert not plain.roll_flipped
    if plain.q is not None:  # reached as asked: the camera's own pose, far from the current joints
        position_error, angle_error = pose_errors(robot.camera_pose(plain.q), target)
        assert position_error < DEFAULT_IK.position_tol and angle_error < DEFAULT_IK.rotation_tol
        assert plain.distance > 1.0
    # a target that is nearer as it is stays unflipped
    direct = solve_camera_poses(chain, robot.camera_pose(near)[None], current, rng, roll_symmetric=True)[0]
    assert direct.q is not None and not direct.roll_flipped and direct.distance < 0.3


def test_ik_reports_unreachable_poses(robot, chain):
    target = translation((3.0, 3.0, 3.0))
    assert solve_camera_pose(chain, target, robot.reference_q, np.random.default_rng(3)).q is None


def test_rotation_error_matches_angle():
    rng = np.random.default_rng(4)
    for angle in (0.0, 0.3, 2.0, math.pi - 1e-3):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        rot = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
        vec = rotation_error(rot[None], np.eye(3)[None])[0]
        np.testing.assert_allclose(vec, angle * axis, atol=1e-6)


# --- collision ---------------------------------------------------------------------------------


def empty_grid() -> np.ndarray:
    return np.zeros(GEOMETRY_3DT.shape, dtype=np.int8)


def body_centre(checker: CollisionChecker, q: np.ndarray, name: str) -> np.ndarray:
    """World position of the centroid of a body's convex hull (inside the body's hull)."""
    index = checker.geometry_model.getGeometryId(name)
    pose = checker.body_poses(q)[index]
    centre = body_mesh(checker.geometry_model.geometryObjects[index]).convex_hull.centroid
    return pose[:3, :3] @ centre + pose[:3, 3]


def test_self_collision(robot, checker):
    assert not checker.self_collision(robot.reference_q)
    folded = robot.configuration({"panda_joint4": -3.07, "panda_joint6": -0.08})  # wrist folded back
    assert checker.self_collision(folded)
    assert ("panda_hand_0", "panda_leftfinger_0") not in checker.disabled_at_reference  # adjacent: never paired


@pytest.mark.parametrize("value", [OCCUPIED, UNKNOWN])
def test_grid_collision_with_hand_built_grids(robot, checker, value):
    q = robot.reference_q
    grid = empty_grid()
    free = GridObstacles.from_state(grid, GEOMETRY_3DT)
    assert checker.grid_collisions(q, free) == []
    cell, inside = GEOMETRY_3DT.containing_cell(body_centre(checker, q, "panda_link5_0"))
    assert inside
    grid[tuple(cell)] = value  # one blocked cell inside link 5
    assert checker.grid_collisions(q, GridObstacles.from_state(grid, GEOMETRY_3DT)) == ["panda_link5_0"]
    assert not checker.is_free(q, GridObstacles.from_state(grid, GEOMETRY_3DT))
    far = empty_grid()
    far[120:, 120:, 80:] = value  # a block nowhere near the arm
    assert checker.is_free(q, GridObstacles.from_state(far, GEOMETRY_3DT))
    # a table top under the hand: free at the reference pose, in collision once the hand is lowered into it
    hand_z = body_centre(checker, q, "panda_hand_0")[2]
    table = empty_grid()
    table[:, :, : int(hand_z / GEOMETRY_3DT.resolution) - 10] = value
    assert checker.is_free(q, GridObstacles.from_state(table, GEOMETRY_3DT))
    lowered = robot.configuration({"panda_joint2": 0.9, "panda_joint4": -1.2})
    assert body_centre(checker, lowered, "panda_hand_0")[2] < hand_z - 0.2
    assert "panda_hand_0" in checker.grid_collisions(lowered, GridObstacles.from_state(table, GEOMETRY_3DT))


def test_grid_look_ups_match_a_cell_by_cell_reference(robot, checker):
    rng = np.random.default_rng(7)
    grid = empty_grid()
    region = grid[30:110, 20:120, :50]
    region[rng.random(region.shape) < 0.004] = OCCUPIED  # sparse blocked cells around the arm's reach
    obstacles = GridObstacles.from_state(grid, GEOMETRY_3DT)
    origin, size, shape = np.asarray(GEOMETRY_3DT.origin), GEOMETRY_3DT.resolution, GEOMETRY_3DT.shape
    # points inside and around the grid: the cell (i, j, k) holds origin + [i, i + 1) * size per axis
    points = origin + rng.uniform(-0.2, 1.0, size=(3000, 3)) * np.asarray(shape) * size
    blocked_cells = np.argwhere(obstacles.blocked)[rng.choice(int(obstacles.blocked.sum()), 300)]
    near = blocked_cells + rng.uniform(-0.5, 1.5, size=(300, 3))  # in the blocked cell or a neighbour
    points = np.vstack([points, origin + near * size])
    expected = []
    for p in points:
        cell = [math.floor((p[a] - origin[a]) / size) for a in range(3)]
        inside = all(0 <= cell[a] < shape[a] for a in range(3))
        expected.append(inside and bool(obstacles.blocked[tuple(cell)]))
    np.testing.assert_array_equal(obstacles.hits(points), expected)
    assert sum(expected) > 0
    # box queries (summed-volume table) against slicing, boxes partly or wholly outside included
    for _ in range(300):
        lo = rng.integers(-20, 140, size=3)
        hi = lo + rng.integers(-3, 40, size=3)
        a, b = np.clip(lo, 0, shape), np.clip(hi + 1, 0, shape)
        box = obstacles.blocked[a[0] : b[0], a[1] : b[1], a[2] : b[2]]
        assert obstacles.any_blocked_between(lo, hi) == bool(box.any())
    # the bounded body test gives the answer of looking up every sample point
    qs = np.clip(robot.reference_q + rng.normal(0.0, 0.5, size=(120, robot.reference_q.size)), robot.lower, robot.upper)
    bounded = [checker.grid_collision(q, obstacles) for q in qs]
    every_point = [bool(np.any(obstacles.hits(checker.body_points(q)))) for q in qs]
    assert bounded == every_point
    assert 0 < sum(bounded) < len(qs)


def test_margin_and_path_checks(robot, checker):
    q_a = robot.reference_q
    q_b = robot.configuration({"panda_joint1": 0.8})
    mid = (q_a + q_b) / 2.0
    grid = empty_grid()
    cell, _ = GEOMETRY_3DT.containing_cell(body_centre(checker, mid, "panda_hand_0"))
    grid[tuple(cell)] = OCCUPIED
    obstacles = GridObstacles.from_state(grid, GEOMETRY_3DT)
    assert checker.is_free(q_a, obstacles) and checker.is_free(q_b, obstacles)
    assert not checker.path_is_free(q_a, q_b, obstacles, step=0.05)
    assert checker.path_is_free(q_a, q_b, GridObstacles.from_state(empty_grid(), GEOMETRY_3DT), step=0.05)
    grown = GridObstacles.from_state(grid, GEOMETRY_3DT, margin_cells=2)
    assert grown.blocked.sum() == 25  # |dx| + |dy| + |dz| <= 2 (6-connected growth twice)
    with pytest.raises(ValueError, match="shape"):
        GridObstacles.from_state(np.zeros((4, 4, 4), dtype=np.int8), GEOMETRY_3DT)


def test_tabletop_prior_and_the_space_the_arm_fills(robot, checker):
    unknown = np.full(GEOMETRY_3DT.shape, UNKNOWN, dtype=np.int8)
    unknown[:, :, -1] = OCCUPIED  # the top layer (z = 1.10 m) is seen occupied
    strict = GridObstacles.from_state(unknown, GEOMETRY_3DT)
    assert strict.blocked.all()
    prior = GridObstacles.from_state(unknown, GEOMETRY_3DT, free_above_m=0.5)
    z = (np.arange(GEOMETRY_3DT.shape[2]) + 0.5) * GEOMETRY_3DT.resolution
    assert prior.blocked[:, :, z < 0.5].all()
    assert not prior.blocked[:, :, (z >= 0.5) & (z < 1.0)].any()  # unknown above the prior height passes
    assert prior.blocked[:, :, -1].all()  # occupied always blocks
    q = robot.reference_q
    assert not checker.is_free(q, strict)
    cleared = strict.cleared(checker.body_points(q))
    assert checker.is_free(q, cleared)  # where the arm is, nothing else is
    assert cleared.blocked.sum() < strict.blocked.sum()


# --- capability map ----------------------------------------------------------------------------

COARSE_STRIDE = 24


@pytest.fixture(scope="module")
def capability(robot) -> CapabilityMap:
    return load_or_build_capability_map(robot, GEOMETRY_3DT, COARSE_STRIDE, progress=False)


def test_capability_map_agrees_with_exact_ik(robot, chain, capability):
    rng = np.random.default_rng(5)
    rotations = view_rotations()
    counts = {"tp": 0, "fn": 0, "fp": 0, "tn": 0}
    shoulder = robot.frame_pose(robot.reference_q, "panda_link1")[:3, 3]
    cells = []
    while len(cells) < 80:  # half near the shoulder (mostly reachable), half anywhere
        cell = rng.integers(0, GEOMETRY_3DT.shape)
        near = np.linalg.norm(GEOMETRY_3DT.cell_centre(cell) - shoulder) < 0.7
        if near or len(cells) % 2:
            cells.append(cell)
    for cell in cells:
        view = int(rng.integers(len(rotations)))
        target = np.eye(4)
        target[:3, :3] = rotations[view]
        target[:3, 3] = GEOMETRY_3DT.cell_centre(cell)
        exact = solve_camera_pose(chain, target, robot.reference_q, rng).q is not None
        mapped = bool(capability.views_at(cell[None])[0, view])
        counts[("t" if exact == mapped else "f") + ("p" if mapped else "n")] += 1
    positives = counts["tp"] + counts["fn"]
    print(f"capability map (stride {COARSE_STRIDE}) vs exact IK on 80 samples: {counts}")
    assert positives >= 10
    assert counts["fn"] <= 0.05 * positives
    assert counts["tn"] > 0  # it does prune


def test_capability_map_is_cached_and_prunes(robot, capability):
    path = capability_map_path(capability_key(robot, GEOMETRY_3DT, COARSE_STRIDE, MAP_IK, 2))
    assert path.is_file()
    again = load_or_build_capability_map(robot, GEOMETRY_3DT, COARSE_STRIDE, progress=False)
    np.testing.assert_array_equal(again.reachable, capability.reachable)
    origins = np.array([[0, 64, 40], [127, 127, 95]])
    far_views = capability.views_at(origins[1:])
    assert not far_views.any()  # 1.9 m from the shoulder
    np.testing.assert_array_equal(capability.origin_filter(origins), origins[:1])


def test_capability_lookup_takes_the_or_of_surrounding_nodes():
    geometry = GridGeometry((0.0, 0.0, 0.0), 0.01, (20, 20, 20))
    table = np.zeros((3, 3, 3, 52), dtype=bool)
    table[1, 1, 1, 7] = True  # node at cell (10, 10, 10)
    cmap = CapabilityMap(table, 10, geometry)
    views = cmap.views_at(np.array([[10, 10, 10], [5, 5, 5], [15, 19, 11], [4, 4, 4]]))
    assert views[:, 7].tolist() == [True, True, True, True]
    assert views[:, :7].sum() == 0
    views = cmap.views_at(np.array([[0, 0, 0], [0, 12, 2], [3, 12, 2], [20, 20, 20]]))
    assert views[:, 7].tolist() == [False, False, True, False]  # on a node axis only that node counts


def test_unreachable_workspace_gives_clear_error():
    far_robot = RobotModel(RobotConfig(world_from_base=translation((10.0, 10.0, 0.0))))
    with pytest.raises(UnreachableWorkspaceError, match="reaches no camera pose"):
        build_capability_map(far_robot, GEOMETRY_3DT, COARSE_STRIDE, progress=False)
    with pytest.raises(UnreachableWorkspaceError):
        CapabilityMap(np.zeros((2, 2, 2, 52), dtype=bool), 8, GEOMETRY_3DT)


# --- exact check and motion cost -----------------------------------------------------------------


def choice_at(xyz, view_index: int, gain: float) -> ViewChoice:
    cell, inside = GEOMETRY_3DT.containing_cell(np.asarray(xyz, dtype=np.float64))
    assert inside
    return ViewChoice(cell, view_index, gain)


def test_exact_check_takes_the_first_feasible_view(robot, chain, checker, capability):
    context = PlanningContext.for_dataset("3dt")
    down = 50  # looking straight down (view_directions_3d()[25]), roll 0
    grid = empty_grid()
    unreachable = ViewChoice(np.array([127, 5, 90]), down, 30.0)  # far corner
    blocked = choice_at((0.45, 0.60, 0.45), down, 20.0)
    feasible = choice_at((0.45, 0.85, 0.45), down, 10.0)
    # block the cells around the second view's camera (the hand must be there)
    c = blocked.cell
    grid[c[0] - 8 : c[0] + 9, c[1] - 8 : c[1] + 9, c[2] + 3 : c[2] + 25] = UNKNOWN
    arm = ArmFeasibility(robot, checker, capability=None, rng=np.random.default_rng(6))
    report = arm.select([unreachable, blocked, feasible], grid, context, GEOMETRY_3DT, robot.reference_q)
    assert report.view is not None and report.view.choice is feasible
    # the hand (rigid with the camera) of the blocked view enters the unknown box: rejected
    # before IK, without spending an exact check
    assert (report.checked, report.unreachable, report.camera_blocked, report.in_collision) == (2, 1, 1, 0)
    target = np.eye(4)
    target[:3, :3] = view_rotations()[down]
    target[:3, 3] = GEOMETRY_3DT.cell_centre(feasible.cell)
    position_error, angle_error = pose_errors(robot.camera_pose(report.view.q), target)
    assert position_error < DEFAULT_IK.position_tol and angle_error < DEFAULT_IK.rotation_tol
    # with the capability map the unreachable corner is pruned before any IK
    pruned = ArmFeasibility(robot, checker, capability=capability, rng=np.random.default_rng(6), ik_alternatives=4)
    report = pruned.select([unreachable, blocked, feasible], grid, context, GEOMETRY_3DT, robot.reference_q)
    assert report.view is not None, report
    assert report.view.choice is feasible and report.unreachable == 0
    nothing = arm.select([unreachable], grid, context, GEOMETRY_3DT, robot.reference_q)
    assert nothing.view is None
    budget = ArmFeasibility(robot, checker, max_checks=2, rng=np.random.default_rng(6))
    report = budget.select([unreachable, unreachable, feasible], grid, context, GEOMETRY_3DT, robot.reference_q)
    assert report.view is None and report.checked == 2 and report.budget_exhausted


def test_motion_cost_trades_gain_for_joint_travel(robot, chain, checker):
    context = PlanningContext.for_dataset("3dt")
    down = 50
    grid = empty_grid()
    start = choice_at((0.35, 0.74, 0.45), down, 1.0)
    current = (
        ArmFeasibility(robot, checker, rng=np.random.default_rng(7))
        .select([start], grid, context, GEOMETRY_3DT, robot.reference_q)
        .view.q
    )  # the arm already looks down there
    far = choice_at((0.50, 0.40, 0.35), down, 10.0)
    near = choice_at((0.35, 0.74, 0.40), down, 9.0)
    lengths = {}
    for choice in (far, near):
        single = ArmFeasibility(robot, checker, rng=np.random.default_rng(7))
        lengths[id(choice)] = single.select([choice], grid, context, GEOMETRY_3DT, current).view.path_length
    assert lengths[id(far)] > lengths[id(near)] + 0.2
    paper = ArmFeasibility(robot, checker, motion_weight=0.0, rng=np.random.default_rng(7))
    assert paper.select([far, near], grid, context, GEOMETRY_3DT, current).view.choice is far
    lam = 2.0 / (lengths[id(far)] - lengths[id(near)])  # the 1-gain gap costs less than the travel gap
    costly = ArmFeasibility(robot, checker, motion_weight=lam, rng=np.random.default_rng(7))
    view = costly.select([far, near], grid, context, GEOMETRY_3DT, current).view
    assert view.choice is near
    assert view.utility == pytest.approx(9.0 - lam * view.path_length)
    with pytest.raises(ValueError, match="motion_weight"):
        ArmFeasibility(robot, checker, motion_weight=-1.0)


# --- self-filter -------------------------------------------------------------------------------


def test_self_filter_keeps_the_arm_out_of_the_grid(robot):
    import trimesh

    from nbv_prob_cnn.arm.self_filter import RobotSelfFilter
    from nbv_prob_cnn.perception.depth_camera import DepthCamera, Intrinsics
    from nbv_prob_cnn.perception.tsdf import TsdfIntegrator

    voxel = 0.02
    origin = np.array([-0.3, 0.2, 0.0])
    shape = (50, 50, 50)  # 1 m box around the arm
    table_top = 0.1
    table = trimesh.creation.box(extents=(1.0, 1.0, 0.04))
    table.apply_translation(origin + [0.5, 0.5, table_top - 0.02])
    q = robot.reference_q
    self_filter = RobotSelfFilter(robot)
    arm = self_filter.robot_meshes(q)
    intrinsics = Intrinsics.from_hfov(120, 90, 70.0)
    # an external camera 1.2 m away looking at the arm and the table
    eye = np.array([0.9, 0.742, 0.8])
    look = np.array([0.0, 0.742, 0.35]) - eye
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(look)
    pose[:3, 3] = eye
    depth = DepthCamera([table, *arm], intrinsics).render(pose)
    arm_pixels = self_filter.mask(depth, q, intrinsics, pose)
    assert arm_pixels.sum() > 200  # the arm is in view
    filtered = self_filter.filter(depth, q, intrinsics, pose)
    assert np.all(filtered[~arm_pixels] == depth[~arm_pixels])

    def occupied_above_table(image: np.ndarray) -> int:
        tsdf = TsdfIntegrator(origin_m=origin, shape_cells=shape, voxel_size_m=voxel)
        tsdf.integrate(image, intrinsics, pose, depth_max=3.0)
        grid = tsdf.ternary()
        z_cells = origin[2] + (np.arange(shape[2]) + 0.5) * voxel
        above = z_cells > table_top + 3 * voxel
        return int((grid[:, :, above] == OCCUPIED).sum()), int((grid[:, :, ~above] == OCCUPIED).sum())

    raw_arm, raw_table = occupied_above_table(depth)
    kept_arm, kept_table = occupied_above_table(filtered)
    assert raw_arm > 50  # unfiltered, the arm is integrated as occupied
    assert kept_arm == 0  # filtered, no arm cell is occupied
    assert kept_table > 0.5 * raw_table  # the table is still seen


# --- simulated motion and flat parameters --------------------------------------------------------


def test_motion_respects_velocity_limits_and_waypoint_times():
    from nbv_prob_cnn.arm.motion import JointMotion

    motion = JointMotion(np.zeros(2), np.array([1.0, 0.5]), now=10.0)
    arrival = motion.move_through(
        [np.array([0.5, 1.0]), np.array([0.5, 1.0]), np.array([0.0, 1.0])], now=10.0, min_durations=[0.0, 0.0, 3.0]
    )
    # segment 1: joint 2 needs 1.0 / 0.5 = 2 s; the repeated waypoint adds nothing; segment 3: 0.5 s by speed, 3 s asked
    assert arrival == pytest.approx(15.0)
    np.testing.assert_allclose(motion.position(11.0), [0.25, 0.5])
    np.testing.assert_allclose(motion.velocity(11.0), [0.25, 0.5])
    np.testing.assert_allclose(motion.position(13.5), [0.25, 1.0])
    np.testing.assert_allclose(motion.position(99.0), [0.0, 1.0])
    assert motion.moving(14.9) and not motion.moving(15.0)
    times = np.linspace(10.0, 15.0, 501)
    speeds = np.abs(np.diff([motion.position(t) for t in times], axis=0)) / np.diff(times)[:, None]
    assert np.all(speeds <= motion.velocity_limits + 1e-9)
    # a new goal starts from where the arm is now
    motion.move_through([np.array([1.0, 0.5])], now=11.0)
    np.testing.assert_allclose(motion.position(11.0), [0.25, 0.5])
    assert motion.arrival_time() == pytest.approx(11.75)
    with pytest.raises(ValueError, match="finite joint positions"):
        motion.move_through([np.array([np.nan, 0.0])], now=12.0)
    with pytest.raises(ValueError, match="at least one waypoint"):
        motion.move_through([], now=12.0)


def test_robot_config_from_flat_parameters(robot):
    from nbv_prob_cnn.arm.robot import pose_from_xyz_rpy, robot_config

    pose = pose_from_xyz_rpy((1.0, 2.0, 3.0), (0.0, 0.0, math.pi / 2))
    np.testing.assert_allclose(pose[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [1.0, 2.0, 3.0])
    pitched = pose_from_xyz_rpy((0, 0, 0), (0.0, math.pi / 2, 0.0))
    np.testing.assert_allclose(pitched[:3, :3] @ [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], atol=1e-12)
    config = robot_config()
    np.testing.assert_allclose(config.world_from_base, robot.config.world_from_base)
    np.testing.assert_allclose(config.parent_from_camera, robot.config.parent_from_camera)
    with pytest.raises(ValueError, match="camera_parent: required"):
        robot_config(urdf_path="/some/robot.urdf")
    with pytest.raises(ValueError, match="3 finite xyz"):
        robot_config(base_xyz=(0.0, 1.0))


def test_plan_with_arm_around_a_gain_planner(robot, checker, capability):
    from dataclasses import replace

    from nbv_prob_cnn.arm.feasibility import plan_with_arm
    from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner

    defaults = DATASETS["3dt"]
    sensor = replace(defaults.sensor, r_max=24)  # 28 cm: the best views are close to the object
    context = PlanningContext(defaults, rng=np.random.default_rng(8), sensor=sensor)
    state = np.zeros(GEOMETRY_3DT.shape, dtype=np.int8)
    state[24:40, 56:72, 16:32] = UNKNOWN  # an unexplored object within reach
    planner = GainPlanner(GAIN_METHODS["prob_ig"])
    arm = ArmFeasibility(robot, checker, capability=capability, rng=np.random.default_rng(8))
    report = plan_with_arm(planner, state, context, GEOMETRY_3DT, arm, robot.reference_q, top_k=40)
    assert set(report.times) == {"gain", "capability", "ik_collision"}
    assert report.view is not None, vars(report)
    choice = report.view.choice
    assert state[tuple(choice.cell)] == 0 and choice.gain > 0
    target = np.eye(4)
    target[:3, :3] = view_rotations()[choice.view_index]
    target[:3, 3] = GEOMETRY_3DT.cell_centre(choice.cell)
    position_error, angle_error = pose_errors(robot.camera_pose(report.view.q), target)
    assert position_error < DEFAULT_IK.position_tol and angle_error < DEFAULT_IK.rotation_tol
    obstacles = GridObstacles.from_state(state, GEOMETRY_3DT).cleared(checker.body_points(robot.reference_q))
    assert checker.is_free(report.view.q, obstacles)
    # every better-ranked view was rejected for a reason the counters record
    assert report.checked == 1 + report.unreachable + report.in_collision + report.path_blocked
