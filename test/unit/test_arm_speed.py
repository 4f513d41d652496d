"""The arm's planning speed-ups keep the answers (no ROS): batched IK of many candidate views,
the capability map's stored configurations and its cache on disk, block-wise IK in the
feasibility check, and the compact (array) form of ranked views and view masks."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from nbv_prob_cnn.arm.capability import (  # noqa: E402
    MAP_IK,
    build_capability_map,
    capability_key,
    capability_map_path,
    load_capability_map,
    load_or_build_capability_map,
    save_capability_map,
    view_rotations,
)
from nbv_prob_cnn.arm.feasibility import ArmFeasibility  # noqa: E402
from nbv_prob_cnn.arm.ik import (  # noqa: E402
    DEFAULT_IK,
    alternative_solutions,
    alternative_solutions_batch,
    rotation_error,
    solve_camera_pose,
    solve_camera_poses,
)
from nbv_prob_cnn.basics.camera import DATASETS, matrix_from_quaternion  # noqa: E402
from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.basics.grid import EMPTY  # noqa: E402
from nbv_prob_cnn.planners import PlanningContext, ViewChoice  # noqa: E402
from nbv_prob_cnn.planners.base import search_views  # noqa: E402
from nbv_prob_cnn.planners.ranked_views import (  # noqa: E402
    ranked_from_arrays,
    ranked_to_arrays,
    view_mask_from_bytes,
    view_mask_to_bytes,
)

GEOMETRY_3DT = GridGeometry((0.0, 0.0, 0.0), DATASETS["3dt"].resolution_m, DATASETS["3dt"].shape)


def pinocchio_errors(robot, q: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """Position (m) and rotation (rad) error of the camera at ``q`` by pinocchio's forward
    kinematics (independent of the batched chain the solver uses)."""
    pose = robot.camera_pose(q)
    angle = float(np.linalg.norm(rotation_error(target[None, :3, :3], pose[None, :3, :3])[0]))
    return float(np.linalg.norm(pose[:3, 3] - target[:3, 3])), angle


def random_reachable_targets(robot, chain, count: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Camera poses of random configurations within the limits (reachable by construction)."""
    qs = rng.uniform(chain.lower, chain.upper, size=(count, chain.n))
    return chain.camera_poses(qs)[0], qs


def test_batched_ik_equals_the_per_candidate_ik(robot, chain):
    """Without random restarts both solvers are deterministic: the batch reaches exactly the
    targets the per-candidate solver reaches, with the same configurations (1e-9 rad), and
    each solution puts the camera on its target by pinocchio's FK."""
    from dataclasses import replace

    rng = np.random.default_rng(7)
    targets, _ = random_reachable_targets(robot, chain, 40, rng)
    far = targets[:5].copy()
    far[:, :3, 3] += [3.0, 0.0, 0.0]  # 3 m away: beyond the arm's reach
    targets = np.concatenate([targets, far])
    start_q = robot.reference_q
    settings = replace(DEFAULT_IK, restarts=0)
    reference = [solve_camera_pose(chain, t, start_q, rng, settings).q for t in targets]
    batched = solve_camera_poses(chain, targets, start_q, rng, settings)
    assert [q is not None for q in reference] == [r.q is not None for r in batched]
    assert sum(q is not None for q in reference[:40]) >= 10 and not any(r.q is not None for r in batched[40:])
    for ref, got, target in zip(reference, batched, targets, strict=True):
        if got.q is None:
            continue
        np.testing.assert_allclose(got.q, ref, atol=1e-9)
        position_error, rotation = pinocchio_errors(robot, got.q, target)
        assert position_error < settings.position_tol and rotation < settings.rotation_tol
        assert robot.within_limits(got.q)
        np.testing.assert_array_equal(np.delete(got.q, chain.q_index), np.delete(start_q, chain.q_index))


