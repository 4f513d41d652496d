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
#: the view (FeasibilityReport fields; counts of the pass that found it); with path planning, the
#: goals whose straight path was blocked and that got a planned path / whose planning failed too.
STAGE_COUNTS = (
    "ranked", "candidates", "camera_blocked", "checked", "unreachable", "in_collision", "path_blocked", "fallback",
    "paths_planned", "paths_not_found",
)  # fmt: skip


RUN_COLUMNS = [
    "iteration", "unknown_fraction", "unknown_fraction_all", "gain", "time_total_s", "time_gain_s",
    "time_capability_s", "time_ik_collision_s", "time_path_planning_s", "joint_travel", "path_waypoints",
    "cell_i", "cell_j", "cell_k", "view_index",
    "x", "y", "z", "qx", "qy", "qz", "qw", *STAGE_COUNTS,
]  # fmt: skip


def config_name(motion_weight: float | None, planned_paths: bool = False) -> str:
    """``free_flying`` (None), ``arm_lambda_<λ>`` (straight joint paths only) or
    ``arm_lambda_<λ>_planned`` (planned paths where the straight one is blocked)."""
    if motion_weight is None:
        return FREE_FLYING
    return f"arm_lambda_{motion_weight:g}" + ("_planned" if planned_paths else "")


