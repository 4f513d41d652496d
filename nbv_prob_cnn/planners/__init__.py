"""Next-best-view methods behind one interface, selectable by name (SPEC §6)."""

from __future__ import annotations

from collections.abc import Callable

from nbv_prob_cnn.planners.base import Planner, PlanningContext, ViewChoice, search_best_view, search_views
from nbv_prob_cnn.planners.classic import RandomPlanner
from nbv_prob_cnn.planners.methods import GAIN_METHODS, GainMethod, GainPlanner

#: name -> factory. The City-CNN methods register here too.
PLANNER_FACTORIES: dict[str, Callable[[], Planner]] = {"random": RandomPlanner}
PLANNER_FACTORIES.update({name: (lambda m=method: GainPlanner(m)) for name, method in GAIN_METHODS.items()})


def make_planner(name: str) -> Planner:
    """The planner called ``name``.

    Raises:
        ValueError: unknown method name (the message lists the known ones).
    """
    try:
        factory = PLANNER_FACTORIES[name]
    except KeyError:
        raise ValueError(f"method: unknown method {name!r}; expected one of {sorted(PLANNER_FACTORIES)}") from None
    return factory()


__all__ = [
    "GAIN_METHODS",
    "PLANNER_FACTORIES",
    "GainMethod",
    "GainPlanner",
    "Planner",
    "PlanningContext",
    "ViewChoice",
    "make_planner",
    "search_best_view",
    "search_views",
]