def test_batched_ik_with_restarts_reaches_as_many_targets(robot, chain):
    """With random restarts (different draws in the two solvers) the batch reaches about as many
    random reachable targets as the per-candidate solver (within 2 of 40), each one exactly."""
    rng = np.random.default_rng(8)
    targets, _ = random_reachable_targets(robot, chain, 40, rng)
    reference = [solve_camera_pose(chain, t, robot.reference_q, rng).q for t in targets]
    batched = solve_camera_poses(chain, targets, robot.reference_q, rng)
    reached_reference = sum(q is not None for q in reference)
    reached_batch = sum(r.q is not None for r in batched)
    assert reached_reference >= 34 and reached_batch >= reached_reference - 2
    for got, target in zip(batched, targets, strict=True):
        if got.q is not None:
            position_error, rotation = pinocchio_errors(robot, got.q, target)
            assert position_error < DEFAULT_IK.position_tol and rotation < DEFAULT_IK.rotation_tol


def test_batched_alternative_solutions_equal_the_one_by_one_ones(robot, chain):
    """The same random draws in the same order: the batch of 6 targets gives exactly the
    per-target alternatives (configurations to 1e-9 rad, same count and order)."""
    targets, _ = random_reachable_targets(robot, chain, 6, np.random.default_rng(21))
    one_by_one = [alternative_solutions(chain, t, robot.reference_q, rng) for rng in [np.random.default_rng(5)]
                  for t in targets]  # fmt: skip
    batched = alternative_solutions_batch(chain, targets, robot.reference_q, np.random.default_rng(5))
    assert sum(len(found) for found in one_by_one) >= 6
    for single, batch, target in zip(one_by_one, batched, targets, strict=True):
        assert len(single) == len(batch)
        for a, b in zip(single, batch, strict=True):
            np.testing.assert_allclose(b.q, a.q, atol=1e-9)
            assert pinocchio_errors(robot, b.q, target)[0] < DEFAULT_IK.position_tol


def test_batched_ik_keeps_the_closest_solution_to_the_start(robot, chain):
    """A target the start configuration itself reaches: both solvers return (about) the start."""
    rng = np.random.default_rng(3)
    q0 = robot.reference_q.copy()
    target = robot.camera_pose(q0)
    (result,) = solve_camera_poses(chain, target[None], q0, rng)
    assert result.q is not None and result.distance < 1e-6
    single = solve_camera_pose(chain, target, q0, rng)
    np.testing.assert_allclose(result.q, single.q, atol=1e-9)


def test_warm_seeds_reach_targets_the_start_cannot(robot, chain):
    """With no random restarts, the start seed alone misses some targets; the true configuration
    as a warm seed reaches every one of them (within the tolerances, by pinocchio's FK)."""
    from dataclasses import replace

    rng = np.random.default_rng(11)
    targets, qs = random_reachable_targets(robot, chain, 20, rng)
    settings = replace(DEFAULT_IK, restarts=0)
    cold = solve_camera_poses(chain, targets, robot.reference_q, rng, settings)
    warm = solve_camera_poses(chain, targets, robot.reference_q, rng, settings, warm_seeds=qs + 0.05)
    assert sum(r.q is None for r in cold) >= 1
    for result, target in zip(warm, targets, strict=True):
        assert result.q is not None
        position_error, rotation = pinocchio_errors(robot, result.q, target)
        assert position_error < settings.position_tol and rotation < settings.rotation_tol


# --- capability map: stored configurations, cache -------------------------------------------------

SMALL = GridGeometry((0.3, 0.4, 0.0), 0.05, (16, 16, 12))
STRIDE = 5


@pytest.fixture(scope="module")
def small_map(robot):
    return build_capability_map(robot, SMALL, STRIDE, progress=False)


def test_capability_map_configurations_reach_their_entries(robot, chain, small_map):
    reachable, configurations = small_map.reachable, small_map.configurations
    assert configurations is not None and configurations.shape == reachable.shape + (chain.n,)
    assert np.isnan(configurations[~reachable]).all() and np.isfinite(configurations[reachable]).all()
    rotations = view_rotations()
    entries = np.argwhere(reachable)
    assert entries.shape[0] > 20
    for i, j, k, v in entries[np.random.default_rng(0).choice(entries.shape[0], 20, replace=False)]:
        target = np.eye(4)
        target[:3, :3] = rotations[v]
        target[:3, 3] = SMALL.cell_centre(np.array([i, j, k]) * STRIDE)
        q = chain.full_configuration(configurations[i, j, k, v].astype(np.float64), robot.reference_q)
        position_error, rotation = pinocchio_errors(robot, q, target)
        assert position_error < 2 * MAP_IK.position_tol and rotation < 2 * MAP_IK.rotation_tol  # float32 storage
    # the warm seed of a cell is its nearest node's configuration for that orientation
    i, j, k, v = entries[0]
    cell = np.array([i, j, k]) * STRIDE + np.array([1, -1, 2]).clip(-(np.array([i, j, k]) * STRIDE), None)
    seed = small_map.seed_configurations(cell[None], np.array([v]))
    np.testing.assert_array_equal(seed[0], configurations[i, j, k, v])


