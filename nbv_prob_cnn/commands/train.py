"""``nbv train``: train the completion CNN of a data set (SPEC §3)."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "train"
HELP = "Train the completion CNN of a data set (writes weights, loss CSV/plot and a model card)."


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", required=True, choices=["2d", "3du", "3dt"], help="data set to train on")
    parser.add_argument("--epochs", type=_positive, default=None, help="total epochs (default: 2d 120, 3du 15, 3dt 25)")
    parser.add_argument(
        "--out", type=Path, default=None, help="weights file (default: the shipped nbv_prob_cnn/weights/<dataset>.pt)"
    )
    parser.add_argument("--train-envs", type=_positive, default=None, help="use the first N training environments")
    parser.add_argument("--test-envs", type=_positive, default=None, help="use the first N test environments")
    parser.add_argument(
        "--crop",
        type=_positive,
        default=None,
        help="random training crop edge in cells (default: 2d 256, 3du none, 3dt 64)",
    )
    parser.add_argument(
        "--batch-size", type=_positive, default=None, help="grids per step (default: 2d 8, 3du 4, 3dt 4)"
    )
    parser.add_argument("--workers", type=_positive, default=1, help="processes generating missing training data")
    parser.add_argument("--threads", type=_positive, default=None, help="torch threads (default: min(2, cores))")
    parser.add_argument("--device", default=None, help="torch device (default: cuda if available, else cpu)")
    parser.add_argument("--no-resume", action="store_true", help="start over instead of resuming <out>.last.ckpt")


#: Default epochs per data set, sized for about an hour on 2 CPU cores (see the model docs).
DEFAULT_EPOCHS = {"2d": 120, "3du": 15, "3dt": 25}
#: Default training crop per data set.
DEFAULT_CROP = {"2d": 256, "3du": None, "3dt": 64}


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.completion.inference import default_weights_path
    from nbv_prob_cnn.completion.train import train

    epochs = args.epochs or DEFAULT_EPOCHS[args.dataset]
    out = args.out or default_weights_path(args.dataset)
    crop = args.crop if args.crop is not None else DEFAULT_CROP[args.dataset]
    result = train(
        args.dataset,
        epochs,
        out,
        n_train_envs=args.train_envs,
        n_test_envs=args.test_envs,
        crop=crop,
        resume=not args.no_resume,
        batch_size=args.batch_size,
        workers=args.workers,
        threads=args.threads,
        device=args.device,
    )
    print(f"weights: {result.weights} (best test MSE {result.best_test_loss:.5f}, {result.epochs_done} epochs)")
    print(f"history: {result.history_csv}, plot: {result.plot}, card: {result.card}")
    return 0