@dataclass
class ArmMove:
    """One move of the arm: the joint goal, the joint-space length of the path to it, stage times;
    ``waypoints`` of a planned path (None: straight)."""

    q: np.ndarray
    joint_travel: float
    times: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)  # candidates per stage, see STAGE_COUNTS
    waypoints: np.ndarray | None = None


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
        counts = {name: int(getattr(report, name)) for name in STAGE_COUNTS}  # the pass that found the view
        view = report.view
        times = dict(report.total().times)  # a fallback: both passes
        self.moves.append(ArmMove(view.q.copy(), view.path_length, times, counts, view.waypoints))
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
            row.update(joint_travel="", time_path_planning_s="", path_waypoints="")
            row.update(dict.fromkeys(STAGE_COUNTS, ""))
        else:
            move = moves[index]
            times = move.times if index > 0 else {}
            row.update(
                time_gain_s=f"{times.get('gain', 0.0):.6f}",
                time_capability_s=f"{times.get('capability', 0.0):.6f}",
                time_ik_collision_s=f"{times.get('ik_collision', 0.0):.6f}",
                time_path_planning_s=f"{times.get('path_planning', 0.0):.6f}",
                joint_travel=f"{move.joint_travel:.6f}",
                path_waypoints=2 if move.waypoints is None else len(move.waypoints),
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


def _mean(values: list[float]) -> float:
    """The mean (NaN when a value is NaN or there is none)."""
    return float(np.mean(values)) if values else math.nan


def _finite_mean(values: list[float]) -> float:
    """The mean of the values that are not NaN (NaN when there is none)."""
    finite = [v for v in values if not math.isnan(v)]
    return float(np.mean(finite)) if finite else math.nan


@dataclass(frozen=True)
class RunLogs:
    """What the summaries read from the run logs (:func:`run_rows`) of one configuration.

    Attributes:
        curves: ``(runs, views)`` unknown fraction per view (a run that stopped keeps its last value).
        joint_travel: total joint travel per run.
        planned: per run, the rows of its planned views (iteration ≥ 1).
    """

    runs: int
    views_mean: float
    curves: np.ndarray
    joint_travel: list[float]
    planned: list[list[dict]]

    @classmethod
    def read(cls, logs: list[list[dict]], views: int) -> RunLogs:
        """Of the logs of ``views`` views each at most."""
        curves = np.empty((len(logs), views))
        for r, rows in enumerate(logs):
            fractions = [float(row["unknown_fraction"]) for row in rows]
            curves[r] = (fractions + [fractions[-1]] * views)[:views]
        travel = [sum(_float(row["joint_travel"]) for row in rows) for rows in logs]
        return cls(len(logs), float(np.mean([len(rows) for rows in logs])), curves, travel, [r[1:] for r in logs])

    def per_view(self, column: str) -> list[float]:
        """``column`` of every planned view of every run (NaN where empty or missing)."""
        return [_float(row.get(column, "")) for rows in self.planned for row in rows]


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
        run_logs = RunLogs.read(logs, views)
        out.append(
            ConfigSummary(
                config,
                run_logs.runs,
                run_logs.views_mean,
                float(run_logs.curves[:, -1].mean()),
                float(run_logs.curves[:, -1].std()),
                _mean(run_logs.joint_travel),
                _mean(run_logs.per_view("time_gain_s")),
                _mean(run_logs.per_view("time_capability_s")),
                _mean(run_logs.per_view("time_ik_collision_s")),
                run_logs.curves.mean(axis=0),
                sum(len(rows) == views for rows in logs),
                _mean(run_logs.per_view("checked")),
                _mean(run_logs.per_view("camera_blocked")),
                _mean([sum(_float(row.get("fallback", "")) for row in rows) for rows in run_logs.planned]),
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


def _plot_curves(axes, summaries: list[ConfigSummary] | list[PathsSummary]) -> None:
    """Each configuration's mean unknown fraction per view on ``axes``."""
    for s in summaries:
        axes.plot(np.arange(1, s.curve.size + 1), s.curve, marker=".", label=s.config)
    axes.set_xlabel("views")
    axes.set_ylabel("unknown fraction (mean over scenes)")
    axes.grid(alpha=0.3)
    axes.legend()


def save_comparison_png(summaries: list[ConfigSummary], path: Path, title: str) -> None:
    """Unknown fraction per view per configuration, and the mean total joint travel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (curves, bars) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    _plot_curves(curves, summaries)
    arm = [s for s in summaries if not math.isnan(s.joint_travel_mean)]
    bars.bar([s.config for s in arm], [s.joint_travel_mean for s in arm], color=["C1", "C2", "C3"][: len(arm)])
    bars.set_ylabel("total joint travel per run (rad, mean)")
    bars.tick_params(axis="x", labelrotation=15)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: Views after which ``nbv study arm_compare --paths`` reports the unknown fraction.
CHECKPOINTS = (10, 20, 30)


@dataclass
class PathsSummary:
    """Straight-only against planned paths, one configuration (means over runs; per-view values
    over the planned views, iteration ≥ 1).

    Attributes:
        feasible_fraction: planned iterations that found a feasible view, over all the runs'
            planned iterations (``views − 1`` each; a run ends at its first iteration without one).
        unknown_at: mean unknown fraction after each of :data:`CHECKPOINTS` views (a run that
            ended keeps its last value).
        joint_travel_mean: total joint-space path length per run (rad).
        times: mean seconds per planned view of the stages ``gain``, ``capability``,
            ``ik_collision`` (path planning included) and ``path_planning``.
        path_blocked_mean, paths_planned_mean, paths_not_found_mean: per planned view, exact
            checks rejected for their path, goals reached by a planned path, plans that failed.
        planned_moves_mean: moves per run along a planned (not straight) path.
    """

    config: str
    runs: int
    views_mean: float
    feasible_fraction: float
    unknown_at: dict[int, float]
    joint_travel_mean: float
    times: dict[str, float]
    path_blocked_mean: float
    paths_planned_mean: float
    paths_not_found_mean: float
    planned_moves_mean: float
    curve: np.ndarray


def summarize_paths(runs: dict[str, list[list[dict]]], views: int) -> list[PathsSummary]:
    """:class:`PathsSummary` per configuration of arm run logs (:func:`run_rows`)."""
    stages = ("gain", "capability", "ik_collision", "path_planning")
    out = []
    for config, logs in runs.items():
        run_logs = RunLogs.read(logs, views)
        taken = sum(len(rows) - 1 for rows in logs)
        planned_moves = [
            float(sum(_float(row.get("path_waypoints", "")) > 2 for row in rows)) for rows in run_logs.planned
        ]
        out.append(
            PathsSummary(
                config,
                run_logs.runs,
                run_logs.views_mean,
                taken / max(1, len(logs) * (views - 1)),
                {n: float(run_logs.curves[:, min(n, views) - 1].mean()) for n in CHECKPOINTS if n <= views},
                _finite_mean(run_logs.joint_travel),
                {stage: _finite_mean(run_logs.per_view(f"time_{stage}_s")) for stage in stages},
                _finite_mean(run_logs.per_view("path_blocked")),
                _finite_mean(run_logs.per_view("paths_planned")),
                _finite_mean(run_logs.per_view("paths_not_found")),
                _finite_mean(planned_moves),
                run_logs.curves.mean(axis=0),
            )
        )
    return out


def write_paths_summary(summaries: list[PathsSummary], csv_path: Path, md_path: Path, header: str) -> None:
    """Summary CSV and markdown table of straight-only against planned paths."""
    checkpoints = sorted({n for s in summaries for n in s.unknown_at})
    stages = ("gain", "capability", "ik_collision", "path_planning")
    columns = ["config", "runs", "views_mean", "feasible_iteration_fraction"]
    columns += [f"unknown_fraction_after_{n}" for n in checkpoints] + ["joint_travel_total_rad_mean"]
    columns += [f"time_{stage}_s_per_view" for stage in stages]
    columns += ["path_blocked_per_view", "paths_planned_per_view", "paths_not_found_per_view", "planned_moves_per_run"]
    with open(csv_path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        for s in summaries:
            writer.writerow(
                [s.config, s.runs, f"{s.views_mean:.2f}", f"{s.feasible_fraction:.4f}"]
                + [_cell(s.unknown_at.get(n, math.nan), 6) for n in checkpoints]
                + [_cell(s.joint_travel_mean, 4)]
                + [_cell(s.times[stage], 6) for stage in stages]
                + [_cell(v, 3) for v in (s.path_blocked_mean, s.paths_planned_mean, s.paths_not_found_mean)]
                + [_cell(s.planned_moves_mean, 2)]
            )
    lines = [
        header,
        "",
        "| configuration | runs | views (mean) | iterations with a feasible view | "
        + " | ".join(f"unknown after {n}" for n in checkpoints)
        + " | total joint travel (rad) | gain s/view | capability s/view | IK+collision s/view (planning included) "
        "| path planning s/view | straight path blocked/view | paths planned/view | planning failed/view "
        "| planned moves/run |",
        "|---" * (13 + len(checkpoints)) + "|",
    ]
    for s in summaries:
        lines.append(
            f"| {s.config} | {s.runs} | {s.views_mean:.1f} | {100 * s.feasible_fraction:.1f} % | "
            + " | ".join(f"{s.unknown_at[n]:.4f}" if n in s.unknown_at else "—" for n in checkpoints)
            + f" | {s.joint_travel_mean:.2f} | "
            + " | ".join(_cell(s.times[stage], 3) or "—" for stage in stages)
            + f" | {_cell(s.path_blocked_mean, 2) or '—'} | {_cell(s.paths_planned_mean, 2) or '—'} "
            f"| {_cell(s.paths_not_found_mean, 2) or '—'} | {_cell(s.planned_moves_mean, 1) or '—'} |"
        )
    md_path.write_text("\n".join(lines) + "\n")


def save_paths_png(summaries: list[PathsSummary], path: Path, title: str) -> None:
    """Unknown fraction per view, total joint travel per run, and seconds per view by stage."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (curves, travel, stages) = plt.subplots(1, 3, figsize=(15, 4.4), gridspec_kw={"width_ratios": [2, 1, 1.3]})
    _plot_curves(curves, summaries)
    names = [s.config for s in summaries]
    travel.bar(names, [s.joint_travel_mean for s in summaries], color=[f"C{i}" for i in range(len(summaries))])
    travel.set_ylabel("total joint travel per run (rad, mean)")
    travel.tick_params(axis="x", labelrotation=15)
    bottom = np.zeros(len(summaries))
    ik_only = [s.times["ik_collision"] - (0.0 if math.isnan(s.times["path_planning"]) else s.times["path_planning"])
               for s in summaries]  # fmt: skip
    parts = [
        ("gain", [s.times["gain"] for s in summaries]),
        ("capability", [s.times["capability"] for s in summaries]),
        ("IK + collision", ik_only),
        ("path planning (OMPL)", [s.times["path_planning"] for s in summaries]),
    ]
    for label, values in parts:
        height = np.nan_to_num(np.asarray(values, dtype=np.float64))
        stages.bar(names, height, bottom=bottom, label=label)
        bottom += height
    stages.set_ylabel("planning time per view (s, mean)")
    stages.set_ylim(0.0, 1.35 * max(float(bottom.max()), 1e-3))  # room for the legend above the bars
    stages.tick_params(axis="x", labelrotation=15)
    stages.legend(fontsize=8, loc="upper left", ncols=2)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