def test_persisted_capability_map_loads_equal_and_is_rebuilt_for_another_key(robot, small_map, tmp_path, monkeypatch):
    path = tmp_path / "map.npz"
    save_capability_map(small_map, path)
    loaded = load_capability_map(path, SMALL)
    np.testing.assert_array_equal(loaded.reachable, small_map.reachable)
    np.testing.assert_array_equal(loaded.configurations, small_map.configurations)
    assert loaded.stride == STRIDE
    with pytest.raises(ValueError, match="lattice"):
        load_capability_map(path, GridGeometry((0.3, 0.4, 0.0), 0.05, (40, 16, 12)))  # another grid

    monkeypatch.setenv("NBV_CACHE_DIR", str(tmp_path / "cache"))
    first = load_or_build_capability_map(robot, SMALL, STRIDE, progress=False)
    key = capability_key(robot, SMALL, STRIDE, MAP_IK, 2)
    assert capability_map_path(key).is_file() and str(tmp_path) in str(capability_map_path(key))
    assert first.build_seconds > 0  # built
    again = load_or_build_capability_map(robot, SMALL, STRIDE, progress=False)
    assert again.build_seconds == 0  # loaded
    np.testing.assert_array_equal(again.reachable, first.reachable)
    np.testing.assert_array_equal(again.configurations, first.configurations)
    float32 = GridGeometry(tuple(float(np.float32(v)) for v in SMALL.origin), float(np.float32(0.05)), SMALL.shape)
    assert capability_key(robot, float32, STRIDE, MAP_IK, 2) == key  # a grid message's float32 sizes: the same map
    moved = GridGeometry((0.35, 0.4, 0.0), 0.05, (16, 16, 12))  # another grid placement: another key
    assert capability_key(robot, moved, STRIDE, MAP_IK, 2) != key
    rebuilt = load_or_build_capability_map(robot, moved, STRIDE, progress=False)
    assert rebuilt.build_seconds > 0
    capability_map_path(key).write_bytes(b"not a map")  # a damaged file is rebuilt, not fatal
    assert load_or_build_capability_map(robot, SMALL, STRIDE, progress=False).build_seconds > 0


# --- feasibility: IK in blocks --------------------------------------------------------------------


def test_blockwise_ik_checks_candidates_in_gain_order(robot, checker):
    """Five views 3 m outside the arm's reach, then a reachable one, then more: the check counts
    five unreachable and picks the sixth, as a candidate-by-candidate check does; a budget of
    three stops after three unreachable ones."""
    context = PlanningContext.for_dataset("3dt")
    state = np.full(GEOMETRY_3DT.shape, EMPTY, dtype=np.int8)
    camera = robot.camera_pose(robot.reference_q)
    reachable_cell, _ = GEOMETRY_3DT.containing_cell(camera[None, :3, 3])
    quats = np.array([context.view_quaternion(i) for i in range(len(context.orientations))])
    down = int(np.argmax([matrix_from_quaternion(q)[2, 2] * -1 for q in quats]))  # optical axis down
    far = [ViewChoice(np.array([127, 127, 95 - i]), i, 10.0 - i) for i in range(5)]  # ~1.8 m from the shoulder
    ranked = far + [ViewChoice(reachable_cell[0], down, 1.0)] + [ViewChoice(reachable_cell[0], down, 0.5)]
    arm = ArmFeasibility(robot, checker, rng=np.random.default_rng(0))
    report = arm.select(ranked, state, context, GEOMETRY_3DT, robot.reference_q)
    assert report.view is not None and report.view.choice is ranked[5]
    assert (report.checked, report.unreachable) == (6, 5)
    position_error, _ = pinocchio_errors(robot, report.view.q, arm_target(report.view.choice, context))
    assert position_error < DEFAULT_IK.position_tol
    budget = ArmFeasibility(robot, checker, rng=np.random.default_rng(0), max_checks=3)
    limited = budget.select(ranked, state, context, GEOMETRY_3DT, robot.reference_q)
    assert limited.view is None and limited.budget_exhausted and (limited.checked, limited.unreachable) == (3, 3)


