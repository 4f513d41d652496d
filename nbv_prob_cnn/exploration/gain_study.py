"""Does the predicted gain rank what a real camera then sees? (``nbv gain-study``,
docs/evaluation.md#does-the-gain-predict-what-a-real-camera-sees)

A recording (posed depth frames in a bag) is fused in order. At ``K`` anchor frames the grid fused so
far is taken; each of the next ``M`` recorded camera poses is then

* **predicted**: scored by each method and scoring variant, as ``/nbv/evaluate_views`` scores a pose
  (the probability map of the method on the anchor grid, then
  :func:`~nbv_prob_cnn.planners.pose_scoring.score_poses` with the service's planning context;
  ``context_for`` builds it), and
* **realized**: the number of cells unknown at the anchor that the pose's own frame observes, fused
  alone with the same settings on the same box (:mod:`~nbv_prob_cnn.perception.realized_gain`), and
  the **realized surface**: those of them the frame sees occupied (the new surface it gave).

The camera was at each recorded pose, so its cell is free even where the anchor grid has not seen
it: poses in unknown cells are scored (``score_unknown_cells``), and their count is kept.

A baseline that knows nothing of the grid is scored beside the methods: :data:`BASELINE`, the number
of frames since the anchor. A hand-held camera that moves on reveals more the farther it has gone,
so a gain is worth something only where it ranks better than that.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.camera import in_frustum, quaternion_from_matrix
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import UNKNOWN
from nbv_prob_cnn.exploration.scoring_variants import ScoringVariant
from nbv_prob_cnn.gain.frustum_rays import frustum_rays
from nbv_prob_cnn.perception.bags import read_frames
from nbv_prob_cnn.perception.depth_camera import Intrinsics
from nbv_prob_cnn.perception.realized_gain import (
    Fusion,
    SingleFrameObserver,
    realized_gain,
    realized_surface,
    recording_box,
)
from nbv_prob_cnn.planners.base import PlanningContext
from nbv_prob_cnn.planners.methods import GainMethod, probability_map
from nbv_prob_cnn.planners.pose_scoring import IN_UNKNOWN_CELL, VALID, classify_poses, score_poses

#: The baseline's method and variant names: a pose predicted by its frames since the anchor.
BASELINE = ("frames since anchor", "baseline")
#: ``context_for(geometry, intrinsics, variant)``: the planning context the scoring service would use
#: for a grid of ``geometry``, a camera of ``intrinsics`` and the variant's settings.
ContextFactory = Callable[[GridGeometry, Intrinsics, ScoringVariant], PlanningContext]


@dataclass(frozen=True)
class PoseRow:
    """One pose scored at one anchor by one method and variant."""

    anchor: int  # frame index of the anchor (0-based, bag order)
    frame: int  # frame index of the pose
    method: str
    variant: str
    predicted: float
    realized: int
    in_unknown_cell: bool  # the camera's cell was unknown at the anchor (scored all the same)
    rays_in_frustum: int
    realized_surface: int = 0  # of the realized cells, those the frame saw occupied


@dataclass
class GainStudy:
    """What a study found: every pose row, the anchors, the box and the anchors' unknown shares."""

    geometry: GridGeometry
    anchors: list[int]
    rows: list[PoseRow] = field(default_factory=list)
    unknown_share: dict[int, float] = field(default_factory=dict)
    frames: int = 0


def anchor_frames(n_frames: int, n_anchors: int, next_poses: int) -> list[int]:
    """``n_anchors`` anchor frames spread evenly over the frames that have ``next_poses`` frames after
    them (the first is frame 0, the last ``n_frames - 1 - next_poses``).

    Raises:
        ValueError: fewer than 1 anchor or next pose, or too few frames (the message names the numbers).
    """
    if n_anchors < 1 or next_poses < 1:
        raise ValueError(f"anchors and next poses: expected at least 1 each, got {n_anchors} and {next_poses}")
    last = n_frames - 1 - next_poses
    if last < n_anchors - 1:
        raise ValueError(
            f"anchors: {n_frames} frames hold at most {max(0, last + 1)} anchors with {next_poses} next poses "
            f"each, {n_anchors} asked"
        )
    return sorted({int(round(a)) for a in np.linspace(0, last, n_anchors)})


def rays_in_frustum(context: PlanningContext, quats: np.ndarray, rays_across: int) -> np.ndarray:
    """Per pose, how many rays its score sums: the view search's rays inside its frustum, or all
    ``rays_across`` rays of its own image."""
    sensor = context.active_sensor
    if rays_across:
        n = frustum_rays(context.defaults.dims, rays_across, sensor.hfov_deg, sensor.vfov_deg)[0].shape[0]
        return np.full(quats.shape[0], n, dtype=np.int64)
    return in_frustum(context.directions, quats, sensor.hfov_deg, sensor.vfov_deg).sum(axis=0).astype(np.int64)


