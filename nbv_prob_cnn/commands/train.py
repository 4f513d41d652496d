"""``nbv train``: train a network of a data set: the completion CNN (SPEC §3) or a City-CNN
baseline (SPEC §6)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from nbv_prob_cnn.basics.datasets import DATASET_SPECS, LR_SCHEDULES, SPEC_LEARNING_RATE
from nbv_prob_cnn.completion.tasks import TRAINABLE_MODELS

NAME = "train"
HELP = "Train a network (completion CNN or City-CNN) of a data set: weights, loss CSV/plot, model card."


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text}")
    return value


def _positive_float(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def _defaults(field: str) -> str:
    return ", ".join(f"{name} {getattr(spec.training, field)}" for name, spec in DATASET_SPECS.items())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", required=True, choices=sorted(DATASET_SPECS), help="data set to train on")
    parser.add_argument(
        "--method", default="cnn_prob", choices=TRAINABLE_MODELS, help="network to train (default: cnn_prob)"
    )
    parser.add_argument("--epochs", type=_positive, default=None, help=f"total epochs (default: {_defaults('epochs')})")
    parser.add_argument(
        "--out", type=Path, default=None, help="weights file (default: nbv_prob_cnn/weights/<dataset>_<method>.pt)"
    )
    parser.add_argument("--train-envs", type=_positive, default=None, help="use the first N training environments")
    parser.add_argument("--val-envs", type=_positive, default=None, help="use the first N validation environments")
    parser.add_argument("--test-envs", type=_positive, default=None, help="use the first N test environments")
    parser.add_argument(
        "--crop",
        type=_positive,
        default=None,
        help=f"random training crop edge (default: {_defaults('crop')})",
    )
    parser.add_argument(
        "--test-crop",
        type=_positive,
        default=None,
        help=f"fixed validation/test crop edge (default: {_defaults('test_crop')}; None = whole grids)",
    )
    parser.add_argument(
        "--batch-size", type=_positive, default=None, help=f"grids per step (default: {_defaults('batch_size')})"
    )
    parser.add_argument(
        "--lr",
        type=_positive_float,
        default=None,
        help=f"Adam's learning rate (default: {_defaults('lr')}; SPEC {SPEC_LEARNING_RATE:g})",
    )
    parser.add_argument(
        "--lr-schedule",
        choices=LR_SCHEDULES,
        default=None,
        help=f"constant, or cosine decay from --lr over the run's epochs (default: {_defaults('lr_schedule')})",
    )
    parser.add_argument("--workers", type=_positive, default=1, help="processes generating missing training data")
    parser.add_argument("--threads", type=_positive, default=None, help="torch threads (default: min(2, cores))")
    parser.add_argument("--device", default=None, help="torch device (default: cuda if available, else cpu)")
    parser.add_argument("--no-resume", action="store_true", help="start over instead of resuming <out>.last.ckpt")
    parser.add_argument("--note", default="", help="a sentence for the model card (e.g. why the run was short)")


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.completion.train import train

    training = DATASET_SPECS[args.dataset].training
    result = train(
        args.dataset,
        args.epochs or training.epochs,
        args.out,
        n_train_envs=args.train_envs,
        n_test_envs=args.test_envs,
        crop=args.crop if args.crop is not None else training.crop,
        resume=not args.no_resume,
        batch_size=args.batch_size,
        test_crop=args.test_crop if args.test_crop is not None else "default",
        workers=args.workers,
        threads=args.threads,
        device=args.device,
        method=args.method,
        n_val_envs=args.val_envs,
        note=args.note,
        lr=args.lr,
        lr_schedule=args.lr_schedule,
    )
    ece = f", test ECE {result.ece:.4f}" if result.ece is not None else ""
    print(
        f"weights: {result.weights} (best validation MSE {result.validation_mse:.5f}, "
        f"test MSE {result.test_mse:.5f}{ece}, {result.epochs_done} epochs; all-zero output: "
        f"validation MSE {result.validation_zero_mse:.5f}, test MSE {result.test_zero_mse:.5f})"
    )
    print(f"history: {result.history_csv}, plot: {result.plot}, card: {result.card}")
    return 0
