"""gain_server's and nbv_planner's gain sensor model comes from their parameters (SensorParams):
the measuring ranges in cells of the grid, the grazing limit and the walls (docs/sensing.md)."""

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from test_ros_planning import ros_fixture  # noqa: E402

from nbv_prob_cnn.planners import PlanningContext  # noqa: E402
from nbv_prob_cnn.ros.camera_sensor import SensorParams  # noqa: E402

ros = ros_fixture(105, 3)  # test_tf2_msgs's domains 105..107 (the suite runs one module at a time)


def test_parameters_set_the_returns_model_in_cells_of_the_grid():
    context = PlanningContext.for_dataset("3dt")
    SensorParams().apply_sensor_model(context, 0.0116)  # default: the paper's gain
    assert context.sensor_model == "paper" and context.returns_sensor is None
    params = SensorParams(sensor_model="returns", measure_min_range_m=0.58, measure_max_range_m=2.32,
                          measure_grazing_deg=70.0, measure_walls=False)  # fmt: skip
    params.apply_sensor_model(context, 0.0116)
    sensor = context.returns_sensor
    assert sensor is not None
    assert (sensor.min_range, sensor.max_range) == pytest.approx((50.0, 200.0))
    assert sensor.grazing_deg == 70.0 and not sensor.walls
    assert np.isclose(sensor.cos_grazing, np.cos(np.radians(70.0)))


def test_inverted_ranges_are_refused():
    context = PlanningContext.for_dataset("3dt")
    params = SensorParams(sensor_model="returns", measure_min_range_m=3.0, measure_max_range_m=1.0)
    with pytest.raises(ValueError, match="max_range"):
        params.apply_sensor_model(context, 0.0116)


@pytest.mark.slow  # a ROS graph
def test_gain_server_ranks_with_the_returns_model(ros):
    from nbv_prob_cnn_msgs.srv import RankViews
    from test_ros_planning import GEOMETRY, call, random_grid

    from nbv_prob_cnn.basics.camera import dataset_defaults
    from nbv_prob_cnn.gain.sampling import GainSensor
    from nbv_prob_cnn.planners import GainPlanner
    from nbv_prob_cnn.planners.methods import GAIN_METHODS
    from nbv_prob_cnn.ros.conversions import grid_to_msg

    node, graph, context = ros
    params = {"dataset": "3du", "backend": "opencl", "method": "prob_ig", "sensor_model": "returns",
              "measure_min_range_m": 0.05, "measure_max_range_m": 0.5, "measure_walls": False}  # fmt: skip
    graph.start_node("gain_server", "gain_server", params)
    state = random_grid(4)
    request = RankViews.Request(grid=grid_to_msg(state, GEOMETRY), method="prob_ig", top_k=5)
    reply = call(node, context, RankViews, "/nbv/rank_views", request)
    assert reply.success, reply.message
    sensor = GainSensor(0.05 / GEOMETRY.resolution, 0.5 / GEOMETRY.resolution, 75.0, walls=False)
    for model, gain_sensor in (("returns", sensor), ("paper", None)):
        core_context = PlanningContext(dataset_defaults("3du"), backend="opencl", sensor_model=model,
                                       gain_sensor=gain_sensor)  # fmt: skip
        core = GainPlanner(GAIN_METHODS["prob_ig"]).rank(state, core_context, 5)
        same = [v.gain for v in reply.ranked] == pytest.approx([c.gain for c in core], rel=1e-6)
        assert same == (model == "returns")  # the node's ranking is the returns model's, not the paper's