def predict(
    state: np.ndarray,
    geometry: GridGeometry,
    poses: np.ndarray,
    intrinsics: Intrinsics,
    methods: Sequence[GainMethod],
    variants: Sequence[ScoringVariant],
    context_for: ContextFactory,
) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]:
    """Per (method, variant label): the predicted gains of ``poses`` (``(P, 4, 4)`` world-from-optical)
    and the rays each sums. Each method's probability map is made once (with the first variant's
    context: the map does not depend on the scoring settings)."""
    positions = poses[:, :3, 3]
    quats = np.array([quaternion_from_matrix(p[:3, :3]) for p in poses])
    contexts = [context_for(geometry, intrinsics, v) for v in variants]
    found = {}
    for method in methods:
        prob = probability_map(method, state, contexts[0])
        for variant, context in zip(variants, contexts, strict=True):
            scores = score_poses(state, prob, geometry, positions, quats, context, method.mode,
                                 score_unknown_cells=True, rays_across=variant.rays_across,
                                 surface=method.surface)  # fmt: skip
            if np.any(scores.validity != VALID):
                bad = int(np.flatnonzero(scores.validity != VALID)[0])
                raise ValueError(f"pose {bad}: cannot be scored: {scores.reasons[bad]}")
            found[(method.name, variant.label)] = (scores.gains, rays_in_frustum(context, quats, variant.rays_across))
    return found


def run_gain_study(
    bag: str | Path,
    fusion: Fusion,
    methods: Sequence[GainMethod],
    variants: Sequence[ScoringVariant],
    context_for: ContextFactory,
    n_anchors: int,
    next_poses: int,
    progress: bool = False,
) -> GainStudy:
    """Run the study on a bag (module docstring). Two passes over the bag: the first finds the box
    (:func:`~nbv_prob_cnn.perception.realized_gain.recording_box`) and the poses, the second fuses,
    predicts at each anchor and counts what each next frame reveals.

    Raises:
        ValueError: an unreadable bag, too few frames for the anchors, a pose the service cannot score.
    """
    from tqdm import tqdm

    poses: list[np.ndarray] = []
    intrinsics: list[Intrinsics] = []

    def remember(frames):
        for frame in frames:
            poses.append(frame.pose_4x4)
            intrinsics.append(frame.intrinsics)
            yield frame

    frames = tqdm(read_frames(bag), desc="box", unit="frame", disable=not progress)
    geometry = recording_box(remember(frames), fusion)
    anchors = anchor_frames(len(poses), n_anchors, next_poses)
    study = GainStudy(geometry, anchors, frames=len(poses))
    grid, observer = fusion.integrator(geometry), SingleFrameObserver(geometry, fusion)
    pending: dict[int, tuple[np.ndarray, dict]] = {}  # anchor -> (its grid, predictions)
    last = anchors[-1] + next_poses
    bar = tqdm(read_frames(bag, validate=False), desc="study", unit="frame", total=last + 1, disable=not progress)
    for index, frame in enumerate(bar):
        if index > last:
            break
        fusion.fuse(grid, frame)
        waiting = [a for a in pending if a < index <= a + next_poses]
        if waiting:
            labels = observer.labels(frame)
            observed = labels != UNKNOWN
            for anchor in waiting:
                state, predictions = pending[anchor]
                gained = (realized_gain(state, observed), realized_surface(state, labels))
                study.rows += _rows(anchor, index, gained, predictions, index - anchor - 1)
        for anchor in [a for a in pending if a + next_poses <= index]:
            del pending[anchor]
        if index in anchors:
            state = grid.ternary()
            study.unknown_share[index] = float(np.mean(state == UNKNOWN))
            nxt = np.array(poses[index + 1 : index + 1 + next_poses])
            predictions = predict(state, geometry, nxt, intrinsics[index], methods, variants, context_for)
            in_unknown = classify_poses(state, geometry, nxt[:, :3, 3], np.tile([0, 0, 0, 1.0], (len(nxt), 1)))[0]
            pending[index] = (state, {"scores": predictions, "in_unknown": in_unknown == IN_UNKNOWN_CELL})
            bar.set_postfix(anchor=index, unknown=f"{study.unknown_share[index]:.0%}")
    return study


def _rows(anchor: int, frame: int, gained: tuple[int, int], predictions: dict, k: int) -> list[PoseRow]:
    """The rows of the ``k``-th next pose of an anchor (``gained``: its realized cells and surface),
    the baseline's last."""
    in_unknown = bool(predictions["in_unknown"][k])
    cells, surface = gained
    return [
        PoseRow(anchor, frame, method, variant, float(gains[k]), cells, in_unknown, int(rays[k]), surface)
        for (method, variant), (gains, rays) in predictions["scores"].items()
    ] + [PoseRow(anchor, frame, *BASELINE, float(k + 1), cells, in_unknown, 0, surface)]
