"""gain_server's and nbv_planner's gain sensor model comes from their parameters (SensorParams):
the measuring ranges in cells of the grid, the grazing limit and the walls (docs/sensing.md)."""

import numpy as np
import pytest

from nbv_prob_cnn.planners import PlanningContext
from nbv_prob_cnn.ros.camera_sensor import SensorParams


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
