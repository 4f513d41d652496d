"""Parameters come from one config dataclass per node (``declare_config``): values are validated
in the on-set callback (with a reason) and applied in the post-set callback."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.exceptions import ParameterException  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from nbv_prob_cnn.ros.parameters import declare_config, param, positive_seconds  # noqa: E402


def _odd(value: int) -> None:
    if value % 2 == 0:
        raise ValueError(f"odd: expected an odd number, got {value}")


@dataclass
class ExampleConfig:
    mode: str = param("fast", "how to run", choices=("fast", "exact"))
    odd: int = param(3, "an odd number", min_value=1, max_value=99, dynamic=True, check=_odd)
    timeout_s: float = param(1.0, "a timeout", dynamic=True, check=positive_seconds, attribute="timeout")
    origin: list = param([0.0, 0.5, 1.0], "a point")


@pytest.fixture
def context():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=110)
    yield context
    rclpy.shutdown(context=context)


def test_declare_config_validates_on_set_and_applies_after(context):
    node = rclpy.create_node("params_test", context=context)
    config = declare_config(node, ExampleConfig)
    assert config == ExampleConfig() and node.mode == "fast" and node.timeout == 1.0
    assert config.origin == [0.0, 0.5, 1.0]
    desc = node.describe_parameter("mode")
    assert desc.read_only and "one of ['fast', 'exact']" in desc.description

    results = node.set_parameters([Parameter("odd", value=4)])
    assert not results[0].successful and "expected an odd number" in results[0].reason
    assert config.odd == 3 and node.odd == 3  # refused: nothing applied
    results = node.set_parameters([Parameter("odd", value=101)])
    assert not results[0].successful  # out of the declared range (rclpy)
    results = node.set_parameters([Parameter("mode", value="exact")])
    assert not results[0].successful  # read-only
    assert node.set_parameters([Parameter("odd", value=7), Parameter("timeout_s", value=2.5)])[0].successful
    assert (config.odd, node.odd, config.timeout_s, node.timeout) == (7, 7, 2.5, 2.5)
    node.destroy_node()


def test_bad_start_up_values_are_refused_with_the_parameter_named(context):
    overrides = [Parameter("mode", value="slow")]
    node = rclpy.create_node("params_bad", context=context, parameter_overrides=overrides)
    with pytest.raises(ValueError, match="mode: expected one of"):
        declare_config(node, ExampleConfig)
    node.destroy_node()
    node = rclpy.create_node("params_range", context=context, parameter_overrides=[Parameter("odd", value=200)])
    with pytest.raises(ParameterException):
        declare_config(node, ExampleConfig)
    node.destroy_node()
