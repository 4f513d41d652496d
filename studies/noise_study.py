"""Noisy depth sensors against the ideal one on held-out environments (issue 19, docs/sensing.md).

Every combination of sensor (``ideal`` = the exact observation of docs/method.md#sensor-and-simulated-observation
within ``R_max``, or a
:mod:`~nbv_prob_cnn.sensing.sensor_noise` preset), method and room (walls ``margin`` metres
outside the grid, or none) explores each environment for ``views`` views with
:func:`~nbv_prob_cnn.exploration.explore.explore`, with the view guard unless ``--no-guard``.
The exact observation has no room (its rays end at the grid's border), so the ideal runs serve
both rooms. One CSV per run (resumable: a run whose CSV has the views asked for is read back),
then a table (``noise_table.csv``, ``noise_table.md``) and the curves (``noise_curves.png``).

    nbv study noise_study --out studies/results/evaluation/noise \\
        --methods cnn_prob --sensors ideal kinect_v1 astra --rooms 0.3
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from tqdm import tqdm

from nbv_prob_cnn.basics.datasets import EVALUATION_SEEDS, dataset_spec
from nbv_prob_cnn.exploration.evaluation import padded, read_run
from nbv_prob_cnn.exploration.explore import explore, write_csv
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.sensing.sensor_noise import sensor_noise

SENSORS = ("ideal", "kinect_v1", "astra")
METHODS = ("cnn_prob", "prob_ig")
#: Room margins [m]; None = no walls.
ROOMS: tuple[float | None, ...] = (0.3, None)
#: Table columns: the unknown fraction after these views.
AT_VIEWS = (10, 20)


@dataclass(frozen=True)
class Config:
    """One sensor, method and room."""

    sensor: str
    method: str
    room_m: float | None

    @property
    def room(self) -> str:
        return "no_walls" if self.room_m is None else f"walls_{self.room_m:g}m"

    def run_path(self, out: Path, dataset: str, seed: int, guard: bool) -> Path:
        room = "exact" if self.sensor == "ideal" else self.room  # the exact observation has no room
        suffix = "" if guard else "_plain"
        return out / "runs" / f"{dataset}_{self.method}_{self.sensor}_{room}{suffix}_seed{seed}.csv"


def run_one(config: Config, dataset: str, seed: int, views: int, guard: bool, path: Path) -> None:
    """One exploration, written to ``path`` (CSV) and ``path`` with ``.json`` (why it stopped)."""
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate(dataset, seed)
    context = PlanningContext(dataset_spec(dataset), rng=np.random.default_rng(seed), ground_truth=world.ground_truth)
    noise = None if config.sensor == "ideal" else sensor_noise(config.sensor)
    result = explore(
        world, make_planner(config.method), context, views, progress=False, noise=noise,
        room_margin_m=None if noise is None else config.room_m,
        guard=ViewGuard.for_grid(world.shape) if guard else None,
    )  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    write_csv(result.records, tmp)
    meta = {"views": views, "stop_reason": result.stop_reason, "sensor": config.sensor, "method": config.method,
            "room_margin_m": config.room_m, "guard": guard}  # fmt: skip
    path.with_suffix(".json").write_text(json.dumps(meta) + "\n")
    tmp.replace(path)


def is_done(path: Path, views: int) -> bool:
    meta = path.with_suffix(".json")
    return path.is_file() and meta.is_file() and int(json.loads(meta.read_text())["views"]) >= views


def configs(sensors, methods, rooms) -> list[Config]:
    return [Config(s, m, r) for m in methods for r in rooms for s in sensors]


def run_all(cfgs: list[Config], dataset: str, seeds: list[int], views: int, guard: bool, out: Path) -> None:
    """Every run of ``cfgs`` × ``seeds`` that is not done yet (an ideal run once for both rooms)."""
    jobs: dict[Path, tuple[Config, int]] = {}
    for config in cfgs:
        for seed in seeds:
            path = config.run_path(out, dataset, seed, guard)
            if not is_done(path, views) and path not in jobs:
                jobs[path] = (config, seed)
    bar = tqdm(total=len(jobs), desc=f"noise study {dataset}", unit="run")
    for path, (config, seed) in jobs.items():
        bar.set_postfix(sensor=config.sensor, method=config.method, room=config.room, seed=seed)
        run_one(config, dataset, seed, views, guard, path)
        bar.update(1)
    bar.close()


def summarise(cfgs: list[Config], dataset: str, seeds: list[int], views: int, guard: bool, out: Path) -> list[dict]:
    """Rows of the table (configurations whose runs all exist)."""
    rows: list[dict] = []
    ideal: dict[str, dict] = {}
    listed: set[Path] = set()
    for config in cfgs:
        paths = [config.run_path(out, dataset, s, guard) for s in seeds]
        if paths[0] in listed or not all(is_done(p, views) for p in paths):
            continue  # an ideal configuration once (both rooms), complete ones only
        listed.add(paths[0])
        logs = [read_run(p, views) for p in paths]
        curves = padded([log.unknown_fraction for log in logs], views)
        extra = [_columns(p, views) for p in paths]
        room = "exact (no room)" if config.sensor == "ideal" else config.room
        row: dict = {"sensor": config.sensor, "method": config.method, "room": room, "runs": len(paths)}
        for v in AT_VIEWS:
            if v <= views:
                row[f"unknown_after_{v}"] = float(curves[:, v - 1].mean())
                row[f"std_after_{v}"] = float(curves[:, v - 1].std())
        row["ruled_out_views_mean"] = float(np.mean([e["ruled_out"] for e in extra]))
        row["views_changing_0_cells_mean"] = float(np.mean([e["zero"] for e in extra]))
        row["plan_time_mean_s"] = float(np.mean(np.concatenate([log.time_total_s[1:] for log in logs])))
        row["curve"] = curves.mean(axis=0)
        rows.append(row)
        if config.sensor == "ideal":
            ideal[config.method] = row
    for row in rows:
        ref = ideal.get(row["method"])
        for v in AT_VIEWS:
            key = f"unknown_after_{v}"
            if ref is not None and key in row and ref[key] > 0:
                row[f"ratio_to_ideal_after_{v}"] = row[key] / ref[key]
    return rows


def _columns(path: Path, views: int) -> dict:
    with open(path) as handle:
        records = list(csv.DictReader(handle))[:views]
    ruled = int(records[-1].get("ruled_out_views", 0) or 0)
    zero = sum(1 for r in records[1:] if int(r.get("changed_cells", 1) or 0) == 0)
    return {"ruled_out": ruled, "zero": zero}


TABLE_COLUMNS = (
    "sensor", "method", "room", "runs", "unknown_after_10", "std_after_10", "unknown_after_20", "std_after_20",
    "ratio_to_ideal_after_10", "ratio_to_ideal_after_20", "ruled_out_views_mean", "views_changing_0_cells_mean",
    "plan_time_mean_s",
)  # fmt: skip


def write_table(rows: list[dict], out: Path, name: str) -> list[Path]:
    """``<name>.csv`` (fractions of the ground-truth-empty cells, ratios, mean counts of views per
    run, seconds) and ``<name>.md``."""
    csv_path, md_path = out / f"{name}.csv", out / f"{name}.md"
    with open(csv_path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(TABLE_COLUMNS)
        for row in rows:
            writer.writerow([_fmt(row.get(c, "")) for c in TABLE_COLUMNS])
    lines = [
        (
            "| sensor | method | room | runs | unknown after 10 views | after 20 views | ratio to ideal (20) "
            "| views ruled out per run | plan time (s) |"
        ),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        ratio = row.get("ratio_to_ideal_after_20")
        lines.append(
            f"| {row['sensor']} | {row['method']} | {row['room'].replace('_', ' ')} | {row['runs']} "
            f"| {row.get('unknown_after_10', math.nan):.4f} ± {row.get('std_after_10', math.nan):.4f} "
            f"| {row.get('unknown_after_20', math.nan):.4f} ± {row.get('std_after_20', math.nan):.4f} "
            f"| {'–' if ratio is None else f'{ratio:.2f}'} | {row['ruled_out_views_mean']:.1f} "
            f"| {row['plan_time_mean_s']:.2f} |"
        )
    md_path.write_text("\n".join(lines) + "\n")
    return [csv_path, md_path]


def _fmt(value) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def save_curves(rows: list[dict], views: int, out: Path, name: str, title: str) -> Path:
    """Mean unknown fraction per view, one panel per room."""
    rooms = sorted({r["room"] for r in rows if r["sensor"] != "ideal"}) or ["exact (no room)"]
    fig = Figure(figsize=(6.5 * max(1, len(rooms)), 4.8))
    colours = {"ideal": "black", "kinect_v1": "tab:blue", "astra": "tab:orange"}
    styles = {"cnn_prob": "-", "prob_ig": "--"}
    x = np.arange(1, views + 1)
    for i, room in enumerate(rooms):
        ax = fig.add_subplot(1, len(rooms), i + 1)
        for row in rows:
            if row["room"] == room or row["sensor"] == "ideal":
                ax.plot(x, 100 * row["curve"], styles.get(row["method"], ":"), color=colours.get(row["sensor"]),
                        label=f"{row['method']}, {row['sensor']}")  # fmt: skip
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("views")
        ax.set_ylabel("unknown empty cells (%)")
        ax.set_yscale("log")
        ax.set_title(f"{title}: {room.replace('_', ' ')}")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / f"{name}.png"
    fig.savefig(path, dpi=90)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="3dt")
    parser.add_argument("--out", default="out/noise_study")
    parser.add_argument("--sensors", nargs="+", default=list(SENSORS), choices=SENSORS)
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    parser.add_argument("--rooms", nargs="+", default=["0.3", "none"], help="room margins [m], or 'none' (no walls)")
    parser.add_argument("--seeds", nargs="+", type=int, default=list(EVALUATION_SEEDS[:10]))
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--no-guard", action="store_true", help="the plain loop (no view guard)")
    parser.add_argument("--summarise-only", action="store_true", help="no runs: table and plot of those that exist")
    args = parser.parse_args(argv)
    rooms = [None if r.lower() == "none" else float(r) for r in args.rooms]
    if args.views < max(AT_VIEWS):
        raise ValueError(f"--views: expected at least {max(AT_VIEWS)}")
    out, guard = Path(args.out), not args.no_guard
    cfgs = configs(args.sensors, args.methods, rooms)
    if not args.summarise_only:
        run_all(cfgs, args.dataset, args.seeds, args.views, guard, out)
    # the table covers every configuration with complete runs, not only those run now
    every = configs(SENSORS, METHODS, ROOMS)
    rows = summarise(every, args.dataset, args.seeds, args.views, guard, out)
    name = "noise_table" if guard else "noise_table_plain"
    written = write_table(rows, out, name)
    written.append(save_curves(rows, args.views, out, name.replace("table", "curves"),
                               f"{args.dataset.upper()}, {len(args.seeds)} environments"))  # fmt: skip
    print((out / f"{name}.md").read_text())
    print("wrote " + ", ".join(map(str, written)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
