"""Next-best-view methods behind one interface, selectable by name (SPEC §6)."""

from __future__ import annotations

from collections.abc import Callable

from nbv_prob_cnn.planners.base import Planner, PlanningContext, ViewChoice, search_best_view
from nbv_prob_cnn.planners.classic import (
    InformationGainPlanner,
    ProbabilisticPlanner,
    RandomPlanner,
    constant_probability,
    oracle_probability,
)

#: name -> factory; methods with a CNN register themselves in the same table.
PLANNER_FACTORIES: dict[str, Callable[[], Planner]] = {
    "random": RandomPlanner,
    "ig": InformationGainPlanner,
    "prob_ig": lambda: ProbabilisticPlanner("prob_ig", constant_probability),
    "omniscient": lambda: ProbabilisticPlanner("omniscient", oracle_probability),
}


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


__all__ = ["PLANNER_FACTORIES", "Planner", "PlanningContext", "ViewChoice", "make_planner", "search_best_view"]
