"""What keeps the arm-constrained exploration going: the swept space counted free, the capability
map as view mask in the ranking (strict lookup), camera-rigid bodies checked before IK, and other
IK solutions of a pose tried when the first one collides."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from arm_views import GEOMETRY_3DT, near_view  # noqa: E402

from nbv_prob_cnn.arm.capability import CapabilityMap  # noqa: E402
from nbv_prob_cnn.arm.collision import GridObstacles  # noqa: E402
from nbv_prob_cnn.arm.feasibility import ArmFeasibility  # noqa: E402
from nbv_prob_cnn.arm.ik import DEFAULT_IK, alternative_solutions, solve_camera_pose  # noqa: E402
from nbv_prob_cnn.arm.swept import SweptVolume  # noqa: E402
from nbv_prob_cnn.basics.camera import DatasetDefaults, Sensor, matrix_from_quaternion  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN, probability_with_constant  # noqa: E402
from nbv_prob_cnn.gain import ray_gains  # noqa: E402
from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner, PlanningContext, ViewChoice  # noqa: E402
from nbv_prob_cnn.planners.base import search_views  # noqa: E402

SMALL_3D = DatasetDefaults("3du", 3, (18, 16, 14), 0.01, Sensor(60.0, 46.0, 8), 4, 3)


def unknown_grid() -> np.ndarray:
    return np.full(GEOMETRY_3DT.shape, UNKNOWN, dtype=np.int8)


def moved(robot, changes: dict[str, float]) -> np.ndarray:
    q = robot.reference_q.copy()
    for name, delta in changes.items():
        q[robot.joint_names.index(name)] += delta
    return np.clip(q, robot.lower, robot.upper)


# --- swept space --------------------------------------------------------------------------------


def test_swept_space_is_free_for_every_sampled_configuration(robot, checker):
    goal = moved(robot, {"panda_joint1": 0.6, "panda_joint4": 0.5})
    swept = SweptVolume(checker, GEOMETRY_3DT, path_step=0.05)
    swept.add_path(robot.reference_q, goal)
    carved = swept.carve(unknown_grid())
    assert swept.cell_count == int(np.count_nonzero(carved == EMPTY)) > 0
    obstacles = GridObstacles.from_state(carved, GEOMETRY_3DT)
    # every configuration sampled on the path (12 steps of 0.05 rad for 0.6 rad) is free ...
    for t in np.linspace(0.0, 1.0, 13):
        assert checker.grid_collisions(robot.reference_q + t * (goal - robot.reference_q), obstacles) == []
    # ... and a configuration the arm never took is not
    elsewhere = moved(robot, {"panda_joint1": -1.2})
    assert checker.grid_collision(elsewhere, obstacles)
    assert checker.grid_collision(goal, GridObstacles.from_state(unknown_grid(), GEOMETRY_3DT))


def test_carving_keeps_occupied_cells_and_the_input(robot, checker):
    swept = SweptVolume(checker, GEOMETRY_3DT)
    swept.add_configuration(robot.reference_q)
    cell, inside = GEOMETRY_3DT.containing_cell(checker.body_points(robot.reference_q))
    a, b = cell[inside][0], cell[inside][-1]
    state = unknown_grid()
    state[a[0], a[1], a[2]] = OCCUPIED
    state[b[0], b[1], b[2]] = EMPTY
    carved = swept.carve(state)
    assert carved[a[0], a[1], a[2]] == OCCUPIED and carved[b[0], b[1], b[2]] == EMPTY
    assert state[b[0] - 0, b[1], b[2]] == EMPTY and int(np.count_nonzero(state == EMPTY)) == 1  # input unchanged
    # cells no body filled stay unknown
    assert carved[0, 0, 0] == UNKNOWN and carved[127, 127, 95] == UNKNOWN


def test_swept_volume_bad_input(robot, checker):
    with pytest.raises(ValueError, match="path_step"):
        SweptVolume(checker, GEOMETRY_3DT, path_step=0.0)
    swept = SweptVolume(checker, GEOMETRY_3DT)
    with pytest.raises(ValueError, match="expected a grid of shape"):
        swept.carve(np.full((4, 4, 4), UNKNOWN, dtype=np.int8))
    with pytest.raises(ValueError, match="q_goal"):
        swept.add_path(robot.reference_q, np.zeros(3))


# --- camera-rigid bodies ------------------------------------------------------------------------


def test_camera_rigid_points_follow_the_camera(robot, chain, checker):
    names = sorted(checker.geometry_model.geometryObjects[i].name for i in checker.camera_rigid)
    assert names == ["panda_hand_0", "panda_leftfinger_0", "panda_link7_0", "panda_rightfinger_0"]
    local = checker.camera_rigid_points(robot.reference_q)
    rng = np.random.default_rng(11)
    for _ in range(5):
        q = chain.full_configuration(rng.uniform(chain.lower, chain.upper), robot.reference_q)
        camera = robot.camera_pose(q)
        poses = checker.body_poses(q)  # pinocchio forward kinematics of the bodies themselves
        expected = np.vstack([checker.points[i] @ poses[i][:3, :3].T + poses[i][:3, 3] for i in checker.camera_rigid])
        np.testing.assert_allclose(local @ camera[:3, :3].T + camera[:3, 3], expected, atol=1e-9)


# --- view mask in the ranking -------------------------------------------------------------------


def test_view_mask_ranks_only_the_allowed_views(rng):
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=SMALL_3D.shape, p=[0.5, 0.45, 0.05])
    prob = probability_with_constant(state, 0.15)
    context = PlanningContext(SMALL_3D, backend="numpy")
    origins = np.argwhere(state == 0)
    allowed = np.random.default_rng(4).random((origins.shape[0], context.membership.shape[1])) < 0.3
    index = {tuple(c): k for k, c in enumerate(origins)}

    def view_mask(cells: np.ndarray) -> np.ndarray:
        return allowed[[index[tuple(c)] for c in cells]]

    full = ray_gains(state, prob, context.directions, 8, origins, "numpy") @ context.membership
    masked = np.where(allowed, full, 0.0).ravel()
    order = np.lexsort((np.arange(masked.size), -masked))[:20]
    found = search_views(state, prob, origins, context, top_k=20, view_mask=view_mask)
    assert len(found) == 20
    np.testing.assert_allclose([f.gain for f in found], masked[order], atol=1e-5)
    assert all(allowed[index[tuple(f.cell)], f.view_index] for f in found)
    with pytest.raises(ValueError, match="view_mask"):
        search_views(state, prob, origins, context, top_k=5, view_mask=lambda cells: np.ones((1, 1), bool))


def test_strict_capability_lookup_takes_the_and_of_surrounding_nodes():
    geometry = GridGeometry((0.0, 0.0, 0.0), 0.01, (20, 20, 20))
    table = np.zeros((3, 3, 3, 52), dtype=bool)
    table[1, 1, 1, 7] = True  # node at cell (10, 10, 10)
    table[1:, 1:, 1:, 9] = True  # the 8 nodes around cells (11..19, 11..19, 11..19)
    cmap = CapabilityMap(table, 10, geometry)
    cells = np.array([[10, 10, 10], [5, 5, 5], [15, 15, 15], [10, 15, 15], [15, 15, 10], [9, 15, 15]])
    strict = cmap.views_at(cells, strict=True)
    assert strict[:, 7].tolist() == [True, False, False, False, False, False]
    assert strict[:, 9].tolist() == [True, False, True, True, True, False]
    loose = cmap.views_at(cells)
    assert loose[:, 7].tolist() == [True, True, True, True, True, True]
    assert not np.any(strict & ~loose)
    np.testing.assert_array_equal(cmap.strict_views_at(cells), strict)


def test_plan_with_arm_ranks_only_views_the_map_keeps(robot, checker):
    """With a map that allows one orientation everywhere, every ranked view has it (without the
    view mask the top views of this grid use other orientations)."""
    context = PlanningContext.for_dataset("3dt", backend="numpy")
    state = unknown_grid()
    state[30:50, 60:80, 40:60] = EMPTY
    table = np.zeros((17, 17, 13, 52), dtype=bool)
    table[..., 3] = True
    capability = CapabilityMap(table, 8, GEOMETRY_3DT)
    planner = GainPlanner(GAIN_METHODS["prob_ig"])
    unmasked = planner.rank(state, context, top_k=20, origin_filter=capability.origin_filter)
    assert any(c.view_index != 3 for c in unmasked)
    arm = ArmFeasibility(robot, checker, capability, max_checks=1, rng=np.random.default_rng(0))
    from nbv_prob_cnn.arm.feasibility import plan_with_arm

    report = plan_with_arm(planner, state, context, GEOMETRY_3DT, arm, robot.reference_q, top_k=20)
    assert report.ranked == report.candidates == 20  # all kept by the map: no pair pruned after the gain


# --- other IK solutions -------------------------------------------------------------------------


def test_alternative_solutions_reach_the_pose_and_differ(robot, chain):
    goal = moved(robot, {"panda_joint1": 0.3, "panda_joint2": 0.2, "panda_joint4": 0.4})
    target = robot.camera_pose(goal)
    found = alternative_solutions(chain, target, robot.reference_q, np.random.default_rng(2))
    assert len(found) >= 2  # a 7-joint arm reaches a 6-D pose in several ways
    distances = [r.distance for r in found]
    assert distances == sorted(distances)
    for r in found:
        pose = robot.camera_pose(r.q)
        assert np.linalg.norm(pose[:3, 3] - target[:3, 3]) < DEFAULT_IK.position_tol
        assert robot.within_limits(r.q)
    chains = [r.q[chain.q_index] for r in found]
    assert all(np.linalg.norm(a - b) >= 0.2 for k, a in enumerate(chains) for b in chains[k + 1 :])


def test_other_ik_solutions_rescue_a_view_whose_first_one_collides(robot, chain, checker):
    context = PlanningContext.for_dataset("3dt")
    rescued = 0
    for view in (50, 30, 20):  # a few orientations at one reachable cell
        cell, _ = GEOMETRY_3DT.containing_cell(np.array([0.50, 0.60, 0.30]))
        choice = ViewChoice(cell, view, 1.0)
        quaternion = context.view_quaternion(view)
        target = np.eye(4)
        target[:3, :3] = matrix_from_quaternion(quaternion)
        target[:3, 3] = GEOMETRY_3DT.cell_centre(cell)
        first = solve_camera_pose(chain, target, robot.reference_q, np.random.default_rng(9))
        if first.q is None:
            continue
        # a 5-cell cube of obstacle at the elbow (link 4 frame) of the first solution
        state = np.zeros(GEOMETRY_3DT.shape, dtype=np.int8)
        elbow = next(i for i in checker.moving if checker.geometry_model.geometryObjects[i].name == "panda_link4_0")
        c, inside = GEOMETRY_3DT.containing_cell(checker.body_poses(first.q)[elbow][:3, 3])
        assert inside
        state[c[0] - 2 : c[0] + 3, c[1] - 2 : c[1] + 3, c[2] - 2 : c[2] + 3] = OCCUPIED
        single = ArmFeasibility(robot, checker, rng=np.random.default_rng(9))
        report = single.select([choice], state, context, GEOMETRY_3DT, robot.reference_q)
        if report.view is not None:  # the obstacle also overlapped the reference pose: cleared
            continue
        assert report.in_collision + report.path_blocked == 1
        several = ArmFeasibility(robot, checker, rng=np.random.default_rng(9), ik_alternatives=4)
        report = several.select([choice], state, context, GEOMETRY_3DT, robot.reference_q)
        if report.view is None:
            continue
        rescued += 1
        q = report.view.q
        assert np.abs(q - first.q).max() > 1e-3
        position = robot.camera_pose(q)[:3, 3]
        assert np.linalg.norm(position - target[:3, 3]) < DEFAULT_IK.position_tol
        obstacles = GridObstacles.from_state(state, GEOMETRY_3DT).cleared(checker.body_points(robot.reference_q))
        assert checker.is_free(q, obstacles)
        assert checker.path_is_free(robot.reference_q, q, obstacles, 0.1)
    assert rescued >= 1


def test_bad_feasibility_arguments(robot, checker):
    with pytest.raises(ValueError, match="ik_alternatives"):
        ArmFeasibility(robot, checker, ik_alternatives=-1)


# --- the selector shared by arm-compare and the ROS nbv_planner ---------------------------------


def test_selector_carves_the_planner_grid_only_where_the_arm_has_been(robot, checker):
    from nbv_prob_cnn.arm.selection import ArmViewSelector

    arm = ArmFeasibility(robot, checker)
    state = unknown_grid()
    state[:, :, :3] = OCCUPIED  # floor
    state[60:70, 60:70, 20:30] = EMPTY
    selector = ArmViewSelector(arm, GEOMETRY_3DT, SweptVolume(checker, GEOMETRY_3DT))
    np.testing.assert_array_equal(selector.known(state), state)  # nothing swept yet
    q = moved(robot, {"panda_joint1": 0.4})
    selector.swept.add_configuration(q)
    known = selector.known(state)
    cells, inside = GEOMETRY_3DT.containing_cell(checker.body_points(q))
    filled = np.zeros(state.shape, dtype=bool)
    filled[tuple(cells[inside].T)] = True
    assert filled.sum() > 100
    np.testing.assert_array_equal(known[filled & (state == UNKNOWN)], EMPTY)
    np.testing.assert_array_equal(known[~filled], state[~filled])  # nowhere else
    np.testing.assert_array_equal(known[state == OCCUPIED], OCCUPIED)  # occupied stays occupied
    unswept = ArmViewSelector(arm, GEOMETRY_3DT)
    assert unswept.known(state) is state
    with pytest.raises(ValueError, match="swept"):
        ArmViewSelector(arm, GEOMETRY_3DT, SweptVolume(checker, GridGeometry((0, 0, 0), 0.01, (4, 4, 4))))


def views_grid(first: ViewChoice) -> np.ndarray:
    """Unknown, but a 9-cell cube of empty space around the view's cell."""
    state = unknown_grid()
    c = first.cell
    state[c[0] - 4 : c[0] + 5, c[1] - 4 : c[1] + 5, c[2] - 4 : c[2] + 5] = EMPTY
    return state


