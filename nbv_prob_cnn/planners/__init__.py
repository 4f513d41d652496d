"""Next-best-view methods behind one interface, selectable by name (docs/method.md#methods); the registry is
:mod:`nbv_prob_cnn.planners.registry`."""

from __future__ import annotations

from collections.abc import Callable

from nbv_prob_cnn.planners.base import (
    Planner,
    PlanningContext,
    RankingPlanner,
    ViewChoice,
    search_best_view,
    search_views,
)
from nbv_prob_cnn.planners.methods import GAIN_METHODS, GainMethod, GainPlanner
from nbv_prob_cnn.planners.registry import (
    METHODS,
    MethodSpec,
    check_ros_method,
    make_planner,
    method_spec,
    ros_method,
)

#: name -> factory, derived from :data:`METHODS` (kept for existing callers).
PLANNER_FACTORIES: dict[str, Callable[[], Planner]] = {name: spec.factory for name, spec in METHODS.items()}

__all__ = [
    "GAIN_METHODS",
    "METHODS",
    "PLANNER_FACTORIES",
    "GainMethod",
    "GainPlanner",
    "MethodSpec",
    "Planner",
    "PlanningContext",
    "RankingPlanner",
    "ViewChoice",
    "check_ros_method",
    "make_planner",
    "method_spec",
    "ros_method",
    "search_best_view",
    "search_views",
]
