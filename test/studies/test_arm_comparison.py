"""ArmPlanner of the arm comparison study (studies.arm_comparison): near-camera fallback, views taken."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from arm_views import GEOMETRY_3DT, near_view  # noqa: E402

from nbv_prob_cnn.arm.feasibility import ArmFeasibility  # noqa: E402
from nbv_prob_cnn.arm.ik import DEFAULT_IK  # noqa: E402
from nbv_prob_cnn.basics.camera import (  # noqa: E402
    DatasetDefaults,
    Sensor,  # noqa: E402
)
from nbv_prob_cnn.basics.grid import EMPTY, UNKNOWN  # noqa: E402
from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner, PlanningContext, ViewChoice  # noqa: E402

SMALL_3D = DatasetDefaults("3du", 3, (18, 16, 14), 0.01, Sensor(60.0, 46.0, 8), 4, 3)


class TwoViews:
    """A stand-in ranker (not a GainPlanner: no view mask): the far view first, then the near one,
    each kept only if the origin filter keeps its cell."""

    name = "two_views"

    def __init__(self, far: ViewChoice, near: ViewChoice) -> None:
        self.views = [far, near]

    def rank(self, state, context, top_k=1, origin_filter=None):
        cells = np.array([v.cell for v in self.views])
        kept = origin_filter(cells) if origin_filter is not None else cells
        return [ViewChoice(v.cell, v.view_index, v.gain) for v in self.views if (kept == v.cell).all(axis=1).any()]


def test_fallback_ranks_again_near_the_camera(robot, checker):
    from studies.arm_comparison import ArmMove, ArmPlanner

    context = PlanningContext.for_dataset("3dt")
    far = ViewChoice(np.array([127, 5, 90]), 50, 1.0)  # 1.9 m from the shoulder: IK fails
    near = near_view(robot, context)
    state = np.zeros(GEOMETRY_3DT.shape, dtype=np.int8)
    start = ArmMove(robot.reference_q.copy(), 0.0)
    arm = ArmFeasibility(robot, checker, max_checks=1, rng=np.random.default_rng(0))  # budget: one check
    without = ArmPlanner(TwoViews(far, near), arm, GEOMETRY_3DT, start)
    assert without.plan(state, context) is None  # the far view spends the budget
    assert without.last_report.unreachable == 1 and without.last_report.budget_exhausted
    planner = ArmPlanner(TwoViews(far, near), arm, GEOMETRY_3DT, start, fallback_radius_m=0.2)
    camera = robot.camera_pose(robot.reference_q)[:3, 3]
    assert np.linalg.norm(GEOMETRY_3DT.cell_centre(near.cell) - camera) <= 0.2
    np.testing.assert_array_equal(planner.selector.near_camera(planner.q)(np.array([far.cell, near.cell])), [near.cell])
    choice = planner.plan(state, context)
    assert choice is not None and (choice.cell == near.cell).all() and choice.view_index == near.view_index
    assert planner.last_report.fallback and len(planner.moves) == 2
    position = robot.camera_pose(planner.q)[:3, 3]
    assert np.linalg.norm(position - GEOMETRY_3DT.cell_centre(near.cell)) < DEFAULT_IK.position_tol
    with pytest.raises(ValueError, match="fallback_radius_m"):
        ArmPlanner(TwoViews(far, near), arm, GEOMETRY_3DT, start, fallback_radius_m=-1.0)


def test_views_taken_are_not_ranked_again(robot, checker):
    from studies.arm_comparison import ArmMove, ArmPlanner

    context = PlanningContext.for_dataset("3dt", backend="numpy")
    first = near_view(robot, context)
    state = np.full(GEOMETRY_3DT.shape, UNKNOWN, dtype=np.int8)
    c = first.cell
    state[c[0] - 4 : c[0] + 5, c[1] - 4 : c[1] + 5, c[2] - 4 : c[2] + 5] = EMPTY
    arm = ArmFeasibility(robot, checker, free_above_m=0.0, max_checks=5, rng=np.random.default_rng(0))
    start = ArmMove(robot.reference_q.copy(), 0.0)
    planner = ArmPlanner(GainPlanner(GAIN_METHODS["prob_ig"]), arm, GEOMETRY_3DT, start, top_k=20, first=first)
    mask = planner.selector.not_taken(np.array([first.cell, first.cell + 1]))
    assert mask.shape == (2, 52) and mask.sum() == 103 and not mask[0, first.view_index]
    taken = {(tuple(first.cell), first.view_index)}
    for _ in range(3):  # the map does not change: without the rule the same best view would come back
        choice = planner.plan(state, context)
        assert choice is not None
        key = (tuple(int(v) for v in choice.cell), choice.view_index)
        assert key not in taken
        taken.add(key)
    assert planner.taken == taken
    # the counterfactual: forgetting the views taken, the same view comes back on the same map
    again = ArmPlanner(GainPlanner(GAIN_METHODS["prob_ig"]), arm, GEOMETRY_3DT, start, top_k=20)
    views = []
    for _ in range(2):
        again.taken.clear()
        again.moves = [start]  # and the arm back where it started
        choice = again.plan(state, context)
        views.append((tuple(int(v) for v in choice.cell), choice.view_index))
    assert views[0] == views[1]
