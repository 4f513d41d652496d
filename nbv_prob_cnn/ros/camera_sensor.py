"""The planning frustum of the real depth camera: its fields of view from the ``CameraInfo`` it
publishes (``K``, width, height; :attr:`~nbv_prob_cnn.perception.Intrinsics.fov_deg`), the
range from parameters. Not a node: ``gain_server`` and ``nbv_planner`` each own one.

Precedence, per quantity: a request's own field (``EvaluateViews`` ``hfov_deg``, ...), then the
node parameter (``hfov_deg``, ``vfov_deg``, ``min_range_m``, ``max_range_m``; 0 = not set), then
the latest ``CameraInfo`` on ``camera_info_topic`` (fields of view only, with
``sensor_from_camera_info``), then the data set's sensor (docs/method.md#sensor-and-simulated-observation).
What is used is logged at
start-up and again when the first (or a changed) ``CameraInfo`` arrives.

The gain's sensor model (``sensor_model``: ``paper``, or ``returns`` with the measuring ranges
``measure_min_range_m`` .. ``measure_max_range_m``, ``measure_grazing_deg`` and ``measure_walls``;
docs/sensing.md) comes from parameters: ``CameraInfo`` carries no ranges.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo

from nbv_prob_cnn.basics.camera import dataset_defaults
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.gain.sampling import SENSOR_MODELS, GainSensor
from nbv_prob_cnn.perception.messages import camera_info_to_intrinsics
from nbv_prob_cnn.planners.base import PlanningContext
from nbv_prob_cnn.planners.requests import planning_context
from nbv_prob_cnn.ros import names
from nbv_prob_cnn.ros.parameters import param

#: Best effort matches both best-effort (SENSOR_DATA) and reliable camera_info publishers.
CAMERA_INFO_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


@dataclass
class SensorParams:
    """Parameters of the planning frustum (a mixin of the planning nodes' configs)."""

    sensor_from_camera_info: bool = param(
        True, "planning fields of view from the depth camera's CameraInfo on camera_info_topic (until one "
        "arrives, and with false: the data set's sensor)",
    )  # fmt: skip
    camera_info_topic: str = param(names.CAMERA_INFO, "the depth camera's CameraInfo (K, width, height)")
    hfov_deg: float = param(0.0, "planning horizontal field of view [deg]; 0 = from CameraInfo / data set",
                            min_value=0.0, max_value=179.0)  # fmt: skip
    vfov_deg: float = param(0.0, "planning vertical field of view [deg]; 0 = from CameraInfo / data set",
                            min_value=0.0, max_value=179.0)  # fmt: skip
    min_range_m: float = param(0.0, "planning minimum range [m]; 0 = the data set's", min_value=0.0,
                               max_value=100.0)  # fmt: skip
    max_range_m: float = param(0.0, "planning maximum range [m]; 0 = the data set's", min_value=0.0,
                               max_value=100.0)  # fmt: skip
    sensor_model: str = param("paper", "gain: 'paper', or 'returns': a cell counts by the probability that the "
                              "camera measures it (the measure_* parameters; docs/sensing.md)",
                              choices=SENSOR_MODELS)  # fmt: skip
    measure_min_range_m: float = param(0.5, "sensor_model returns: the camera's minimum measuring range [m]",
                                       min_value=0.0, max_value=100.0)  # fmt: skip
    measure_max_range_m: float = param(4.0, "sensor_model returns: the camera's maximum measuring range [m]",
                                       min_value=0.01, max_value=100.0)  # fmt: skip
    measure_grazing_deg: float = param(75.0, "sensor_model returns: no depth beyond this incidence [deg] (90 = "
                                       "any)", min_value=1.0, max_value=90.0)  # fmt: skip
    measure_walls: bool = param(True, "sensor_model returns: a ray leaving the grid meets a surface (a room); "
                                "false: it returns nothing")  # fmt: skip

    def apply_sensor_model(self, context, resolution_m: float) -> None:
        """Set ``context``'s gain sensor model from these parameters (grid of ``resolution_m``)."""
        if self.sensor_model == "paper":
            return
        context.gain_sensor = GainSensor(self.measure_min_range_m / resolution_m,
                                         self.measure_max_range_m / resolution_m, self.measure_grazing_deg,
                                         self.measure_walls)  # fmt: skip
        context.sensor_model = self.sensor_model


@dataclass(frozen=True)
class Frustum:
    """Sensor overrides for :func:`~nbv_prob_cnn.planners.requests.planning_context` (0 = the data set's)."""

    hfov_deg: float = 0.0
    vfov_deg: float = 0.0
    max_range_m: float = 0.0
    min_range_m: float = 0.0


class PlanningParams(Protocol):
    """What a planning node's config gives :func:`node_planning_context` (``gain_server``'s, ``nbv_planner``'s)."""

    @property
    def dataset(self) -> str: ...

    @property
    def backend(self) -> str: ...

    @property
    def n_rays(self) -> int: ...

    @property
    def gain_variant(self) -> str: ...

    @property
    def surface_blend(self) -> float: ...

    @property
    def image_rerank(self) -> int: ...

    def apply_sensor_model(self, context, resolution_m: float) -> None: ...


def node_planning_context(
    params: PlanningParams, geometry: GridGeometry, frustum: Frustum, rng: np.random.Generator
) -> PlanningContext:
    """The planning set-up of one request on ``geometry``: the node's data set, backend, rays, gain
    variant, surface blend, image re-ranking and sensor model, planned with ``frustum``.

    Raises:
        ValueError: the grid does not fit the data set, or bad frustum overrides.
    """
    context = planning_context(
        params.dataset, geometry, params.backend, params.n_rays, rng,
        frustum.hfov_deg, frustum.vfov_deg, frustum.max_range_m, frustum.min_range_m,
    )  # fmt: skip
    context.gain_variant = params.gain_variant
    context.surface_blend = float(params.surface_blend)
    context.image_rerank = int(params.image_rerank)
    params.apply_sensor_model(context, geometry.resolution)
    return context


def planning_frustum(
    params: SensorParams,
    camera_fov: tuple[float, float] | None,
    hfov_deg: float = 0.0,
    vfov_deg: float = 0.0,
    max_range_m: float = 0.0,
) -> Frustum:
    """The overrides to plan with (module docstring's precedence): a request's own (0 = not set), then
    the parameters, then the camera's fields of view ``camera_fov`` (None: no CameraInfo yet)."""
    fov = camera_fov or (0.0, 0.0)
    return Frustum(
        hfov_deg=hfov_deg or params.hfov_deg or fov[0],
        vfov_deg=vfov_deg or params.vfov_deg or fov[1],
        max_range_m=max_range_m or params.max_range_m,
        min_range_m=params.min_range_m,
    )


class CameraInfoSensor:
    """The frustum a node plans with: parameters, the latest CameraInfo, the data set."""

    def __init__(self, node: Node, params: SensorParams, dataset: str, callback_group=None) -> None:
        self._node = node
        self._params = params
        self._dataset = dataset
        self._lock = threading.Lock()
        self._fov: tuple[float, float] | None = None  # from the latest CameraInfo
        self._described = ""
        if params.sensor_from_camera_info:
            node.create_subscription(
                CameraInfo, params.camera_info_topic, self._on_camera_info, CAMERA_INFO_QOS,
                callback_group=callback_group,
            )  # fmt: skip
        node.get_logger().info(f"planning sensor: {self.describe()}")

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            intrinsics = camera_info_to_intrinsics(msg)
        except ValueError as exc:
            self._node.get_logger().warning(f"{self._params.camera_info_topic}: {exc}; ignored",
                                            throttle_duration_sec=10.0)  # fmt: skip
            return
        fov = intrinsics.fov_deg
        with self._lock:
            changed = self._fov is None or max(abs(a - b) for a, b in zip(fov, self._fov, strict=True)) > 1e-6
            self._fov = fov
        if changed:
            self._node.get_logger().info(
                f"planning sensor from CameraInfo {intrinsics.width}x{intrinsics.height} px, fx {intrinsics.fx:g} "
                f"fy {intrinsics.fy:g}: {self.describe()}"
            )

    def camera_fov(self) -> tuple[float, float] | None:
        """Fields of view [deg] of the latest CameraInfo (None before one arrived)."""
        with self._lock:
            return self._fov

    def frustum(self, hfov_deg: float = 0.0, vfov_deg: float = 0.0, max_range_m: float = 0.0) -> Frustum:
        """The overrides to plan with, given a request's own (0 = not set)."""
        return planning_frustum(self._params, self.camera_fov(), hfov_deg, vfov_deg, max_range_m)

    def describe(self) -> str:
        """What the frustum is now and where each part comes from."""
        p = self._params
        sensor = dataset_defaults(self._dataset).sensor
        fov = self.camera_fov()
        source = "parameter" if p.hfov_deg else ("CameraInfo" if fov else f"data set {self._dataset}")
        hfov = p.hfov_deg or (fov[0] if fov else sensor.hfov_deg)
        text = f"hfov {hfov:.1f} deg ({source})"
        if sensor.vfov_deg is not None:
            source = "parameter" if p.vfov_deg else ("CameraInfo" if fov else f"data set {self._dataset}")
            vfov = p.vfov_deg or (fov[1] if fov else sensor.vfov_deg)
            text += f", vfov {vfov:.1f} deg ({source})"
        resolution = dataset_defaults(self._dataset).resolution_m
        max_range = p.max_range_m or sensor.r_max * resolution
        min_range = p.min_range_m or sensor.min_range * resolution
        source = "parameters" if p.max_range_m or p.min_range_m else "data set"
        text += f", range {min_range:g}..{max_range:g} m ({source})"
        if p.sensor_from_camera_info and not fov:
            text += f"; fields of view from {self._node.resolve_topic_name(p.camera_info_topic)} once it arrives"
        return text
