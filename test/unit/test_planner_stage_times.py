"""The exploration log line of ``nbv_planner``: where one step's time went (no ROS graph needed)."""

import pytest

pytest.importorskip("nbv_prob_cnn_msgs")


def test_stage_times_by_hand():
    from nbv_prob_cnn_msgs.srv import PlanNextBestView

    from nbv_prob_cnn.ros.nbv_planner import stage_times

    planned = PlanNextBestView.Response(time_total_s=10.0, time_cnn_s=2.5, time_raycast_s=0.25, time_views_s=0.05)
    assert stage_times(planned, 1.5, 0.25) == (
        "plan 10.00 s (CNN 2.50, ray casting 0.25, views 0.05, other 7.20), move 1.50 s, grid wait 0.25 s"
    )
    # parts measured on another clock may exceed the total: "other" is never negative
    planned.time_total_s = 2.7
    assert "other 0.00)" in stage_times(planned, 0.0, 0.0)


def test_stage_times_with_the_ranking_and_the_arm_by_hand():
    from nbv_prob_cnn_msgs.srv import PlanNextBestView

    from nbv_prob_cnn.ros.nbv_planner import stage_times

    planned = PlanNextBestView.Response(
        time_total_s=4.0, time_cnn_s=1.0, time_raycast_s=0.5, time_views_s=0.1, time_rank_s=0.9,
        time_capability_s=0.2, time_ik_collision_s=1.5, arm_checked=12,
    )  # fmt: skip
    # rank reply = 0.9 - 0.5 - 0.1 = 0.3; other = 4.0 - 1.0 - 0.9 - 0.2 - 1.5 = 0.4
    assert stage_times(planned, 1.0, 0.5) == (
        "plan 4.00 s (CNN 1.00, ray casting 0.50, views 0.10, rank reply 0.30, capability 0.20, IK+collision 1.50 "
        "(12 checked), other 0.40), move 1.00 s, grid wait 0.50 s"
    )


def test_server_stage_times_by_hand():
    from nbv_prob_cnn.ros.nbv_planner import server_stage_times

    assert server_stage_times({}) == ""  # in-process planning: no server request
    both = {"cnn_server": 1.75, "cnn_inference": 1.5, "rank_server": 0.625}
    assert server_stage_times(both) == "; servers: completion server 1.75 (inference 1.50), ranking server 0.62"
    assert server_stage_times({"rank_server": 0.5}) == "; servers: ranking server 0.50"  # a method without CNN
