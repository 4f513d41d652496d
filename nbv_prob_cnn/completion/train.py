"""The one training loop of the project's networks (docs/method.md: completion CNN, methods): the completion CNN
(``cnn_prob``) and the City-CNN baselines (``flat_city_cnn``, ``b_city_cnn``, ``d_city_cnn``),
Adam (lr 1e-3 by default, the paper's), MSE loss (:mod:`~nbv_prob_cnn.completion.tasks` says what each one
learns). The learning rate is constant by default; ``lr_schedule="cosine"`` decays it per epoch
(:func:`learning_rate`), for runs that become unstable at a constant rate.

Environment split (:mod:`nbv_prob_cnn.basics.datasets`): training, validation, test. After every epoch
the validation loss is measured; the weights kept are those of the epoch with the lowest
validation loss (the test split never chooses anything). When training ends, the kept weights
are scored once on the test split: test MSE and, for the completion CNN, the calibration of its
probabilities on unknown cells (reliability table, ECE, reliability plot).

For weights ``out = <dir>/<stem>.pt`` training writes, next to it:

* ``<stem>.pt``: the best-validation weights so far, with their model card;
* ``<stem>.last.ckpt``: the last epoch's model, optimizer, history and the best epoch's weights (resumable);
* ``<stem>.csv``: per-epoch train/validation MSE and wall time; ``<stem>.png``: their plot;
* ``<stem>.calibration.png`` (completion CNN): reliability plot on the test split;
* ``<stem>.md``: the model card (data set, seeds, versions, epochs, time, MSEs, ECE, command).

An epoch visits every training environment once under every augmentation rotation, in a
shuffled order (one random crop each when ``crop`` is set; City-CNN crops start on the output
lattice and their targets are ray-cast through the whole rotated grid). Validation and test
items are unrotated, on a fixed crop per environment when ``test_crop`` is set.

A run's settings are one :class:`TrainConfig`. Beside this loop: the examples
(:mod:`~nbv_prob_cnn.completion.train_sources`), a step and the scores
(:mod:`~nbv_prob_cnn.completion.train_steps`), the files a run writes and reads back
(:mod:`~nbv_prob_cnn.completion.train_files`) and the model card (:mod:`~nbv_prob_cnn.completion.train_card`).
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from nbv_prob_cnn.basics.datasets import LR_SCHEDULES, SPEC_LEARNING_RATE, DatasetSpec, dataset_spec
from nbv_prob_cnn.completion.calibration import save_reliability_plot
from nbv_prob_cnn.completion.city_cache import CITY_CACHE_VERSION, CachedCityExamples, CacheLayout, ensure_chunks
from nbv_prob_cnn.completion.city_scores import CityScores, mean_target_per_channel, score_city
from nbv_prob_cnn.completion.data import DATA_VERSION, load_samples, rotations
from nbv_prob_cnn.completion.inference import clear_model_cache, default_weights_path, resolve_device, save_weights
from nbv_prob_cnn.completion.model import CompletionNet
from nbv_prob_cnn.completion.tasks import TrainingTask
from nbv_prob_cnn.completion.train_card import CardFacts, model_card, optimizer_text, retrain_args, write_card_file
from nbv_prob_cnn.completion.train_files import (
    RunState,
    load_checkpoint,
    save_checkpoint,
    side_paths,
    warm_start_state,
    write_history,
)
from nbv_prob_cnn.completion.train_sources import CachedSource, SampleSource
from nbv_prob_cnn.completion.train_steps import (
    calibration_of,
    evaluate,
    same_shape_groups,
    start_at_mean_target,
    train_step,
    zero_output_mse,
)


@dataclass(frozen=True)
class TrainConfig:
    """What to train and how (``nbv train``'s options).

    Attributes:
        dataset: ``2d``, ``3du`` or ``3dt``.
        epochs: total number of epochs (a resumed run continues up to this number).
        out: weights file (default ``nbv_prob_cnn/weights/<dataset>_<method>.pt``); the side
            files of :func:`~nbv_prob_cnn.completion.train_files.side_paths` go next to it.
        n_train_envs, n_val_envs, n_test_envs: use only the first N environments of each split.
        crop: random training crop edge (cells, per axis); None: whole grids.
        resume: continue from ``<stem>.last.ckpt`` when it exists.
        batch_size: grids per step (default: the data set's, :mod:`nbv_prob_cnn.basics.datasets`).
        test_crop: fixed validation/test crop edge; ``"default"``: the data set's.
        workers: processes generating missing training data (Ray Train: workers).
        threads: torch intra-op threads (default :func:`default_threads`).
        device: default CUDA when available, else CPU.
        seed: seed of initialisation, shuffling and crops.
        progress: show tqdm progress bars.
        train_seeds, validation_seeds, test_seeds: override the environment split (default:
            the data set's, :mod:`nbv_prob_cnn.basics.datasets`).
        method: ``cnn_prob`` (completion CNN) or a City-CNN variant.
        first_channels: width of the first conv block (default 8 in 2D, 16 in 3D).
        backend: ray-casting backend of the City-CNN targets.
        note: a sentence for the model card (e.g. why a run was short).
        lr: Adam's (initial) learning rate (default: the data set's; the paper's 1e-3 except on 3DT).
        lr_schedule: ``constant`` or ``cosine`` (:func:`learning_rate`; default: the data set's).
        cache: City-CNNs read their examples from the cached training set
            (:mod:`~nbv_prob_cnn.completion.city_cache`, generated first where missing) instead of
            ray-casting targets in every step. Ignored for ``cnn_prob``.
        patience: stop early once the validation MSE has not improved for this many epochs
            (None: run all ``epochs``).
        time_budget_s: end the call after the first epoch that ends past this many seconds
            (checkpoint written; no test scoring; ``finished`` is False): to share a CPU between
            several runs that each resume later.
        warm_start: a weights file of the same architecture (e.g. the shipped weights of an
            earlier run of this command, with its loss-curve CSV beside it) to start from when
            there is no checkpoint to resume: the weights, and the history up to their epoch, are
            taken over; the optimizer state starts anew
            (:func:`~nbv_prob_cnn.completion.train_files.warm_start_state`).

    Raises:
        ValueError: fewer than one epoch, or a patience below one epoch.
    """

    dataset: str
    epochs: int
    out: str | Path | None = None
    n_train_envs: int | None = None
    n_test_envs: int | None = None
    crop: int | None = None
    resume: bool = True
    batch_size: int | None = None
    test_crop: int | None | str = "default"
    workers: int = 1
    threads: int | None = None
    device: str | torch.device | None = None
    seed: int = 0
    progress: bool = True
    train_seeds: Sequence[int] | None = None
    test_seeds: Sequence[int] | None = None
    method: str = "cnn_prob"
    n_val_envs: int | None = None
    validation_seeds: Sequence[int] | None = None
    first_channels: int | None = None
    backend: str = "auto"
    note: str = ""
    lr: float | None = None
    lr_schedule: str | None = None
    cache: bool = True
    patience: int | None = None
    time_budget_s: float | None = None
    warm_start: str | Path | None = None

    def __post_init__(self) -> None:
        if self.epochs < 1:
            raise ValueError(f"epochs: expected >= 1, got {self.epochs}")
        if self.patience is not None and self.patience < 1:
            raise ValueError(f"patience: expected >= 1 epochs, got {self.patience}")


@dataclass
class TrainResult:
    """What a training run produced."""

    weights: Path
    last_checkpoint: Path
    history_csv: Path
    plot: Path
    card: Path
    validation_mse: float
    test_mse: float
    ece: float | None
    epochs_done: int
    validation_zero_mse: float = float("nan")
    test_zero_mse: float = float("nan")
    validation_mean_mse: float = float("nan")  # City-CNNs: MSE of predicting the mean training target
    test_mean_mse: float = float("nan")
    validation_rho: float = float("nan")  # City-CNNs: Spearman ρ, prediction vs target (city_scores)
    test_rho: float = float("nan")
    finished: bool = True  # False: a time budget ended the call before the last epoch
    validation_cell_rho: float = float("nan")  # City-CNNs: ρ of each cell's best view gain, across cells
    test_cell_rho: float = float("nan")

    @classmethod
    def for_weights(
        cls, out: Path, validation_mse: float, test_mse: float, ece: float | None, epochs_done: int, **scores: Any
    ) -> TrainResult:
        """The result of a run whose weights file is ``out`` (side files by
        :func:`~nbv_prob_cnn.completion.train_files.side_paths`); ``scores``: the other fields."""
        paths = side_paths(out)
        return cls(out, paths["last"], paths["csv"], paths["png"], paths["card"], validation_mse, test_mse, ece,
                   epochs_done, **scores)  # fmt: skip


def learning_rate(base: float, schedule: str, epoch: int, epochs: int) -> float:
    """Learning rate of 0-based ``epoch`` of a run of ``epochs`` epochs.

    ``constant``: ``base`` throughout. ``cosine``: ``base · (1 + cos(π · epoch / epochs)) / 2``,
    from ``base`` at the first epoch down to near 0 at the last (half a cosine period, no restart).
    """
    if schedule not in LR_SCHEDULES:
        raise ValueError(f"lr schedule: expected one of {', '.join(LR_SCHEDULES)}, got {schedule!r}")
    if not (math.isfinite(base) and base > 0):
        raise ValueError(f"lr: expected a positive finite number, got {base}")
    if schedule == "constant":
        return base
    return base * 0.5 * (1.0 + math.cos(math.pi * epoch / epochs))


def default_threads() -> int:
    """Intra-op threads: at most 2 (the reference machine has 2 shared cores)."""
    return max(1, min(2, os.cpu_count() or 1))


@dataclass
class _Plan:
    """A run's settings with the data set's defaults filled in: seeds split, paths, device, the
    checkpoint's run configuration and the command that reproduces the run."""

    config: TrainConfig
    spec: DatasetSpec
    task: TrainingTask
    out: Path
    lr: float
    lr_schedule: str
    batch_size: int
    crop_edge: int | None
    train_seeds: list[int]
    val_seeds: list[int]
    test_seeds: list[int]
    device: torch.device
    rank: int
    world: int

    @property
    def paths(self) -> dict[str, Path]:
        return side_paths(self.out)

    @property
    def cached(self) -> bool:
        """City-CNN examples from the cached training set."""
        return self.config.cache and not self.task.is_completion

    @property
    def progress(self) -> bool:
        return self.config.progress and self.rank == 0

    @property
    def command(self) -> str:
        c = self.config
        return retrain_args(
            c.dataset, c.epochs, self.out, c.n_train_envs, c.n_test_envs, c.crop, self.batch_size, method=c.method,
            n_val_envs=c.n_val_envs, test_crop=self.crop_edge, lr=self.lr, lr_schedule=self.lr_schedule,
            patience=c.patience,
        )  # fmt: skip

    def run_config(self) -> dict:
        """The settings a checkpoint must share to be resumed (keys absent at their defaults, so that
        older checkpoints still resume)."""
        c = self.config
        run_config: dict[str, Any] = {
            "dataset": c.dataset, "method": c.method, "train_seeds": self.train_seeds,
            "validation_seeds": self.val_seeds, "test_seeds": self.test_seeds, "crop": c.crop,
            "test_crop": self.crop_edge, "batch_size": self.batch_size, "seed": c.seed, "data_version": DATA_VERSION,
        }  # fmt: skip
        if self.cached:
            run_config["examples"] = f"cached v{CITY_CACHE_VERSION}"
        if self.lr != SPEC_LEARNING_RATE or self.lr_schedule != "constant":
            run_config["optimizer"] = optimizer_text(self.lr, self.lr_schedule)
            if self.lr_schedule == "cosine":  # the schedule depends on the run's length
                run_config["epochs"] = c.epochs
        return run_config


def _plan(config: TrainConfig) -> _Plan:
    """Check ``config``, fill in the data set's defaults, create the output folder and set torch's threads."""
    spec = dataset_spec(config.dataset)
    task = TrainingTask(config.method, spec, config.backend)
    lr = spec.training.lr if config.lr is None else config.lr
    lr_schedule = spec.training.lr_schedule if config.lr_schedule is None else config.lr_schedule
    learning_rate(lr, lr_schedule, 0, config.epochs)  # validates both
    out = (
        Path(config.out).expanduser() if config.out is not None else default_weights_path(config.dataset, config.method)
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    test_crop = config.test_crop
    crop_edge = spec.training.test_crop if test_crop == "default" else None if test_crop is None else int(test_crop)
    train_seeds = list(spec.train_seeds if config.train_seeds is None else config.train_seeds)[: config.n_train_envs]
    val_seeds = list(spec.validation_seeds if config.validation_seeds is None else config.validation_seeds)[
        : config.n_val_envs
    ]
    test_seeds = list(spec.test_seeds if config.test_seeds is None else config.test_seeds)[: config.n_test_envs]
    if not train_seeds or not val_seeds or not test_seeds:
        raise ValueError("train/val/test envs: need at least one training, validation and test environment")
    if set(train_seeds) & set(test_seeds) or set(train_seeds) & set(val_seeds) or set(val_seeds) & set(test_seeds):
        raise ValueError("seeds: training, validation and test environments overlap")
    torch.set_num_threads(config.threads or default_threads())
    device = resolve_device(config.device)
    rank, world = _rank_and_world()
    if world > 1 and config.time_budget_s is not None:
        raise ValueError("time_budget_s: not available in data-parallel training (the workers must stop together)")
    return _Plan(config, spec, task, out, lr, lr_schedule, config.batch_size or spec.training.batch_size, crop_edge,
                 train_seeds, val_seeds, test_seeds, device, rank, world)  # fmt: skip


def _training_source(plan: _Plan) -> CachedSource | SampleSource:
    """The run's examples: the cached City-CNN training set (its missing chunks generated first;
    data-parallel workers each generate their share) or the simulated samples."""
    c = plan.config
    if plan.cached:
        layout = CacheLayout.for_training(c.dataset, c.crop, plan.crop_edge)
        chunk_seeds = {"train": plan.train_seeds, "eval": plan.val_seeds + plan.test_seeds}
        if plan.world > 1:  # each worker generates its share, then every one checks it sees them all
            ensure_chunks(layout, chunk_seeds, c.backend, plan.progress, share=(plan.rank, plan.world))
            torch.distributed.barrier()
        ensure_chunks(layout, chunk_seeds, c.backend, plan.progress)
        examples = CachedCityExamples(c.method, layout, plan.train_seeds, plan.val_seeds, plan.test_seeds, c.crop)
        return CachedSource(examples)
    n_envs = len(plan.train_seeds) + len(plan.val_seeds) + len(plan.test_seeds)
    with tqdm(total=n_envs, desc=f"training data {c.dataset}", disable=not plan.progress) as bar:
        train_samples = load_samples(c.dataset, plan.train_seeds, c.workers, bar.update)
        val_samples = load_samples(c.dataset, plan.val_seeds, c.workers, bar.update)
        test_samples = load_samples(c.dataset, plan.test_seeds, c.workers, bar.update)
    return SampleSource(plan.task, train_samples, val_samples, test_samples, c.crop, plan.crop_edge)


class _TrainingRun:
    """One call of :func:`train`: the plan, the examples, where the run stands and its card."""

    def __init__(self, plan: _Plan) -> None:
        c = self.config = plan.config
        self.plan = plan
        self.run_config = plan.run_config()
        self.rots = rotations(c.dataset)
        self.source = _training_source(plan)
        self.val_examples = self.source.validation()
        if plan.task.is_completion:
            self.mean_target = np.zeros(1, np.float32)
            zero = {"validation_zero_mse": zero_output_mse(self.val_examples)}
        else:
            self.mean_target = mean_target_per_channel(self.source.mean_target_examples())
            zero = {}
        torch.manual_seed(c.seed)
        model = plan.task.build(c.first_channels).to(plan.device)
        if model.head == "sigmoid" and model.final.bias is not None:  # City-CNN gain heads (a resume overwrites it)
            start_at_mean_target(model, self.source.first_examples(8, np.random.default_rng([c.seed, 0x1B1A5])))
        self.state = RunState(model, torch.optim.Adam(model.parameters(), lr=plan.lr))
        note = c.note
        warm = False  # started from warm_start's weights (no checkpoint to resume)
        if c.resume and plan.paths["last"].is_file():
            load_checkpoint(plan.paths["last"], self.state, self.run_config)
        elif c.warm_start is not None:
            warm = True
            self.state.history, self.state.best, self.state.elapsed = warm_start_state(Path(c.warm_start), model)
            self.state.keep_weights()
            note = (note + " " if note else "") + (
                f"Warm start at epoch {self.state.best['epoch']} from {Path(c.warm_start).name} (its weights and "
                "history; the optimizer state started anew)."
            )
        self.net = model if plan.world == 1 else torch.nn.parallel.DistributedDataParallel(model)
        card_config = {**self.run_config, **({"patience": c.patience} if c.patience is not None else {})}
        self.facts = CardFacts(c.dataset, c.method, model, card_config, self.source.generator_versions(),
                               [r.name for r in self.rots], plan.device, plan.command, note, zero)  # fmt: skip
        if warm and plan.rank == 0:  # the output holds the starting weights until an epoch beats them
            save_weights(model, plan.out, c.dataset, self.card(), name=c.method)

    def card(self) -> dict:
        return model_card(self.facts, self.state.history, self.state.best, self.state.elapsed)

    def stopped_early(self) -> bool:
        return _stopped_early(self.state.history, self.state.best, self.config.patience)

    def train_epochs(self) -> bool:
        """Train up to the configured epochs (or early stopping); False when the time budget ended
        the call first."""
        c, plan = self.config, self.plan
        call_start = time.perf_counter()
        steps_per_epoch = -(-len(plan.train_seeds) * len(self.rots) // plan.batch_size)
        start_epoch = len(self.state.history)
        bar = tqdm(total=steps_per_epoch * c.epochs, initial=steps_per_epoch * min(start_epoch, c.epochs),
                   desc=f"train {c.dataset} {c.method}", unit="step", disable=not plan.progress)  # fmt: skip
        for epoch in range(start_epoch, c.epochs):
            if self.stopped_early():
                break
            t0 = time.perf_counter()
            epoch_lr = learning_rate(plan.lr, plan.lr_schedule, epoch, c.epochs)
            for group_params in self.state.optimizer.param_groups:
                group_params["lr"] = epoch_lr
            train_mse = self._train_epoch(epoch, bar)
            val_mse, val_scores = self._validate()
            self._record_epoch(epoch, train_mse, epoch_lr, time.perf_counter() - t0, val_mse, val_scores)
            bar.set_postfix(epoch=epoch + 1, loss=f"{train_mse:.4f}", val=_fmt(self.state.history))
            out_of_time = c.time_budget_s is not None and time.perf_counter() - call_start > c.time_budget_s
            if out_of_time and epoch + 1 < c.epochs and not self.stopped_early():
                bar.close()
                return False
        bar.close()
        return True

    def _train_epoch(self, epoch: int, bar: tqdm) -> float:
        """One pass over every training item under every rotation, in a shuffled order; the mean train MSE."""
        plan, rank, world = self.plan, self.plan.rank, self.plan.world
        items_per_epoch = len(plan.train_seeds) * len(self.rots)
        rng = np.random.default_rng([self.config.seed, epoch])
        order = rng.permutation(items_per_epoch)
        loss_sum, n_items = 0.0, 0
        for start in range(0, items_per_epoch, plan.batch_size):
            items = [int(item) for item in order[start : start + plan.batch_size]]
            # data-parallel: worker r builds items r, r + world, ...; every worker draws every
            # item's random crop so that all follow the single-process random sequence
            mine = [k % world == rank for k in range(len(items))] if len(items) >= world else [False] * len(items)
            examples = []
            for item, own in zip(items, mine, strict=True):
                example = self.source.train_example(item // len(self.rots), item % len(self.rots), rng, build=own)
                if example is not None:
                    examples.append(example)
            groups = same_shape_groups(examples)
            if world > 1 and len(groups) > 1:
                raise ValueError("data-parallel training needs equal-shape examples in a step: set a crop")
            for group in groups:
                loss = train_step(self.net, self.state.optimizer, group, plan.device)
                loss_sum += loss * len(group)
                n_items += len(group)
            bar.update(1)
            bar.set_postfix(epoch=epoch + 1, loss=f"{loss_sum / max(n_items, 1):.4f}", val=_fmt(self.state.history))
        if world > 1:
            loss_sum, n_items = _sum_over_workers(loss_sum, n_items)
        return loss_sum / max(n_items, 1)

    def _validate(self) -> tuple[float, CityScores | None]:
        """The validation MSE (rank 0's decides for all workers: early stopping must agree) and, for
        the City-CNNs, their scores (whose baselines go to the card)."""
        plan, model = self.plan, self.state.model
        if plan.task.is_completion:
            val_mse, val_scores = evaluate(model, self.val_examples, plan.device, plan.batch_size), None
        else:
            val_scores = score_city(model, self.config.method, plan.spec, self.val_examples, self.mean_target,
                                    plan.device, plan.batch_size)  # fmt: skip
            val_mse = val_scores.mse
            self.facts.zero.update(_baselines("validation", val_scores))
        return (_from_rank0(val_mse) if plan.world > 1 else val_mse), val_scores

    def _record_epoch(self, epoch: int, train_mse: float, epoch_lr: float, epoch_s: float, val_mse: float,
                      val_scores: CityScores | None) -> None:  # fmt: skip
        """Append the epoch to the history; keep its weights if they are the best so far; rank 0
        writes the weights, the history, the checkpoint and the card."""
        plan, state, c = self.plan, self.state, self.config
        state.elapsed += epoch_s
        cells = {} if val_scores is None else {"validation_rho": round(val_scores.rho, 5),
                                               "validation_cell_rho": round(val_scores.cell_rho, 5)}  # fmt: skip
        state.history.append({"epoch": epoch + 1, "train_mse": train_mse, "validation_mse": val_mse,
                              "epoch_seconds": round(epoch_s, 2), "elapsed_seconds": round(state.elapsed, 2),
                              "lr": epoch_lr, **cells})  # fmt: skip
        if val_mse < state.best["validation_mse"]:
            state.best = {"validation_mse": val_mse, "epoch": epoch + 1}
            if val_scores is not None:
                state.best["validation_rho"] = val_scores.rho
                state.best["validation_cell_rho"] = val_scores.cell_rho
            state.keep_weights()
            if plan.rank == 0:
                save_weights(state.model, plan.out, c.dataset, self.card(), name=c.method)
                clear_model_cache()
        if plan.rank == 0:
            write_history(state.history, plan.paths["csv"], plan.paths["png"], f"{c.method}, {c.dataset}")
            save_checkpoint(plan.paths["last"], state, self.run_config)
            write_card_file(plan.paths, self.card())

    def kept_model(self) -> CompletionNet:
        """The kept (best-validation) weights: from the run's own state, not from ``out``, which a
        resumed run may have found overwritten by another run."""
        if self.state.best_state is not None:
            kept = copy.deepcopy(self.state.model)
            kept.load_state_dict(self.state.best_state)
            kept.eval()
            return kept
        from nbv_prob_cnn.completion.inference import load_model  # a checkpoint without its best weights

        return load_model(self.plan.out, self.config.dataset, self.plan.device, model_name=self.config.method)

    def score_kept(self) -> TrainResult:
        """Score the kept weights once on the test split (City-CNNs: on validation too), write them
        with the final card (the completion CNN: and its calibration plot)."""
        plan, c, state, zero = self.plan, self.config, self.state, self.facts.zero
        kept = self.kept_model()
        test_examples = self.source.test()
        best = dict(state.best)
        if plan.task.is_completion:
            test_mse = evaluate(kept, test_examples, plan.device, plan.batch_size)
            zero["test_zero_mse"] = zero_output_mse(test_examples)
            assert isinstance(self.source, SampleSource)
            table = calibration_of(kept, plan.task, self.source.test_samples, plan.crop_edge, plan.device,
                                   plan.batch_size)  # fmt: skip
        else:
            kept_val, test_scores = (
                score_city(kept, c.method, plan.spec, examples, self.mean_target, plan.device, plan.batch_size)
                for examples in (self.val_examples, test_examples)
            )
            test_mse = test_scores.mse
            zero.update({**_baselines("validation", kept_val), **_baselines("test", test_scores)})
            best.update(validation_rho=kept_val.rho, test_rho=test_scores.rho, validation_cell_rho=kept_val.cell_rho,
                        test_cell_rho=test_scores.cell_rho)  # fmt: skip
        best["test_mse"] = test_mse
        if self.stopped_early() and len(state.history) < c.epochs:
            best["stopped"] = (f"early at epoch {len(state.history)} of {c.epochs}: no lower validation MSE for "
                               f"{c.patience} epochs")  # fmt: skip
        if plan.task.is_completion:
            save_reliability_plot(table, plan.paths["calibration"], f"{c.dataset}: calibration on the test split")
            best["ece"] = table.ece
        state.best = best
        card = self.card()
        save_weights(kept, plan.out, c.dataset, card, name=c.method)
        clear_model_cache()
        write_card_file(plan.paths, card)
        return TrainResult.for_weights(
            plan.out, float(best["validation_mse"]), float(test_mse), best.get("ece"), len(state.history),
            validation_zero_mse=zero["validation_zero_mse"], test_zero_mse=zero["test_zero_mse"],
            validation_mean_mse=zero.get("validation_mean_mse", float("nan")),
            test_mean_mse=zero.get("test_mean_mse", float("nan")), **_rhos(best),
        )  # fmt: skip


def train(config: TrainConfig) -> TrainResult:
    """Train the network ``config.method`` of ``config.dataset`` and write the weights to ``config.out``
    (with the side files of :func:`~nbv_prob_cnn.completion.train_files.side_paths`).

    Raises:
        ValueError: a bad setting (naming it), no environment in a split, overlapping splits, or a
            checkpoint of another run configuration to resume.
    """
    run = _TrainingRun(_plan(config))
    finished = run.train_epochs()
    best, epochs_done = run.state.best, len(run.state.history)
    if not finished:
        rhos = _rhos(best, ("validation_rho", "validation_cell_rho"))
        return TrainResult.for_weights(run.plan.out, float(best["validation_mse"]), float("nan"), None, epochs_done,
                                       finished=False, **rhos)  # fmt: skip
    if run.plan.rank != 0:  # rank 0 scores the kept weights and writes the card
        return TrainResult.for_weights(run.plan.out, float(best["validation_mse"]), float("nan"), None, epochs_done)
    return run.score_kept()


def _rhos(best: dict, keys: Sequence[str] = ("validation_rho", "test_rho", "validation_cell_rho", "test_cell_rho")):
    """The City-CNN ρ fields of a :class:`TrainResult` from ``best`` (NaN where absent)."""
    return {key: float(best.get(key, float("nan"))) for key in keys}


def _rank_and_world() -> tuple[int, int]:
    """``(rank, world size)`` of the torch.distributed group (``(0, 1)`` outside one)."""
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


def _sum_over_workers(loss_sum: float, n_items: int) -> tuple[float, int]:
    totals = torch.tensor([loss_sum, float(n_items)], dtype=torch.float64)
    torch.distributed.all_reduce(totals)
    return float(totals[0]), int(totals[1])


def _from_rank0(value: float) -> float:
    tensor = torch.tensor([value], dtype=torch.float64)
    torch.distributed.broadcast(tensor, src=0)
    return float(tensor[0])


def _stopped_early(history: list[dict], best: dict, patience: int | None) -> bool:
    """True once ``patience`` epochs have passed since the best validation epoch."""
    return patience is not None and bool(history) and len(history) - int(best["epoch"]) >= patience


def _baselines(split: str, scores: CityScores) -> dict[str, float]:
    return {f"{split}_zero_mse": scores.zero_mse, f"{split}_mean_mse": scores.mean_mse}


def _fmt(history: list[dict]) -> str:
    return f"{history[-1]['validation_mse']:.4f}" if history else "-"