def test_remote_ranking_skips_taken_views_and_sees_the_carved_grid(robot, checker):
    """Through the servers the ranking ignores view masks: the selector still never returns a
    view taken, and the ranker gets the grid with the swept space carved."""
    pytest.importorskip("rclpy")
    from nbv_prob_cnn.arm.selection import ArmViewSelector
    from nbv_prob_cnn.ros.nbv_planner import RecordingPlanner

    context = PlanningContext.for_dataset("3dt", backend="numpy")
    near = near_view(robot, context)
    other = ViewChoice(near.cell + np.array([0, -2, 0]), near.view_index, 0.4)
    seen = []

    def ranker(method, state, prob, top_k):
        seen.append(state)
        return [ViewChoice(near.cell, near.view_index, 0.5), ViewChoice(other.cell, other.view_index, 0.4)]

    context.ranker = ranker
    arm = ArmFeasibility(robot, checker, free_above_m=0.0, max_checks=5, rng=np.random.default_rng(0))
    selector = ArmViewSelector(arm, GEOMETRY_3DT, SweptVolume(checker, GEOMETRY_3DT))
    selector.swept.add_configuration(robot.reference_q)
    state = views_grid(near)
    planner = RecordingPlanner(GainPlanner(GAIN_METHODS["prob_ig"]), lambda origins: origins)
    first = selector.select(planner, state, context, robot.reference_q, 20)
    assert first.view is not None and (first.view.choice.cell == near.cell).all()
    assert (seen[0] == EMPTY).sum() > (state == EMPTY).sum()  # carved before the ranking
    np.testing.assert_array_equal(seen[0], selector.swept.carve(state))
    selector.moved(robot.reference_q, first.view)
    second = selector.select(planner, state, context, first.view.q, 20)
    assert second.view is not None and (second.view.choice.cell == other.cell).all()
    selector.take(second.view.choice)
    assert selector.select(planner, state, context, first.view.q, 20).view is None  # both taken


