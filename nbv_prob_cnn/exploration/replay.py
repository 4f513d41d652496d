"""Replay a stored run: take its recorded views again, without planning, to measure what its CSV
does not hold (the surface coverage of runs written before that column, the Chamfer distance).

A run CSV (:data:`~nbv_prob_cnn.exploration.explore.CSV_COLUMNS`) records each view's camera
position (the centre of its cell) and quaternion (a candidate orientation). :func:`replay_rows`
turns them back into the cell and the orientation index, observes the world from them as the run
did (the exact sensor: :func:`~nbv_prob_cnn.sensing.observe.observe` without noise is
deterministic) and checks, view by view, that the pose gives back the stored pose and that the
grid gives back the stored unknown fractions within :data:`TOLERANCE` (a run that does not replay
so, of a noisy sensor or on another world, is refused). Runs made today and the shipped 2D runs
replay to the CSV's six decimals; the shipped 3D runs of earlier versions to a few cells (3DU: at
most 5.0e-5 of the empty cells, 13 cells; 3DT: 6.0e-5, about 90 cells, in environment 129, at most
1.5e-5 in the others; the largest difference of each run is kept in its ``.json``,
:data:`DIFFERENCE_KEY`). The replayed CSV is the stored one, byte for byte per field, with the
``surface_coverage`` column set (appended when missing).
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.grid import unknown_fraction, unknown_fraction_all
from nbv_prob_cnn.exploration.mesh_chamfer import CHAMFER_KEY, ChamferResult, MeshReconstruction
from nbv_prob_cnn.exploration.surface_metrics import SurfaceCoverage
from nbv_prob_cnn.planners import PlanningContext
from nbv_prob_cnn.sensing.observe import observe
from nbv_prob_cnn.worlds.world import World

#: The column :func:`replay_rows` fills.
COVERAGE_COLUMN = "surface_coverage"
#: Key of a replayed run's ``.json`` that names the run it replayed.
REPLAY_KEY = "replayed_from"
#: Key of a replayed run's ``.json`` with the largest difference of an unknown fraction, replayed
#: against stored, over its views.
DIFFERENCE_KEY = "replay_max_difference"
#: The largest difference of an unknown fraction a replayed view may show: 1e-4 (157 cells of 3DT,
#: 26 of 3DU, 16 of 2D).
TOLERANCE = 1e-4


@dataclass
class ReplayedRun:
    """The stored run's header and rows with the surface coverage filled in, and the Chamfer
    distance after its last view (None unless asked)."""

    header: list[str]
    rows: list[list[str]]
    chamfer: ChamferResult | None
    max_difference: float = 0.0

    def csv_text(self) -> str:
        text = io.StringIO()
        writer = csv.writer(text)
        writer.writerow(self.header)
        writer.writerows(self.rows)
        return text.getvalue()


def read_rows(path: str | Path, views: int | None = None) -> tuple[list[str], list[list[str]]]:
    """The header and the first ``views`` rows (all without it) of a run CSV, as strings."""
    with open(path, newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader)
        rows = list(itertools.islice(reader, views))
    return header, rows


#: The pose columns of a run CSV (older ones name the position ``x, y, z``, metres too).
POSE_COLUMNS = ("x_m", "y_m", "z_m", "qx", "qy", "qz", "qw")
OLD_POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")


def view_of_row(pose: list[str], world: World, context: PlanningContext) -> tuple[np.ndarray, int]:
    """The cell and the candidate-orientation index of a recorded pose ``[x, y, z, qx, qy, qz,
    qw]`` (the cell whose centre it is, the candidate whose quaternion is nearest)."""
    geometry = world.geometry
    position = np.array([float(v) for v in pose[:3]])
    scaled = (position[: world.dims] - np.asarray(geometry.origin)[: world.dims]) / world.resolution
    cell = np.floor(scaled).astype(np.int64)
    quaternion = np.array([float(v) for v in pose[3:]])
    candidates = np.array([context.view_quaternion(i) for i in range(len(context.orientations))])
    view = int(np.argmax(np.abs(candidates @ (quaternion / np.linalg.norm(quaternion)))))
    return cell, view


def replay_rows(
    world: World,
    context: PlanningContext,
    header: list[str],
    rows: list[list[str]],
    chamfer: bool = False,
    source: str = "run",
) -> ReplayedRun:
    """Take the views of ``rows`` again on ``world`` (module docstring).

    Raises:
        ValueError: a row whose pose or unknown fractions the replay does not give back, or a CSV
            without the pose columns.
    """
    pose_columns = POSE_COLUMNS if "x_m" in header else OLD_POSE_COLUMNS
    missing = {"unknown_fraction", "unknown_fraction_all", *pose_columns} - set(header)
    if missing:
        raise ValueError(f"{source}: not a run CSV (no column {', '.join(sorted(missing))})")
    # a missing coverage column goes where today's CSV has it: after ruled_out_views (or last)
    column = header.index(COVERAGE_COLUMN) if COVERAGE_COLUMN in header else (
        header.index("ruled_out_views") + 1 if "ruled_out_views" in header else len(header))  # fmt: skip
    out_header = header if COVERAGE_COLUMN in header else [*header[:column], COVERAGE_COLUMN, *header[column:]]
    state = np.full(world.shape, -1, dtype=np.int8)
    reconstruction = MeshReconstruction(world, context.active_sensor) if chamfer else None
    out_rows, largest = [], 0.0
    for number, values in enumerate(rows):
        row = dict(zip(header, values, strict=True))
        stored_pose = [row[k] for k in pose_columns]
        cell, view = view_of_row(stored_pose, world, context)
        position, quaternion = world.geometry.cell_centre(cell), context.view_quaternion(view)
        pose = [*(f"{v:.6f}" for v in position), *(f"{v:.6f}" for v in quaternion)]
        if pose != stored_pose:
            raise ValueError(f"{source}: view {number}: pose {stored_pose} is no candidate view (nearest: {pose})")
        if number == 0:
            coverage = SurfaceCoverage.seen_from(world.ground_truth, cell)
        observe(state, world.ground_truth, cell, context.orientations[view], context.active_sensor)
        replayed = (unknown_fraction(state, world.ground_truth), unknown_fraction_all(state))
        stored = (float(row["unknown_fraction"]), float(row["unknown_fraction_all"]))
        difference = max(abs(a - b) for a, b in zip(replayed, stored, strict=True))
        if difference > TOLERANCE:
            raise ValueError(
                f"{source}: view {number}: the replay gives unknown fractions {replayed[0]:.6f}, {replayed[1]:.6f}, "
                f"the run stored {stored[0]:.6f}, {stored[1]:.6f} (not a run of the exact sensor on this world?)"
            )
        largest = max(largest, difference)
        if reconstruction is not None:
            reconstruction.add_view(position, quaternion)
        out = list(values) if len(out_header) == len(header) else [*values[:column], "", *values[column:]]
        out[column] = f"{coverage(state):.6f}"
        out_rows.append(out)
    distance = None if reconstruction is None else reconstruction.chamfer()
    return ReplayedRun(out_header, out_rows, distance, largest)


def replay_run(
    dataset: str,
    seed: int,
    views: int,
    source: str | Path,
    gain_variant: str = "paper",
    chamfer: bool = False,
) -> tuple[str, dict]:
    """Replay the first ``views`` views of the run CSV ``source`` of ``dataset`` environment
    ``seed`` (its ``.json`` beside it, when there, is carried over with :data:`REPLAY_KEY` and,
    with ``chamfer``, the Chamfer distance added): the CSV text and its metadata. The sensor and
    orientations are the data set's (``gain_variant`` as the run's)."""
    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate(dataset, seed)
    context = PlanningContext(
        dataset_spec(dataset), rng=np.random.default_rng(seed), ground_truth=world.ground_truth,
        gain_variant=gain_variant,
    )  # fmt: skip
    header, rows = read_rows(source, views)
    replayed = replay_rows(world, context, header, rows, chamfer, str(source))
    meta_path = Path(source).with_suffix(".json")
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {"views": len(rows)}
    meta.update({REPLAY_KEY: str(source), DIFFERENCE_KEY: replayed.max_difference, "host": os.uname().nodename})
    if replayed.chamfer is not None:
        meta[CHAMFER_KEY] = replayed.chamfer.as_dict()
    return replayed.csv_text(), meta
