"""The field's volumetric gains (gain/volumetric.py) on single rays worked by hand, with OctoMap's
default probabilities: free 0.1192, occupied 0.971, unknown 0.5."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nbv_prob_cnn.gain.volumetric import (
    VOLUMETRIC_GAINS,
    OctoMapProbabilities,
    entropy_bits,
    volumetric_view_gains,
)

E, O, U = 0, 1, -1  # noqa: E741
H_FREE = -(0.1192 * math.log2(0.1192) + 0.8808 * math.log2(0.8808))
H_OCC = -(0.971 * math.log2(0.971) + 0.029 * math.log2(0.029))
RIGHT = np.array([[1.0, 0.0]])
ONE_VIEW = np.array([[1.0]])


def _gain(row, formulation, prob=None, r_max=5):
    state = np.array(row, dtype=np.int8).reshape(-1, 1)
    p = None if prob is None else np.array(prob, dtype=np.float32).reshape(-1, 1)
    return float(volumetric_view_gains(state, p, RIGHT, r_max, ONE_VIEW, np.array([[0, 0]]), formulation)[0, 0])


#       x: 0  1  2  3  4  5   (the origin at x = 0; samples t = 1..5 are x = 1..5)
HITTING = [E, E, U, U, O, U]
MISSING = [E, E, U, U, E, U]  # leaves the grid at x = 6 without a hit


def test_entropy_by_hand():
    assert entropy_bits(np.array([0.5, 0.0, 1.0])).tolist() == [1.0, 0.0, 0.0]
    assert float(entropy_bits(np.array([0.1192]))[0]) == pytest.approx(H_FREE)


def test_occlusion_aware_sums_visible_entropy_up_to_the_hit():
    # visibility: 1, then x (1 - 0.1192), then x 0.5, x 0.5; the hit at x = 4 counts, x = 5 is hidden
    expected = H_FREE + 0.8808 * 1 + 0.4404 * 1 + 0.2202 * H_OCC
    assert _gain(HITTING, "occlusion_aware") == pytest.approx(expected, rel=1e-6)


def test_unobserved_voxel_counts_the_unknown_cells_only():
    assert _gain(HITTING, "unobserved_voxel") == pytest.approx(0.8808 + 0.4404, rel=1e-6)
    # without a hit the ray goes on to the border: x = 5 (visibility 0.8808 * 0.5 * 0.5 * 0.8808) counts too
    assert _gain(MISSING, "unobserved_voxel") == pytest.approx(0.8808 + 0.4404 + 0.8808 * 0.25 * 0.8808, rel=1e-6)


def test_rear_side_voxel_needs_a_hit_right_after_unknown_space():
    assert _gain(HITTING, "rear_side_voxel") == 1.0
    assert _gain(MISSING, "rear_side_voxel") == 0.0
    assert _gain([E, U, E, O, U, U], "rear_side_voxel") == 0.0  # an empty cell between: a front side seen


def test_proximity_count_weights_unknown_cells_by_closeness_to_the_surface():
    # d_max 5: x = 2 is 2 cells from the occupied x = 4 (counts 3), x = 3 is 1 cell (counts 4); x = 5 is hidden
    assert _gain(HITTING, "proximity_count") == pytest.approx(7.0)
    assert _gain(MISSING, "proximity_count") == 0.0  # no surface known: nothing near it


def test_average_entropy_over_the_cells_of_hitting_rays():
    assert _gain(HITTING, "average_entropy") == pytest.approx((H_FREE + 2.0 + H_OCC) / 4, rel=1e-6)
    assert _gain(MISSING, "average_entropy") == 0.0


def test_the_cnn_map_replaces_the_prior_in_unknown_cells():
    prob = [0, 0, 0.9, 0.2, 1, 0.5]
    h9, h2 = float(entropy_bits(np.array([0.9]))[0]), float(entropy_bits(np.array([0.2]))[0])
    expected = 0.8808 * h9 + 0.8808 * 0.1 * h2
    assert _gain(HITTING, "unobserved_voxel", prob) == pytest.approx(expected, rel=1e-6)


def test_bad_formulation_and_probabilities():
    with pytest.raises(ValueError, match="formulation"):
        _gain(HITTING, "frontier")
    with pytest.raises(ValueError, match="free"):
        OctoMapProbabilities(free=0.0)
    assert len(VOLUMETRIC_GAINS) == 5


@pytest.mark.parametrize("formulation", ["rear_side_voxel", "proximity_count", "occlusion_aware"])
def test_the_planner_ranks_as_a_brute_force_search(formulation):
    """Through the method registry (as nbv explore / evaluate / the nodes call it): on a grid with
    fewer empty cells than the origin budget every empty cell is a candidate, and the ranking is the
    brute force's over all of them."""
    from nbv_prob_cnn.gain import empty_origins
    from nbv_prob_cnn.planners import PlanningContext, make_planner
    from nbv_prob_cnn.planners.candidates import near_unknown_origins, ray_reach

    rng = np.random.default_rng(4)
    draw = rng.random((12, 11, 10))
    state = np.where(draw < 0.5, U, np.where(draw < 0.65, O, E)).astype(np.int8)
    context = PlanningContext.for_dataset("3dt", rng=np.random.default_rng(0), backend="numpy")
    ranked = make_planner(formulation).rank(state, context, top_k=3)
    # the method's candidates: the data set's origin stride, within the rays' reach of unknown space
    origins = near_unknown_origins(state, context.candidate_origins(state), ray_reach(context.active_sensor.r_max))
    assert 0 < origins.shape[0] < 500 and empty_origins(state).shape[0] > origins.shape[0]
    sensor = context.active_sensor
    gains = volumetric_view_gains(state, None, context.directions, sensor.r_max, context.membership, origins,
                                  formulation)  # fmt: skip
    flat = np.argsort(-gains.ravel(), kind="stable")[:3]
    assert [float(c.gain) for c in ranked] == pytest.approx([float(gains.flat[i]) for i in flat])
    best = flat[0]
    assert (
        tuple(ranked[0].cell) == tuple(origins[best // gains.shape[1]])
        and ranked[0].view_index == best % gains.shape[1]
    )


@pytest.mark.parametrize("formulation", ["rear_side_voxel", "proximity_count", "average_entropy"])
def test_without_a_known_surface_the_surface_formulations_fall_back_to_unobserved_voxel(formulation):
    from nbv_prob_cnn.planners import PlanningContext, make_planner

    state = np.full((12, 11, 10), U, dtype=np.int8)
    state[3:8, 3:8, 3:8] = E  # a first view that saw empty space and no surface
    context = PlanningContext.for_dataset("3dt", rng=np.random.default_rng(0), backend="numpy")
    rear = make_planner(formulation).rank(state, context, top_k=2)
    unobserved = make_planner("unobserved_voxel").rank(state, PlanningContext.for_dataset(
        "3dt", rng=np.random.default_rng(0), backend="numpy"), top_k=2)  # fmt: skip
    assert rear and [(tuple(c.cell), c.view_index, c.gain) for c in rear] == [
        (tuple(c.cell), c.view_index, c.gain) for c in unobserved
    ]
