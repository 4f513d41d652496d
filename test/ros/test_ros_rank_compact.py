"""``/nbv/rank_views``'s compact reply (the ``ranked_*`` arrays) and its view mask
(``allowed_views``) through a running ``gain_server``: the same ranking as the per-message reply
and as the core search with the same mask; a malformed mask is an error and the node keeps serving."""

from __future__ import annotations

import array

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from nbv_prob_cnn_msgs.srv import RankViews  # noqa: E402
from test_ros_planning import GEOMETRY, call, random_grid, ros_fixture  # noqa: E402

from nbv_prob_cnn.basics.camera import dataset_defaults  # noqa: E402
from nbv_prob_cnn.planners import GainPlanner, PlanningContext  # noqa: E402
from nbv_prob_cnn.planners.methods import GAIN_METHODS  # noqa: E402
from nbv_prob_cnn.planners.requests import flat_cells  # noqa: E402
from nbv_prob_cnn.ros.conversions import grid_to_msg, pose_to_arrays  # noqa: E402

pytestmark = pytest.mark.slow  # a ROS graph

ros = ros_fixture(221, 12)  # test_ros_planning's domains (the suite runs one module at a time)


def test_compact_reply_carries_the_per_message_ranking_and_the_view_mask(ros):
    node, graph, context = ros
    graph.start_node("gain_server", "gain_server", {"dataset": "3du", "backend": "opencl", "method": "prob_ig"})
    state = random_grid(5)
    core_context = PlanningContext(dataset_defaults("3du"), backend="opencl")
    origins = core_context.candidate_origins(state)
    rng = np.random.default_rng(1)
    allowed = origins[rng.random(origins.shape[0]) < 0.5]
    n_views = len(core_context.orientations)
    table = rng.random((allowed.shape[0], n_views)) < 0.25
    flat = flat_cells(allowed, state.shape)
    request = RankViews.Request(grid=grid_to_msg(state, GEOMETRY), method="prob_ig", top_k=60)
    request.allowed_origins = array.array("I", flat.astype(np.uint32).tobytes())
    request.allowed_views = array.array("B", table.astype(np.uint8).tobytes())

    messages = call(node, context, RankViews, "/nbv/rank_views", request)
    request.compact = True
    compact = call(node, context, RankViews, "/nbv/rank_views", request)
    assert messages.success and compact.success, (messages.message, compact.message)
    assert len(compact.ranked) == 0 and len(messages.ranked) == 60
    gains = np.frombuffer(compact.ranked_gains, dtype=np.float32)
    positions = np.frombuffer(compact.ranked_positions, dtype=np.float64).reshape(-1, 3)
    quaternions = np.frombuffer(compact.ranked_quaternions, dtype=np.float64).reshape(-1, 4)
    cells = np.frombuffer(compact.ranked_cells, dtype=np.uint32)
    views = np.frombuffer(compact.ranked_orientations, dtype=np.uint16)
    for index, view in enumerate(messages.ranked):  # the same ranking, view by view
        position, quaternion = pose_to_arrays(view.pose.pose)
        np.testing.assert_allclose(position, positions[index], atol=1e-9)
        np.testing.assert_allclose(quaternion, quaternions[index], atol=1e-9)
        assert view.gain == pytest.approx(float(gains[index]), rel=1e-6)

    def reference_mask(cells_: np.ndarray) -> np.ndarray:  # per origin, by matching rows (no bytes)
        out = np.zeros((cells_.shape[0], n_views), dtype=bool)
        rows = {tuple(c): r for r, c in enumerate(allowed)}
        for n, cell in enumerate(cells_):
            if tuple(cell) in rows:
                out[n] = table[rows[tuple(cell)]]
        return out

    core = GainPlanner(GAIN_METHODS["prob_ig"]).rank(
        state, core_context, 60, lambda o: o[np.isin(flat_cells(o, state.shape), flat)], view_mask=reference_mask
    )
    assert [(flat_cells(c.cell[None], state.shape)[0], c.view_index) for c in core] == list(
        zip(cells.tolist(), views.tolist(), strict=True)
    )
    np.testing.assert_allclose(gains, [c.gain for c in core], rtol=1e-6)
    assert all(table[np.nonzero(flat == cell)[0][0], view] for cell, view in zip(cells, views, strict=True))

    request.allowed_views = array.array("B", b"\x01" * 7)  # not one row per allowed origin
    bad = call(node, context, RankViews, "/nbv/rank_views", request)
    assert not bad.success and "allowed_views" in bad.message
    request.allowed_views = array.array("B")
    assert call(node, context, RankViews, "/nbv/rank_views", request).success  # still serving