def test_ros_planner_wrapper_chooses_as_the_core_planner(robot, checker):
    """``nbv_planner``'s in-process path (the ranking wrapped by ``RecordingPlanner``) and the
    core's ``GainPlanner`` choose the same views from the same grid and configurations, the strict
    capability map applied as view mask inside the ranking in both."""
    pytest.importorskip("rclpy")
    from nbv_prob_cnn.arm.selection import ArmViewSelector
    from nbv_prob_cnn.ros.nbv_planner import RecordingPlanner

    context = PlanningContext.for_dataset("3dt", backend="numpy")
    near = near_view(robot, context)
    state = views_grid(near)
    look = matrix_from_quaternion(context.orientations[near.view_index])[:, 2]
    table = np.zeros((17, 17, 13, 52), dtype=bool)  # the map keeps the orientations within 90° of the near view's
    table[..., [matrix_from_quaternion(q)[:, 2] @ look > 0.0 for q in context.orientations]] = True
    capability = CapabilityMap(table, 8, GEOMETRY_3DT)
    runs = []
    for wrap in (False, True):
        arm = ArmFeasibility(
            robot, checker, capability, free_above_m=0.0, max_checks=0, rng=np.random.default_rng(0),
            strict_capability=True,
        )  # fmt: skip
        selector = ArmViewSelector(arm, GEOMETRY_3DT, SweptVolume(checker, GEOMETRY_3DT), fallback_radius_m=0.25)
        gain = GainPlanner(GAIN_METHODS["prob_ig"])
        planner = RecordingPlanner(gain, lambda origins: origins) if wrap else gain
        q, views = robot.reference_q.copy(), []
        for _ in range(2):
            report = selector.select(planner, state, context, q, 20)
            assert report.view is not None
            views.append((tuple(int(c) for c in report.view.choice.cell), report.view.choice.view_index))
            selector.moved(q, report.view)
            q = report.view.q
        assert len(set(views)) == 2
        runs.append((views, q))
    assert runs[0][0] == runs[1][0]
    np.testing.assert_allclose(runs[0][1], runs[1][1])
