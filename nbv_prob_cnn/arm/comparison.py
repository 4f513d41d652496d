"""Free-flying camera against the arm-constrained camera (λ = 0 and λ > 0) on simulated 3DT
explorations: the exploration loop of :mod:`nbv_prob_cnn.exploration.explore` with an arm-aware planner,
per-run CSV logs (resumable), a summary CSV / markdown table and a PNG.

All configurations of a scene start from the same first view: a random (cell, orientation) that
the arm reaches collision-free from its reference configuration on the all-unknown grid.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbv_prob_cnn.arm.feasibility import ArmFeasibility, FeasibilityReport
from nbv_prob_cnn.arm.selection import ArmViewSelector
from nbv_prob_cnn.arm.swept import SweptVolume
from nbv_prob_cnn.exploration.explore import ExplorationResult
from nbv_prob_cnn.planners import GainPlanner, PlanningContext, ViewChoice
from nbv_prob_cnn.planners.base import OriginFilter

FREE_FLYING = "free_flying"

#: Per planned arm view: views ranked by gain, left by the capability map, rejected because a
#: camera-rigid body (link 7, hand, fingers) would enter a blocked cell, exactly checked, and rejected by
#: IK / collision at the goal / collision on the path, and whether the near-camera fallback found
#: the view (FeasibilityReport fields; counts of the pass that found it).
STAGE_COUNTS = (
    "ranked", "candidates", "camera_blocked", "checked", "unreachable", "in_collision", "path_blocked", "fallback",
)  # fmt: skip


RUN_COLUMNS = [
    "iteration", "unknown_fraction", "unknown_fraction_all", "gain", "time_total_s", "time_gain_s",
    "time_capability_s", "time_ik_collision_s", "joint_travel", "cell_i", "cell_j", "cell_k", "view_index",
    "x", "y", "z", "qx", "qy", "qz", "qw", *STAGE_COUNTS,
]  # fmt: skip


def config_name(motion_weight: float | None) -> str:
    """``free_flying`` (None) or ``arm_lambda_<λ>``."""
    return FREE_FLYING if motion_weight is None else f"arm_lambda_{motion_weight:g}"


@dataclass
class ArmMove:
    """One move of the arm: the joint goal, the joint-space length of the path to it, stage times."""

    q: np.ndarray
    joint_travel: float
    times: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)  # candidates per stage, see STAGE_COUNTS


class ArmPlanner:
    """A :class:`GainPlanner` restricted to what the arm can take, as a ``Planner`` for
    :func:`explore`: each iteration is one :meth:`ArmViewSelector.select` from the arm's
    configuration; it keeps the configuration and logs each move.

    With ``swept`` (a :class:`SweptVolume`), the space the arm has swept (the move from its
    reference configuration to ``start``, then every planned move) is carved free in the grid
    the planner and the collision check see; the camera's map is not changed. ``fallback_radius_m``:
    the near-camera fallback of :class:`ArmViewSelector`. Views already taken (``first`` and every
    planned one) are never ranked again."""

    def __init__(
        self,
        planner: GainPlanner,
        arm: ArmFeasibility,
        geometry,
        start: ArmMove,
        top_k: int = 200,
        swept: SweptVolume | None = None,
        fallback_radius_m: float = 0.0,
        first: ViewChoice | None = None,
    ) -> None:
        self.planner = planner
        self.arm = arm
        self.geometry = geometry
        self.top_k = top_k
        self.selector = ArmViewSelector(arm, geometry, swept, fallback_radius_m)
        if first is not None:
            self.selector.take(first)
        self.name = f"{planner.name} arm λ={arm.motion_weight:g}"
        self.moves: list[ArmMove] = [start]
        self.last_report: FeasibilityReport | None = None
        if swept is not None:
            swept.add_path(arm.robot.reference_q, start.q)

    @property
    def q(self) -> np.ndarray:
        return self.moves[-1].q

    @property
    def swept(self) -> SweptVolume | None:
        return self.selector.swept

    @property
    def taken(self) -> set[tuple[tuple[int, ...], int]]:
        return self.selector.taken

    def rank(
        self, state: np.ndarray, context: PlanningContext, top_k: int = 1, origin_filter: OriginFilter | None = None
    ) -> list[ViewChoice]:
        """The first feasible view in gain order, as a list (the arm check stops at it, so
        ``top_k`` > 1 gives no more views; the capability map is the origin filter)."""
        if origin_filter is not None:
            raise ValueError("origin_filter: the arm planner filters origins with its capability map")
        choice = self.plan(state, context)
        return [] if choice is None else [choice]

    def plan(self, state: np.ndarray, context: PlanningContext) -> ViewChoice | None:
        report = self.selector.select(self.planner, state, context, self.q, self.top_k)
        self.last_report = report
        if report.view is None:
            return None
        q_start = self.q
        counts = {name: int(getattr(report, name)) for name in STAGE_COUNTS}
        self.moves.append(ArmMove(report.view.q.copy(), report.view.path_length, dict(report.times), counts))
        self.selector.moved(q_start, report.view)
        return report.view.choice


def reachable_first_view(
    world, context: PlanningContext, arm: ArmFeasibility, rng: np.random.Generator, tries: int = 500
) -> tuple[ViewChoice, ArmMove]:
    """A random empty (cell, orientation) that ``arm`` takes from its reference configuration on
    the all-unknown grid, and the move to it.

    Raises:
        ValueError: none found in ``tries`` random draws.
    """
    free = np.argwhere(world.ground_truth == 0)
    unknown = np.full(world.shape, -1, dtype=np.int8)
    start_q = arm.robot.reference_q
    n_views = context.orientations.shape[0]
    for _ in range(tries):
        choice = ViewChoice(free[rng.integers(free.shape[0])], int(rng.integers(n_views)), float("nan"))
        report = arm.select([choice], unknown, context, world.geometry, start_q)
        if report.view is not None:
            return choice, ArmMove(report.view.q.copy(), report.view.path_length, dict(report.times))
    raise ValueError(f"world seed {world.seed}: no view reachable by the arm in {tries} random draws")


def run_rows(result: ExplorationResult, context: PlanningContext, moves: list[ArmMove] | None) -> list[dict]:
    """Per-view rows of one run (``moves`` None: free-flying, joint columns left empty)."""
    rows = []
    if moves is not None and len(moves) != len(result.records):
        raise ValueError(f"{len(moves)} arm moves for {len(result.records)} views")
    for index, record in enumerate(result.records):
        row = {
            "iteration": record.iteration,
            "unknown_fraction": f"{record.unknown_fraction:.6f}",
            "unknown_fraction_all": f"{record.unknown_fraction_all:.6f}",
            "gain": f"{record.gain:.6g}",
            "time_total_s": f"{record.time_total_s:.6f}",
            "cell_i": int(record.cell[0]),
            "cell_j": int(record.cell[1]),
            "cell_k": int(record.cell[2]),
            "x": f"{record.position_m[0]:.6f}",
            "y": f"{record.position_m[1]:.6f}",
            "z": f"{record.position_m[2]:.6f}",
        }
        view = [i for i, q in enumerate(context.orientations) if np.allclose(q, record.quaternion)]
        row["view_index"] = view[0] if view else ""
        row.update(zip(("qx", "qy", "qz", "qw"), (f"{v:.6f}" for v in record.quaternion), strict=True))
        if moves is None:
            row.update(time_gain_s=f"{record.time_total_s:.6f}", time_capability_s="", time_ik_collision_s="")
            row["joint_travel"] = ""
            row.update(dict.fromkeys(STAGE_COUNTS, ""))
        else:
            move = moves[index]
            times = move.times if index > 0 else {}
            row.update(
                time_gain_s=f"{times.get('gain', 0.0):.6f}",
                time_capability_s=f"{times.get('capability', 0.0):.6f}",
                time_ik_collision_s=f"{times.get('ik_collision', 0.0):.6f}",
                joint_travel=f"{move.joint_travel:.6f}",
            )
            row.update({name: move.counts.get(name, "") for name in STAGE_COUNTS})
            row.update({f"q{j}": f"{v:.8f}" for j, v in enumerate(move.q)})
        rows.append(row)
    return rows


def write_run_csv(rows: list[dict], path: Path) -> None:
    """Write a run log atomically (a finished file means a finished run)."""
    columns = list(RUN_COLUMNS) + sorted((k for k in rows[0] if k not in RUN_COLUMNS), key=lambda k: int(k[1:]))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(path)


def read_run_csv(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _float(value: str) -> float:
    return float(value) if value not in ("", None) else math.nan


@dataclass
class ConfigSummary:
    """Mean over runs of one configuration."""

    config: str
    runs: int
    views_mean: float
    unknown_final_mean: float
    unknown_final_std: float
    joint_travel_mean: float
    time_gain_mean: float
    time_capability_mean: float
    time_ik_collision_mean: float
    curve: np.ndarray  # mean unknown fraction per view (a run that stopped keeps its last value)
    runs_complete: int = 0  # runs that took every view
    checked_mean: float = math.nan  # exact checks per planned view (arm)
    camera_blocked_mean: float = math.nan  # views rejected by the camera-rigid bodies per planned view (arm)
    fallback_views_mean: float = math.nan  # planned views per run found by the near-camera fallback (arm)


def summarize(runs: dict[str, list[list[dict]]], views: int) -> list[ConfigSummary]:
    """Summaries per configuration; per-view times are means over planned views (iteration ≥ 1)."""
    out = []
    for config, logs in runs.items():
        curves = np.empty((len(logs), views))
        travel, gain_t, cap_t, ik_t = [], [], [], []
        checked, blocked, fallback = [], [], []
        for r, rows in enumerate(logs):
            fractions = [float(row["unknown_fraction"]) for row in rows]
            curves[r] = fractions + [fractions[-1]] * (views - len(fractions))
            travel.append(sum(_float(row["joint_travel"]) for row in rows))
            planned = rows[1:]
            gain_t += [_float(row["time_gain_s"]) for row in planned]
            cap_t += [_float(row["time_capability_s"]) for row in planned]
            ik_t += [_float(row["time_ik_collision_s"]) for row in planned]
            checked += [_float(row.get("checked", "")) for row in planned]
            blocked += [_float(row.get("camera_blocked", "")) for row in planned]
            fallback.append(sum(_float(row.get("fallback", "")) for row in planned))

        def mean(values: list[float]) -> float:
            return float(np.mean(values)) if values else math.nan

        out.append(
            ConfigSummary(
                config,
                len(logs),
                float(np.mean([len(rows) for rows in logs])),
                float(curves[:, -1].mean()),
                float(curves[:, -1].std()),
                mean(travel),
                mean(gain_t),
                mean(cap_t),
                mean(ik_t),
                curves.mean(axis=0),
                sum(len(rows) == views for rows in logs),
                mean(checked),
                mean(blocked),
                mean(fallback),
            )
        )
    return out


SUMMARY_COLUMNS = [
    "config", "runs", "views_mean", "unknown_fraction_final_mean", "unknown_fraction_final_std",
    "joint_travel_total_mean", "time_gain_s_mean", "time_capability_s_mean", "time_ik_collision_s_mean",
    "runs_complete", "checked_per_view_mean", "camera_blocked_per_view_mean", "fallback_views_per_run_mean",
]  # fmt: skip


def _cell(value: float, digits: int) -> str:
    return "" if math.isnan(value) else f"{value:.{digits}f}"


def write_summary(summaries: list[ConfigSummary], csv_path: Path, md_path: Path, views: int, header: str) -> None:
    """Summary CSV and a markdown table."""
    with open(csv_path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(SUMMARY_COLUMNS)
        for s in summaries:
            writer.writerow(
                [s.config, s.runs, f"{s.views_mean:.2f}", f"{s.unknown_final_mean:.6f}", f"{s.unknown_final_std:.6f}"]
                + [_cell(v, 6) for v in (s.joint_travel_mean, s.time_gain_mean, s.time_capability_mean)]
                + [_cell(s.time_ik_collision_mean, 6), s.runs_complete]
                + [_cell(v, 3) for v in (s.checked_mean, s.camera_blocked_mean, s.fallback_views_mean)]
            )
    lines = [
        header,
        "",
        (
            f"| configuration | runs | views (mean) | unknown fraction after {views} views | total joint travel (rad) "
            "| gain s/view | capability s/view | IK+collision s/view | runs with all views "
            "| exact checks/view | hand-blocked/view | fallback views/run |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        lines.append(
            f"| {s.config} | {s.runs} | {s.views_mean:.1f} | {s.unknown_final_mean:.4f} ± {s.unknown_final_std:.4f} "
            f"| {_cell(s.joint_travel_mean, 2) or '—'} | {s.time_gain_mean:.3f} "
            f"| {_cell(s.time_capability_mean, 3) or '—'} | {_cell(s.time_ik_collision_mean, 3) or '—'} "
            f"| {s.runs_complete} | {_cell(s.checked_mean, 1) or '—'} | {_cell(s.camera_blocked_mean, 1) or '—'} "
            f"| {_cell(s.fallback_views_mean, 1) or '—'} |"
        )
    md_path.write_text("\n".join(lines) + "\n")


def save_comparison_png(summaries: list[ConfigSummary], path: Path, title: str) -> None:
    """Unknown fraction per view per configuration, and the mean total joint travel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (curves, bars) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    for s in summaries:
        curves.plot(np.arange(1, s.curve.size + 1), s.curve, marker=".", label=s.config)
    curves.set_xlabel("views")
    curves.set_ylabel("unknown fraction (mean over scenes)")
    curves.grid(alpha=0.3)
    curves.legend()
    arm = [s for s in summaries if not math.isnan(s.joint_travel_mean)]
    bars.bar([s.config for s in arm], [s.joint_travel_mean for s in arm], color=["C1", "C2", "C3"][: len(arm)])
    bars.set_ylabel("total joint travel per run (rad, mean)")
    bars.tick_params(axis="x", labelrotation=15)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
