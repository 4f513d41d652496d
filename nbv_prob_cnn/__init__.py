"""nbv_prob_cnn: next best view planning for depth cameras with a completion CNN and
probabilistic ray casting (Monica & Aleotti). The core library imports no ROS; the rclpy
nodes live in :mod:`nbv_prob_cnn.ros`.

The sub-packages follow the pipeline:

* :mod:`~nbv_prob_cnn.basics`: grids, geometry, camera/sensor model, data sets, OpenCL device;
* :mod:`~nbv_prob_cnn.worlds`: ground-truth scenes (2D city, 3D unstructured, 3D tabletop);
* :mod:`~nbv_prob_cnn.sensing`: simulated observation of a ground truth (ideal and noisy);
* :mod:`~nbv_prob_cnn.perception`: depth images to a ternary grid (fusion, bags, messages);
* :mod:`~nbv_prob_cnn.completion`: the completion CNN (occupancy probabilities of unknown cells);
* :mod:`~nbv_prob_cnn.gain`: probabilistic ray casting and view gains;
* :mod:`~nbv_prob_cnn.planners`: the nine next-best-view methods and pose scoring;
* :mod:`~nbv_prob_cnn.arm`: the manipulator in the loop (IK, collisions, feasibility);
* :mod:`~nbv_prob_cnn.exploration`: the exploration loop and the method comparison;
* :mod:`~nbv_prob_cnn.viz`, :mod:`~nbv_prob_cnn.bench`, :mod:`~nbv_prob_cnn.commands`: pictures,
  benchmarks and the ``nbv`` command line; :mod:`~nbv_prob_cnn.ros`: the ROS 2 nodes.

The most used names are importable from the package itself (loaded on first use, so
``import nbv_prob_cnn`` stays light), e.g. ``from nbv_prob_cnn import best_origin_view``.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> the module that defines it
_PUBLIC: dict[str, str] = {
    **dict.fromkeys(
        ("UNKNOWN", "EMPTY", "OCCUPIED", "check_state", "frontier_mask", "unknown_fraction",
         "probability_with_constant", "probability_from_truth"),
        "nbv_prob_cnn.basics.grid",
    ),
    "GridGeometry": "nbv_prob_cnn.basics.geometry",
    **dict.fromkeys(("ViewPose", "view_pose"), "nbv_prob_cnn.basics.view_pose"),
    **dict.fromkeys(("orientations", "in_frustum", "dataset_defaults"), "nbv_prob_cnn.basics.camera"),
    **dict.fromkeys(("DATASET_SPECS", "DatasetSpec", "dataset_spec"), "nbv_prob_cnn.basics.datasets"),
    "Sensor": "nbv_prob_cnn.basics.sensor",
    **dict.fromkeys(("observe", "traverse"), "nbv_prob_cnn.sensing.observe"),
    **dict.fromkeys(("SensorNoise", "sensor_noise"), "nbv_prob_cnn.sensing.sensor_noise"),
    **dict.fromkeys(
        ("ray_directions", "ray_gains", "origin_view_gains", "view_gains", "view_membership", "empty_origins",
         "best_origin_view", "BestOriginView", "GainSettings"),
        "nbv_prob_cnn.gain",
    ),
    **dict.fromkeys(("complete", "load_model"), "nbv_prob_cnn.completion"),
    **dict.fromkeys(("PlanningContext", "ViewChoice", "make_planner", "METHODS"), "nbv_prob_cnn.planners"),
    **dict.fromkeys(("score_poses", "PoseScores"), "nbv_prob_cnn.planners.pose_scoring"),
    **dict.fromkeys(("explore", "ExplorationResult"), "nbv_prob_cnn.exploration.explore"),
    **dict.fromkeys(("World", "load_or_generate", "generate_world"), "nbv_prob_cnn.worlds"),
}  # fmt: skip

__all__ = ["__version__", *sorted(_PUBLIC)]


def __getattr__(name: str) -> Any:
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'nbv_prob_cnn' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
