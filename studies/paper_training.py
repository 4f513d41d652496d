"""The paper-scale training of the nine City-CNNs (issue #21) as one resumable background job:

    nbv study paper_training [--slice-min M] [--only 3dt:flat_city_cnn ...]

For each network, in :data:`ORDER` (cheapest step first), :func:`~nbv_prob_cnn.completion.train.train`
runs with the paper's epoch counts (:func:`~nbv_prob_cnn.commands.train.paper_epochs`), early
stopping after :data:`~nbv_prob_cnn.commands.train.CITY_PATIENCE` epochs without a lower
validation MSE, all 100 training environments, the data set's crops and batch size (as
``nbv train``), the cached training sets (generated on the
first call of each data set) and one torch thread (without a GPU, 3DU D-City-CNN,
:data:`GPU_ONLY`, is left out unless ``--only`` names it). Weights, checkpoints, loss curves and cards
go to :func:`runs_dir` (``<cache>/city_training``), never to the shipped weights: a network is
shipped by copying its files once it has finished and beats the shipped one.

With ``--slice-min M`` the networks take turns of about ``M`` minutes (a turn ends after the
first epoch past ``M``) so that all of them progress; without it each one runs to its end before
the next starts. Every call resumes from the ``.last.ckpt`` checkpoints, and a finished
network (``<stem>.done.json``) is skipped, so the same command continues the job after an
interruption or in a later session.

A machine without the checkpoints (a new session's machine keeps nothing outside git) starts each
network from its shipped weights when an earlier run of this job made them (:func:`shipped_run`:
the card's note is :data:`NOTE`): a warm start at the epoch of those weights, with their history
and a new optimizer state (``TrainConfig(warm_start=...)``); a shipped run that finished (its card has
test scores) counts as done.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from nbv_prob_cnn.completion.data import cache_root

#: Training order (cheapest step first, measured: docs/training.md): the 3DT networks (8× output
#: lattice), 3DU B- and Flat City-CNN, the 2D ones, and last 3DU D-City-CNN, whose 256³ output
#: makes its step about 20 times as long as 3DU Flat City-CNN's on one CPU thread.
ORDER: tuple[tuple[str, str], ...] = (
    ("3dt", "flat_city_cnn"),
    ("3dt", "d_city_cnn"),
    ("3dt", "b_city_cnn"),
    ("3du", "b_city_cnn"),
    ("3du", "flat_city_cnn"),
    ("2d", "flat_city_cnn"),
    ("2d", "d_city_cnn"),
    ("2d", "b_city_cnn"),
    ("3du", "d_city_cnn"),
)


def runs_dir() -> Path:
    """``<NBV_CACHE_DIR or ~/.cache/nbv_prob_cnn>/city_training``."""
    return cache_root() / "city_training"


def weights_path(dataset: str, method: str) -> Path:
    return runs_dir() / f"{dataset}_{method}.pt"


def done_path(dataset: str, method: str) -> Path:
    return runs_dir() / f"{dataset}_{method}.done.json"


#: Networks left out without a GPU unless ``--only`` names them: 3DU D-City-CNN's step took
#: 66–80 s and ~15 GB of memory on one CPU thread (its output is 256³).
GPU_ONLY: tuple[tuple[str, str], ...] = (("3du", "d_city_cnn"),)


#: The scores of a finished network in its ``done.json`` (besides ``epochs``): fields of a
#: ``TrainResult``, keys of a model card.
SCORE_KEYS = ("validation_mse", "validation_zero_mse", "validation_mean_mse", "validation_rho",
              "test_mse", "test_zero_mse", "test_mean_mse", "test_rho", "validation_cell_rho",
              "test_cell_rho")  # fmt: skip

#: The model-card note of this job's runs (how :func:`shipped_run` recognises their weights).
NOTE = "Paper-scale run of issue #21 (studies.paper_training, 1 torch thread)."


def shipped_run(dataset: str, method: str) -> tuple[Path, dict] | None:
    """``(path, card)`` of the shipped weights of ``dataset``/``method`` when a run of this job
    made them (the card's note starts with :data:`NOTE`), else None."""
    from nbv_prob_cnn.completion.inference import WeightsError, default_weights_path, read_weights

    path = default_weights_path(dataset, method)
    try:
        card = read_weights(path, dataset, method).get("card", {})
    except WeightsError:
        return None
    return (path, card) if str(card.get("note", "")).startswith(NOTE) else None


def _parse_only(items: list[str] | None) -> list[tuple[str, str]]:
    if not items:
        import torch

        if torch.cuda.is_available():
            return list(ORDER)
        print(f"no GPU: leaving out {', '.join(f'{d}:{m}' for d, m in GPU_ONLY)} (name it in --only to train it)")
        return [n for n in ORDER if n not in GPU_ONLY]
    chosen = []
    for item in items:
        dataset, _, method = item.partition(":")
        if (dataset, method) not in ORDER:
            raise SystemExit(f"--only: {item!r} is not one of {', '.join(f'{d}:{m}' for d, m in ORDER)}")
        chosen.append((dataset, method))
    return chosen


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slice-min", type=float, default=None, help="minutes per turn (default: run each to its end)")
    parser.add_argument(
        "--only", nargs="*", default=None, help="networks as dataset:method (default: all nine; eight without a GPU)"
    )
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args(argv)

    from nbv_prob_cnn.basics.datasets import dataset_spec
    from nbv_prob_cnn.commands.train import CITY_PATIENCE, paper_epochs
    from nbv_prob_cnn.completion.train import TrainConfig, train
    from nbv_prob_cnn.completion.train_files import side_paths

    networks = _parse_only(args.only)
    budget = None if args.slice_min is None else 60.0 * args.slice_min
    runs_dir().mkdir(parents=True, exist_ok=True)
    while True:
        pending = [(d, m) for d, m in networks if not done_path(d, m).is_file()]
        if not pending:
            print("all networks finished", flush=True)
            return 0
        for dataset, method in pending:
            warm_start = None
            resumable = side_paths(weights_path(dataset, method))["last"].is_file()
            shipped = None if resumable else shipped_run(dataset, method)
            if shipped is not None and "test_mse" in shipped[1]:
                print(f"== {dataset} {method}: the shipped weights come from a finished run of this job", flush=True)
                summary = {"epochs": shipped[1].get("epochs"), **{k: shipped[1].get(k) for k in SCORE_KEYS}}
                done_path(dataset, method).write_text(json.dumps(summary, indent=1) + "\n")
                continue
            if shipped is not None:
                warm_start = shipped[0]
                print(f"== {dataset} {method}: no checkpoint here; warm start from {warm_start} "
                      f"(epoch {shipped[1].get('best_epoch')})", flush=True)  # fmt: skip
            print(f"== {dataset} {method}: turn starts", flush=True)
            result = train(
                TrainConfig(
                    dataset,
                    paper_epochs(dataset, method),
                    weights_path(dataset, method),
                    crop=dataset_spec(dataset).training.crop,  # as `nbv train` (and the card's command)
                    method=method,
                    threads=args.threads,
                    patience=CITY_PATIENCE,
                    time_budget_s=budget,
                    note=NOTE,
                    warm_start=warm_start,
                )
            )
            state = "finished" if result.finished else "paused"
            print(
                f"== {dataset} {method}: {state} after {result.epochs_done} epochs, best validation MSE "
                f"{result.validation_mse:.6f}, validation rho {result.validation_rho:.3f}, "
                f"cell rho {result.validation_cell_rho:.3f}",
                flush=True,
            )
            if result.finished:
                summary = {"epochs": result.epochs_done, **{k: getattr(result, k) for k in SCORE_KEYS}}
                done_path(dataset, method).write_text(json.dumps(summary, indent=1) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
