"""The one method registry (docs/method.md#methods): every next-best-view method by name, read by ``nbv explore``,
``nbv evaluate``, the gain server and the planner node.

Adding a method = one module with a planner class (see :class:`~nbv_prob_cnn.planners.base.RankingPlanner`)
plus one :class:`MethodSpec` line in :data:`METHODS`. Over ROS it then works unchanged: the
planner node's ranking hook sends the method name to ``/nbv/rank_views``, where the gain
server runs the same planner.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from nbv_prob_cnn.planners.base import Planner
from nbv_prob_cnn.planners.classic import RandomPlanner
from nbv_prob_cnn.planners.methods import GAIN_METHODS, GainPlanner


@dataclass(frozen=True)
class MethodSpec:
    """One selectable method.

    Attributes:
        name: the name users type (``--method``, ``method`` fields of the services).
        factory: builds a fresh planner.
        needs_ground_truth: an oracle (refused by the ROS nodes, which have no ground truth).
        weights: name of the trained model it loads, ``<dataset>_<weights>.pt`` in
            ``nbv_prob_cnn/weights/`` (None: no network).
        summary: one line for help texts and the README table.
    """

    name: str
    factory: Callable[[], Planner]
    needs_ground_truth: bool = False
    weights: str | None = None
    summary: str = ""


def _gain(name: str) -> Callable[[], Planner]:
    return lambda: GainPlanner(GAIN_METHODS[name])


def _volumetric(name: str) -> Callable[[], Planner]:
    def build() -> Planner:
        from nbv_prob_cnn.planners.volumetric import VolumetricPlanner

        return VolumetricPlanner(name)

    return build


def _city(name: str) -> Callable[[], Planner]:
    def build() -> Planner:
        from nbv_prob_cnn.planners.city_cnn import CityCnnPlanner

        return CityCnnPlanner(name)

    return build


#: The nine methods of the paper's comparison (``nbv evaluate``'s default: the reproduction's tables).
PAPER_METHODS = ("random", "ig", "prob_ig", "cnn_prob", "cnn_prob_d", "omniscient", "flat_city_cnn", "b_city_cnn",
                 "d_city_cnn")  # fmt: skip

#: The method every entry point uses when none is named: ``nbv plan``, ``nbv view``, the planner and gain
#: nodes (so the Explore action), ``explore_sim.py``, ``plan_from_bag.py`` and the main job. The surface gain
#: (issue 45, docs/evaluation.md#re-ranking-the-best-views-by-their-image-rays): it finishes surfaces in fewer
#: views than the paper's method at a planning time within 1.2 times its own (docs/performance.md).
DEFAULT_METHOD = "cnn_surface"

METHODS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in (
        MethodSpec("random", RandomPlanner, summary="a random orientation at a random empty cell"),
        MethodSpec("ig", _gain("ig"), summary="non-probabilistic information gain"),
        MethodSpec("prob_ig", _gain("prob_ig"), summary="probabilistic gain with constant P0"),
        MethodSpec("cnn_prob", _gain("cnn_prob"), weights="cnn_prob", summary="completion CNN + probabilistic gain"),
        MethodSpec("cnn_prob_d", _gain("cnn_prob_d"), weights="cnn_prob", summary="cnn_prob on random origins"),
        MethodSpec("omniscient", _gain("omniscient"), needs_ground_truth=True, summary="gain on the ground truth"),
        MethodSpec("flat_city_cnn", _city("flat_city_cnn"), weights="flat_city_cnn", summary="CNN: gain per view"),
        MethodSpec("b_city_cnn", _city("b_city_cnn"), weights="b_city_cnn", summary="CNN: best view per cell"),
        MethodSpec("d_city_cnn", _city("d_city_cnn"), weights="d_city_cnn", summary="CNN: gain per ray"),
        MethodSpec("cnn_surface", _gain("cnn_surface"), weights="cnn_prob", summary="completion CNN + surface gain"),
        MethodSpec("prob_surface", _gain("prob_surface"), summary="surface gain with constant P0"),
        MethodSpec(
            "omniscient_surface",
            _gain("omniscient_surface"),
            needs_ground_truth=True,
            summary="surface gain on the ground truth",
        ),  # fmt: skip
        MethodSpec("occlusion_aware", _volumetric("occlusion_aware"), summary="Isler: visible entropy"),
        MethodSpec("unobserved_voxel", _volumetric("unobserved_voxel"), summary="Isler: visible unknown entropy"),
        MethodSpec("rear_side_voxel", _volumetric("rear_side_voxel"), summary="Isler: rays hitting a rear side"),
        MethodSpec("proximity_count", _volumetric("proximity_count"), summary="Isler: unknown cells near surface"),
        MethodSpec("average_entropy", _volumetric("average_entropy"), summary="Kriegel: mean entropy of hitting rays"),
    )
}


def method_spec(name: str) -> MethodSpec:
    """The registry entry called ``name``.

    Raises:
        ValueError: unknown method name (the message lists the known ones).
    """
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"method: unknown method {name!r}; expected one of {sorted(METHODS)}") from None


def make_planner(name: str) -> Planner:
    """A fresh planner of the method called ``name`` (raises ValueError for unknown names)."""
    return method_spec(name).factory()


def ros_method(name: str, default: str) -> MethodSpec:
    """The method a ROS request names (``""`` = ``default``); oracles are refused (no ground
    truth on the robot). ``"prob"`` is an alias of ``cnn_prob`` (the map sent with the request).

    Raises:
        ValueError: unknown method or one that needs the ground truth.
    """
    name = name or default
    name = "cnn_prob" if name == "prob" else name
    spec = METHODS.get(name)
    if spec is None or spec.needs_ground_truth:
        raise ValueError(f"unknown method {name!r}; expected one of {ros_method_names()}")
    return spec


def ros_method_names() -> list[str]:
    """The methods the ROS nodes serve, sorted: every one of :data:`METHODS` but the oracles
    (the launch scripts' ``--method`` choices)."""
    return sorted(name for name, spec in METHODS.items() if not spec.needs_ground_truth)


def check_ros_method(name: str) -> None:
    """A parameter check: ``name`` is a method the ROS nodes serve (raises ValueError otherwise)."""
    ros_method(name, name)
