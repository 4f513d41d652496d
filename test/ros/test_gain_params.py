"""The ray-casting parameters that ``gain_server`` and ``nbv_planner`` both declare
(nbv_prob_cnn/ros/gain_params.py): declared by both configs with the core's defaults, refused out of
range with the parameter named, and applied to the planning context of each request
(``node_planning_context``, which both nodes plan with)."""

from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from rclpy.exceptions import ParameterException  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.gain.settings import DEFAULT_SURFACE_BLEND  # noqa: E402
from nbv_prob_cnn.planners.base import DEFAULT_IMAGE_RERANK  # noqa: E402
from nbv_prob_cnn.ros.camera_sensor import Frustum, node_planning_context  # noqa: E402
from nbv_prob_cnn.ros.gain_params import MAX_IMAGE_RERANK  # noqa: E402
from nbv_prob_cnn.ros.gain_server import GainServerConfig  # noqa: E402
from nbv_prob_cnn.ros.nbv_planner import PlannerConfig  # noqa: E402
from nbv_prob_cnn.ros.parameters import declare_config  # noqa: E402

CONFIGS = [GainServerConfig, PlannerConfig]
GEOMETRY = GridGeometry((0.0, 0.0, 0.0), 0.01, (32, 32, 32))  # a 3D grid for the nodes' default data set, 3dt


@pytest.fixture
def context(ros_domain):
    env = ros_domain(175)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    yield context
    rclpy.shutdown(context=context)


def _planning(context, config_type, overrides: list[Parameter]):
    """The planning context of a request on a node of ``config_type`` started with ``overrides``."""
    node = rclpy.create_node("gain_params_test", context=context, parameter_overrides=overrides)
    try:
        config = declare_config(node, config_type, mirror=False)
        return node_planning_context(config, GEOMETRY, Frustum(), np.random.default_rng(0))
    finally:
        node.destroy_node()


@pytest.mark.parametrize("config_type", CONFIGS, ids=lambda c: c.__name__)
def test_surface_parameters_reach_the_planning_context(context, config_type):
    assert DEFAULT_IMAGE_RERANK not in (0, 7) and DEFAULT_SURFACE_BLEND != 0.25  # the overrides below are no defaults
    planning = _planning(context, config_type, [])
    assert (planning.surface_blend, planning.image_rerank) == (DEFAULT_SURFACE_BLEND, DEFAULT_IMAGE_RERANK)
    for blend, rerank in [(0.25, 7), (0.25, 0)]:
        overrides = [Parameter("surface_blend", value=blend), Parameter("image_rerank", value=rerank)]
        planning = _planning(context, config_type, overrides)
        assert (planning.surface_blend, planning.image_rerank) == (blend, rerank)

    node = rclpy.create_node("gain_params_describe", context=context)
    try:
        declare_config(node, config_type, mirror=False)
        desc = node.describe_parameter("image_rerank")
        assert desc.read_only and "re-rank" in desc.description
        assert [(r.from_value, r.to_value) for r in desc.integer_range] == [(0, MAX_IMAGE_RERANK)]
    finally:
        node.destroy_node()


@pytest.mark.parametrize("config_type", CONFIGS, ids=lambda c: c.__name__)
@pytest.mark.parametrize("bad", [-1, MAX_IMAGE_RERANK + 1, 2.5])
def test_a_bad_image_rerank_is_refused_with_the_parameter_named(context, config_type, bad):
    node = rclpy.create_node(
        "gain_params_bad", context=context, parameter_overrides=[Parameter("image_rerank", value=bad)]
    )
    try:
        with pytest.raises(ParameterException, match="image_rerank"):
            declare_config(node, config_type, mirror=False)
    finally:
        node.destroy_node()
