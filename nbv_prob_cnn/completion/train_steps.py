"""One optimizer step of a network on a batch of examples, and the scores of a network on examples:
mean squared error (of the output times the mask, against the target), the all-zero and mean-target
baselines, and the calibration of the completion CNN's probabilities."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from nbv_prob_cnn.completion.calibration import Reliability, reliability
from nbv_prob_cnn.completion.data import TrainingSample
from nbv_prob_cnn.completion.model import CompletionNet
from nbv_prob_cnn.completion.tasks import Example, TrainingTask
from nbv_prob_cnn.completion.train_sources import fixed_examples


def _batch(examples: Sequence[Example], device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    def stack(name: str) -> torch.Tensor:
        return torch.as_tensor(np.stack([getattr(e, name) for e in examples]), dtype=torch.float32, device=device)

    return stack("inputs"), stack("target"), stack("mask")


def train_step(
    model: CompletionNet | torch.nn.parallel.DistributedDataParallel,
    optimizer: torch.optim.Optimizer,
    examples: Sequence[Example],
    device: torch.device,
) -> float:
    """One Adam step on examples of equal shape; returns the MSE of ``output · mask`` and the target."""
    model.train()
    x, target, mask = _batch(examples, device)
    optimizer.zero_grad(set_to_none=True)
    loss = torch.mean((model(x) * mask - target) ** 2)
    loss.backward()
    optimizer.step()
    return float(loss.detach())


def evaluate(model: CompletionNet, examples: Sequence[Example], device: torch.device, batch: int) -> float:
    """Mean per-example MSE of ``output · mask`` and the target (no gradient)."""
    return float(np.mean(per_example_outputs(model, examples, device, batch)[0])) if examples else float("nan")


def per_example_outputs(
    model: CompletionNet, examples: Sequence[Example], device: torch.device, batch: int
) -> tuple[list[float], list[np.ndarray]]:
    model.eval()
    losses, outputs = [], []
    with torch.inference_mode():
        for start in range(0, len(examples), batch):
            for group in same_shape_groups(examples[start : start + batch]):
                x, target, mask = _batch(group, device)
                out = model(x) * mask
                losses += ((out - target) ** 2).flatten(1).mean(dim=1).cpu().tolist()
                outputs += list(out.cpu().numpy())
    return losses, outputs


def same_shape_groups(examples: Sequence[Example]) -> list[list[Example]]:
    groups: dict[tuple, list[Example]] = {}
    for e in examples:
        groups.setdefault((e.inputs.shape, e.target.shape, e.mask.shape), []).append(e)
    return list(groups.values())


def zero_output_mse(examples: Sequence[Example]) -> float:
    """Mean per-example MSE of an all-zero output (as :func:`evaluate` scores a network): the
    trivial solution that sparse targets invite, the baseline a trained network must beat."""
    return float(np.mean([np.mean(e.target.astype(np.float64) ** 2) for e in examples])) if examples else float("nan")


def mean_masked_target(examples: Sequence[Example]) -> float:
    """Mean target over the output cells the masks keep."""
    kept = [np.broadcast_to(e.mask, e.target.shape) > 0 for e in examples]
    count = sum(int(k.sum()) for k in kept)
    return sum(float(e.target[k].sum()) for e, k in zip(examples, kept, strict=True)) / count if count else float("nan")


def start_at_mean_target(model: CompletionNet, examples: Sequence[Example]) -> float:
    """Set the final bias of a sigmoid gain head to the logit of the mean masked target of
    ``examples`` (clipped to [0.001, 0.5]); returns that mean. Typical gains differ by data set
    (2D about 0.1, 3DT crops about 0.006): a head starting far above them collapsed to the
    all-zero output (3DT ``flat_city_cnn`` from logit(0.1): validation MSE equal to the all-zero
    output's to seven digits)."""
    bias = model.final.bias
    if bias is None:
        raise ValueError("model: the final conv has no bias to start at the mean target")
    mean = mean_masked_target(examples)
    p = float(np.clip(mean, 1e-3, 0.5))
    with torch.no_grad():
        bias.fill_(float(np.log(p / (1.0 - p))))
    return mean


def calibration_of(
    model: CompletionNet, task: TrainingTask, samples: Sequence[TrainingSample], crop: int | None, device, batch: int
) -> Reliability:
    """Reliability of the completion CNN's probabilities on the unknown cells of ``samples``."""
    examples = fixed_examples(task, samples, crop)
    _, outputs = per_example_outputs(model, examples, device, batch)
    predicted, occupied = [], []
    for example, out in zip(examples, outputs, strict=True):
        unknown = (example.inputs[0] == 0) & (example.inputs[1] == 0)
        predicted.append(np.clip(out[0][unknown], 0.0, 1.0))
        occupied.append(example.target[0][unknown])
    return reliability(np.concatenate(predicted), np.concatenate(occupied))
