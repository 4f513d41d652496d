"""``nbv train``: train a network of a data set: the completion CNN (docs/method.md#completion-cnn) or a City-CNN
baseline (docs/method.md#methods)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from nbv_prob_cnn.basics.datasets import DATASET_SPECS, LR_SCHEDULES, SPEC_LEARNING_RATE
from nbv_prob_cnn.completion.tasks import TRAINABLE_MODELS

#: Default early-stopping patience of the City-CNNs (epochs without a lower validation MSE).
CITY_PATIENCE = 10

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
    parser.add_argument(
        "--epochs",
        type=_positive,
        default=None,
        help=f"total epochs (default cnn_prob: {_defaults('epochs')}; City-CNNs: the paper's, {_city_epochs_text()})",
    )
    parser.add_argument(
        "--patience",
        type=_positive,
        default=None,
        help=f"stop when the validation MSE has not improved for N epochs (default: {CITY_PATIENCE} for "
        "City-CNNs, none for cnn_prob)",
    )
    parser.add_argument(
        "--no-cache",
        action="store_true",
        help="City-CNNs: ray-cast each step's targets instead of reading the cached training set",
    )
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
        help=f"Adam's learning rate (default: {_defaults('lr')}; the paper's {SPEC_LEARNING_RATE:g})",
    )
    parser.add_argument(
        "--lr-schedule",
        choices=LR_SCHEDULES,
        default=None,
        help=f"constant, or cosine decay from --lr over the run's epochs (default: {_defaults('lr_schedule')})",
    )
    parser.add_argument(
        "--workers",
        type=_positive,
        default=1,
        help="processes generating missing training data; with --ray: Ray Train workers (data-parallel)",
    )
    parser.add_argument(
        "--ray", action="store_true", help="train data-parallel with Ray Train (TorchTrainer, DDP: gloo/NCCL)"
    )
    parser.add_argument(
        "--address", default=None, help="with --ray: cluster address HOST:PORT (default: a local Ray instance)"
    )
    parser.add_argument("--threads", type=_positive, default=None, help="torch threads (default: min(2, cores))")
    parser.add_argument("--device", default=None, help="torch device (default: cuda if available, else cpu)")
    parser.add_argument("--no-resume", action="store_true", help="start over instead of resuming <out>.last.ckpt")
    parser.add_argument("--note", default="", help="a sentence for the model card (e.g. why the run was short)")


def paper_epochs(dataset: str, method: str) -> int:
    """Default epochs: ``cnn_prob`` keeps the data set's (:class:`TrainingDefaults`); the
    City-CNNs the paper's, up to 120, and 20 for B-City-CNN on 3DU and 3DT (paper §V)."""
    if method == "cnn_prob":
        return DATASET_SPECS[dataset].training.epochs
    return 20 if method == "b_city_cnn" and DATASET_SPECS[dataset].dims == 3 else 120


def _city_epochs_text() -> str:
    return "120, b_city_cnn on 3du/3dt 20"


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.completion.train import TrainConfig, train

    training = DATASET_SPECS[args.dataset].training
    patience = args.patience if args.patience is not None else (None if args.method == "cnn_prob" else CITY_PATIENCE)
    if args.address and not args.ray:
        raise SystemExit("--address needs --ray")
    config = TrainConfig(
        args.dataset,
        args.epochs or paper_epochs(args.dataset, args.method),
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
        cache=not args.no_cache,
        patience=patience,
    )
    if args.ray:
        from nbv_prob_cnn.completion.ray_train import train_with_ray

        result = train_with_ray(config, address=args.address)
    else:
        result = train(config)
    ece = f", test ECE {result.ece:.4f}" if result.ece is not None else ""
    print(
        f"weights: {result.weights} (best validation MSE {result.validation_mse:.5f}, "
        f"test MSE {result.test_mse:.5f}{ece}, {result.epochs_done} epochs; all-zero output: "
        f"validation MSE {result.validation_zero_mse:.5f}, test MSE {result.test_zero_mse:.5f})"
    )
    if args.method != "cnn_prob":
        print(
            f"mean-target output: validation MSE {result.validation_mean_mse:.5f}, test MSE "
            f"{result.test_mean_mse:.5f}; Spearman rho: validation {result.validation_rho:.3f}, "
            f"test {result.test_rho:.3f}; cell rho: validation {result.validation_cell_rho:.3f}, "
            f"test {result.test_cell_rho:.3f}"
        )
    print(f"history: {result.history_csv}, plot: {result.plot}, card: {result.card}")
    return 0
