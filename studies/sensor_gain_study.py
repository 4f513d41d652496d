"""The sensor-aware gain and the exact-traversal sampling on held-out environments (issue 19,
deliverables 3–4; docs/sensing.md).

``returns``: every combination of gain sensor model (``paper``, ``returns``) and room (walls
``margin`` m outside the grid, or none) explores each environment with each noise preset
(``--noise``) and the view guard, as :mod:`~studies.noise_study` does; table
``returns_table.{md,csv}`` (a row per method, preset, room and model).

``sampling``: the paper's plain loop (no guard) with the ideal sensor, the gain's rays sampled
``exact`` (voxel traversal), against the committed ``rounded`` runs of ``nbv evaluate`` (read
from ``--committed``; runs missing there are run here); per run how many planned views repeat the
previous pose, and the unknown fraction; table ``sampling_table.{md,csv}``.

One CSV per run (resumable: a run whose CSV has the views asked for is read back).

    nbv study sensor_gain_study returns --out studies/results/evaluation/noise/sensor_gain \\
        --seeds 120 121 122 --views 20
    nbv study sensor_gain_study sampling --out studies/results/evaluation/noise/sensor_gain \\
        --dataset 2d --methods prob_ig ig --views 100 --committed studies/results/evaluation/2d/runs
"""

from __future__ import annotations

import argparse
import csv
import json
from collections.abc import Callable
from functools import partial
from itertools import product
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nbv_prob_cnn.basics.datasets import EVALUATION_SEEDS, dataset_spec
from nbv_prob_cnn.exploration.evaluation import read_run
from nbv_prob_cnn.exploration.explore import explore, write_csv
from nbv_prob_cnn.exploration.view_guard import ViewGuard
from nbv_prob_cnn.gain.sampling import GainSensor
from nbv_prob_cnn.planners import PlanningContext, make_planner
from nbv_prob_cnn.sensing.sensor_noise import sensor_noise

#: Unknown fraction columns of the tables: after these views.
AT_VIEWS = (10, 20)


def _room_name(room_m: float | None) -> str:
    return "no_walls" if room_m is None else f"walls_{room_m:g}m"


def _done(path: Path, views: int) -> bool:
    """Whether ``path`` is a run of at least ``views`` views (its first ``views`` are read)."""
    if not path.exists() or not path.with_suffix(".json").exists():
        return False
    meta = json.loads(path.with_suffix(".json").read_text())
    return int(meta.get("views", 0)) >= views


