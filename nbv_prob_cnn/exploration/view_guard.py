"""Never repeat a view for nothing: poses whose view changed (almost) no cell are ruled out.

A gain model can keep crediting a view that the sensor cannot improve: the grid does not change,
so neither does the view's gain, and a plain loop takes the same pose again and again
(the rounded ray samples of docs/method.md#probabilistic-ray-casting-gain slip between diagonal
occupied cells; a noisy sensor cannot measure cells
inside its minimum range, at grazing incidence or without a return). The guard keeps a tabu
list of the (cell, orientation) pairs whose view changed fewer than ``min_changed_cells`` cells,
and the planner's ranking leaves them out: through the planner's ``view_mask`` where it takes
one and ranks in this process (gain-based methods, the same exact search with the ruled-out
pairs at zero gain), else by ranking ``len(ruled_out)`` more views and dropping the ruled-out
ones (City-CNNs, ``random``, a remote ranker). The exploration stops, with a reason, when no
view with positive gain is left outside the list.

The paper's protocol (docs/method.md#exploration-protocol-and-metrics) is the plain loop: ``nbv evaluate``
runs it unless ``--guard``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nbv_prob_cnn.planners import Planner, PlanningContext, ViewChoice

#: Default threshold as a fraction of the grid's cells (3DT: 79 cells of 1.57 M; 3DU: 14; 2D
#: 400x400: 8). A repeated exact view changes 0 cells, a repeated noisy 3DT view 0-30.
DEFAULT_MIN_CHANGED_FRACTION = 5e-5

#: A view's identity: (cell index, orientation index).
ViewKey = tuple[tuple[int, ...], int]


def default_min_changed_cells(shape: tuple[int, ...]) -> int:
    """The default threshold of a grid: :data:`DEFAULT_MIN_CHANGED_FRACTION` of its cells, at least 1."""
    return max(1, math.ceil(DEFAULT_MIN_CHANGED_FRACTION * int(np.prod(shape))))


def view_key(choice: ViewChoice) -> ViewKey:
    return tuple(int(c) for c in np.asarray(choice.cell).reshape(-1)), int(choice.view_index)


@dataclass
class ViewGuard:
    """The tabu list of one exploration.

    Attributes:
        min_changed_cells: a view that changed fewer cells than this rules its pose out (>= 1).
        ruled_out: the (cell, orientation) pairs ruled out so far.
    """

    min_changed_cells: int
    ruled_out: set[ViewKey] = field(default_factory=set)

    def __post_init__(self) -> None:
        if isinstance(self.min_changed_cells, bool) or not isinstance(self.min_changed_cells, (int, np.integer)):
            raise ValueError(f"min_changed_cells: expected an integer >= 1, got {self.min_changed_cells!r}")
        if self.min_changed_cells < 1:
            raise ValueError(f"min_changed_cells: expected an integer >= 1, got {self.min_changed_cells}")

    @classmethod
    def for_grid(cls, shape: tuple[int, ...], min_changed_cells: int | None = None) -> ViewGuard:
        """A guard with ``min_changed_cells`` (default: :func:`default_min_changed_cells` of ``shape``)."""
        return cls(default_min_changed_cells(shape) if min_changed_cells is None else min_changed_cells)

    def record(self, choice: ViewChoice, changed_cells: int) -> bool:
        """Rule ``choice``'s pose out if its view changed fewer than ``min_changed_cells`` cells;
        returns whether it did."""
        if changed_cells < self.min_changed_cells:
            self.ruled_out.add(view_key(choice))
            return True
        return False

    def allowed_views(self, origins: np.ndarray, n_views: int) -> np.ndarray:
        """``(N, n_views)`` bool: False for the ruled-out (origin, orientation) pairs."""
        allowed = np.ones((origins.shape[0], n_views), dtype=bool)
        for cell, view in self.ruled_out:
            allowed[np.all(origins == np.asarray(cell), axis=1), view] = False
        return allowed

    def rank(self, planner: Planner, state: np.ndarray, context: PlanningContext, top_k: int = 1) -> list[ViewChoice]:
        """The planner's ``top_k`` best views that are not ruled out, best first."""
        if not self.ruled_out:
            return planner.rank(state, context, top_k)
        from nbv_prob_cnn.arm.feasibility import takes_view_mask

        if takes_view_mask(planner) and context.ranker is None:
            n_views = context.orientations.shape[0]
            return planner.rank(state, context, top_k, None, view_mask=lambda o: self.allowed_views(o, n_views))  # type: ignore[call-arg]
        found = planner.rank(state, context, top_k + len(self.ruled_out))
        return [c for c in found if view_key(c) not in self.ruled_out][:top_k]

    def plan(self, planner: Planner, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        """The best view that is not ruled out, or None when none has positive gain."""
        found = self.rank(planner, state, context)
        return found[0] if found else None