def arm_target(choice: ViewChoice, context: PlanningContext) -> np.ndarray:
    target = np.eye(4)
    target[:3, :3] = matrix_from_quaternion(context.view_quaternion(choice.view_index))
    target[:3, 3] = GEOMETRY_3DT.cell_centre(choice.cell)
    return target


# --- compact ranked views -------------------------------------------------------------------------


def test_ranked_arrays_round_trip_the_ranking():
    context = PlanningContext.for_dataset("3dt")
    rng = np.random.default_rng(2)
    ranked = [
        ViewChoice(rng.integers(0, GEOMETRY_3DT.shape), int(rng.integers(52)), float(g))
        for g in sorted(rng.uniform(0, 5, 30), reverse=True)
    ]
    arrays = ranked_to_arrays(ranked, context, GEOMETRY_3DT)
    for index, choice in enumerate(ranked):
        x, y, z = choice.cell  # the flat index convention of VoxelGrid: x fastest
        assert arrays.cells[index] == x + 128 * (y + 128 * z)
        np.testing.assert_allclose(arrays.positions[index], (choice.cell + 0.5) * GEOMETRY_3DT.resolution)
        np.testing.assert_array_equal(arrays.quaternions[index], context.orientations[choice.view_index])
    back = ranked_from_arrays(arrays.cells, arrays.orientations, arrays.gains, GEOMETRY_3DT.shape, 52)
    assert [(tuple(c.cell), c.view_index) for c in back] == [(tuple(c.cell), c.view_index) for c in ranked]
    np.testing.assert_allclose([c.gain for c in back], [c.gain for c in ranked], rtol=1e-6)
    with pytest.raises(ValueError, match="orientation"):
        ranked_from_arrays(arrays.cells, arrays.orientations + 52, arrays.gains, GEOMETRY_3DT.shape, 52)
    with pytest.raises(ValueError, match="lengths"):
        ranked_from_arrays(arrays.cells[:3], arrays.orientations, arrays.gains, GEOMETRY_3DT.shape, 52)


def test_view_mask_bytes_rank_as_the_mask_itself():
    """A search with the mask sent as allowed_views bytes ranks the same views as with the mask
    function, and the mask forbids what it should (independent per-pair check)."""
    geometry = GridGeometry((0.0, 0.0, 0.0), 0.04, (24, 24, 16))
    state = np.full(geometry.shape, -1, dtype=np.int8)
    state[4:20, 4:20, 2:12] = EMPTY
    context = PlanningContext.for_dataset("3dt", backend="numpy")
    origins = context.candidate_origins(state)
    rng = np.random.default_rng(4)
    allowed = origins[rng.random(origins.shape[0]) < 0.6]
    table = rng.random((allowed.shape[0], 52)) < 0.3
    flat = allowed[:, 0] + 24 * (allowed[:, 1] + 24 * allowed[:, 2])

    def reference(cells: np.ndarray) -> np.ndarray:
        out = np.zeros((cells.shape[0], 52), dtype=bool)
        for n, cell in enumerate(cells):
            match = np.nonzero(np.all(allowed == cell, axis=1))[0]
            if match.size:
                out[n] = table[match[0]]
        return out

    mask = view_mask_from_bytes(flat, view_mask_to_bytes(flat, table), geometry.shape, 52)
    np.testing.assert_array_equal(mask(origins), reference(origins))
    prob = np.where(state == -1, 0.15, 0.0).astype(np.float32)
    with_bytes = search_views(state, prob, allowed, context, top_k=40, view_mask=mask)
    with_function = search_views(state, prob, allowed, context, top_k=40, view_mask=reference)
    assert [(tuple(c.cell), c.view_index, c.gain) for c in with_bytes] == [
        (tuple(c.cell), c.view_index, c.gain) for c in with_function
    ]
    assert len(with_bytes) == 40 and all(reference(c.cell[None])[0, c.view_index] for c in with_bytes)
    with pytest.raises(ValueError, match="allowed_views"):
        view_mask_from_bytes(flat, b"\x01" * 5, geometry.shape, 52)