def _write(path: Path, records, meta: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    write_csv(records, tmp)
    path.with_suffix(".json").write_text(json.dumps(meta) + "\n")
    tmp.replace(path)


def run_returns(dataset: str, method: str, noise_name: str, room_m: float | None, model: str, seed: int,
                views: int, path: Path) -> None:  # fmt: skip
    """One guarded exploration with the noisy sensor and the gain's sensor model ``model``."""
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate(dataset, seed)
    noise = sensor_noise(noise_name)
    gain_sensor = GainSensor.from_noise(noise, world.geometry.resolution, walls=room_m is not None)
    context = PlanningContext(dataset_spec(dataset), rng=np.random.default_rng(seed), ground_truth=world.ground_truth,
                              sensor_model=model, gain_sensor=gain_sensor)  # fmt: skip
    result = explore(world, make_planner(method), context, views, progress=False, noise=noise, room_margin_m=room_m,
                     guard=ViewGuard.for_grid(world.shape))  # fmt: skip
    _write(path, result.records, {"views": views, "stop_reason": result.stop_reason, "sensor": noise_name,
                                  "method": method, "room_margin_m": room_m, "sensor_model": model})  # fmt: skip


def run_sampling(dataset: str, method: str, sampling: str, seed: int, views: int, path: Path) -> None:
    """One plain-loop exploration with the ideal sensor and the gain's rays sampled ``sampling``."""
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate(dataset, seed)
    context = PlanningContext(dataset_spec(dataset), rng=np.random.default_rng(seed), ground_truth=world.ground_truth,
                              sampling=sampling)  # fmt: skip
    result = explore(world, make_planner(method), context, views, progress=False)
    _write(path, result.records, {"views": views, "stop_reason": result.stop_reason, "method": method,
                                  "sampling": sampling})  # fmt: skip


def repeated_views(path: Path) -> np.ndarray:
    """Per planned view (1 ..) whether it is the pose of the view before it, from a run's CSV."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    keys = [k for k in ("x", "y", "z", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw") if k in rows[0]]
    poses = np.array([[float(r[k]) for k in keys] for r in rows])
    return np.all(np.isclose(poses[1:], poses[:-1], atol=1e-6), axis=1)


def _mean_std(values) -> str:
    v = np.asarray(values, dtype=float)
    return f"{v.mean():.4f} ± {v.std():.4f}"


def _unknown_after(path: Path, views: int, at: int) -> float:
    """Unknown fraction after ``at`` views (the last one when the run stopped before)."""
    fractions = read_run(path, views).unknown_fraction
    return float(fractions[min(at, len(fractions)) - 1])


def returns_table(out: Path, dataset: str, methods, noise_names, rooms, seeds, views: int,
                  committed: Path | None = None) -> str:  # fmt: skip
    """Markdown (returned) and CSV (written) of the ``returns`` runs: a row per method, noise
    preset, room and gain sensor model whose runs exist."""
    at = sorted({a for a in AT_VIEWS if a <= views} | {views})
    lines = ["| method | sensor | room | gain sensor model | runs | "
             + " | ".join(f"unknown after {a}" for a in at) + " | views ruled out (mean) |",
             "|---|---|---|---|---|" + "---|" * len(at) + "---|"]  # fmt: skip
    rows = ["method,sensor,room,sensor_model,runs," + ",".join(f"mean_after_{a},std_after_{a}" for a in at)
            + ",ruled_out_mean"]  # fmt: skip
    for method, noise_name, room_m, model in product(methods, noise_names, rooms, ("paper", "returns")):
        paths = [returns_path(out, dataset, method, noise_name, room_m, model, s, committed, views) for s in seeds]
        paths = [p for p in paths if _done(p, views)]
        if not paths:
            continue
        values = {a: [_unknown_after(p, views, a) for p in paths] for a in at}
        ruled = [int(read_csv_column(p, "ruled_out_views")[-1]) for p in paths]
        room = _room_name(room_m)
        cells = " | ".join(_mean_std(values[a]) for a in at)
        lines.append(f"| {method} | {noise_name} | {room} | {model} | {len(paths)} | {cells} | {np.mean(ruled):.1f} |")
        stats = ",".join(f"{np.mean(values[a]):.6f},{np.std(values[a]):.6f}" for a in at)
        rows.append(f"{method},{noise_name},{room},{model},{len(paths)},{stats},{np.mean(ruled):.2f}")
    out.mkdir(parents=True, exist_ok=True)
    (out / "returns_table.csv").write_text("\n".join(rows) + "\n")
    (out / "returns_table.md").write_text("\n".join(lines) + "\n")
    return "\n".join(lines)


def read_csv_column(path: Path, name: str) -> list[str]:
    with open(path, newline="") as f:
        return [r[name] for r in csv.DictReader(f)]


def returns_path(out, dataset, method, noise_name, room_m, model, seed, committed=None, views=0) -> Path:
    """The run's CSV; for the paper's model the committed noise-study run (``committed``, the
    same guarded exploration; never written here) when it has the views."""
    if model == "paper" and committed is not None:
        path = committed / f"{dataset}_{method}_{noise_name}_{_room_name(room_m)}_seed{seed}.csv"
        if _done(path, views):
            return path
    return out / "runs" / f"{dataset}_{method}_{noise_name}_{_room_name(room_m)}_{model}_seed{seed}.csv"


def sampling_path(out: Path, dataset: str, method: str, sampling: str, seed: int) -> Path:
    return out / "runs" / f"{dataset}_{method}_{sampling}_plain_seed{seed}.csv"


def sampling_table(out: Path, committed: Path | None, dataset: str, methods, seeds, views: int) -> str:
    """Markdown (returned) and CSV (written) of the ``sampling`` runs: rounded (committed or run
    here) against exact."""
    at = sorted({views // 2, views})
    lines = ["| data set | method | sampling | runs | planned views that repeat the previous pose (mean) | "
             "runs with a repeat | runs whose last view repeats | "
             + " | ".join(f"unknown after {a}" for a in at) + " |",
             "|---|---|---|---|---|---|---|" + "---|" * len(at)]  # fmt: skip
    rows = ["dataset,method,sampling,runs,repeats_mean,runs_with_repeat,runs_last_repeats,"
            + ",".join(f"mean_after_{a},std_after_{a}" for a in at)]  # fmt: skip
    for method in methods:
        for sampling in ("rounded", "exact"):
            paths = [_sampling_source(out, committed, dataset, method, sampling, s, views) for s in seeds]
            paths = [p for p in paths if _done(p, views)]
            if not paths:
                continue
            repeats = [repeated_views(p)[: views - 1] for p in paths]
            counts = [int(r.sum()) for r in repeats]
            with_repeat = sum(c > 0 for c in counts)
            last = sum(bool(r[-1]) for r in repeats if r.size)
            values = {a: [_unknown_after(p, views, a) for p in paths] for a in at}
            lines.append(f"| {dataset} | {method} | {sampling} | {len(paths)} | {np.mean(counts):.1f} | "
                         f"{with_repeat}/{len(paths)} | {last}/{len(paths)} | "
                         + " | ".join(_mean_std(values[a]) for a in at) + " |")  # fmt: skip
            stats = ",".join(f"{np.mean(values[a]):.6f},{np.std(values[a]):.6f}" for a in at)
            rows.append(
                f"{dataset},{method},{sampling},{len(paths)},{np.mean(counts):.2f},{with_repeat},{last},{stats}"
            )
    name = f"sampling_table_{dataset}"
    (out / f"{name}.csv").write_text("\n".join(rows) + "\n")
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    return "\n".join(lines)


def _sampling_source(out, committed, dataset, method, sampling, seed, views) -> Path:
    """The run's CSV to read: the committed ``nbv evaluate`` run for ``rounded`` if it has the
    views (never written here), else ours."""
    if sampling == "rounded" and committed is not None:
        path = committed / f"{dataset}_{method}_seed{seed}.csv"
        if _done(path, views):
            return path
    return sampling_path(out, dataset, method, sampling, seed)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("part", choices=("returns", "sampling"))
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--dataset", default="3dt")
    parser.add_argument("--methods", nargs="+", default=["cnn_prob"])
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="default: the first 3 evaluation seeds")
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--noise", nargs="+", default=["kinect_v1"], help="returns: the noise presets")
    parser.add_argument("--rooms", nargs="+", default=["0.3", "none"], help="returns: wall margins [m] or none")
    parser.add_argument("--committed", type=Path, default=None,
                        help="the committed runs to read (never written): sampling, the rounded ones of nbv evaluate; "
                             "returns, the paper-model ones of the noise study")  # fmt: skip
    parser.add_argument("--summarise-only", action="store_true")
    args = parser.parse_args(argv)
    seeds = args.seeds or list(EVALUATION_SEEDS[:3])
    rooms = [None if r == "none" else float(r) for r in args.rooms]
    jobs: list[tuple[Path, Callable[[], None]]] = []
    if args.part == "returns":
        for method, noise_name, room_m, model, seed in product(args.methods, args.noise, rooms, ("paper", "returns"),
                                                               seeds):  # fmt: skip
            path = returns_path(args.out, args.dataset, method, noise_name, room_m, model, seed, args.committed,
                                args.views)  # fmt: skip
            if _done(path, args.views):
                continue
            path = returns_path(args.out, args.dataset, method, noise_name, room_m, model, seed)
            job = partial(run_returns, args.dataset, method, noise_name, room_m, model, seed, args.views, path)
            jobs.append((path, job))
    else:
        for method in args.methods:
            for sampling in ("rounded", "exact"):
                for seed in seeds:
                    if _done(_sampling_source(args.out, args.committed, args.dataset, method, sampling, seed,
                                              args.views), args.views):  # fmt: skip
                        continue
                    path = sampling_path(args.out, args.dataset, method, sampling, seed)
                    jobs.append((path, partial(run_sampling, args.dataset, method, sampling, seed, args.views, path)))
    pending = [(p, job) for p, job in jobs if not _done(p, args.views)]
    if not args.summarise_only:
        for path, job in tqdm(pending, desc=f"sensor gain study {args.part}", unit="run"):
            job()
            tqdm.write(f"{path.name}: done")
    if args.part == "returns":
        print(returns_table(args.out, args.dataset, args.methods, args.noise, rooms, seeds, args.views, args.committed))
    else:
        print(sampling_table(args.out, args.committed, args.dataset, args.methods, seeds, args.views))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
