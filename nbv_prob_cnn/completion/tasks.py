"""What a network learns, for the one training loop of :mod:`nbv_prob_cnn.completion.train`:
the completion CNN (``cnn_prob``) or a City-CNN variant (``flat_city_cnn``, ``b_city_cnn``,
``d_city_cnn``). A task builds the network and turns a (rotated) grid, its ground truth and a
crop box into one example: network input, target and output mask (the loss is
``MSE(output · mask, target)``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from nbv_prob_cnn.basics.datasets import DatasetSpec
from nbv_prob_cnn.completion.model import CompletionNet, encode_state

#: Model names ``nbv train --method`` accepts (the ``weights`` of the registry's methods).
TRAINABLE_MODELS = ("cnn_prob", "flat_city_cnn", "b_city_cnn", "d_city_cnn")


@dataclass(frozen=True)
class Example:
    """One training/validation/test item (arrays without the batch axis)."""

    inputs: np.ndarray  # (2, *spatial) float32
    target: np.ndarray  # (C, *out_spatial) float32
    mask: np.ndarray  # broadcastable to target


@dataclass(frozen=True)
class TrainingTask:
    """A model name on a data set; ``backend`` is the ray-casting backend of City-CNN targets."""

    model: str
    spec: DatasetSpec
    backend: str = "auto"

    def __post_init__(self) -> None:
        if self.model not in TRAINABLE_MODELS:
            raise ValueError(f"method: no trainable model {self.model!r}; expected one of {TRAINABLE_MODELS}")

    @property
    def is_completion(self) -> bool:
        return self.model == "cnn_prob"

    @property
    def align(self) -> int:
        """Crop boxes start on multiples of this (the City-CNN output lattice)."""
        return 1 if self.is_completion else self.spec.city_output_stride

    def build(self, first_channels: int | None = None) -> CompletionNet:
        if self.is_completion:
            return CompletionNet(self.spec.dims, self.spec.n_conv, first_channels)
        from nbv_prob_cnn.planners.city_cnn import build_network

        return build_network(self.model, self.spec, first_channels)

    def encode(self, states: np.ndarray) -> torch.Tensor:
        """The network input of a batch of ternary grids ``(N, *spatial)``: the completion CNN's
        two channels, or the City-CNNs' empty and frontier grids."""
        if self.is_completion:
            return encode_state(states)
        from nbv_prob_cnn.planners.city_cnn import encode_city_input

        return encode_city_input(states)

    def example(self, state: np.ndarray, truth: np.ndarray, box: tuple[slice, ...]) -> Example:
        """The example of the crop ``box`` of a grid (City-CNN targets see the whole grid)."""
        if self.is_completion:
            return Example(
                self.encode(state[box][None])[0].numpy(),
                truth[box][None].astype(np.float32),
                np.ones((1,) * (state.ndim + 1), dtype=np.float32),
            )
        from nbv_prob_cnn.planners.city_cnn import CityGeometry, city_targets, output_mask

        inputs = self.encode(state[None])[0].numpy()[(slice(None), *box)]  # frontier of the whole grid
        target = city_targets(self.model, state, truth, self.spec, box, self.backend)
        mask = output_mask(CityGeometry.of(self.model, self.spec), state[box])[None]
        return Example(np.ascontiguousarray(inputs), target, mask)
