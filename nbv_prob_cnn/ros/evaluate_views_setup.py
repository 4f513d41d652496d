"""How ``gain_server`` scores poses (``/nbv/evaluate_views``) with its default parameters, for callers
outside the node that must score alike (``nbv gain-study``). Not a node."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nbv_prob_cnn.basics.camera import dataset_defaults
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.exploration.gain_study import ContextFactory
from nbv_prob_cnn.exploration.scoring_variants import ScoringVariant
from nbv_prob_cnn.perception.depth_camera import Intrinsics
from nbv_prob_cnn.planners.base import PlanningContext
from nbv_prob_cnn.ros.camera_sensor import node_planning_context, planning_frustum
from nbv_prob_cnn.ros.gain_server import GainServerConfig


def service_variant(config: GainServerConfig) -> ScoringVariant:
    """The scoring settings of a ``gain_server`` configuration (``n_rays`` 0 read as the data set's)."""
    return ScoringVariant(
        n_rays=config.n_rays or dataset_defaults(config.dataset).n_rays,
        sensor=config.sensor_model,
        sampling=config.evaluate_sampling,
        rays_across=config.evaluate_rays_across,
        max_range_m=config.max_range_m,
    )


def service_scoring(dataset: str = "") -> tuple[ScoringVariant, ContextFactory]:
    """``gain_server``'s default scoring (its data set, or ``dataset``) and a factory of the planning
    context it would score a request with: the grid's geometry, the camera's CameraInfo (its fields
    of view) and a variant's settings in place of the defaults.

    Raises:
        ValueError: an unknown data set.
    """
    config = GainServerConfig()
    if dataset:
        dataset_defaults(dataset)  # names the known ones
        config = replace(config, dataset=dataset)

    def context_for(geometry: GridGeometry, intrinsics: Intrinsics, variant: ScoringVariant) -> PlanningContext:
        cfg = replace(config, n_rays=variant.n_rays, sensor_model=variant.sensor, max_range_m=variant.max_range_m,
                      evaluate_sampling=variant.sampling, evaluate_rays_across=variant.rays_across)  # fmt: skip
        camera_fov = intrinsics.fov_deg if cfg.sensor_from_camera_info else None
        context = node_planning_context(cfg, geometry, planning_frustum(cfg, camera_fov), np.random.default_rng(0))
        cfg.apply_pose_scoring(context)
        return context

    return service_variant(config), context_for
